"""The drivers a guarded SUMO vehicle may have: each proposes ``[acceleration, steering]`` every step from its own body
and the others' bodies (``guardian.model.sensing.Sensed``, the road model's frame)."""
from __future__ import annotations

import math

import numpy as np

from guardian.errors import ConfigError

AGENTS = ("random", "reckless", "seek")


def agent_of(name: str, setting, rng: np.random.Generator):
    """A driver proposing ``[acceleration, steering]``; ``setting`` (a ``SumoSetting``) gives its bounds."""
    if name not in AGENTS:
        raise ConfigError(f"agent must be one of {', '.join(AGENTS)}, got {name!r}")
    amax, smax = setting.traffic.emergency_decel, setting.max_steering
    held = {"u": (0.0, 0.0), "left": 0}

    def random_agent(ego, others, t):
        if held["left"] <= 0:
            held["u"] = (float(rng.uniform(-amax, amax)), float(rng.uniform(-0.05, 0.05)))
            held["left"] = int(rng.integers(5, 20))
        held["left"] -= 1
        return held["u"]

    def reckless(ego, others, t):
        return amax, float(np.clip(0.05 * math.sin(t / 1.5) - 0.5 * ego.heading, -smax, smax))

    def seek(ego, others, t):
        ahead = [b for b in others if 0 < b.x - ego.x < 80]
        if not ahead:
            return amax, -0.5 * ego.heading
        target = min(ahead, key=lambda b: math.dist((b.x, b.y), (ego.x, ego.y)))
        bearing = math.atan2(target.y - ego.y, target.x - ego.x) - ego.heading
        return amax, float(np.clip(0.3 * bearing, -0.05, 0.05))

    return {"random": random_agent, "reckless": reckless, "seek": seek}[name]
