"""The one registry of agents: every driver of every environment, for either action type.

Every agent is built as ``make_agent(name, env, rng)`` and called as ``agent(obs) -> action`` in the
environment's own action space: a highway-env ``DiscreteMetaAction`` or ``ContinuousAction``
(normalised to ``[-1, 1]``), or a ``Box`` in physical units (``guardian/Overtake-v0``'s ``U_e``).

* ``random``: uniform in the action space (meta: one of the five actions);
* ``reckless``: meta: changes lanes whenever it can, alternating sides, else FASTER;
  continuous: full throttle, steering hard to one side then the other (2 s each);
* ``idle``: IDLE, or zero acceleration and steering;
* ``mpc``, ``bad``, ``careful``: the switched MPC drivers of Section 6.5.3 (``envs.mpc``) on the
  overtake state (``guardian/Overtake-v0``, or ``guardian/HighwayOvertake-v0`` with continuous actions).

``BASELINES`` are the four drivers of Section 6.5.3's experiment (``--driver all``).
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from envs.mpc import STYLES, MPCDriver


@runtime_checkable
class Agent(Protocol):
    """A driver: called once per step with the observation, returns an action of the env's space."""

    def __call__(self, obs): ...


def _kind(env) -> str:
    """``DiscreteMetaAction``, ``ContinuousAction`` (highway-env) or ``Box`` (physical units)."""
    action_type = getattr(env.unwrapped, "action_type", None)
    return type(action_type).__name__ if action_type is not None else "Box"


def _meta_names(env) -> list:
    return list(env.unwrapped.action_type.actions.values())


def _continuous(env, throttle: float, steer: float):
    """An action at fractions ``throttle, steer`` in ``[-1, 1]`` of the env's continuous range."""
    if _kind(env) == "ContinuousAction":
        return np.array([throttle, steer], dtype=np.float32)
    space = env.action_space
    mid, half = (space.high + space.low) / 2, (space.high - space.low) / 2
    return (mid + half * np.array([throttle, steer])).astype(space.dtype)


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
        return _continuous(self.env, 1.0, side)


class IdleAgent:
    def __init__(self, env, rng):
        self.env, self.kind = env, _kind(env)

    def __call__(self, obs):
        if self.kind == "DiscreteMetaAction":
            return _meta_names(self.env).index("IDLE")
        return np.clip(np.zeros(2), self.env.action_space.low, self.env.action_space.high).astype(
            self.env.action_space.dtype)


class MPCAgent:
    """A switched MPC driver of ``envs.mpc`` on the overtake state, in the env's continuous action."""

    def __init__(self, env, rng, style):
        base = env.unwrapped
        self.kind = _kind(env)
        overtake_env = self.kind == "Box" and hasattr(base, "params") and hasattr(base, "model")
        highway_overtake = self.kind == "ContinuousAction" and hasattr(base, "overtake_state")
        if not (overtake_env or highway_overtake):
            raise ValueError("the MPC drivers drive guardian/Overtake-v0, or guardian/HighwayOvertake-v0 "
                             "with --action continuous")
        self.base = base
        self.driver = MPCDriver(style, base.params)
        self.driver.reset()
        if self.kind == "ContinuousAction":
            at = base.action_type
            self.ranges = (np.asarray(at.acceleration_range, float), np.asarray(at.steering_range, float))

    def __call__(self, obs):
        if self.kind == "Box":
            return self.driver.act(obs)
        u = self.driver.act(self.base.overtake_state())
        out = [2 * (u[k] - r[0]) / (r[1] - r[0]) - 1 for k, r in enumerate(self.ranges)]
        return np.clip(np.array(out, dtype=np.float32), -1.0, 1.0)


def _mpc(style: str):
    return lambda env, rng: MPCAgent(env, rng, STYLES[style])


_FACTORIES = {"random": RandomAgent, "reckless": RecklessAgent, "idle": IdleAgent,
              **{name: _mpc(name) for name in STYLES}}
AGENTS = tuple(_FACTORIES)
BASELINES = ("mpc", "bad", "careful", "random")


def make_agent(name: str, env, rng: np.random.Generator) -> Agent:
    """The agent ``name`` for ``env``.

    Parameters
    ----------
    name : str
        One of ``AGENTS``.
    env : gymnasium.Env
        The environment it drives (wrappers allowed); its action space decides the action's form.
    rng : numpy.random.Generator
        The agent's own randomness (the rollout seeds it per episode).

    Returns
    -------
    Agent
        A callable ``agent(obs) -> action``.
    """
    if name not in _FACTORIES:
        raise ValueError(f"unknown agent {name!r}; choose from {', '.join(AGENTS)}")
    return _FACTORIES[name](env, rng)


def collision_fault(env, lateral_before: float | None = None, entered_responsibly=None) -> str | None:
    """None if the ego has not crashed; else "ego" or "other" (who hit whom).

    The ego is at fault if the car it hit is ahead of it (it rear-ended it), or if it was
    moving sideways towards that car: changing lanes towards its lane (highway-env's
    vehicles), or with ``lateral_before`` (its lateral position a step earlier) moving
    towards it (point masses) — unless ``entered_responsibly(lane_id)`` says the ego's
    entry into that car's lane was ρ̂-responsible when it began (ITHA: the car behind then
    answers for its own safety).

    Parameters
    ----------
    env : gymnasium.Env
        A highway-env environment, right after a step.
    lateral_before : float, optional
        The ego's lateral position a step earlier (point-mass egos).
    entered_responsibly : callable, optional
        ``entered_responsibly(lane_id) -> bool``.

    Returns
    -------
    str or None
        ``"ego"``, ``"other"``, or None when the ego has not crashed.
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
