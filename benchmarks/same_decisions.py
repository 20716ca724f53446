"""Does a change keep every decision? The recorded decisions of this tree against those of an older commit.

    python benchmarks/same_decisions.py --before REV [--only sumo|highway-env] [--json]
    python benchmarks/same_decisions.py --hash OUT.json [--only ...]    # this tree's hashes only

Not a speed figure: the check a restructuring or a speed-up must pass ("the same decisions"). Each run hashes what
the guardian decided at every step (sha256 of the JSON):

* sumo: 13 SUMO episodes (libsumo, the `sumo` extra): the straight, merge and exit roads x the random, reckless and
  SUMO drivers with one guarded vehicle, the random driver with three, and one merge-road episode also decided by a
  ``guardian serve`` scene session every step (the road and scenes over HTTP; its disagreements counted); every
  proposal, applied input and ``Decision``, every crash and every count of the episode;
* highway-env: 13 runs of two episodes (up to 40 policy steps) over every env family the guardian wraps (highway,
  highway-fast, merge-v0, guardian/Merge-v0 with one and two controlled cars, exit-v0, HighwayOvertake-v0; meta and
  continuous actions; random, seeking, line-hugging, brake-checking, oscillating and MPC drivers): every
  ``info["guardian"]``, reward and observation.

``--before REV`` checks REV out beside this tree (``worktree.checkout``), hashes both in fresh processes and prints
each run's verdict; the exit status is 1 when any run differs. About 5 minutes a tree on 2 idle cores.
"""
from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from worktree import ROOT, checkout

HIGHWAY_RUNS = [
    ("highway-fast-v0", "random", "meta", {}), ("highway-fast-v0", "seek", "continuous", {}),
    ("highway-fast-v0", "line", "continuous", {}), ("highway-v0", "brake_check", "continuous", {}),
    ("highway-v0", "random", "continuous", {"controlled": 3}), ("highway-v0", "seek", "meta", {"controlled": 2}),
    ("guardian/Merge-v0", "random", "continuous", {}), ("merge-v0", "seek", "meta", {}),
    ("guardian/Merge-v0", "random", "continuous", {"controlled": 2, "env_config": {"traffic": "medium"}}),
    ("exit-v0", "random", "continuous", {}), ("exit-v0", "oscillate", "meta", {}),
    ("guardian/HighwayOvertake-v0", "random", None, {}), ("guardian/HighwayOvertake-v0", "mpc", None, {}),
]


class _DecisionHash:
    """A SUMO recorder that hashes what it is given instead of drawing it."""

    def __init__(self):
        self.h, self.decisions = hashlib.sha256(), 0

    def start_episode(self, *_):
        self.h.update(b"|episode|")

    def step(self, t):
        self.h.update(repr(round(t, 6)).encode())

    def bodies(self, *_):
        pass

    def crash(self, crash):
        self.h.update(repr(sorted(crash.items())).encode())

    def close(self):
        pass

    def decision(self, name, proposed, applied, decision):
        self.decisions += 1
        self.h.update(repr((name, [float(x) for x in proposed], [float(x) for x in applied])).encode())
        if decision is not None:
            self.h.update(repr(decision).encode())


def _counts_json(counts: dict) -> bytes:
    """An episode's counts as hashed: every count but the crash list (hashed with the decisions) and the counts that
    were not measured (None): a count a newer tree adds as None (e.g. ``actuator_clipped`` without a jerk limit) is
    the same episode, while a count that turns None, or appears with a value, changes the hash."""
    kept = {k: v for k, v in counts.items() if k != "crashes" and v is not None}
    return json.dumps(kept, sort_keys=True, default=str).encode()


def sumo_hashes() -> dict:
    from guardian.adapters.sumo.network import HighwayNet, Traffic
    from guardian.evaluation.sumo import run_episode
    from guardian.evaluation.sumo_setting import SumoSetting

    # spelled out, not HighwayNet.of_road: the script runs against older trees too
    nets = {"straight": HighwayNet(), "merge": HighwayNet(ramp_at=1000.0), "exit": HighwayNet(exit_at=1000.0)}
    cells = list(itertools.product(("Krauss", "IDM", "EIDM"), (False, True)))
    out = {}
    for i, (road, agent) in enumerate(itertools.product(nets, ("random", "reckless", "sumo"))):
        car_following, sublane = cells[i % len(cells)]
        for guarded in (1, 3) if agent == "random" else (1,):
            setting = SumoSetting(net=nets[road], traffic=Traffic(car_following=car_following, sublane=sublane),
                                  guarded=guarded)
            hashed = _DecisionHash()
            counts = run_episode(setting, agent, 900 + i, recorder=hashed)
            hashed.h.update(_counts_json(counts))
            out[f"sumo {road} {agent} guarded {guarded}"] = {"steps": hashed.decisions, "sha256": hashed.h.hexdigest()}
            print(f"  {list(out)[-1]}: {hashed.decisions} decisions", file=sys.stderr, flush=True)
    out.update(_through_the_service(nets["merge"]))
    return out


def _through_the_service(net) -> dict:
    """One merge-road episode decided in process and, beside it, by a ``guardian serve`` scene session every step
    (``guardian sumo --through-service``): the road, the vehicle and the scenes go over HTTP, and the service's
    disagreements are counted into the hash."""
    import argparse

    from guardian.adapters.sumo.network import Traffic
    from guardian.cli.sumo import _service
    from guardian.evaluation.sumo import run_episode
    from guardian.evaluation.sumo_setting import SumoSetting

    hashed = _DecisionHash()
    with _service(argparse.Namespace(through_service=True)) as ask:
        counts = run_episode(SumoSetting(net=net, traffic=Traffic(car_following="IDM", sublane=True)), "random", 950,
                             recorder=hashed, ask=ask)
    hashed.h.update(_counts_json(counts))
    run = "sumo merge random guarded 1, through the service"
    print(f"  {run}: {hashed.decisions} decisions, {counts['service_disagreements']} disagreements", file=sys.stderr)
    return {run: {"steps": hashed.decisions, "disagreements": counts["service_disagreements"],
                  "sha256": hashed.h.hexdigest()}}


def _plain(o):
    import numpy as np

    if isinstance(o, np.ndarray):
        return o.round(9).tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    return repr(o)


def highway_hashes() -> dict:
    import numpy as np

    from envs.agents import make_agent
    from guardian.evaluation.rollouts import Rollout, make_env

    out = {}
    for env_id, agent, action, extra in HIGHWAY_RUNS:
        env = make_env(Rollout(env_id, agent, action=action, max_seconds=40, **extra))
        h, steps = hashlib.sha256(), 0
        for episode in range(2):
            obs, info = env.reset(seed=100 + episode)
            policy = make_agent(agent, env, np.random.default_rng(episode))
            h.update(json.dumps(info.get("guardian"), default=_plain, sort_keys=True).encode())
            for _ in range(40):
                obs, reward, terminated, truncated, info = env.step(policy(obs))
                steps += 1
                h.update(json.dumps([info.get("guardian"), float(reward), np.asarray(obs).round(9).tolist()],
                                    default=_plain, sort_keys=True).encode())
                if terminated or truncated:
                    break
        env.close()
        out[f"highway-env {env_id} {agent} {action} {extra}"] = {"steps": steps, "sha256": h.hexdigest()}
        print(f"  {list(out)[-1]}: {steps} steps", file=sys.stderr, flush=True)
    return out


def hash_tree(tree: Path, only, out: Path) -> dict:
    """This script's ``--hash`` run with ``tree`` first on the path, in a fresh process."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--hash", str(out)] + (["--only", only] if only else [])
    subprocess.run(cmd, check=True, env=env, cwd=tempfile.gettempdir())
    return json.loads(out.read_text())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", metavar="REV", help="the commit to compare with")
    ap.add_argument("--hash", type=Path, metavar="OUT", help="write this tree's hashes to OUT and stop")
    ap.add_argument("--only", choices=("sumo", "highway-env"))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if (args.before is None) == (args.hash is None):
        ap.error("give --before REV or --hash OUT")
    if args.hash is not None:
        hashes = {}
        if args.only in (None, "sumo"):
            hashes.update(sumo_hashes())
        if args.only in (None, "highway-env"):
            hashes.update(highway_hashes())
        args.hash.write_text(json.dumps(hashes, indent=1))
        return 0
    with tempfile.TemporaryDirectory() as tmp, checkout(args.before) as old:
        print(f"hashing {args.before}", file=sys.stderr)
        before = hash_tree(old, args.only, Path(tmp) / "before.json")
        print("hashing this tree", file=sys.stderr)
        now = hash_tree(ROOT, args.only, Path(tmp) / "now.json")
    verdicts = {run: {"same": before.get(run) == now.get(run), "before": before.get(run), "now": now.get(run)}
                for run in sorted(set(before) | set(now))}
    if args.json:
        print(json.dumps(verdicts, indent=1))
    else:
        for run, v in verdicts.items():
            print(f"{'same     ' if v['same'] else 'DIFFERENT'} {run}")
        print(f"{sum(v['same'] for v in verdicts.values())} of {len(verdicts)} runs decide as before")
    return 0 if all(v["same"] for v in verdicts.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
