"""The service decides as the in-process guardian does, to the bit: highway-env episodes where every decision of
every guarded car is also asked of a ``guardian serve`` scene session, over HTTP and over its stream.

Run: python benchmarks/service_equivalence.py [--episodes 100] [--settings highway-meta highway-continuous merge
                                              four-cars] [--first 0] [--workers 2] [--json]

Each episode drives the gymnasium wrapper (``guardian.wrappers.guardian.Guardian``) as every rollout does
(``guardian.evaluation.rollouts.make_env``; the seeding rule of ``run_episodes``). After each reset, every guarded
car's decision object is wrapped in two ``guardian.client.shadow.Shadow`` s: one asks a scene session over HTTP,
the other a second session over its WebSocket stream; meta agents' lane-change queries go to ``lane_change``.
The vehicle applies the in-process decision; each answer of the service is compared with it: the applied input
bit for bit, whether and how it changed it, the lanes, each lane-change verdict. Every decision must have been
asked (the counts are checked against the cars' own). The service runs as ``guardian serve --workers N`` in its
own process, so sessions are handed between workers as in use.

Prints per setting: episodes, decisions, lane-change queries, disagreements (0 expected), and the first few
disagreements if any. Exit status 1 when any disagreement or unasked decision was found.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = ("highway-meta", "highway-continuous", "merge", "four-cars")


def rollout(setting: str, agent: str):
    from guardian.config import GuardianConfig
    from guardian.evaluation.rollouts import Rollout

    if setting == "highway-meta":
        return Rollout("highway-v0", agent, action="meta")
    if setting == "highway-continuous":
        return Rollout("highway-v0", agent, action="continuous")
    if setting == "merge":
        return Rollout("merge-v0", agent)
    if setting == "four-cars":
        return Rollout("highway-v0", agent, action="meta", controlled=4, config=GuardianConfig(overapprox="ordered"))
    raise ValueError(f"unknown setting {setting!r}; choose from {', '.join(SETTINGS)}")


class ServiceProcess:
    """``guardian serve --port 0 --workers N`` in its own process; its URL read from its ``--json`` line."""

    def __init__(self, workers: int):
        cmd = [sys.executable, "-m", "guardian.cli", "serve", "--port", "0", "--json", "--workers", str(workers)]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, cwd=str(ROOT))
        lines = []
        while not lines or lines[-1] != "}":
            line = self.proc.stdout.readline()
            if not line:
                raise RuntimeError(f"guardian serve did not start (exit {self.proc.wait()})")
            lines.append(line.rstrip("\n"))
        self.url = json.loads("\n".join(lines))["url"]

    def wait_ready(self, client, timeout: float = 120.0) -> None:
        deadline = time.monotonic() + timeout
        while not client.ready().get("ready"):
            if time.monotonic() > deadline:
                raise RuntimeError("guardian serve never became ready")
            time.sleep(0.1)

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


class ShadowObserver:
    """A rollout observer: after each reset, every guarded car's decisions are also asked of the service (one
    HTTP session and one streamed session per car); at the episode's end the answers are tallied."""

    def __init__(self, client, config):
        from guardian.client.bodies import guardian_body

        self.client, self.options = client, guardian_body(config)
        self.open = []       # (car, http shadow, stream shadow, session, streamed session, stream)
        self.totals = {"episodes": 0, "decisions": 0, "http_steps": 0, "stream_steps": 0, "lane_changes": 0,
                       "unasked": 0, "disagreements": 0}
        self.examples = []

    def start_episode(self, env, episode: int, obs) -> None:
        from guardian.client.bodies import vehicle_body
        from guardian.client.shadow import Shadow

        self.episode = episode
        road = env.road
        for car in env.cars:
            guard = car.guard
            vehicle = vehicle_body(guard.kin, guard.meta)
            over_http = self.client.create_scene_session(road, vehicle, self.options)
            streamed = self.client.create_scene_session(road, vehicle, self.options)
            stream = streamed.stream()
            inner = Shadow(guard, over_http, road)
            outer = Shadow(inner, stream, road, lane_changes=streamed)
            car.guard = outer
            self.open.append((car, inner, outer, over_http, streamed, stream))

    def before_step(self, env, obs, action) -> None: ...

    def after_step(self, env, obs, action, info) -> None: ...

    def end_episode(self, env, episode: int) -> None:
        t = self.totals
        t["episodes"] += 1
        for car, inner, outer, over_http, streamed, stream in self.open:
            t["decisions"] += car.calls
            t["http_steps"] += inner.tally.steps
            t["stream_steps"] += outer.tally.steps
            t["lane_changes"] += inner.tally.lane_changes + outer.tally.lane_changes
            t["unasked"] += (car.calls - inner.tally.steps) + (car.calls - outer.tally.steps)
            for transport, shadow in (("http", inner), ("stream", outer)):
                for d in shadow.tally.disagreements:
                    t["disagreements"] += 1
                    if len(self.examples) < 10:
                        self.examples.append({"episode": episode, "car": car.index, "transport": transport,
                                              "index": d.index, "what": d.what, "local": d.local,
                                              "remote": d.remote})
            stream.close()
            over_http.close()
            streamed.close()
        self.open = []

    def close(self) -> None:
        for _, _, _, over_http, streamed, stream in self.open:
            for thing in (stream, over_http, streamed):
                try:
                    thing.close()
                except Exception:  # the episode failed; its sessions expire on their own
                    pass
        self.open = []


def run_setting(client, setting: str, episodes: int, seed: int, first: int, agent: str, progress=None) -> dict:
    from guardian.evaluation.episodes import run_episodes
    from guardian.evaluation.rollouts import make_env

    r = rollout(setting, agent)
    observer = ShadowObserver(client, r.config)
    started = time.perf_counter()
    run_episodes(make_env(r), agent, episodes, seed, [observer], progress, first=first)
    return {"setting": setting, "agent": agent, "seed": seed, "first_episode": first, **observer.totals,
            "seconds": round(time.perf_counter() - started, 1), "examples": observer.examples}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=SETTINGS)
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--first", type=int, default=0, help="start at episode FIRST of the seeding rule (pieces)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--agent", default="random")
    p.add_argument("--workers", type=int, default=2, help="guardian serve --workers")
    p.add_argument("--url", default=None, help="a running service instead of starting one")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from guardian.client import GuardianClient

    service = None if args.url else ServiceProcess(args.workers)
    url = args.url or service.url
    results = []
    try:
        with GuardianClient(url, timeout=60.0) as client:
            if service is not None:
                service.wait_ready(client)
            for setting in args.settings:
                def progress(done, total, setting=setting):
                    print(f"\r{setting}: {done}/{total} episodes", end="", file=sys.stderr, flush=True)
                results.append(run_setting(client, setting, args.episodes, args.seed, args.first, args.agent,
                                           progress))
                print(file=sys.stderr)
    finally:
        if service is not None:
            service.stop()
    if args.json:
        print(json.dumps({"workers": args.workers, "results": results}, indent=2))
    else:
        print(f"{'setting':20} {'episodes':>8} {'decisions':>10} {'http':>9} {'stream':>9} {'lane chg':>8} "
              f"{'unasked':>7} {'disagree':>8} {'s':>7}")
        for r in results:
            print(f"{r['setting']:20} {r['episodes']:8d} {r['decisions']:10d} {r['http_steps']:9d} "
                  f"{r['stream_steps']:9d} {r['lane_changes']:8d} {r['unasked']:7d} {r['disagreements']:8d} "
                  f"{r['seconds']:7.1f}")
            for e in r["examples"]:
                print("   ", e)
    bad = any(r["disagreements"] or r["unasked"] for r in results)
    return 1 if bad else 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    sys.exit(main())
