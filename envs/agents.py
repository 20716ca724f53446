"""Agents that drive highway-env environments, for either action type, and the collision-fault rule.

Every agent is built as ``make_agent(name, env, rng)`` and called as
``agent(obs) -> action`` in the environment's own action space:

* ``random``: uniform in the action space (meta: one of the five actions);
* ``reckless``: meta: changes lanes whenever it can, alternating sides, else FASTER;
  continuous: full throttle, steering hard to one side then the other (2 s each);
* ``idle``: IDLE, or zero acceleration and steering;
* ``mpc``, ``bad``, ``careful`` (``HighwayOvertake-v0``, continuous only): the switched MPC
  drivers of Section 6.5.3 (``envs.drivers``) on the overtake state, mapped to the action's
  normalised range.
"""
from __future__ import annotations

import numpy as np

from envs.drivers import STYLES, MPCDriver

AGENTS = ("random", "reckless", "idle", "mpc", "bad", "careful")


def _kind(env) -> str:
    return type(env.unwrapped.action_type).__name__


def _meta_names(env) -> list:
    return list(env.unwrapped.action_type.actions.values())


class RandomAgent:
    def __init__(self, env, rng):
        self.space, self.rng, self.kind = env.action_space, rng, _kind(env)

    def __call__(self, obs):
        if self.kind == "DiscreteMetaAction":
            return int(self.rng.integers(self.space.n))
        return self.rng.uniform(self.space.low, self.space.high).astype(self.space.dtype)


class RecklessAgent:
    SWITCH_STEPS = 20  # continuous: steering side changes every this many steps

    def __init__(self, env, rng):
        self.env, self.rng, self.kind, self.t = env, rng, _kind(env), 0

    def __call__(self, obs):
        self.t += 1
        if self.kind == "DiscreteMetaAction":
            names = _meta_names(self.env)
            pick = ("LANE_LEFT", "LANE_RIGHT", "FASTER")[self.t % 3] if self.rng.uniform() < 0.9 else "FASTER"
            return names.index(pick)
        side = 1.0 if (self.t // self.SWITCH_STEPS) % 2 == 0 else -1.0
        return np.array([1.0, side], dtype=np.float32)


class IdleAgent:
    def __init__(self, env, rng):
        self.env, self.kind = env, _kind(env)

    def __call__(self, obs):
        if self.kind == "DiscreteMetaAction":
            return _meta_names(self.env).index("IDLE")
        return np.zeros(2, dtype=np.float32)


class MPCAgent:
    """A switched MPC driver of ``envs.drivers`` acting through a ``ContinuousAction``."""

    def __init__(self, env, rng, style):
        base = env.unwrapped
        if not hasattr(base, "overtake_state") or _kind(env) != "ContinuousAction":
            raise ValueError("the MPC drivers drive guardian/HighwayOvertake-v0 with --action continuous")
        self.base = base
        self.driver = MPCDriver(style, base.params)
        self.driver.reset()
        at = base.action_type
        self.ranges = (np.asarray(at.acceleration_range, float), np.asarray(at.steering_range, float))

    def __call__(self, obs):
        u = self.driver.act(self.base.overtake_state())
        out = [2 * (u[k] - r[0]) / (r[1] - r[0]) - 1 for k, r in enumerate(self.ranges)]
        return np.clip(np.array(out, dtype=np.float32), -1.0, 1.0)


def make_agent(name: str, env, rng: np.random.Generator):
    if name == "random":
        return RandomAgent(env, rng)
    if name == "reckless":
        return RecklessAgent(env, rng)
    if name == "idle":
        return IdleAgent(env, rng)
    if name in STYLES:
        return MPCAgent(env, rng, STYLES[name])
    raise ValueError(f"unknown agent {name!r}; choose from {', '.join(AGENTS)}")


def collision_fault(env, lateral_before: float | None = None, entered_responsibly=None) -> str | None:
    """None if the ego has not crashed; else "ego" or "other" (who hit whom).

    The ego is at fault if the car it hit is ahead of it (it rear-ended it), or if it was
    moving sideways towards that car: changing lanes towards its lane (highway-env's
    vehicles), or with ``lateral_before`` (its lateral position a step earlier) moving
    towards it (point masses) — unless ``entered_responsibly(lane_id)`` says the ego's
    entry into that car's lane was ρ̂-responsible when it began (ITHA: the car behind then
    answers for its own safety).
    """
    base = env.unwrapped
    ego = base.vehicle
    if not ego.crashed:
        return None
    others = [v for v in base.road.vehicles if v is not ego and v.crashed]
    if not others:
        return "ego"  # crashed into an object
    other = min(others, key=lambda o: np.linalg.norm(o.position - ego.position))
    if other.position[0] > ego.position[0]:
        return "ego"
    target = getattr(ego, "target_lane_index", ego.lane_index)
    if ego.lane_index[2] != target[2] and other.lane_index[2] in (target[2], other.target_lane_index[2]):
        return "ego"
    if lateral_before is not None:
        moved = float(ego.position[1]) - lateral_before
        if moved * (float(other.position[1]) - float(ego.position[1])) > 0:
            if entered_responsibly is not None and entered_responsibly(other.lane_index[2]):
                return "other"
            return "ego"
    return "other"
