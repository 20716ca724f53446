"""The guardian's cost per simulation step beside the simulator's own step (issue 9: under 10 %).

Run: python benchmarks/bench_highway_guardian.py [--json] [--episodes N]

For each environment and action type, seeded episodes of a random agent run twice: without the
guardian (the simulator's own step, timed per simulation step) and with it (the guardian's
supervision, timed inside its per-simulation-step hook). Figures: median and p99 in ms, the
guardian's median as a share of the simulator's median simulation step, and a whole ``env.step``
(simulation, observation, reward) with and without the guardian.
"""
from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np

import envs  # noqa: F401
from envs.agents import make_agent
from guardian.rollout import OVERTAKE_ENV, highway_env_config
from guardian.wrapper import Guardian
from intention.library import build_library

CASES = [(OVERTAKE_ENV, "continuous"), (OVERTAKE_ENV, "meta"), ("highway-v0", "meta"), ("highway-v0", "continuous")]


def _timed_sim(env, episodes: int, guarded: bool):
    base_times, hook_times = [], []
    base = env.unwrapped
    original_simulate = base._simulate

    def timed_simulate(action=None):
        t = time.perf_counter()
        original_simulate(action)
        base_times.append((time.perf_counter() - t) / max(1, base.config["simulation_frequency"]
                                                           // base.config["policy_frequency"]))
    base._simulate = timed_simulate
    if guarded:
        for name in ("_supervise_overtake", "_supervise_highway"):
            original = getattr(env, name)

            def timed(*a, _f=original):
                t = time.perf_counter()
                _f(*a)
                hook_times.append(time.perf_counter() - t)
            setattr(env, name, timed)
    step_times = []
    for ep in range(episodes):
        obs, _ = env.reset(seed=ep)
        agent = make_agent("random", env, np.random.default_rng(ep))
        done = False
        while not done:
            action = agent(obs)
            t = time.perf_counter()
            obs, _, term, trunc, _ = env.step(action)
            step_times.append(time.perf_counter() - t)
            done = term or trunc
    env.close()
    return np.array(base_times), np.array(hook_times), np.array(step_times)


def bench(episodes: int) -> dict:
    library = build_library(quiet=True, workers=2)
    out = {}
    for env_id, action in CASES:
        cfg = highway_env_config(env_id, action, "cautious", "random", None, library)
        free, _, free_steps = _timed_sim(gym.make(env_id, config=cfg), episodes, False)
        _, hook, guarded_steps = _timed_sim(Guardian(gym.make(env_id, config=cfg), library), episodes, True)
        sim_ms = 1e3 * np.median(free)
        out[f"{env_id} {action}"] = {
            "sim_steps": int(len(hook)),
            "simulator_step_ms_median": round(sim_ms, 3),
            "env_step_ms_median": round(1e3 * np.median(free_steps), 3),
            "guarded_env_step_ms_median": round(1e3 * np.median(guarded_steps), 3),
            "guardian_ms_median": round(1e3 * np.median(hook), 3),
            "guardian_ms_p99": round(1e3 * np.percentile(hook, 99), 3),
            "guardian_share_of_sim_step": round(float(np.median(hook)) / float(np.median(free)), 3),
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--episodes", type=int, default=3)
    args = ap.parse_args()
    res = bench(args.episodes)
    if args.json:
        print(json.dumps(res, indent=2))
        return
    for k, v in res.items():
        print(f"{k:40s} sim step {v['simulator_step_ms_median']:.2f} ms | guardian median "
              f"{v['guardian_ms_median']:.3f} ms p99 {v['guardian_ms_p99']:.3f} ms | share "
              f"{100 * v['guardian_share_of_sim_step']:.1f} % | env.step {v['env_step_ms_median']:.2f} ms "
              f"-> {v['guarded_env_step_ms_median']:.2f} ms guarded")


if __name__ == "__main__":
    main()
