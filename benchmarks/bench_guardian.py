"""Speed of one guardian step (the service: bench_service.py).

Run: python benchmarks/bench_guardian.py [--json]
Targets: one guardian step (estimator update, admissible set, override)
median < 1 ms, 99th percentile < 5 ms.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

import gymnasium as gym

import envs  # noqa: F401 - registers guardian/Overtake-v0
from envs.agents import make_agent
from guardian.decide.lead import IntentionAwareGuardian
from intention.library import build_library


def guardian_step_times(lib, use_intention: bool, episodes: int = 20) -> np.ndarray:
    env = gym.make("guardian/Overtake-v0", config={"intention": "cautious",
                                                    "initial_region": lib.region("bounded_velocity")})
    guard = IntentionAwareGuardian(lib, use_intention=use_intention)
    times = []
    for ep in range(episodes):
        obs, _ = env.reset(seed=ep)
        driver = make_agent("bad" if ep % 2 else "random", env, np.random.default_rng(ep))
        guard.reset()
        done = False
        while not done:
            u = env.unwrapped.action_type.get_action(driver(obs))
            u = [u["acceleration"], u["steering"]]
            t = time.perf_counter()
            applied, _ = guard.step(obs, u)
            times.append(time.perf_counter() - t)
            at = env.unwrapped.action_type
            unit = [2 * (applied[k] - r[0]) / (r[1] - r[0]) - 1 for k, r in enumerate((at.acceleration_range,
                                                                                      at.steering_range))]
            obs, _, term, trunc, _ = env.step(np.array(unit, dtype=np.float32))
            done = term or trunc
    return np.array(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    lib = build_library(quiet=True)
    out = {}
    for use in (True, False):
        t = guardian_step_times(lib, use)
        out["guardian_step_ms" + ("" if use else "_no_intention")] = {
            "median": float(np.median(t) * 1e3), "p99": float(np.percentile(t, 99) * 1e3), "steps": int(t.size)}
    if args.json:
        print(json.dumps(out, indent=2))
        return
    for k in ("guardian_step_ms", "guardian_step_ms_no_intention"):
        print(f"{k:32s} median {out[k]['median']:.3f} ms, p99 {out[k]['p99']:.3f} ms over {out[k]['steps']} steps "
              f"(target median < 1 ms, p99 < 5 ms)")


if __name__ == "__main__":
    main()
