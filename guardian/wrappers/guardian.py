"""The guardian: one gymnasium wrapper between any highway-env agent and the vehicle.

The wrapper decides nothing. Every simulation step (highway-env calls the ego's ``act(None)`` once
per simulation step, after the policy step's ``act(action)``) the scenario's supervision
(``guardian.adapters.highway_env.supervision``) reads the state, asks the decision object and applies its
answer to the vehicle; the wrapper keeps the record (``guardian.wrappers.record``):

* ``guardian/HighwayOvertake-v0``: ``guardian.decide.overtake.PointMassGuardian`` (the lead part of
  Chapter 6 composed with ITHA; the composed invariant set is explained there);
* highway-env's roads (the ``highway-v0`` family, ``merge-v0``, ``merge-generic-v0``, ``exit-v0``):
  ``guardian.decide.bicycle.BicycleGuardian`` (ITHA for highway-env's bicycle) on the road
  ``guardian.adapters.highway_env.road`` reads (one straight road, or a ``guardian.model.roads.RoadMap``
  with on-ramps, exits and lanes that end).

**Many guarded cars.** With highway-env's ``MultiAgentAction`` every controlled car gets its own decision
object and model monitor (one object per car, nothing shared but the road they read), and each sees the
others as traffic. With ``GuardianConfig.overapprox = "ordered"`` the guarded cars announce their
triggering actions to each other in Example 8's order (``itha.road.example8_order``: ahead first, on ties
the slower lane first), at every policy step (meta lane changes) and every simulation step (the lanes
each may occupy); a car decides knowing what the cars before it announced, and the cars after it yield
(they answer for themselves). With ``trivial`` no car assumes anything of another. Uncontrolled
(IDM) cars announce nothing. ``info["guardian"]`` then holds one record per car (``"agents"``) and their
sum (below).

Supervision is never lost silently: every ``step`` checks that the env's ego is the vehicle the
guardian is attached to; an ego that was reset or replaced behind the guardian's back (an inner
``Autoreset``, an env reset before wrapping, ``configure`` then reset) is re-attached, the road and
frequencies are read again and the record says so (``reattached``). Simulation steps the hook did
not see are counted (``unsupervised_steps``).

``info["guardian"]`` (the key is asserted free)::

    {"proposed": [a, lateral] | "LANE_LEFT" ...,  # the agent's action (decoded for continuous agents)
     "applied": [a, lateral] | "IDLE" ...,         # the input of the last simulation step; meta: the action
                                                   # executed over the policy step (applied_action's name)
     "applied_action": int | [float, ...],        # the policy step as an action of the env's space
     "applied_mean": [a, lateral], "applied_range": [[lo, hi], [lo, hi]],   # over the simulation steps
     "overridden": bool,               # any change to the agent's action
     "safety_override": bool,          # a change for safety (not only a clip to the model's bounds)
     "changed": "none" | "throttle" | "steering" | "both" | "lane_change" | "conflict" | "failsafe",
     "level": "composed" | "follower_dropped" | "conflict" | "failsafe",   # the worst of the step
     "reasons": [str, ...],
     "refused_lane_change": bool, "entered": [lane, ...],   # lanes begun this step (each checked, responsible)
     "lanes": [lane, ...],            # lanes the body was allowed to overlap (held at the step's start, or entered responsibly)
     "active_set": "aggressive" | "cautious" | "bounded_velocity" | "itha",
     "valid_intentions": [str, ...], "identified": str | None,
     "in_invariant_set": bool,         # the state lay in the composed invariant set (first simulation step)
     "sim_steps": int, "clipped_steps": int, "model_clip_steps": int,
     "follower_dropped_steps": int, "conflict_steps": int,
     "failsafe_steps": int, "unsupervised_steps": int, "reattached": bool,
     "model_violations": {"ego": int, "lead": int, "traffic": int,   # simulation steps (guardian.adapters.highway_env.monitor)
                          "traffic_blind": int, "traffic_reversing_uncovered": int},
     "admissible_acceleration": [[lo, hi], ...],   # at the applied lateral input, last simulation step
     "admissible_lateral": [[lo, hi], ...]}        # at the applied acceleration (overtake scenarios)

and at reset ``{"enabled", "scenario", "action", "start_inside", "start_attempts"}``. With
``GuardianConfig.override_penalty``, a step with a safety override also has ``"penalty"`` (subtracted
from the reward).

With several guarded cars ``info["guardian"]`` is::

    {"agents": [record, ...],            # each car's record, as above (in highway-env's controlled order)
     "controlled": int, "overapprox": "trivial" | "ordered",
     "order": [int, ...],                 # the announcing order of the last simulation step (car numbers)
     "applied_action": (action, ...),     # the policy step as an action of the MultiAgentAction's space
     "overridden", "safety_override", "refused_lane_change", "reattached": bool,   # any car
     "level": str,                        # the worst of the cars
     "reasons": ["car 0: ...", ...],
     "sim_steps": int,                    # the policy step's simulation steps
     "clipped_steps", "model_clip_steps", "follower_dropped_steps", "conflict_steps", "failsafe_steps",
     "unsupervised_steps": int,           # summed over the cars
     "model_violations": {"ego": int, "lead": 0, "traffic": int, "traffic_blind": int,
                          "traffic_reversing_uncovered": int}}
                                          # summed (traffic, traffic_reversing_uncovered: car 0's monitor;
                                          # traffic_blind: each car's)

(``"penalty"`` is the penalty times the number of cars overridden for safety), and at reset
``{"enabled", "scenario", "action", "controlled", "start_inside" (all cars), "agents_start_inside",
"start_attempts"}``.
"""
from __future__ import annotations

import os

import gymnasium as gym
import numpy as np
from highway_env.envs.common.abstract import AbstractEnv

from envs.highway_overtake import HighwayOvertakeEnv
from guardian.adapters.highway_env.checks import (check_action, check_env, controlled_action_types,
                                                  controlled_vehicles, multi_agent)
from guardian.adapters.highway_env.supervision import META, OvertakeSupervision, RoadSupervision
from guardian.config import GuardianConfig
from guardian.errors import ConfigError
from guardian.wrappers.cars import GuardedCar, Hook, hooked_by
from guardian.wrappers.record import CarRecord, FleetRecord, penalised

__all__ = ["Guardian", "GuardianConfig"]

REATTACHED_INSIDE = "the env was reset inside the step; re-attached to the new ego"
REATTACHED_BEHIND = "the ego was reset or replaced behind the guardian's back (or before it wrapped the env); re-attached"


class Guardian(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Supervises the ego of ``guardian/Overtake-v0``, ``guardian/HighwayOvertake-v0`` or a
    ``highway-v0``-family environment.

    Parameters
    ----------
    env : gymnasium.Env
        The environment (possibly wrapped); its ``unwrapped`` is a highway-env ``AbstractEnv``.
    library : intention.library.OvertakeLibrary, optional
        The overtake RCIS library (the lead part of the overtake scenarios); by default it is loaded
        from the set cache, or built there, for the env's parameters. Unused elsewhere.
    config : GuardianConfig, optional
    """

    def __init__(self, env: gym.Env, library=None, config: GuardianConfig | None = None):
        # recorded as given (env.spec): the library's sets are read-only and large, the config is frozen
        gym.utils.RecordConstructorArgs.__init__(self, library=library, config=config, _disable_deepcopy=True)
        super().__init__(env)
        config = GuardianConfig() if config is None else config
        inner = env
        while isinstance(inner, gym.Wrapper):
            if isinstance(inner, Guardian):
                raise ConfigError("Guardian: the env is already wrapped in a Guardian; wrap it once")
            inner = inner.env
        base = env.unwrapped
        if not isinstance(base, AbstractEnv):
            raise ConfigError(f"Guardian: {type(base).__name__} is not a highway-env environment")
        if not isinstance(config, GuardianConfig):
            raise ConfigError(f"Guardian: config must be a GuardianConfig, got {type(config).__name__}")
        if getattr(env, "render_mode", None) == "rgb_array":  # SDL's offscreen driver: no display looked for
            os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
        self.config = config
        if isinstance(base, HighwayOvertakeEnv):
            self.supervision = OvertakeSupervision(base, library, config)
        else:
            self.supervision = RoadSupervision(config)
        self.scenario = self.supervision.name
        self.kind = check_env(base)
        self.cars = []              # the guarded cars (GuardedCar), in highway-env's controlled order
        self.last_record = None     # the first car's record of the last policy step (the panel's)
        if self.scenario == "overtake" or base.road is not None:
            # refuse a bad road, library or configuration now, not at the first reset
            self.supervision.decision_objects(base, self.kind, len(controlled_action_types(base)))

    @property
    def library(self):
        return getattr(self.supervision, "library", None)

    @property
    def road(self):
        return self.supervision.road

    @property
    def guard(self):
        """The first guarded car's decision object."""
        return self.cars[0].guard if self.cars else None

    @property
    def monitor(self):
        """The first guarded car's model monitor."""
        return self.cars[0].monitor if self.cars else None

    # ---- attaching to the ego ------------------------------------------------------------------------
    def _attach(self, base) -> None:
        """Hook every guarded vehicle, with decision objects for the env's road, frequencies and action type."""
        if base.vehicle is None:
            raise RuntimeError("Guardian: the env has no ego vehicle; call reset() first")
        self.kind = check_env(base)
        vehicles, types = controlled_vehicles(base), controlled_action_types(base)
        objects = self.supervision.decision_objects(base, self.kind, len(types))
        if len(vehicles) != len(types):
            raise ConfigError(f"Guardian: {len(vehicles)} controlled cars but {len(types)} action types")
        asked = base.config.get("controlled_vehicles")
        if multi_agent(base) and asked is not None and asked != len(vehicles):
            raise ConfigError(f"Guardian: config 'controlled_vehicles' is {asked}, but the env spawned "
                              f"{len(vehicles)} controlled car(s)")
        self.cars = []
        for i, (vehicle, action_type) in enumerate(zip(vehicles, types)):
            guard, monitor = objects[i]
            car = GuardedCar(i, vehicle, action_type, guard, monitor)
            vehicle.act = Hook(self, car, self._simulation_step)
            guard.reset()
            monitor.reset()
            self.cars.append(car)
        self.supervision.attached(vehicles)

    def _simulation_step(self, car: GuardedCar) -> None:
        self.supervision.decide(self.env.unwrapped, car, self.cars)

    def _is_attached(self, base) -> bool:
        if base.vehicle is None or not self.cars:
            return False
        vehicles = controlled_vehicles(base)
        return len(vehicles) == len(self.cars) and all(
            v is car.vehicle and hooked_by(v, self) for v, car in zip(vehicles, self.cars))

    def start_inside(self) -> bool:
        """Does the present state lie in the guardian's invariant sets (a start it can keep safe), for every
        guarded car?"""
        return all(self.starts_inside())

    def starts_inside(self) -> list:
        """Per guarded car: does its start lie in its invariant sets?"""
        return self.supervision.starts_inside(self.env.unwrapped, self.cars)

    # ---- gym API --------------------------------------------------------------------------------------
    def reset(self, *, seed=None, options=None):
        """Reset the env and attach to its ego.

        ``options={"safe_start": True}`` (or ``GuardianConfig.resample_unsafe_start``) draws the start
        again, up to ``start_attempts`` times, until it lies in the guardian's invariant sets; the
        other options go to the env.
        """
        options = dict(options or {})
        resample = bool(options.pop("safe_start", self.config.resample_unsafe_start))
        attempts = 0
        while True:
            attempts += 1
            obs, info = self.env.reset(seed=seed if attempts == 1 else None, options=options or None)
            base = self.env.unwrapped
            self._attach(base)
            each = self.starts_inside()
            inside = all(each)
            if inside or not resample:
                break
            if attempts >= self.config.start_attempts:
                raise RuntimeError(f"Guardian.reset: no start inside the invariant sets in {attempts} attempts")
        self.last_record = None
        assert "guardian" not in info
        info["guardian"] = {"enabled": True, "scenario": self.scenario, "action": self.kind,
                            "start_inside": inside, "start_attempts": attempts}
        if multi_agent(base):
            info["guardian"].update({"controlled": len(self.cars), "agents_start_inside": each})
        return obs, info

    def step(self, action):
        """Supervise ``action`` for one policy step and pass it on.

        Parameters
        ----------
        action
            The agent's action, in the env's action space.

        Returns
        -------
        tuple
            The env's ``(obs, reward, terminated, truncated, info)``; ``info["guardian"]`` holds what
            the guardian did (see the module docstring).
        """
        check_action(self.env.action_space, action)
        base = self.env.unwrapped
        reattached = not self._is_attached(base)
        if reattached:
            self._attach(base)
        cars = list(self.cars)
        for car in cars:
            car.new_step()
        proposed, applied_action = self._policy_step(base, action)
        frames_before, ego_before = base.steps, base.vehicle
        calls_before = [car.calls for car in cars]
        obs, reward, terminated, truncated, info = self.env.step(applied_action)
        frames = base.steps - frames_before if base.vehicle is ego_before else 0
        unsupervised = [max(frames - (car.calls - c0), 0) for car, c0 in zip(cars, calls_before)]
        notes = []
        if base.vehicle is not ego_before:  # an inner wrapper reset the env instead of stepping it
            self._attach(base)
            reattached = True
            notes.append(REATTACHED_INSIDE)
        elif reattached:
            notes.append(REATTACHED_BEHIND)
        assert "guardian" not in info
        records = [CarRecord.of(car, self.kind, p, notes, reattached, u) for car, p, u in zip(cars, proposed, unsupervised)]
        self.last_record = records[0].as_dict(inputs=True)
        if len(cars) == 1 and not multi_agent(base):
            info["guardian"] = records[0].as_dict(inputs=self.kind == META)
        else:
            info["guardian"] = FleetRecord(records, self.config.overapprox, self.supervision.order, applied_action,
                                           meta=self.kind == META).as_dict()
        reward = penalised(reward, info["guardian"], records, self.config.override_penalty)
        return obs, reward, terminated, truncated, info

    def _policy_step(self, base, action):
        """Each car's proposed action, and the action passed to the env: a meta lane change the supervision
        refuses at the policy step becomes ``IDLE``.

        Returns the proposed action of each car and the action to pass to the env."""
        actions = list(action) if multi_agent(base) else [action]
        if len(actions) != len(self.cars):
            raise ValueError(f"Guardian.step: {len(actions)} actions for {len(self.cars)} controlled cars")
        if self.kind != META:
            return [np.asarray(a, dtype=float).tolist() for a in actions], action
        proposed = [car.action_type.actions[int(a)] for car, a in zip(self.cars, actions)]
        self.supervision.refuse_lane_changes(base, self.cars, proposed)
        applied = [car.action_type.actions_indexes["IDLE"] if car.refused_meta else a
                   for car, a in zip(self.cars, actions)]
        return proposed, tuple(applied) if multi_agent(base) else applied[0]

    # ---- rendering -------------------------------------------------------------------------------
    def render(self):
        """highway-env's frame with the guardian's panel below it (``rgb_array``); other modes unchanged."""
        frame = self.env.render()
        if not isinstance(frame, np.ndarray):
            return frame
        from guardian.wrappers.panel import with_panel

        record = self.last_record or {"active_set": "-", "reasons": ["episode start"]}
        base = self.env.unwrapped
        return with_panel(frame, record, self.supervision.acceleration_bounds(base), self.supervision.lateral_axis(base))
