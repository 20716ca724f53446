"""The guardian's decisions on seeded highway-v0-family episodes, recorded for a bit-for-bit regression test.

``tests/support/data/highway_decisions.json`` is written by ``python tests/support/highway_decisions.py --write``. The test
(``tests/guardian/evaluation/test_highway_regression.py``) replays the same episodes and compares every applied input (each
simulation step, exact floats) and every policy step's decision fields with the file: a change that alters
any decision on the straight road fails it, and is made on purpose, with the file written again and the
reason in the commit.

The applied inputs are read from the vehicle itself (``Vehicle.step`` is wrapped), not from the guardian's
internals, so the recording does not depend on how the guardian is organised.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

FIXTURE = Path(__file__).parent / "data" / "highway_decisions.json"
FIELDS = ("applied_action", "level", "refused_lane_change", "entered", "lanes", "overridden", "safety_override",
          "in_invariant_set", "changed", "sim_steps", "failsafe_steps", "follower_dropped_steps")

# (env, agent, action, env config, seed)
EPISODES = (
    ("highway-v0", "random", "meta", {"vehicles_count": 20, "duration": 15}, 3),
    ("highway-v0", "reckless", "meta", {"vehicles_count": 20, "duration": 15}, 10),
    ("highway-v0", "random", "continuous", {"vehicles_count": 20, "duration": 15}, 1),
    ("highway-v0", "reckless", "continuous", {"vehicles_count": 20, "duration": 15}, 10),
    ("highway-fast-v0", "trap", "continuous", {"vehicles_density": 2.5, "duration": 15}, 7),
    ("highway-fast-v0", "brake_check", "meta", {"lanes_count": 1, "vehicles_density": 2.5, "duration": 15}, 5),
    ("highway-v0", "oscillate", "continuous", {"vehicles_count": 20, "duration": 8, "policy_frequency": 5}, 2),
    ("highway-fast-v0", "seek", "meta", {"vehicles_density": 2.5, "duration": 15}, 4),
)


def record(env_id: str, agent: str, action: str, config: dict, seed: int) -> dict:
    """One episode as the guardian decided it: ``{"inputs": [[a, steering], ...], "steps": [{field: ...}]}``."""
    import gymnasium as gym
    import highway_env  # noqa: F401
    from highway_env.vehicle.kinematics import Vehicle

    from envs.agents import make_agent
    from guardian.evaluation.rollouts import ACTIONS
    from guardian.wrappers.guardian import Guardian

    env = Guardian(gym.make(env_id, config={**config, "action": dict(ACTIONS[action])}))
    inputs = []
    original = Vehicle.step

    def step(vehicle, dt):
        if vehicle is env.unwrapped.vehicle:
            inputs.append([float(vehicle.action["acceleration"]), float(vehicle.action["steering"])])
        return original(vehicle, dt)

    Vehicle.step = step
    try:
        obs, _ = env.reset(seed=seed)
        act = make_agent(agent, env, np.random.default_rng([seed, 0]))
        steps, done = [], False
        while not done:
            obs, _, terminated, truncated, info = env.step(act(obs))
            g = info["guardian"]
            steps.append({k: g[k] for k in FIELDS})
            done = terminated or truncated
    finally:
        Vehicle.step = original
        env.close()
    return {"inputs": inputs, "steps": json.loads(json.dumps(steps, default=lambda o: o.item()))}


def record_all() -> list:
    return [{"episode": [env_id, agent, action, config, seed], **record(env_id, agent, action, config, seed)}
            for env_id, agent, action, config, seed in EPISODES]


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit("usage: python tests/support/highway_decisions.py --write   (only with the code the fixture pins)")
    FIXTURE.write_text(json.dumps(record_all()) + "\n")
    print(f"wrote {FIXTURE}")
