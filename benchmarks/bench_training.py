"""Training DQN with the guardian: does the policy lean on the shield?

Run: python benchmarks/bench_training.py [--json] [--seeds 0 1] [--steps 5000] [--episodes 20]
                                         [--penalty 1.0] [--variants plain shielded relabelled] [--out DIR]

Trains stable-baselines3's DQN on ``highway-fast-v0`` (stock config: DiscreteMetaAction, Kinematics)
with highway-env's own DQN settings, the same seeds and the same number of steps for each variant:

* ``plain``: no guardian;
* ``shielded``: under the ``Guardian`` (default config: no penalty, the proposal stored);
* ``penalised``: under the ``Guardian`` with ``override_penalty``, the proposal stored (no relabelling);
* ``relabelled``: under the ``Guardian`` with ``override_penalty`` and ``guardian.integrations.sb3.ShieldedReplayBuffer``
  (the executed action stored with its reward, the overridden proposal with the penalised one).

Each trained policy is then run for ``--episodes`` seeded episodes (the same seeds for every policy)
without and with the guardian and tallied by the project's tally and fault judge
(``guardian.evaluation.tally.HighwayTally``, ``guardian.evaluation.judge``): return (the env's reward, no penalty), episodes
that crashed, at-fault crashes, distance, and the guardian's override rate (policy steps changed for
safety). Needs the ``rl`` extra: ``pip install 'guardian[rl]'``.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np

ENV_ID = "highway-fast-v0"
VARIANTS = ("plain", "shielded", "penalised", "relabelled")
# highway-env's DQN example (scripts/sb3_highway_dqn.py) with its exploration schedule
DQN_KWARGS = dict(policy_kwargs=dict(net_arch=[256, 256]), learning_rate=5e-4, buffer_size=15_000,
                  learning_starts=200, batch_size=32, gamma=0.8, train_freq=1, gradient_steps=1,
                  target_update_interval=50, exploration_fraction=0.7)


class TrainingLog(gym.Wrapper):
    """Counts what happened while training: episodes, crashed episodes, steps changed for safety."""

    def __init__(self, env):
        super().__init__(env)
        self.episodes = self.crashes = self.steps = self.overrides = 0

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.steps += 1
        self.overrides += int(bool(info.get("guardian", {}).get("safety_override")))
        if terminated or truncated:
            self.episodes += 1
            self.crashes += int(bool(info.get("crashed")))
        return obs, reward, terminated, truncated, info


class EpisodeReturn(gym.Wrapper):
    """The env's reward summed per episode."""

    def __init__(self, env):
        super().__init__(env)
        self.returns, self._ret = [], None

    def reset(self, **kwargs):
        if self._ret is not None:
            self.returns.append(self._ret)
        self._ret = 0.0
        return self.env.reset(**kwargs)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._ret += float(reward) + float(info.get("guardian", {}).get("penalty", 0.0))
        return obs, reward, terminated, truncated, info

    def close(self):
        if self._ret is not None:
            self.returns.append(self._ret)
            self._ret = None
        super().close()


def train(variant: str, seed: int, steps: int, penalty: float, out: Path) -> dict:
    import torch
    from stable_baselines3 import DQN

    from guardian import Guardian, GuardianConfig
    from guardian.integrations.sb3 import ShieldedReplayBuffer

    torch.set_num_threads(1)
    env = gym.make(ENV_ID)
    kwargs = dict(DQN_KWARGS)
    if variant != "plain":
        config = GuardianConfig(override_penalty=penalty if variant in ("penalised", "relabelled") else 0.0)
        env = Guardian(env, config=config)
    if variant == "relabelled":
        kwargs["replay_buffer_class"] = ShieldedReplayBuffer
    env = TrainingLog(env)
    t = time.perf_counter()
    model = DQN("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **kwargs)
    model.learn(total_timesteps=steps)
    path = out / f"dqn_{variant}_{seed}.zip"
    model.save(path)
    log = {"seconds": round(time.perf_counter() - t, 1), "episodes": env.episodes, "crashed_episodes": env.crashes,
           "override_rate": round(env.overrides / max(env.steps, 1), 3), "path": str(path)}
    if variant == "relabelled":
        log["relabelled"] = model.replay_buffer.relabelled
        log["proposals_stored"] = model.replay_buffer.proposals_stored
    env.close()
    return log


def evaluate(path: str, guardian: bool, episodes: int, seed: int) -> dict:
    from guardian import Guardian, GuardianConfig
    from guardian.evaluation.tally import HighwayTally
    from guardian.evaluation.episodes import run_episodes

    env = gym.make(ENV_ID)
    if guardian:
        env = Guardian(env)
    env = EpisodeReturn(env)
    tally = HighwayTally(env, guardian, GuardianConfig())
    run_episodes(env, f"policy:{path}", episodes, seed, [tally])
    r = tally.result(episodes)
    return {"return": round(float(np.mean(env.returns)), 2), "crashes": r["collisions"],
            "at_fault": r["ego_at_fault_collisions"] + r["ego_at_fault_after_outside_starts"],
            "starts_outside": r["starts_outside"], "distance": round(r["distance_mean"], 1),
            "override_rate": round(r["override_steps"] / r["steps"], 3) if guardian else None,
            "steps": r["steps"]}


def bench(variants, seeds, steps: int, episodes: int, penalty: float, out: Path, eval_seed: int) -> dict:
    rows = []
    total = len(variants) * len(seeds)
    for k, (variant, seed) in enumerate((v, s) for v in variants for s in seeds):
        print(f"[bench_training] training {variant} seed {seed} ({k + 1}/{total}) ...", file=sys.stderr, flush=True)
        log = train(variant, seed, steps, penalty, out)
        row = {"variant": variant, "seed": seed, "training": log}
        for guarded in (False, True):
            row["with_guardian" if guarded else "without_guardian"] = evaluate(log["path"], guarded, episodes,
                                                                               eval_seed)
        print(f"[bench_training] {variant} seed {seed}: {json.dumps(row)}", file=sys.stderr, flush=True)
        rows.append(row)
    return {"env": ENV_ID, "steps": steps, "seeds": list(seeds), "episodes": episodes, "penalty": penalty,
            "eval_seed": eval_seed, "dqn": {k: v for k, v in DQN_KWARGS.items()}, "rows": rows}


def table(res: dict) -> str:
    lines = [f"DQN on {res['env']}, {res['steps']} steps per run, seeds {res['seeds']}, penalty {res['penalty']}; "
             f"{res['episodes']} evaluation episodes per policy (seeds {res['eval_seed']}..)",
             "| trained | seed | train crashes | train overrides | evaluated | return | crashes | at fault | distance [m] "
             "| override rate |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in res["rows"]:
        t = r["training"]
        for key, name in (("without_guardian", "without guardian"), ("with_guardian", "with guardian")):
            e = r[key]
            rate = "-" if e["override_rate"] is None else f"{100 * e['override_rate']:.1f} %"
            lines.append(f"| {r['variant']} | {r['seed']} | {t['crashed_episodes']}/{t['episodes']} | "
                         f"{100 * t['override_rate']:.1f} % | {name} | {e['return']:.2f} | {e['crashes']}/{res['episodes']} "
                         f"| {e['at_fault']} | {e['distance']:.0f} | {rate} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--penalty", type=float, default=1.0)
    ap.add_argument("--eval-seed", type=int, default=1000)
    ap.add_argument("--variants", nargs="+", choices=VARIANTS, default=["plain", "shielded", "relabelled"])
    ap.add_argument("--out", type=Path, default=None, help="folder for the trained policies (default: a temporary one)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        res = bench(args.variants, args.seeds, args.steps, args.episodes, args.penalty, out, args.eval_seed)
    print(json.dumps(res, indent=2) if args.json else table(res))


if __name__ == "__main__":
    main()
