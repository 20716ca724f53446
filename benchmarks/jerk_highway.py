"""What an actuator that cannot jump costs on highway-env: the guardian's override rate, the starts its sets
accept, and its promise, with the controlled car's actuator limited to a jerk of 10 and 5 m/s^3, a first-order lag
of 0.2 and 0.5 s, or both, beside today's (none).

The world is ``envs.actuator.Actuated`` (highway-env's Euler step, the acceleration held over a simulation step,
changed by at most ``jerk * dt`` from one to the next and, under a lag, moved only part of the way to the command,
the speed stopping at 0); the guardian reads the actuator and decides on ``itha.actuator.RateLimitedSet``. Per env x
action type x actuator, seeded episodes of the random driver (``guardian rollout --env ENV --agent random --action
ACTION [--jerk J] [--lag TAU] --episodes N --seed S`` each), with ``highway-v0`` cut to 15 s as the falsification
campaign does. Printed per row: the share of episodes whose start lies inside the sets (``1 - starts_outside /
episodes``), override steps per policy step, clips to the model (simulation steps), collisions, at a guarded car's
fault after a start inside, and simulation steps whose command the actuator could not follow (0 by construction
with the guardian). Then the share of random car-following states (speeds 0-30 m/s, gap 5-60 m, acceleration now
-5..5 m/s^2, dt 1/15 s) each set accepts.

    python benchmarks/jerk_highway.py [--episodes 10] [--seed 0] [--actuator NAME ...] [--json]
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from guardian.config import GuardianConfig
from guardian.evaluation.rollouts import Rollout, highway_rollouts
from itha.actuator import Actuator, RateLimitedSet
from itha.car_following import CarFollowingParams, MaximalSet

ENVS = (("highway-fast-v0", {}), ("highway-v0", {"duration": 15}))
ACTIONS = ("meta", "continuous")
ACTUATORS = {"none": (None, None), "jerk 10": (10.0, None), "jerk 5": (5.0, None), "lag 0.2": (None, 0.2),
             "lag 0.5": (None, 0.5), "jerk 10 lag 0.3": (10.0, 0.3)}   # name: (jerk [m/s^3], lag [s])


def rollouts(episodes: int, seed: int, names) -> list:
    rows = []
    for env, config in ENVS:
        for action in ACTIONS:
            for name in names:
                jerk, lag = ACTUATORS[name]
                t0 = time.perf_counter()
                r = highway_rollouts(Rollout(env, "random", action=action, env_config=config, jerk=jerk, lag=lag),
                                     episodes, seed)
                rows.append({"env": env, "action": action, "actuator": name, "jerk": jerk, "lag": lag,
                             "episodes": episodes,
                             "accepted_starts": 1 - r["starts_outside"] / episodes,
                             "override_rate": r["override_steps"] / r["steps"], "steps": r["steps"],
                             "model_clip_steps": r["model_clip_steps"], "collisions": r["collisions"],
                             "at_fault_after_inside": r["ego_at_fault_collisions"],
                             "actuator_clipped_steps": r["actuator_clipped_steps"],
                             "failsafe_steps": r["failsafe_steps"], "seconds": round(time.perf_counter() - t0, 1)})
                print(f"{env} {action} {name}: done", file=sys.stderr, flush=True)
    return rows


def accepted_states(samples: int, seed: int) -> dict:
    c = GuardianConfig()
    p = CarFollowingParams(dt=1 / 15, v_max=c.v_max, h_min=c.h_min, u_min=-c.traffic_accel, u_max=c.traffic_accel,
                           d_min=-c.traffic_accel, d_max=c.traffic_accel)
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(0, 30, samples), rng.uniform(5, 60, samples), rng.uniform(0, 30, samples),
                         rng.uniform(-c.traffic_accel, c.traffic_accel, samples)])
    out = {"none": float(np.mean(MaximalSet(p).contains(X[:, :3])))}
    for name, (jerk, lag) in list(ACTUATORS.items())[1:]:
        S = RateLimitedSet(p, Actuator(jerk=np.inf if jerk is None else jerk, lag=lag or 0.0, profile="hold"))
        out[name] = float(np.mean([S.contains(x) for x in X]))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--actuator", action="append", choices=list(ACTUATORS), default=None,
                    help="only these rows (repeatable; default all)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    result = {"rollouts": rollouts(args.episodes, args.seed, args.actuator or list(ACTUATORS)),
              "accepted_states": accepted_states(20000, args.seed)}
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    print("env              action      actuator         starts in  override/step  model clips  collisions  at fault  "
          "actuator clips  fail-safe")
    for r in result["rollouts"]:
        clips = "-" if r["actuator_clipped_steps"] is None else r["actuator_clipped_steps"]
        print(f"{r['env']:16} {r['action']:10} {r['actuator']:15}  {r['accepted_starts']:9.0%}  {r['override_rate']:13.1%}  "
              f"{r['model_clip_steps']:11}  {r['collisions']:10}  {r['at_fault_after_inside']:8}  {clips:>14}  "
              f"{r['failsafe_steps']:9}")
    print("random car-following states accepted:",
          ", ".join(f"{k} {v:.1%}" for k, v in result["accepted_states"].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
