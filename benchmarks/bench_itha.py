"""Speed of the ITHA experiments and of the highway-env guardian.

Run: python benchmarks/bench_itha.py [--json] [--episodes N]
Targets (issue 4): Section 7.4.1 (25 runs x 500 steps, both over-approximations) under
2 minutes; the per-step cost of the highway-env guardian.
"""
from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np

from envs.highway_guard import HighwayGuardianWrapper
from itha.car_following import CarFollowingParams, load_or_build
from itha.highway import HighwayParams, highway_experiment


def bench_7_4_1() -> dict:
    t0 = time.perf_counter()
    S = load_or_build(CarFollowingParams())
    t_set = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = highway_experiment(25, 500, 0, S, HighwayParams())
    return {"set_seconds": round(t_set, 3), "experiment_seconds": round(time.perf_counter() - t0, 3),
            "steps": 2 * 25 * 500, "distance_mean": {k: round(v["distance_mean"], 1) for k, v in r.items()}}


def bench_highway_env(episodes: int) -> dict:
    out = {}
    for guarded in (False, True):
        env = gym.make("highway-v0")
        if guarded:
            env = HighwayGuardianWrapper(env)
            inner = {"interval": [], "lane_change": []}
            orig_interval, orig_lc = env._acceleration_interval, env._lane_change_responsible

            def timed_interval():
                t = time.perf_counter()
                r = orig_interval()
                inner["interval"].append(time.perf_counter() - t)
                return r

            def timed_lc(trig):
                t = time.perf_counter()
                r = orig_lc(trig)
                inner["lane_change"].append(time.perf_counter() - t)
                return r
            env._acceleration_interval, env._lane_change_responsible = timed_interval, timed_lc
        step_times = []
        rng = np.random.default_rng(0)
        for ep in range(episodes):
            env.reset(seed=ep)
            done = False
            while not done:
                t = time.perf_counter()
                _, _, term, trunc, _ = env.step(int(rng.integers(5)))
                step_times.append(time.perf_counter() - t)
                done = term or trunc
        env.close()
        key = "guarded" if guarded else "unguarded"
        out[key] = {"policy_steps": len(step_times), "policy_step_ms_median": round(1e3 * np.median(step_times), 2)}
        if guarded:
            iv, lc = np.array(inner["interval"]), np.array(inner["lane_change"])
            out[key]["acceleration_guard_ms_median"] = round(1e3 * np.median(iv), 3)
            out[key]["acceleration_guard_ms_p99"] = round(1e3 * np.percentile(iv, 99), 3)
            if len(lc):
                out[key]["lane_change_check_ms_median"] = round(1e3 * np.median(lc), 3)
                out[key]["lane_change_check_ms_p99"] = round(1e3 * np.percentile(lc, 99), 3)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--episodes", type=int, default=5, help="highway-v0 episodes per configuration")
    args = ap.parse_args()
    res = {"section_7_4_1": bench_7_4_1(), "highway_env": bench_highway_env(args.episodes)}
    if args.json:
        print(json.dumps(res, indent=2))
        return
    a = res["section_7_4_1"]
    print(f"7.4.1: 25 x 500 steps x 2 over-approximations in {a['experiment_seconds']:.1f} s "
          f"(set {a['set_seconds']:.2f} s); distances {a['distance_mean']}")
    for k, v in res["highway_env"].items():
        print(f"highway-v0 {k}: " + ", ".join(f"{kk}={vv}" for kk, vv in v.items()))


if __name__ == "__main__":
    main()
