"""The guardian: one gymnasium wrapper between any highway-env agent and the vehicle.

The wrapper decides nothing. Every simulation step (highway-env calls the ego's ``act(None)`` once
per simulation step, after the policy step's ``act(action)``) it reads the state (``guardian.adapters.highway_env.scene``),
asks the decision object, applies its answer to the vehicle and keeps the record:

* ``guardian/HighwayOvertake-v0``: ``guardian.decide.overtake.PointMassGuardian`` (the lead part of
  Chapter 6 composed with ITHA; the composed invariant set is explained there);
* highway-env's roads (the ``highway-v0`` family, ``merge-v0``, ``merge-generic-v0``, ``exit-v0``):
  ``guardian.decide.bicycle.BicycleGuardian`` (ITHA for highway-env's bicycle) on the road ``guardian.adapters.highway_env.scene``
  reads (one straight road, or a ``guardian.model.roads.RoadMap`` with on-ramps, exits and lanes that end).

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
from highway_env.vehicle.controller import ControlledVehicle

from envs.highway_overtake import HighwayOvertakeEnv
from envs.vehicles import OvertakeEgo
from guardian.decide.bicycle import BicycleGuardian
from guardian.config import GuardianConfig
from guardian.model.decision import LEVELS
from guardian.decide.kinematics import BicycleEgo, RoadMapEgo
from guardian.adapters.highway_env.checks import check_config, merge_limits
from guardian.errors import ConfigError
from guardian.adapters.highway_env.monitor import COUNTS as MONITOR_COUNTS, ModelMonitor, no_counts
from guardian.decide.overtake import PointMassGuardian
from guardian.model.roads import RoadMap
from guardian.adapters.highway_env.scene import bicycle_state, road_scene
from guardian.adapters.highway_env.road import read_road
from itha.road import example8_order

__all__ = ["Guardian", "GuardianConfig"]

LANE_CHANGES = ("LANE_LEFT", "LANE_RIGHT")
ACTION_TYPES = ("ContinuousAction", "DiscreteAction", "DiscreteMetaAction")


def _action_types(base) -> list:
    """The action type of each supervised car (one, or each agent's of a ``MultiAgentAction``)."""
    if type(base.action_type).__name__ == "MultiAgentAction":
        return list(base.action_type.agents_action_types)
    return [base.action_type]


def allowed_lanes(decisions) -> list:
    """The lanes a car's body was allowed to overlap over one policy step: those its first decision held
    (where the body was, and entries judged before) and every lane entered responsibly during the step.

    Not the lanes of every decision: a later decision starts where the body is, so a lane the body reached
    in between without an entry would look held (``unchecked_entries`` counts exactly those)."""
    if not decisions:
        return []
    return sorted(set(decisions[0].lanes) | {lane for d in decisions for lane in d.entered})


def _action_kind(base) -> str:
    """``DiscreteMetaAction`` or ``ContinuousAction`` (highway-env's ``DiscreteAction`` is a grid of the
    latter; either may control one axis only, the env then holds the other at 0)."""
    kinds = set()
    for at in _action_types(base):
        kind = type(at).__name__
        if kind not in ACTION_TYPES:
            raise ConfigError(f"Guardian: config 'action.type' {kind!r} cannot be supervised; use one of {ACTION_TYPES}"
                              " (or MultiAgentAction of one of them)")
        if kind == "DiscreteMetaAction" and list(at.actions.values()) != \
                ["LANE_LEFT", "IDLE", "LANE_RIGHT", "FASTER", "SLOWER"]:
            raise ConfigError("Guardian: config 'action' must offer all five meta actions "
                              "('longitudinal' and 'lateral' true)")
        kinds.add("DiscreteMetaAction" if kind == "DiscreteMetaAction" else "ContinuousAction")
    if len(kinds) != 1:
        raise ConfigError("Guardian: every controlled car must have the same action type")
    return kinds.pop()


def _multi(base) -> bool:
    return type(base.action_type).__name__ == "MultiAgentAction"


def _check_env(base) -> str:
    """Refuse a config the guardian cannot supervise (``guardian.adapters.highway_env.checks``); the action kind."""
    kind = _action_kind(base)
    name = base.spec.id if base.spec is not None else type(base).__name__
    check_config(type(base).default_config(), base.config, f"Guardian: {name}")
    merge_limits(type(base), name, kind == "ContinuousAction", _multi(base))
    return kind


class _Car:
    """One guarded car: its vehicle, its own decision object and model monitor, the agent's command it
    holds, and what happened to it in this policy step."""

    def __init__(self, index: int, vehicle, action_type, guard, monitor):
        self.index, self.vehicle, self.action_type = index, vehicle, action_type
        self.guard, self.monitor = guard, monitor
        self.original = vehicle.act
        self.agent_command = dict(vehicle.action)
        self.calls = 0
        self.new_step()

    def new_step(self) -> None:
        self.decisions, self.notes, self.refused_meta = [], [], None
        self.monitor_counts = no_counts()


class _Hook:
    """A guarded car's ``act`` while supervised: the agent's action goes to the vehicle's own ``act``; every
    simulation step (``act(None)``) the guardian then decides."""

    def __init__(self, guardian: "Guardian", car: _Car):
        self.guardian, self.car = guardian, car

    @property
    def original(self):
        return self.car.original

    def __call__(self, action=None):
        self.guardian._act(self.car, action)


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
        base = env.unwrapped
        if not isinstance(base, AbstractEnv):
            raise ConfigError(f"Guardian: {type(base).__name__} is not a highway-env environment")
        if not isinstance(config, GuardianConfig):
            raise ConfigError(f"Guardian: config must be a GuardianConfig, got {type(config).__name__}")
        if getattr(env, "render_mode", None) == "rgb_array":  # SDL's offscreen driver: no display looked for
            os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
        self.config = config
        self.scenario = "overtake" if isinstance(base, HighwayOvertakeEnv) else "highway"
        if self.scenario == "overtake":
            if library is None:
                from intention.library import build_library

                library = build_library(params=base.params)
            if library.params != base.params:
                raise ConfigError("Guardian: the library was computed for other OvertakeParams than the env's "
                                  "config 'params'; rebuild it with the env's parameters")
        self.library = library
        self.kind = _check_env(base)
        self.cars = []              # the guarded cars (_Car), in highway-env's controlled order
        self._attached = None       # the vehicles the hooks sit on
        self._geometry = None       # what the decision objects were built for
        self.guard = None           # the first car's decision object (the only one with one guarded car)
        self._sim_key = None        # the simulation step whose decisions are made
        self._order = []
        self._last_record = None
        if self.scenario == "overtake" or base.road is not None:
            self._build(base)  # refuse a bad road, library or configuration now, not at the first reset

    # ---- attaching to the ego ------------------------------------------------------------------------
    def _build(self, base) -> None:
        """The decision objects and monitors for the env's road, frequencies and action type (re-read)."""
        self.kind = _check_env(base)
        self.road = read_road(base)
        self.dt = 1.0 / base.config["simulation_frequency"]
        c = self.config
        if self.scenario == "overtake":
            if _multi(base):
                raise ConfigError("Guardian: the overtake scenarios have one ego; MultiAgentAction is for "
                                  "highway-env's roads")
            p = base.params
            traffic = int(base.config["traffic_count"]) > 0
            key = (self.road, self.dt, traffic, base.config["lateral_scale"])
            if key != self._geometry:
                try:
                    self.guard = PointMassGuardian(self.library, self.road.n_lanes,
                                                   OvertakeEgo.WIDTH / 2 / base.config["lateral_scale"], traffic, c)
                except ValueError as exc:
                    raise ConfigError(f"Guardian: {exc}") from None
                self.monitor = ModelMonitor(self.dt, (-c.traffic_accel, c.traffic_accel), c.v_max, p,
                                            {n: self.library.models[n] for n in ("aggressive", "cautious")},
                                            ego_stops_at_zero=True, reverse_reach=c.reverse_reach)
                self._guards = [(self.guard, self.monitor)]
        elif base.vehicle is not None:
            ego = base.vehicle
            at = _action_types(base)[0]
            max_steer = float(getattr(ego, "MAX_STEERING_ANGLE", np.pi / 3))
            if self.kind == "ContinuousAction":
                max_steer = float(max(abs(s) for s in at.steering_range))
            n = len(_action_types(base))
            key = (self.road, self.dt, self.kind, max_steer, ego.LENGTH, ego.WIDTH, n)
            if key != self._geometry:
                self._guards = []
                for i in range(n):  # one decision object per car: nothing shared
                    if isinstance(self.road, RoadMap):
                        kin = RoadMapEgo(self.dt, c.traffic_accel, ego.LENGTH, ego.WIDTH, self.road, max_steer)
                    else:
                        kin = BicycleEgo(self.dt, c.traffic_accel, ego.LENGTH, ego.WIDTH, self.road.lane_width,
                                         self.road.n_lanes, max_steer)
                    guard = BicycleGuardian(kin, c, meta=self.kind == "DiscreteMetaAction")
                    monitor = ModelMonitor(self.dt, (-c.traffic_accel, c.traffic_accel), c.v_max,
                                           ego_kinematics=kin, watch_traffic=i == 0, reverse_reach=c.reverse_reach)
                    self._guards.append((guard, monitor))
                self.guard, self.monitor = self._guards[0]
        else:
            return  # no ego yet (before the first reset): the road alone was checked
        self._geometry = key

    def _attach(self, base) -> None:
        if base.vehicle is None:
            raise RuntimeError("Guardian: the env has no ego vehicle; call reset() first")
        self._build(base)
        vehicles = list(base.controlled_vehicles) if _multi(base) else [base.vehicle]
        types = _action_types(base)
        if len(vehicles) != len(types):
            raise ConfigError(f"Guardian: {len(vehicles)} controlled cars but {len(types)} action types")
        asked = base.config.get("controlled_vehicles")
        if _multi(base) and asked is not None and asked != len(vehicles):
            raise ConfigError(f"Guardian: config 'controlled_vehicles' is {asked}, but the env spawned "
                              f"{len(vehicles)} controlled car(s)")
        self.cars = []
        for i, (vehicle, at) in enumerate(zip(vehicles, types)):
            guard, monitor = self._guards[i]
            car = _Car(i, vehicle, at, guard, monitor)
            vehicle.act = _Hook(self, car)
            guard.reset()
            monitor.reset()
            self.cars.append(car)
        self._attached = vehicles
        self._guarded = frozenset(id(v) for v in vehicles) if len(vehicles) > 1 else frozenset()
        self._sim_key = None

    def _vehicles(self, base) -> list:
        return list(base.controlled_vehicles) if _multi(base) else [base.vehicle]

    def _is_attached(self, base) -> bool:
        if base.vehicle is None or self._attached is None:
            return False
        vehicles = self._vehicles(base)
        return len(vehicles) == len(self._attached) and all(
            v is a and isinstance(v.__dict__.get("act"), _Hook) and v.__dict__["act"].guardian is self
            for v, a in zip(vehicles, self._attached))

    def start_inside(self) -> bool:
        """Does the present state lie in the guardian's invariant sets (a start it can keep safe), for every
        guarded car?"""
        return all(self.starts_inside())

    def _scene(self, base, *args, **kwargs):
        """``guardian.adapters.highway_env.scene.road_scene`` of this road, with this config's cover for reversing traffic."""
        return road_scene(base, self.road, *args, reverse_reach=self.config.reverse_reach, **kwargs)

    def starts_inside(self) -> list:
        """Per guarded car: does its start lie in its invariant sets?"""
        base = self.env.unwrapped
        if self.scenario == "overtake":
            scene = self._scene(base)
            return [bool(self.guard.inside(base.overtake_state(), scene))]
        out = []
        for car in self.cars:
            state = bicycle_state(car.vehicle, self.road)
            kin = car.guard.kin
            lanes = {self.road.itha_lane(i) for i in (set(kin.body_lanes(state)) or {state.lane})}
            scene = self._scene(base, lanes, ego=car.vehicle, guarded=self._guarded)
            speeds, _ = car.guard.traffic.self_safe_speeds(scene)
            out.append(bool(kin.accel_for_speeds(state.speed, speeds)))
        return out

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
        self._last_record = None
        assert "guardian" not in info
        info["guardian"] = {"enabled": True, "scenario": self.scenario, "action": self.kind,
                            "start_inside": inside, "start_attempts": attempts}
        if _multi(base):
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
        base = self.env.unwrapped
        reattached = not self._is_attached(base)
        if reattached:
            self._attach(base)
        self._step_notes = []
        for car in self.cars:
            car.new_step()
        proposed, applied_action = self._policy_level(base, action)
        cars = list(self.cars)
        frames_before, ego_before = base.steps, base.vehicle
        calls_before = [car.calls for car in cars]
        obs, reward, terminated, truncated, info = self.env.step(applied_action)
        frames = base.steps - frames_before if base.vehicle is ego_before else 0
        unsupervised = [max(frames - (car.calls - c0), 0) for car, c0 in zip(cars, calls_before)]
        if base.vehicle is not ego_before:  # an inner wrapper reset the env instead of stepping it
            self._attach(base)
            reattached = True
            self._step_notes.append("the env was reset inside the step; re-attached to the new ego")
        if reattached and base.vehicle is ego_before:
            self._step_notes.append("the ego was reset or replaced behind the guardian's back (or before it "
                                    "wrapped the env); re-attached")
        assert "guardian" not in info
        records = [self._record(base, car, p, reattached, u) for car, p, u in zip(cars, proposed, unsupervised)]
        record = records[0] if len(cars) == 1 and not _multi(base) else self._summed(records, applied_action)
        self._last_record = self._last_records[0]
        info["guardian"] = record
        overridden = sum(r["safety_override"] for r in records)
        if self.config.override_penalty and overridden:
            penalty = self.config.override_penalty * overridden
            reward -= penalty
            record["penalty"] = penalty
        return obs, reward, terminated, truncated, info

    def _policy_level(self, base, action):
        """Meta lane changes on highway-env roads are decided here, once per policy step, car by car in the
        announcing order (ordered: each knows the lane changes the cars before it announced).

        Returns the proposed action of each car and the action to pass to the env."""
        actions = list(action) if _multi(base) else [action]
        if len(actions) != len(self.cars):
            raise ValueError(f"Guardian.step: {len(actions)} actions for {len(self.cars)} controlled cars")
        if self.kind != "DiscreteMetaAction":
            proposed = [np.asarray(a, dtype=float).tolist() for a in actions]
            return proposed, action
        proposed = [car.action_type.actions[int(a)] for car, a in zip(self.cars, actions)]
        applied = list(actions)
        if self.scenario == "highway":
            announced = {}
            for i in self._announcing_order(base):
                car = self.cars[i]
                if proposed[i] not in LANE_CHANGES:
                    continue
                state = bicycle_state(car.vehicle, self.road)
                target = state.lane + (-1 if proposed[i] == "LANE_LEFT" else 1)
                scene = self._scene(base, ego=car.vehicle, guarded=self._guarded, announced=announced)
                ok, reason = car.guard.policy_lane_change(state, scene, target)
                if not ok:
                    car.refused_meta = f"lane change refused: {reason}"
                    applied[i] = car.action_type.actions_indexes["IDLE"]
                elif self._ordered and 0 <= target < self.road.n_lanes:
                    announced[id(car.vehicle)] = frozenset({self.road.itha_lane(target)})
        if _multi(base):
            return proposed, tuple(applied)
        return proposed, applied[0]

    @property
    def _ordered(self) -> bool:
        return self.config.overapprox == "ordered" and len(self.cars) > 1

    def _announcing_order(self, base) -> list:
        """Car numbers in Example 8's order (ahead first; aligned, the slower lane first) under the ordered
        over-approximation; highway-env's order otherwise (nothing is announced)."""
        if not self._ordered:
            return list(range(len(self.cars)))
        states = [bicycle_state(car.vehicle, self.road) for car in self.cars]
        return example8_order([st.front for st in states], [self.road.itha_lane(st.lane) for st in states])

    # ---- the per-simulation-step supervision ------------------------------------------------------------
    def _act(self, car: _Car, action) -> None:
        base = self.env.unwrapped
        ego = car.vehicle
        if action is not None:  # the agent's action, decoded once per policy step
            car.original(action)
            car.agent_command = dict(ego.action)
            return
        if self.scenario == "overtake":
            car.original(None)
            self._decided(base, car, self._supervise_overtake(base, ego))
            return
        key = (id(base.road), base.steps)
        if key == self._sim_key:
            return  # this simulation step's decisions were made at its first guarded car
        self._sim_key = key
        live = [c for c in self.cars if c.vehicle in base.road.vehicles]
        for c in live:  # every car's proposal first: each vehicle computes its own command
            if not isinstance(c.vehicle, ControlledVehicle):
                c.vehicle.action = dict(c.agent_command)  # a plain Vehicle keeps the last command
            c.original(None)
        order = [i for i in self._announcing_order(base) if self.cars[i] in live]
        self._order = order
        announced = {}
        for i in order:
            c = self.cars[i]
            decision = self._supervise_highway(base, c, announced)
            if self._ordered:  # where this car may be during the step, for the cars after it
                announced[id(c.vehicle)] = frozenset(decision.lanes) | frozenset(decision.touched)
            self._decided(base, c, decision)

    def _decided(self, base, car: _Car, decision) -> None:
        car.calls += 1
        car.decisions.append(decision)
        for k, n in car.monitor.observe(base, decision.applied, car.vehicle).items():
            car.monitor_counts[k] += n

    def _supervise_overtake(self, base, ego):
        u = ego.input.copy()
        scene = self._scene(base)
        applied, decision = self.guard.step(base.overtake_state(), scene, u)
        ego.action = {"acceleration": float(applied[0]), "steering": float(applied[1])}
        if decision.refused and ego.meta is not None:
            ego.keep_lane()  # a meta agent's lane change is abandoned
        return decision

    def _supervise_highway(self, base, car: _Car, announced: dict):
        ego = car.vehicle
        proposed = (float(ego.action["acceleration"]), float(ego.action["steering"]))
        state = bicycle_state(ego, self.road)
        scene = self._scene(base, ego=ego, guarded=self._guarded, announced=announced)
        applied, decision = car.guard.step(state, scene, proposed)
        if decision.refused and self.kind == "DiscreteMetaAction":
            ego.target_lane_index = ego.lane_index  # abandon the lane change, steer back
            car.original(None)
            applied = np.array([applied[0], float(ego.action["steering"])])
            decision.applied = applied.tolist()
        ego.action = {"acceleration": float(applied[0]), "steering": float(applied[1])}
        return decision

    # ---- rendering -------------------------------------------------------------------------------
    def render(self):
        """highway-env's frame with the guardian's panel below it (``rgb_array``); other modes unchanged."""
        frame = self.env.render()
        if not isinstance(frame, np.ndarray):
            return frame
        from guardian.wrappers.panel import with_panel

        base = self.env.unwrapped
        a = self.config.traffic_accel if self.scenario == "highway" else base.params.a_ex_bounds[1]
        return with_panel(frame, self._last_record or {"active_set": "-", "reasons": ["episode start"]}, (-a, a))

    # ---- info --------------------------------------------------------------------------------------
    def _applied_action(self, car: _Car, proposed, ds, inputs):
        """What the vehicle did over the policy step, as an action of the env's own space (so a learner
        can relabel what it proposed): the meta action executed (a refused lane change is ``IDLE``, an
        acceleration held below the proposal ``SLOWER``), or the mean applied input in the action's
        normalised coordinates (a ``DiscreteAction``: the nearest of its grid)."""
        at = car.action_type
        if self.kind == "DiscreteMetaAction":
            name = "IDLE" if car.refused_meta or any(d.refused for d in ds) else proposed
            if any(d.applied[0] < d.proposed[0] - 1e-9 and not d.clipped_to_model for d in ds):
                name = "SLOWER"
            return int(at.actions_indexes[name])
        if not len(ds):
            return None
        mean = inputs.mean(axis=0)
        axes = [(0, at.acceleration_range)] * at.longitudinal + [(1, at.steering_range)] * at.lateral
        unit = np.array([np.clip(2 * (mean[k] - lo) / (hi - lo) - 1, -1.0, 1.0) for k, (lo, hi) in axes])
        if type(at).__name__ == "DiscreteAction":
            grid = np.linspace(-1.0, 1.0, at.actions_per_axis)
            index = 0
            for value in unit:  # itertools.product's order: the first axis varies slowest
                index = index * at.actions_per_axis + int(np.argmin(np.abs(grid - value)))
            return index
        return unit.astype(np.float32).tolist()

    def _record(self, base, car: _Car, proposed, reattached: bool, unsupervised: int) -> dict:
        ds = car.decisions
        last = ds[-1] if ds else None
        reasons = list(self._step_notes)
        if car.refused_meta:
            reasons.append(car.refused_meta)
        for d in ds:
            for r in d.reasons:
                if r not in reasons:
                    reasons.append(r)
        if unsupervised:
            reasons.append(f"{unsupervised} simulation steps ran without the guardian")
        level = max((LEVELS.index(d.level) for d in ds), default=0)
        changed = "none"
        for d in ds:
            if d.changed != "none":
                changed = d.changed
        refused = bool(car.refused_meta) or any(d.refused for d in ds)
        if refused and changed in ("none", "steering"):
            changed = "lane_change" if self.kind == "DiscreteMetaAction" else changed
        inputs = np.array([d.applied for d in ds], dtype=float).reshape(-1, 2)
        applied_action = self._applied_action(car, proposed, ds, inputs)
        applied = proposed
        if self.kind == "DiscreteMetaAction":  # the meta action executed over the whole policy step
            applied = car.action_type.actions[applied_action]
        elif last is not None:
            applied = last.applied
            proposed = last.proposed
        clipped = sum(d.changed != "none" for d in ds)
        model_clips = sum(d.changed != "none" and d.clipped_to_model for d in ds)
        safety = bool(clipped - model_clips or refused)
        lead = getattr(car.guard if car.guard is not None else self.guard, "lead", None)
        out = {"proposed": proposed, "applied": applied, "applied_action": applied_action,
               "applied_mean": inputs.mean(axis=0).tolist() if len(ds) else [],
               "applied_range": [[float(inputs[:, k].min()), float(inputs[:, k].max())] for k in range(2)]
               if len(ds) else [],
               "overridden": bool(clipped or refused), "safety_override": safety, "changed": changed,
               "level": LEVELS[level],
               "reasons": reasons, "refused_lane_change": refused,
               "entered": sorted({lane for d in ds for lane in d.entered}),
               "lanes": allowed_lanes(ds),
               "active_set": last.active_set if last else "itha",
               "valid_intentions": list(lead.estimator.valid) if lead else [],
               "identified": lead.identified if lead else None,
               "in_invariant_set": bool(ds[0].in_invariant_set) if ds else True,
               "admissible_acceleration": last.admissible_acceleration if last else [],
               "admissible_lateral": last.admissible_lateral if last else [],
               "sim_steps": len(ds), "clipped_steps": clipped, "model_clip_steps": model_clips,
               "follower_dropped_steps": sum(d.level == "follower_dropped" for d in ds),
               "conflict_steps": sum(d.level == "conflict" for d in ds),
               "failsafe_steps": sum(d.level == "failsafe" for d in ds),
               "unsupervised_steps": unsupervised, "reattached": reattached,
               "model_violations": dict(car.monitor_counts)}
        if self.kind == "DiscreteMetaAction":
            out["proposed_input"] = last.proposed if last else None
            out["applied_input"] = last.applied if last else None
        if car.index == 0:
            self._last_records = [dict(out, proposed_input=last.proposed if last else None,
                                       applied_input=last.applied if last else None)]
        return out

    def _summed(self, records: list, applied_action) -> dict:
        """Several guarded cars: each car's record and their sum (see the module docstring)."""
        sums = ("clipped_steps", "model_clip_steps", "follower_dropped_steps", "conflict_steps", "failsafe_steps",
                "unsupervised_steps")
        out = {"agents": records, "controlled": len(records), "overapprox": self.config.overapprox,
               "order": list(self._order), "applied_action": tuple(r["applied_action"] for r in records),
               "overridden": any(r["overridden"] for r in records),
               "safety_override": any(r["safety_override"] for r in records),
               "refused_lane_change": any(r["refused_lane_change"] for r in records),
               "reattached": any(r["reattached"] for r in records),
               "level": LEVELS[max(LEVELS.index(r["level"]) for r in records)],
               "reasons": [f"car {i}: {reason}" for i, r in enumerate(records) for reason in r["reasons"]],
               "sim_steps": max(r["sim_steps"] for r in records),
               "model_violations": {k: sum(r["model_violations"][k] for r in records)
                                    for k in MONITOR_COUNTS}}
        out.update({k: sum(r[k] for r in records) for k in sums})
        return out
