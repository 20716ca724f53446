"""The guardian's cost per simulation step beside the simulator's own step (target: under 10 %).

Run: python benchmarks/bench_highway_guardian.py [--json] [--episodes N] [--steps N] [--before REV]

``--before REV`` runs the same cases with the code of an older commit (a temporary git worktree put
first on ``PYTHONPATH``) in the same run, and prints its figures beside these. Target: the
guardian at most 5 % of the simulator's step on ``highway-v0`` defaults and on lanes_count=5,
vehicles_count=80.

For each environment and action type, seeded episodes of a random agent run twice: without the
guardian (the simulator's own step, timed per simulation step) and with it (the guardian's
supervision, timed inside its per-simulation-step hook). Figures: median and p99 in ms, the
guardian's median as a share of the simulator's median simulation step, and a whole ``env.step``
(simulation, observation, reward) with and without the guardian. Then the guarded/unguarded
``env.step`` ratio measured interleaved (``--steps`` policy steps, 200 by default: a guarded and an
unguarded env stepped one after the other, the order alternating), which the machine's drift between
the two runs above does not bias.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np

import envs  # noqa: F401
from envs.agents import make_agent
from guardian.evaluation.rollouts import OVERTAKE_ENV, Rollout, highway_env_config
from guardian.wrappers.guardian import Guardian
from intention.library import build_library
from intention.params import OvertakeParams

DENSE = {"lanes_count": 5, "vehicles_count": 80}  # the dense configuration
CASES = [(OVERTAKE_ENV, "continuous", None), (OVERTAKE_ENV, "meta", None), ("highway-v0", "meta", None),
         ("highway-v0", "continuous", None), ("highway-v0", "meta", DENSE), ("highway-v0", "continuous", DENSE),
         ("highway-fast-v0", "meta", None), ("highway-fast-v0", "continuous", None)]  # what RL users train on


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
        original = env._simulation_step   # the wrapper's per-simulation-step supervision of a guarded car

        def timed(*a, _f=original):
            t = time.perf_counter()
            out = _f(*a)
            hook_times.append(time.perf_counter() - t)
            return out
        env._simulation_step = timed
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


def _interleaved(env_id: str, cfg: dict, library, steps: int) -> dict:
    """``env.step`` with and without the guardian, one after the other (the order alternating) for
    ``steps`` policy steps of the same random agent, so that the machine's drift hits both alike."""
    free = gym.make(env_id, config=cfg)
    guarded = Guardian(gym.make(env_id, config=cfg), library)
    times = {"free": [], "guarded": []}
    envs_ = {"free": free, "guarded": guarded}
    state = {}
    for name, env in envs_.items():
        obs, _ = env.reset(seed=0)
        state[name] = [obs, make_agent("random", env, np.random.default_rng(0)), 0]
    for k in range(steps):
        for name in (("free", "guarded") if k % 2 == 0 else ("guarded", "free")):
            env, (obs, agent, episode) = envs_[name], state[name]
            action = agent(obs)
            t = time.perf_counter()
            obs, _, term, trunc, _ = env.step(action)
            times[name].append(time.perf_counter() - t)
            if term or trunc:
                episode += 1
                obs, _ = env.reset(seed=episode)
                agent = make_agent("random", env, np.random.default_rng(episode))
            state[name] = [obs, agent, episode]
    free.close()
    guarded.close()
    f, g = np.array(times["free"]), np.array(times["guarded"])
    return {"interleaved_steps": steps, "interleaved_env_step_ms_median": round(1e3 * np.median(f), 3),
            "interleaved_guarded_env_step_ms_median": round(1e3 * np.median(g), 3),
            "interleaved_step_ratio_median": round(float(np.median(g) / np.median(f)), 3),
            "interleaved_step_ratio_total": round(float(g.sum() / f.sum()), 3)}


def bench(episodes: int, steps: int = 200) -> dict:
    library = build_library(params=OvertakeParams.among_traffic(), quiet=True, workers=2)  # HighwayOvertake's
    out = {}
    for env_id, action, extra in CASES:
        cfg = highway_env_config(Rollout(env_id, "", action=action, library=library, env_config=extra or {}))
        free, _, free_steps = _timed_sim(gym.make(env_id, config=cfg), episodes, False)
        _, hook, guarded_steps = _timed_sim(Guardian(gym.make(env_id, config=cfg), library), episodes, True)
        sim_ms = 1e3 * np.median(free)
        name = f"{env_id} {action}" + (" lanes_count=5 vehicles_count=80" if extra else "")
        out[name] = {
            "sim_steps": int(len(hook)),
            "simulator_step_ms_median": round(sim_ms, 3),
            "env_step_ms_median": round(1e3 * np.median(free_steps), 3),
            "guarded_env_step_ms_median": round(1e3 * np.median(guarded_steps), 3),
            "guardian_ms_median": round(1e3 * np.median(hook), 3),
            "guardian_ms_p99": round(1e3 * np.percentile(hook, 99), 3),
            "guardian_share_of_sim_step": round(float(np.median(hook)) / float(np.median(free)), 3),
            **_interleaved(env_id, cfg, library, steps),
        }
    return out


def before(rev: str, episodes: int) -> dict:
    from worktree import checkout

    with checkout(rev) as tree:
        env = {**os.environ, "PYTHONPATH": str(tree)}
        out = subprocess.run([sys.executable, __file__, "--json", "--episodes", str(episodes)], env=env,
                             check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--episodes", type=int, default=3)
    ap.add_argument("--steps", type=int, default=200, help="policy steps of the interleaved step-ratio measurement")
    ap.add_argument("--before", default=None, help="an older commit to measure beside this checkout")
    args = ap.parse_args()
    res = bench(args.episodes, args.steps)
    if args.before:
        for k, v in before(args.before, args.episodes).items():
            res[f"before {args.before}: {k}"] = v
    if args.json:
        print(json.dumps(res, indent=2))
        return
    for k, v in res.items():
        ratio = "" if "interleaved_steps" not in v else (
            f" | interleaved ({v['interleaved_steps']} steps) guarded/unguarded step "
            f"{v['interleaved_step_ratio_median']:.3f}x median, {v['interleaved_step_ratio_total']:.3f}x total")
        print(f"{k:80s} sim step {v['simulator_step_ms_median']:.2f} ms | guardian median "
              f"{v['guardian_ms_median']:.3f} ms p99 {v['guardian_ms_p99']:.3f} ms | share "
              f"{100 * v['guardian_share_of_sim_step']:.1f} % | env.step {v['env_step_ms_median']:.2f} ms "
              f"-> {v['guarded_env_step_ms_median']:.2f} ms guarded{ratio}")


if __name__ == "__main__":
    main()
