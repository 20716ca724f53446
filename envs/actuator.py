"""A world whose controlled cars cannot change their acceleration at once: highway-env's vehicles behind an
actuator with a jerk limit, a first-order lag, or both.

``Actuated(env, actuator)`` fits every controlled vehicle (highway-env's ``controlled_vehicles``) at each reset with
``actuator`` (an ``itha.actuator.Actuator`` of profile "hold", no delay): over each simulation step the vehicle
applies ``actuator.follows(last, asked, dt)``: the acceleration asked, moved only part of the way there under a
lag (the lag's response sampled each step), limited to within ``jerk * dt`` of the one it applied over the step
before (starting from 0 at the reset); its speed stops at 0 (it never reverses). Everything else is highway-env's
``Vehicle.step``. ``JerkLimit(env, jerk)`` is the jerk bound alone. The vehicle declares the actuator
(``vehicle.actuator``) and the acceleration it applied (``vehicle.applied_acceleration``); the ``Guardian``
reads both and asks only for what the actuator reaches. A crashed car is braked by highway-env itself
(``Vehicle.clip_actions``), not through the actuator. Every other simulation step whose command the jerk bound
cut (the lag's response to it, or the command itself without a lag, beyond ``jerk dt`` of the last acceleration;
under a lag, beyond rounding: ``Actuator.response``) is counted (``info["actuator"]["clipped_steps"]`` per policy step): a
guarded car's count is 0 by construction, and a nonzero one is a defect of the guardian. A lag is not a clip: the
command is followed the way the lag follows it.

Wrap the world before the guardian: ``Guardian(Actuated(env, actuator))``.
"""
from __future__ import annotations

import math

import gymnasium as gym
from highway_env.envs.common.abstract import AbstractEnv

from guardian.errors import ConfigError
from itha.actuator import Actuator


class _LimitedStep:
    """A vehicle's ``step`` behind the actuator (set on the vehicle, in front of its class's ``step``)."""

    def __init__(self, world: "Actuated", vehicle):
        self.world, self.vehicle = world, vehicle
        self.original = type(vehicle).step.__get__(vehicle)

    def __call__(self, dt: float) -> None:
        v = self.vehicle
        if v.crashed:   # highway-env brakes a crashed car itself (Vehicle.clip_actions): no actuator is modelled
            self.original(dt)
            v.applied_acceleration = float(v.action["acceleration"])
            return
        asked, last, actuator = float(v.action["acceleration"]), v.applied_acceleration, self.world.actuator
        applied, cut = actuator.response(last, asked, dt)
        if cut:
            self.world.clipped += 1
        v.action["acceleration"] = applied
        moving = v.speed >= 0.0
        self.original(dt)
        if moving and v.speed < 0.0:
            v.speed = 0.0
        v.applied_acceleration = float(v.action["acceleration"])
        v.action["acceleration"] = asked   # the command stands as given (a plain Vehicle keeps it for the next step)


class Actuated(gym.Wrapper):
    """highway-env's roads with the controlled vehicles behind an actuator (see the module docstring).

    Parameters
    ----------
    env : gymnasium.Env
        A highway-env environment of the roads family (not the overtake scenarios, whose ego has its own
        dynamics), not yet wrapped in a ``Guardian``.
    actuator : itha.actuator.Actuator
        Profile "hold" (the acceleration held over a simulation step), no delay, a finite jerk bound or a lag.
    """

    def __init__(self, env: gym.Env, actuator: Actuator):
        super().__init__(env)
        from envs.highway_overtake import HighwayOvertakeEnv
        from guardian.wrappers.guardian import Guardian

        name = type(self).__name__
        base = env.unwrapped
        if not isinstance(base, AbstractEnv):
            raise ConfigError(f"{name}: {type(base).__name__} is not a highway-env environment")
        if isinstance(base, HighwayOvertakeEnv):
            raise ConfigError(f"{name}: the overtake scenarios' ego has its own dynamics and sets; an actuator is "
                              "supported on highway-env's roads")
        inner = env
        while isinstance(inner, gym.Wrapper):
            if isinstance(inner, Guardian):
                raise ConfigError(f"{name}: wrap the world before the guardian: Guardian({name}(env, ...))")
            inner = inner.env
        if not isinstance(actuator, Actuator):
            raise ConfigError(f"{name}: the actuator must be an itha.actuator.Actuator, got {actuator!r}")
        if actuator.profile != "hold" or actuator.delay:
            raise ConfigError(f"{name}: highway-env's vehicles hold an acceleration over a simulation step: declare "
                              f"Actuator(profile=\"hold\") without a delay, got {actuator}")
        if math.isinf(actuator.jerk) and not actuator.lag:
            raise ConfigError(f"{name}: the actuator limits nothing (no jerk bound, no lag): leave the world as it is")
        self.actuator = actuator
        self.clipped = 0   # simulation steps whose command the jerk bound cut, since the last count

    def _fit(self) -> None:
        for vehicle in self.env.unwrapped.controlled_vehicles:
            if vehicle.__dict__.get("actuator") is not self.actuator:
                vehicle.actuator = self.actuator
                vehicle.applied_acceleration = 0.0
                vehicle.step = _LimitedStep(self, vehicle)

    def _report(self) -> dict:
        jerk = self.actuator.jerk
        out = {"jerk": None if math.isinf(jerk) else jerk, "lag": self.actuator.lag, "clipped_steps": self.clipped}
        self.clipped = 0
        return out

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.clipped = 0
        self._fit()
        info["actuator"] = self._report()
        return obs, info

    def step(self, action):
        self._fit()
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["actuator"] = self._report()
        self._fit()
        return obs, reward, terminated, truncated, info


class JerkLimit(Actuated):
    """``Actuated`` with a jerk bound alone: ``jerk`` [m/s^3], positive and finite."""

    def __init__(self, env: gym.Env, jerk: float):
        if not (isinstance(jerk, (int, float)) and math.isfinite(jerk) and jerk > 0):
            raise ConfigError(f"JerkLimit: the jerk bound must be a positive finite number [m/s^3], got {jerk!r}")
        super().__init__(env, Actuator(jerk=float(jerk), profile="hold"))
