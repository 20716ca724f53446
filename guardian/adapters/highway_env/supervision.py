"""How the guardian supervises a highway-env scenario: which decision objects, what they read, and how their
answer reaches the vehicles. One class per scenario family, behind one interface (``Supervision``):

* ``OvertakeSupervision``: ``guardian/HighwayOvertake-v0``, one ego decided by
  ``guardian.decide.overtake.PointMassGuardian`` on the overtake state, every simulation step;
* ``RoadSupervision``: highway-env's roads (the ``highway-v0`` family, ``merge-v0``, ``merge-generic-v0``,
  ``exit-v0``, ``guardian/Merge-v0``), one ``guardian.decide.bicycle.BicycleGuardian`` per controlled car.
  The first hook call of a simulation step decides every car; under ``GuardianConfig.overapprox =
  "ordered"`` in Example 8's order (``itha.road.example8_order``: ahead first, on ties the slower lane
  first), each car told where the cars before it announced they may be.

The gymnasium wrapper (``guardian.wrappers.guardian.Guardian``) asks these; it knows no scenario.
"""
from __future__ import annotations

import sys
from typing import Protocol, runtime_checkable

import numpy as np
from highway_env.vehicle.controller import ControlledVehicle

from guardian.adapters.highway_env.monitor import ModelMonitor
from guardian.adapters.highway_env.road import read_road
from guardian.adapters.highway_env.scene import bicycle_state, road_scene
from guardian.decide.bicycle import BicycleGuardian
from guardian.decide.kinematics import BicycleEgo, RoadMapEgo
from guardian.decide.overtake import PointMassGuardian
from guardian.errors import ConfigError
from guardian.model.roads import RoadMap
from itha.road import example8_order

META = "DiscreteMetaAction"
LANE_CHANGES = ("LANE_LEFT", "LANE_RIGHT")


@runtime_checkable
class Supervision(Protocol):
    """What the wrapper asks of a scenario family."""

    name: str
    road: object
    order: list   # the cars' announcing order at the last simulation step decided (car numbers)

    def decision_objects(self, base, kind: str, cars: int) -> list:
        """``[(decision object, ModelMonitor), ...]``, one per guarded car, for the env's road, frequencies
        and action type (the same objects while these do not change)."""

    def starts_inside(self, base, cars: list) -> list:
        """Per guarded car: does the present state lie in its invariant sets?"""

    def refuse_lane_changes(self, base, cars: list, proposed: list) -> None:
        """Meta agents, once per policy step: refuse (``car.refused_meta``) lane changes not responsible now."""

    def decide(self, base, car, cars: list) -> None:
        """One simulation step (``car``'s hook was called with ``act(None)``): decide and apply."""

    def acceleration_bounds(self, base) -> tuple:
        """The ego's acceleration bounds (for the panel)."""

    def lateral_axis(self, base) -> tuple:
        """The ego's second input for the panel: ``(label, (low, high))``."""


class _Supervision:
    """What both families share: the configuration, the road read from the env, the scene reader."""

    name = ""

    def __init__(self, config):
        self.config = config
        self.road = None
        self.dt = None
        self.guarded = frozenset()   # ids of the guarded vehicles (empty with one guarded car)
        self.order = []
        self._key = None              # what the decision objects were built for
        self._objects = []

    def read(self, base) -> None:
        """Read the env's road and simulation step again (a ConfigError if the guardian cannot reason about it)."""
        self.road = read_road(base)
        self.dt = 1.0 / base.config["simulation_frequency"]

    def attached(self, vehicles) -> None:
        self.guarded = frozenset(id(v) for v in vehicles) if len(vehicles) > 1 else frozenset()

    def scene(self, base, *args, **kwargs):
        """``road_scene`` of this road, with this configuration's cover for reversing traffic."""
        return road_scene(base, self.road, *args, reversing=self.config.reversing, **kwargs)

    def _built(self, key, build) -> list:
        if key != self._key:
            self._objects = build()
            self._key = key
        return self._objects


def first_use_notice(params) -> str:
    """What building the overtake library for ``params`` on first use costs and how to build it ahead; "" when the
    cache holds all three sets (the entries' file names are the cache keys, so this reads no set)."""
    from intention.library import SET_NAMES, LibrarySettings, _payload
    from intention.params import OvertakeParams
    from rcis.cache import RegionCache, payload_key

    cache, settings = RegionCache(), LibrarySettings()
    bnd = _payload("bounded_velocity", params, settings, "C_left")
    payloads = [bnd] + [_payload(n, params, settings, payload_key(bnd)) for n in SET_NAMES[1:]]
    if all(cache.path(name, p).exists() for name, p in zip(SET_NAMES, payloads)):
        return ""
    known = {OvertakeParams(): ("about 25 s", "guardian rcis build"),   # measured on 2 idle cores (docs/performance.md)
             OvertakeParams.among_traffic(): ("about 3.5 minutes", "guardian rcis build --ego-speed-min 0")}
    took, ahead = known.get(params, ("minutes", "guardian rcis build with the same parameters (see --help)"))
    return (f"guardian: building the overtake sets C_bnd, C_a and C_c for these parameters once ({took} on 2 idle "
            f"cores, longer on a busy machine), then kept in {cache.dir}. To build them ahead: {ahead}")


class OvertakeSupervision(_Supervision):
    """``guardian/HighwayOvertake-v0``: the overtake ego among traffic (``PointMassGuardian``)."""

    name = "overtake"

    def __init__(self, base, library, config):
        super().__init__(config)
        if library is None:
            from intention.library import build_library

            notice = first_use_notice(base.params)
            if notice:
                print(notice, file=sys.stderr, flush=True)
            library = build_library(params=base.params)
        if library.params != base.params:
            raise ConfigError("Guardian: the library was computed for other OvertakeParams than the env's "
                              "config 'params'; rebuild it with the env's parameters")
        self.library = library

    def decision_objects(self, base, kind: str, cars: int) -> list:
        from envs.vehicles import OvertakeEgo

        if type(base.action_type).__name__ == "MultiAgentAction":
            raise ConfigError("Guardian: the overtake scenarios have one ego; MultiAgentAction is for "
                              "highway-env's roads")
        if getattr(base.vehicle, "actuator", None) is not None:
            raise ConfigError("Guardian: the overtake sets let the ego's acceleration jump; an actuator with a jerk "
                              "limit is supported on highway-env's roads")
        self.read(base)
        c, p = self.config, base.params
        traffic = int(base.config["traffic_count"]) > 0

        def build():
            try:
                guard = PointMassGuardian(self.library, self.road.n_lanes,
                                          OvertakeEgo.WIDTH / 2 / base.config["lateral_scale"], traffic, c)
            except ValueError as exc:
                raise ConfigError(f"Guardian: {exc}") from None
            monitor = ModelMonitor(self.dt, (-c.traffic_accel, c.traffic_accel), c.v_max, p,
                                   {n: self.library.models[n] for n in ("aggressive", "cautious")},
                                   ego_stops_at_zero=True, reversing=c.reversing)
            return [(guard, monitor)]

        return self._built((self.road, self.dt, traffic, base.config["lateral_scale"]), build)

    def starts_inside(self, base, cars: list) -> list:
        return [bool(cars[0].guard.inside(base.overtake_state(), self.scene(base)))]

    def refuse_lane_changes(self, base, cars: list, proposed: list) -> None:
        """A meta lane change is judged every simulation step (``decide``), not here."""

    def decide(self, base, car, cars: list) -> None:
        ego = car.vehicle
        car.original(None)
        applied, decision = car.guard.step(base.overtake_state(), self.scene(base), ego.input.copy())
        ego.action = {"acceleration": float(applied[0]), "steering": float(applied[1])}
        if decision.refused and ego.meta is not None:
            ego.keep_lane()  # a meta agent's lane change is abandoned
        car.decided(base, decision)

    def acceleration_bounds(self, base) -> tuple:
        a = base.params.a_ex_bounds[1]
        return -a, a

    def lateral_axis(self, base) -> tuple:
        return "v_ey [m/s]", tuple(base.params.v_ey_bounds)


class RoadSupervision(_Supervision):
    """highway-env's roads: one ``BicycleGuardian`` and model monitor per controlled car."""

    name = "highway"

    def __init__(self, config):
        super().__init__(config)
        self._step = None   # the simulation step whose decisions are made

    def attached(self, vehicles) -> None:
        super().attached(vehicles)
        self._step = None

    @property
    def ordered(self) -> bool:
        return self.config.overapprox == "ordered" and len(self.guarded) > 1

    def decision_objects(self, base, kind: str, cars: int) -> list:
        self.read(base)
        ego, c = base.vehicle, self.config
        if ego is None:
            return self._objects  # no ego yet (before the first reset): the road alone was checked
        max_steer = float(getattr(ego, "MAX_STEERING_ANGLE", np.pi / 3))
        if kind == "ContinuousAction":
            action_type = base.action_type
            if type(action_type).__name__ == "MultiAgentAction":
                action_type = action_type.agents_action_types[0]
            max_steer = float(max(abs(s) for s in action_type.steering_range))

        actuator = getattr(ego, "actuator", None)   # declared by the world (envs.actuator.JerkLimit)

        def one(i: int):
            if isinstance(self.road, RoadMap):
                kin = RoadMapEgo(self.dt, c.traffic_accel, ego.LENGTH, ego.WIDTH, self.road, max_steer)
            else:
                kin = BicycleEgo(self.dt, c.traffic_accel, ego.LENGTH, ego.WIDTH, self.road.lane_width,
                                 self.road.n_lanes, max_steer)
            monitor = ModelMonitor(self.dt, (-c.traffic_accel, c.traffic_accel), c.v_max, ego_kinematics=kin,
                                   ego_stops_at_zero=actuator is not None, watch_traffic=i == 0,
                                   reversing=c.reversing)
            return BicycleGuardian(kin, c, meta=kind == META, actuator=actuator), monitor

        key = (self.road, self.dt, kind, max_steer, ego.LENGTH, ego.WIDTH, cars, actuator)
        return self._built(key, lambda: [one(i) for i in range(cars)])  # one per car: nothing shared

    def starts_inside(self, base, cars: list) -> list:
        return [bool(car.guard.inside(bicycle_state(car.vehicle, self.road),
                                      self.scene(base, ego=car.vehicle, guarded=self.guarded))) for car in cars]

    def announcing_order(self, cars: list) -> list:
        """Car numbers in Example 8's order (ahead first; aligned, the slower lane first) under the ordered
        over-approximation; highway-env's order otherwise (nothing is announced)."""
        if not self.ordered:
            return list(range(len(cars)))
        states = [bicycle_state(car.vehicle, self.road) for car in cars]
        lanes = self.road.numbering
        return example8_order([st.front for st in states], [lanes.itha(st.lane) for st in states])

    def refuse_lane_changes(self, base, cars: list, proposed: list) -> None:
        announced = {}
        for i in self.announcing_order(cars):
            car = cars[i]
            if proposed[i] not in LANE_CHANGES:
                continue
            state = bicycle_state(car.vehicle, self.road)
            target = state.lane + (-1 if proposed[i] == "LANE_LEFT" else 1)
            scene = self.scene(base, ego=car.vehicle, guarded=self.guarded, announced=announced)
            ok, reason = car.guard.policy_lane_change(state, scene, target)
            if not ok:
                car.refused_meta = f"lane change refused: {reason}"
                if 0 <= target < self.road.n_lanes:
                    car.refused_lane = self.road.numbering.itha(target)
            elif self.ordered and 0 <= target < self.road.n_lanes:
                announced[id(car.vehicle)] = frozenset({self.road.numbering.itha(target)})

    def decide(self, base, car, cars: list) -> None:
        step = (id(base.road), base.steps)
        if step == self._step:
            return  # this simulation step's decisions were made at its first guarded car
        self._step = step
        live = [c for c in cars if c.vehicle in base.road.vehicles]
        for c in live:  # every car's proposal first: each vehicle computes its own command
            if not isinstance(c.vehicle, ControlledVehicle):
                c.vehicle.action = dict(c.agent_command)  # a plain Vehicle keeps the last command
            c.original(None)
        self.order = [i for i in self.announcing_order(cars) if cars[i] in live]
        announced = {}
        for i in self.order:
            c = cars[i]
            decision = self._decide_one(base, c, announced)
            if self.ordered:  # where this car may be during the step, for the cars after it
                announced[id(c.vehicle)] = frozenset(decision.lanes) | frozenset(decision.touched)
            c.decided(base, decision)

    def _decide_one(self, base, car, announced: dict):
        ego = car.vehicle
        proposed = (float(ego.action["acceleration"]), float(ego.action["steering"]))
        state = bicycle_state(ego, self.road)
        scene = self.scene(base, ego=ego, guarded=self.guarded, announced=announced)
        applied, decision = car.guard.step(state, scene, proposed)
        if decision.refused and car.guard.meta:
            ego.target_lane_index = ego.lane_index  # abandon the lane change, steer back
            car.original(None)
            applied = np.array([applied[0], float(ego.action["steering"])])
            decision.applied = applied.tolist()
        ego.action = {"acceleration": float(applied[0]), "steering": float(applied[1])}
        return decision

    def acceleration_bounds(self, base) -> tuple:
        return -self.config.traffic_accel, self.config.traffic_accel

    def lateral_axis(self, base) -> tuple:
        steer = self._objects[0][0].kin.max_steering if self._objects else np.pi / 4
        return "steering [rad]", (-steer, steer)
