"""Many guarded cars on highway-env's on-ramp merge: trivial against ordered, beside Section 7.4.1.

Run: python benchmarks/bench_multiagent.py [--episodes E] [--n 2 4 8] [--density easy medium hard]
     [--agent merge] [--action meta] [--seed 0] [--no-unguarded] [--v0-search] [--json]

Every setting runs ``guardian rollout``'s loop (``guardian.evaluation.rollouts.highway_rollouts``) on ``guardian/Merge-v0``
(merge-v0's road: two main lanes and an on-ramp that ends) with N controlled cars among the on-ramp
merging reference's IDM traffic (easy 1-3, medium 2-4, hard 3-5 other cars; 20 s at 5 Hz, as there),
each controlled car with its own agent and its own guardian, for ``trivial`` (no guarded car assumes
anything of another) and ``ordered`` (guarded cars announce their lane changes in Example 8's order).
The same seeds for every setting. Traffic searches for the cars around it across lane segments
(guardian/Merge-v0's default); ``--v0-search`` gives merge-v0's search on one segment (traffic then may
not see a guarded car on the next segment: docs/roads.md). An unguarded row per (N, density) is beside (``--no-unguarded`` drops it).

Figures per setting, by ``HighwayTally.result``'s rules: episodes; mean distance per car and episode [m];
lane changes and merges completed (cars that began on the ramp and ended on the main road) out of
the cars that began on the ramp; policy steps overridden for safety (summed over the cars); collisions,
those at a guarded car's fault (the independent fault judge, ``guardian.evaluation.judge``) and those between two
guarded cars; failsafe simulation steps. Cost: the guardian's decision per guarded car per simulation
step (``Guardian._supervise_highway``: reading the scene and deciding; median and p99 in ms) beside the
simulator's own simulation step (median, all cars), timed in a separate short run of each setting.
Progress goes to stderr, one line per episode (a bar on a terminal).

The default agent is ``merge`` (on the ramp it asks for the main road, elsewhere for full speed): the
cars' wish to merge is what the two over-approximations treat differently.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings

import numpy as np

warnings.filterwarnings("ignore", message=".*out of date.*")
warnings.filterwarnings("ignore", message=".*not within the observation space.*")

ENV = "guardian/Merge-v0"
REFERENCE = {"duration": 20, "policy_frequency": 5}   # the merging reference's episodes
V0_SEARCH = False  # --v0-search: merge-v0's neighbour search (one lane segment)


# The built-in agents read the road, not the observation: the bench asks highway-env for a near-empty one
# (its Kinematics observation, normalised with pandas, is half the time of a step with N = 2). Nothing a
# car does depends on it: the figures are the same to the last digit either way.
BLIND_OBSERVATION = {"type": "AttributesObservation", "attributes": ["time"]}


def _config(density: str, agent: str = "merge") -> dict:
    extra = {"neighbour_vehicles_connected_lanes": False} if V0_SEARCH else {}
    if not agent.startswith("policy:"):
        extra["observation"] = BLIND_OBSERVATION
    return dict(REFERENCE, traffic=density, **extra)


def figures(n: int, density: str, overapprox: str | None, episodes: int, seed: int, agent: str, action: str) -> dict:
    from guardian.config import GuardianConfig
    from guardian.cli.progress import ProgressBar
    from guardian.evaluation.rollouts import Rollout, highway_rollouts

    guarded = overapprox is not None
    spec = Rollout(ENV, agent, action=action, controlled=n, guarded=guarded, env_config=_config(density, agent),
                   config=GuardianConfig(overapprox=overapprox or "trivial"))
    r = highway_rollouts(spec, episodes, seed, progress=ProgressBar(f"N={n} {density} {overapprox or 'unguarded'}"))
    return {"n": n, "density": density, "overapprox": overapprox or "unguarded", "episodes": episodes,
            "distance_per_car": r["distance_mean"], "lane_changes": r["lane_changes"], "merges": r["merges"],
            "on_ramp": r["on_ending_lane"], "override_steps": r["override_steps"], "collisions": r["collisions"],
            "at_fault": r["ego_at_fault_collisions"] + r["ego_at_fault_after_outside_starts"],
            "guarded_pairs": r["guarded_pair_collisions"], "starts_outside": r["starts_outside"],
            "failsafe_steps": r["failsafe_steps"], "unchecked_entries": r["unchecked_entries"],
            "reversing_uncovered": r["traffic_reversing_uncovered_steps"], "crashes": r["crashes"]}


def cost(n: int, density: str, overapprox: str, episodes: int, seed: int, agent: str, action: str) -> dict:
    """Median and p99 of the guardian's decision per guarded car per simulation step, and the simulator's step."""
    import gymnasium as gym

    import envs  # noqa: F401
    from envs.agents import make_agent
    from guardian.config import GuardianConfig
    from guardian.evaluation.rollouts import Rollout, highway_env_config
    from guardian.wrappers.guardian import Guardian

    config = highway_env_config(Rollout(ENV, agent, action=action, env_config=_config(density, agent), controlled=n))
    env = Guardian(gym.make(ENV, config=config), None, GuardianConfig(overapprox=overapprox))
    decide, sim = [], []
    supervision = env.supervision
    original = supervision._decide_one

    def timed(*a):
        t = time.perf_counter()
        out = original(*a)
        decide.append(time.perf_counter() - t)
        return out
    supervision._decide_one = timed
    for ep in range(episodes):
        obs, _ = env.reset(seed=seed + ep)
        road = env.unwrapped.road
        step = road.step

        def timed_step(dt, _f=step):
            t = time.perf_counter()
            _f(dt)
            sim.append(time.perf_counter() - t)
        road.step = timed_step
        act = make_agent(agent, env, np.random.default_rng([seed, ep]))
        done = False
        while not done:
            obs, _, term, trunc, _ = env.step(act(obs))
            done = term or trunc
    env.close()
    d, s = np.array(decide) * 1e3, np.array(sim) * 1e3
    return {"decision_median_ms": float(np.median(d)), "decision_p99_ms": float(np.percentile(d, 99)),
            "decisions": int(d.size), "simulation_step_median_ms": float(np.median(s))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    from envs.agents import AGENTS
    from envs.mpc import STYLES
    from envs.merge import TRAFFIC_MODES
    from guardian.cli.common import count

    p.add_argument("--episodes", type=count(1), default=20, help="episodes per setting (default 20)")
    p.add_argument("--cost-episodes", type=count(0), default=2,
                   help="episodes of the separate timed run per guarded setting; 0 skips the cost (default 2)")
    p.add_argument("--n", type=count(2), nargs="+", default=[2, 4, 8], help="guarded cars (default 2 4 8)")
    p.add_argument("--density", nargs="+", choices=tuple(TRAFFIC_MODES), default=list(TRAFFIC_MODES),
                   help="the reference's traffic modes (default all three)")
    p.add_argument("--agent", choices=[a for a in AGENTS if a not in STYLES], default="merge", help="every guarded car's agent (default merge)")
    p.add_argument("--action", choices=["meta", "continuous"], default="meta", help="action type (default meta)")
    p.add_argument("--seed", type=count(0), default=0, help="episode i resets with seed SEED + i (default 0)")
    p.add_argument("--no-unguarded", action="store_true", help="drop the unguarded row of each (N, density)")
    p.add_argument("--v0-search", action="store_true", help="merge-v0's neighbour search (one lane segment)")
    p.add_argument("--json", action="store_true", help="print the rows as JSON")
    p.add_argument("--merge", nargs="+", metavar="JSON", help="add up the --json outputs of runs in pieces by seed "
                   "(the same agent and action) instead of running")
    args = p.parse_args(argv)
    if args.merge:
        return _print_merged(args.merge, args.json)
    global V0_SEARCH
    V0_SEARCH = args.v0_search
    rows = []
    if not args.json:
        print(HEADER)
        print("|" + "---|" * HEADER.count(" |"))
    for n in args.n:
        for density in args.density:
            modes = ["trivial", "ordered"] + ([] if args.no_unguarded else [None])
            for mode in modes:
                t = time.perf_counter()
                row = figures(n, density, mode, args.episodes, args.seed, args.agent, args.action)
                row["seconds"] = round(time.perf_counter() - t, 1)
                if mode is not None and args.cost_episodes > 0:
                    row.update(cost(n, density, mode, args.cost_episodes, args.seed, args.agent, args.action))
                rows.append(row)
                if not args.json:
                    print(_line(row), flush=True)
    if args.json:
        json.dump({"agent": args.agent, "action": args.action, "seed": args.seed, "rows": rows}, sys.stdout, indent=1)
        print()
    return 0


SUMMED = ("episodes", "lane_changes", "merges", "on_ramp", "override_steps", "collisions", "at_fault", "guarded_pairs",
          "starts_outside", "failsafe_steps", "unchecked_entries", "reversing_uncovered", "seconds")


def merge(runs: list) -> dict:
    """The rows of runs in pieces by seed, added up per (N, density, over-approximation): counts summed, the
    distance per car weighted by episodes, each crash tagged with the ``--seed`` of its piece (its episode
    replays with ``guardian rollout ... --seed SEED --first-episode EPISODE``). The cost columns are not
    merged (they are timings of separate runs)."""
    kinds = {(r["agent"], r["action"]) for r in runs}
    if len(kinds) != 1:
        raise SystemExit(f"bench_multiagent --merge: the pieces ran different agents or actions: {sorted(kinds)}")
    if any(r.get("seed") is None for r in runs):
        raise SystemExit("bench_multiagent --merge: a piece has no seed (run it with --json)")
    rows: dict = {}
    for run in runs:
        for row in run["rows"]:
            key = (row["n"], row["density"], row["overapprox"])
            if key in rows and run["seed"] in rows[key]["seeds"]:
                raise SystemExit(f"bench_multiagent --merge: each piece of a setting needs its own --seed "
                                 f"({key} twice with seed {run['seed']})")
            crashes = [dict(c, seed=run["seed"]) for c in row["crashes"]]
            if key not in rows:
                rows[key] = {k: v for k, v in row.items() if k in SUMMED or k in ("n", "density", "overapprox")}
                rows[key].update(distance_per_car=row["distance_per_car"] * row["episodes"], crashes=crashes,
                                 seeds=[run["seed"]])
                continue
            total = rows[key]
            for k in SUMMED:  # None: not measured (unguarded rows have no guardian to count unchecked entries)
                if total[k] is None or row[k] is None:
                    total[k] = None
                else:
                    total[k] = round(total[k] + row[k], 1) if k == "seconds" else total[k] + row[k]
            total["distance_per_car"] += row["distance_per_car"] * row["episodes"]
            total["crashes"] += crashes
            total["seeds"].append(run["seed"])
    for total in rows.values():
        total["distance_per_car"] /= total["episodes"]
    return {"agent": runs[0]["agent"], "action": runs[0]["action"], "rows": list(rows.values())}


def _print_merged(paths: list, as_json: bool) -> int:
    runs = []
    for path in paths:
        with open(path) as f:
            runs.append(json.load(f))
    merged = merge(runs)
    if as_json:
        json.dump(merged, sys.stdout, indent=1)
        print()
        return 0
    print(HEADER)
    print("|" + "---|" * HEADER.count(" |"))
    for row in merged["rows"]:
        print(_line(row))
    return 0


HEADER = ("| N | density | over-approx. | episodes | distance/car [m] | lane changes | merges / on ramp | "
          "overrides | collisions | at fault | guarded pairs | failsafe steps | decision/car/step median (p99) [ms] "
          "| sim step [ms] |")


def _line(r: dict) -> str:
    cost_cell = (f"{r['decision_median_ms']:.2f} ({r['decision_p99_ms']:.2f})" if "decision_median_ms" in r else "-")
    sim = f"{r['simulation_step_median_ms']:.2f}" if "simulation_step_median_ms" in r else "-"
    return (f"| {r['n']} | {r['density']} | {r['overapprox']} | {r['episodes']} | {r['distance_per_car']:.1f} | "
            f"{r['lane_changes']} | {r['merges']} / {r['on_ramp']} | {r['override_steps']} | {r['collisions']} | "
            f"{r['at_fault']} | {r['guarded_pairs']} | {r['failsafe_steps']} | {cost_cell} | {sim} |")


if __name__ == "__main__":
    sys.exit(main())
