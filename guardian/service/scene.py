"""Scene sessions: a driving stack's ego among its traffic, decided by the decision object the gymnasium
wrapper uses (``guardian.decide.bicycle.BicycleGuardian``), with the scene built by the one builder every
reader uses (``guardian.model.sensing.scene_of``).

A session is created with the road, the ego's vehicle model and the guardian's options
(``SceneSettings``); each step sends the ego's state, the other cars' bodies and the proposed input
(``SceneStep``) and is answered with the applied input, whether and why it was changed, the lanes held and
entered, the lane entries judged, the fail-safe, and the model coverage of the transition since the last
step. Lanes in requests and answers are slots: 0 the leftmost lane, whose centre line is at ``y = y0``; ``y``
grows to the right of the direction of travel (highway-env's convention); ``x`` runs along the road.

The guarantee holds for the model it was computed for: a vehicle model the guardian does not supervise, or
bounds it was not built for, is refused by name (``VehicleSpec.refusal``), and every record says which model
and parameters decided (``model``).
"""
from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictInt, field_validator, model_validator

from guardian.config import GuardianConfig
from guardian.decide.bicycle import BicycleGuardian
from guardian.decide.coverage import ModelCoverage
from guardian.decide.kinematics import BicycleEgo, RoadMapEgo
from guardian.errors import ConfigError, ServiceError
from guardian.model.roads import RoadMap, road_from_dict
from guardian.model.scene import Car, EgoState
from guardian.model.sensing import Sensed, scene_of
from itha.actuator import Actuator

Finite = Annotated[float, Field(strict=True, allow_inf_nan=False)]   # a number: never "1.5" or true
Positive = Annotated[float, Field(strict=True, gt=0, allow_inf_nan=False)]
Slot = Annotated[int, Field(strict=True, ge=0, le=63)]
MAX_CARS = 512
MODEL_FIELDS = {"bicycle": ("max_steering", "max_acceleration"),
                "point_mass": ("acceleration", "lateral_speed", "lateral_scale")}
MODEL_OPTIONS = {"bicycle": ("meta", "max_jerk", "lag"), "point_mass": ()}


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class BranchSpec(_Strict):
    """A lane off the corridor (an on-ramp's approach, an exit's curve): ``guardian.model.roads.Strip``."""

    kind: Literal["straight", "sine", "arc"]
    start: tuple[Finite, Finite]
    end: tuple[Finite, Finite] = (0.0, 0.0)
    width: Positive
    length: Positive
    slot: Slot
    s0: Finite
    amplitude: Finite = 0.0
    pulsation: Finite = 0.0
    phase: Finite = 0.0
    radius: Finite = 0.0
    start_phase: Finite = 0.0
    direction: Literal[-1, 1] = 1
    open_before: StrictBool = False
    open_after: StrictBool = False


class RoadSpec(_Strict):
    """The road: ``lanes`` lanes of ``lane_width`` along ``+x`` (slot 0 the leftmost, its centre line at ``y0``),
    each present on the x-intervals of ``spans`` (``null`` ends are open; default everywhere), lanes that end
    where they stop (``ends``: ``[slot, x]``, a standing obstacle of length 0 there) and ``branches``."""

    lanes: StrictInt = Field(ge=1, le=64)
    lane_width: Positive = Field(le=20)
    y0: Finite = 0.0
    spans: list[list[tuple[Finite | None, Finite | None]]] | None = None
    ends: list[tuple[Slot, Finite]] = []
    branches: list[BranchSpec] = Field(default=[], max_length=64)

    @model_validator(mode="after")
    def _consistent(self):
        if self.spans is not None and len(self.spans) != self.lanes:
            raise ValueError(f"spans gives {len(self.spans)} lanes' intervals for {self.lanes} lanes")
        for k, _ in self.ends:
            if k >= self.lanes:
                raise ValueError(f"ends names lane {k}; the road has lanes 0..{self.lanes - 1}")
        for b in self.branches:
            if b.slot >= self.lanes:
                raise ValueError(f"a branch joins lane {b.slot}; the road has lanes 0..{self.lanes - 1}")
        return self

    def road(self):
        if self.spans is None and not self.ends and not self.branches and self.y0 == 0.0:
            return road_from_dict({"lanes": self.lanes, "lane_width": self.lane_width})
        spec = self.model_dump()
        spec["spans"] = spec["spans"] or [[[None, None]]] * self.lanes
        return road_from_dict(spec)


class VehicleSpec(_Strict):
    """The ego's vehicle model, as its driving stack declares it; ``dt`` is the time between two steps (the
    decision period). Two models are supervised:

    * ``bicycle`` (highway-env's vehicles, a SUMO or CARLA car): the kinematic bicycle with ``max_steering``
      [rad] and ``max_acceleration`` [m/s^2] (equal to ``guardian.traffic_accel``: the car-following sets take
      one bound for the ego's braking and the traffic's); input ``[acceleration, steering]``; ``meta``: the
      stack's own controller steers lane changes (steps then give the target lane); ``max_jerk`` [m/s^3]: its
      actuator holds an acceleration over a step and changes it by at most ``max_jerk * dt`` from one step to the
      next, the speed stopping at 0; ``lag`` [s]: its actuator follows a command as a first-order lag of that time
      constant, sampled each step (the acceleration held over a step moves the share ``1 - exp(-dt / lag)`` of the
      way to the command; with ``max_jerk``, within its bound too). With either, each step gives the ego's
      ``acceleration`` applied over the last step, the guardian decides on ``itha.actuator.RateLimitedSet`` and
      answers only commands whose applied acceleration it admits;
    * ``point_mass``: the overtake model (6.3) of Chapter 6 among traffic, input ``[a_ex, v_ey]``, with the
      service's intention library: ``acceleration`` and ``lateral_speed`` its bounds and ``dt`` its period
      (they must be the library's), ``lateral_scale`` metres per unit of ``y_e``. Steps name the ``lead``.

    A field of the other model is refused, as is every other model."""

    model: str = "bicycle"
    length: Positive = Field(le=30)
    width: Positive = Field(le=5)
    dt: Positive = Field(le=2)
    max_steering: Positive | None = Field(None, lt=math.pi / 2)
    max_acceleration: Positive | None = Field(None, le=20)
    meta: StrictBool | None = None
    max_jerk: Positive | None = Field(None, le=10000)
    lag: Positive | None = Field(None, le=60)
    acceleration: tuple[Finite, Finite] | None = None
    lateral_speed: tuple[Finite, Finite] | None = None
    lateral_scale: Positive | None = Field(None, le=20)

    def refusal(self, config: GuardianConfig, params, road) -> str | None:
        """Why the guardian cannot guarantee this vehicle on ``road`` (None when it can); ``params``: the
        service's ``OvertakeParams``."""
        if self.model not in MODEL_FIELDS:
            return (f"vehicle model {self.model!r} is not supervised: scene sessions decide for the kinematic "
                    "bicycle ('bicycle', as highway-env's vehicles move) and the overtake point mass of (6.3) "
                    "('point_mass'); a dynamic model (tyre slip) is neither")
        own = set(MODEL_FIELDS[self.model]) | set(MODEL_OPTIONS[self.model])
        foreign = sorted(f for fields in MODEL_FIELDS.values() for f in fields if f not in own
                         and getattr(self, f) is not None) + (["meta"] if "meta" not in own and self.meta else []) \
            + [f for f in ("max_jerk", "lag") if f not in own and getattr(self, f) is not None]
        if foreign:
            return f"vehicle field(s) {', '.join(foreign)} do not apply to model {self.model!r}"
        missing = [f for f in MODEL_FIELDS[self.model] if getattr(self, f) is None]
        if missing:
            return f"vehicle model {self.model!r} needs {', '.join(missing)}"
        if self.model == "bicycle":
            return self._bicycle_refusal(config)
        return self._point_mass_refusal(params, road)

    def _bicycle_refusal(self, config: GuardianConfig) -> str | None:
        if self.max_acceleration != config.traffic_accel:
            return (f"vehicle max_acceleration {self.max_acceleration:g} m/s^2 differs from guardian.traffic_accel "
                    f"{config.traffic_accel:g} m/s^2: the car-following sets take one bound for the ego's braking "
                    "and the traffic's; give them equal")
        return None

    def _point_mass_refusal(self, p, road) -> str | None:
        given = {"dt": self.dt, "acceleration": tuple(self.acceleration), "lateral_speed": tuple(self.lateral_speed)}
        built = {"dt": p.dt, "acceleration": tuple(p.a_ex_bounds), "lateral_speed": tuple(p.v_ey_bounds)}
        for name, value in given.items():
            if value != built[name]:
                return (f"vehicle {name} {value} is not the {built[name]} the service's sets were computed for "
                        "(the point mass is decided by the intention library's sets: serve a library built for "
                        "this vehicle)")
        if p.v_ex_bounds[0] > 0:
            return (f"a point mass among traffic must be able to wait behind its lead: the service's library takes "
                    f"v_ex >= {p.v_ex_bounds[0]:g} m/s (a free left lane); start it with "
                    "'guardian serve --ego-speed-min 0'")
        if isinstance(road, RoadMap) or road.n_lanes < 2:
            return "a point-mass session needs a straight road of at least 2 lanes (no spans, ends or branches)"
        lane_width = 2 * p.left_lane_y * self.lateral_scale
        if not math.isclose(road.lane_width, lane_width, rel_tol=1e-9):
            return (f"road lane_width {road.lane_width:g} m is not the model's {lane_width:g} m (2 left_lane_y "
                    f"= {2 * p.left_lane_y:g} units of y_e at lateral_scale {self.lateral_scale:g} m)")
        return None


class GuardianSpec(_Strict):
    """The guardian's options (``guardian.config.GuardianConfig``; the defaults are highway-env's limits)."""

    overapprox: Literal["trivial", "ordered"] = "trivial"
    h_min: Positive = 2.0
    v_max: Positive = 40.0
    traffic_accel: Positive = 6.0
    wreck_margin: Finite = Field(1.0, ge=0)
    reverse_reach: Finite = Field(21.0, ge=0)
    reverse_horizon: Finite = Field(1.0, ge=0)

    def config(self) -> GuardianConfig:
        return GuardianConfig(**self.model_dump())


class SceneSettings(_Strict):
    """Body of ``POST /sessions`` for a scene session."""

    kind: Literal["scene"]
    road: RoadSpec
    vehicle: VehicleSpec
    guardian: GuardianSpec = GuardianSpec()


class EgoSpec(_Strict):
    """The ego now: its centre ``(x, y)``, heading [rad] and speed [m/s]; ``front`` its front bumper along the
    road (default ``x + length / 2``); ``lane`` the lane it is closest to and ``target_lane`` the lane its
    controller steers to (defaults: the lane whose centre is nearest; that lane); ``announces``: it takes part
    in the ordered over-approximation (several guarded cars); ``acceleration`` [m/s^2]: what its actuator applied
    over the last step (required when the vehicle declares ``max_jerk``, refused otherwise)."""

    x: Finite
    y: Finite
    heading: Finite = Field(0.0, ge=-math.pi, le=math.pi)
    speed: Finite
    front: Finite | None = None
    lane: Slot | None = None
    target_lane: Slot | None = None
    announces: StrictBool = False
    acceleration: Finite | None = None


class CarSpec(_Strict):
    """Another car: its body (centre, heading, length, width), speed and what its reader knows of it: ``lanes``
    it is in or moving to, ``beside`` lanes it may move into, ``swings`` (default: when it drives backwards),
    ``own`` the lane it follows in, ``announced`` lanes it announced (another guarded car), ``crashed``,
    ``blind`` (does not see the ego), ``fixed`` (an obstacle). Its lanes are those its body overlaps and these."""

    id: str = Field(min_length=1, max_length=64)
    x: Finite
    y: Finite
    heading: Finite = Field(0.0, ge=-math.pi, le=math.pi)
    speed: Finite
    length: Positive = Field(le=30)
    width: Positive = Field(le=5)
    front: Finite | None = None
    own: Slot | None = None
    lanes: list[Slot] = Field(default=[], max_length=64)
    beside: list[Slot] = Field(default=[], max_length=64)
    swings: StrictBool | None = None
    announced: list[Slot] = Field(default=[], max_length=64)
    announces: StrictBool = False
    crashed: StrictBool = False
    blind: StrictBool = False
    fixed: StrictBool = False


class SceneStep(_Strict):
    """Body of one scene step: its sequence number, the ego, the other cars and the proposed input
    (bicycle ``[acceleration m/s^2, steering rad]``, point mass ``[a_ex m/s^2, v_ey units of y_e/s]``);
    ``lead``: a point mass's lead, the id of one of ``cars`` (the car ahead in the right lane, (6.3))."""

    seq: StrictInt = Field(ge=0, le=2 ** 62)
    ego: EgoSpec
    cars: list[CarSpec] = Field(default=[], max_length=MAX_CARS)
    input: tuple[Finite, Finite]
    lead: str | None = Field(None, min_length=1, max_length=64)

    @field_validator("cars")
    @classmethod
    def _ids_once(cls, cars):
        seen = set()
        for c in cars:
            if c.id in seen:
                raise ValueError(f"car id {c.id!r} appears twice")
            seen.add(c.id)
        return cars


class LaneChangeQuery(_Strict):
    """Body of ``POST /sessions/ID/lane_change``: may the ego begin a lane change to ``to`` now (meta agents:
    judged once, before the controller starts it)?"""

    ego: EgoSpec
    cars: list[CarSpec] = Field(default=[], max_length=MAX_CARS)
    to: StrictInt = Field(ge=-64, le=127)   # a lane beyond the road's is answered "no such lane"


class SceneGuardian:
    """One scene session's guardian: its road, vehicle, decision object and model coverage.

    ``library``: the service's intention library (a point mass is decided by its sets)."""

    def __init__(self, settings: SceneSettings, library):
        self.config = settings.guardian.config()
        try:
            self.road = settings.road.road()
        except (ValueError, TypeError, ConfigError) as exc:
            raise ServiceError(422, f"road: {exc}") from None
        refusal = settings.vehicle.refusal(self.config, library.params, self.road)
        if refusal:
            raise ServiceError(422, refusal)
        self.vehicle = settings.vehicle
        self.ego = (_PointMass if self.vehicle.model == "point_mass" else _Bicycle)(self, library)
        self.car_ids: dict[str, int] = {}
        self.model = {"vehicle": self.vehicle.model_dump(exclude_none=True), "guardian": settings.guardian.model_dump()}

    # ---- the request as the decision object's inputs ------------------------------------------------------
    def sensed(self, c: CarSpec) -> Sensed:
        own = c.own if c.own is not None else self.road.nearest_slot(c.x, c.y)
        swings = c.speed < 0 if c.swings is None else c.swings
        return Sensed(c.id, c.x, c.y, c.heading, c.speed, c.length, c.width,
                      c.front if c.front is not None else c.x + c.length / 2, own, frozenset(c.lanes),
                      frozenset(c.beside), swings, self.road.numbering.itha_set(c.announced), c.announces, c.crashed,
                      c.blind, c.fixed)

    def scene(self, me: Car, cars):
        ends = self.road.end_cars() if isinstance(self.road, RoadMap) else ()
        return scene_of(self.road, me, [self.sensed(c) for c in cars], self.config.reversing,
                        BicycleEgo.LATERAL_MARGIN, ends)

    # ---- the routes' work -----------------------------------------------------------------------------------
    def lane_change(self, q: LaneChangeQuery) -> dict:
        answer = self.ego.lane_change(q)
        return {**answer, "reason": self.slot_text(answer["reason"])}

    def slot_text(self, text: str) -> str:
        return self.road.numbering.slot_text(text)

    def step(self, req: SceneStep) -> dict:
        applied, d, snapshot = self.ego.decide(req)
        for car in req.cars:
            self.car_ids.setdefault(car.id, len(self.car_ids))
        coverage = self._coverage(req, snapshot)
        slots = self.road.numbering.slot_set
        return {"applied": [float(applied[0]), float(applied[1])], "proposed": [float(v) for v in req.input],
                "overridden": d.changed != "none", "safety_override": d.changed != "none" and not d.clipped_to_model,
                "changed": d.changed, "level": d.level, "failsafe": d.level == "failsafe", "reasons": [self.slot_text(r) for r in d.reasons],
                "lanes": sorted(slots(d.lanes)), "entered": sorted(slots(d.entered)),
                "refused": sorted(slots(d.refused)), "touched": sorted(slots(d.touched)),
                "entries": [{"lane": self.road.numbering.slot(e.lane), "responsible": e.responsible,
                             "reason": self.slot_text(e.reason)} for e in d.entries],
                "in_invariant_set": bool(d.in_invariant_set), "clipped_to_model": bool(d.clipped_to_model),
                "admissible_acceleration": [[float(lo), float(hi)] for lo, hi in d.admissible_acceleration],
                "coverage": coverage, "model": self.model,
                **({"state": [float(v) for v in snapshot["x"]]} if "x" in snapshot else {})}

    def _coverage(self, req: SceneStep, snapshot: dict) -> dict:
        """The transition since the last step against the model (``guardian.decide.coverage``)."""
        moving = [c for c in req.cars if not c.fixed and c.id != req.lead]
        ids = np.array([self.car_ids[c.id] for c in moving], dtype=np.int64)
        x_v = np.array([(c.x, c.speed) for c in moving], dtype=float).reshape(-1, 2)
        lanes = [self.sensed(c).own for c in moving] if self.ego.coverage.reversing.any_may(x_v[:, 1]) else []
        counts = self.ego.coverage.observe({"traffic": (ids, x_v), "lanes": lanes, **snapshot})
        names = ("ego", "lead", "traffic", "traffic_reversing_uncovered") if "x" in snapshot else \
            ("ego", "traffic", "traffic_reversing_uncovered")
        return {**{k: int(counts[k]) for k in names},
                "totals": {k: int(self.ego.coverage.totals[k]) for k in names}}

    def reset(self) -> None:
        self.ego.guard.reset()
        self.ego.coverage.reset()


class _Bicycle:
    """A bicycle ego: ``guardian.decide.bicycle.BicycleGuardian`` (the gymnasium wrapper's highway roads)."""

    def __init__(self, scene: SceneGuardian, library):
        v, c, road = scene.vehicle, scene.config, scene.road
        if isinstance(road, RoadMap):
            kin = RoadMapEgo(v.dt, c.traffic_accel, v.length, v.width, road, v.max_steering)
        else:
            kin = BicycleEgo(v.dt, c.traffic_accel, v.length, v.width, road.lane_width, road.n_lanes, v.max_steering)
        self.scene = scene
        self.actuator = None if v.max_jerk is None and v.lag is None else Actuator(
            jerk=math.inf if v.max_jerk is None else v.max_jerk, lag=v.lag or 0.0, profile="hold")
        self.guard = BicycleGuardian(kin, c, meta=bool(v.meta), actuator=self.actuator)
        self.coverage = ModelCoverage(v.dt, (-c.traffic_accel, c.traffic_accel), c.v_max, ego_kinematics=kin,
                                      ego_stops_at_zero=self.actuator is not None, reversing=c.reversing)

    def state(self, e: EgoSpec) -> EgoState:
        road = self.scene.road
        lane = e.lane if e.lane is not None else road.nearest_slot(e.x, e.y)
        target = e.target_lane if e.target_lane is not None else lane
        front = e.front if e.front is not None else e.x + self.scene.vehicle.length / 2
        if (e.acceleration is None) != (self.actuator is None):
            raise ServiceError(422, "ego.acceleration is required: the vehicle declares max_jerk or lag (what its "
                                    "actuator applied over the last step)" if self.actuator is not None else
                               "ego.acceleration applies to a vehicle that declares max_jerk or lag only")
        bound = self.scene.config.traffic_accel
        if e.acceleration is not None and not -bound <= e.acceleration <= bound:
            raise ServiceError(422, f"ego.acceleration {e.acceleration:g} m/s^2 is outside the vehicle's bounds "
                                    f"±{bound:g} (max_acceleration): the actuator cannot have applied it")
        return EgoState(front, e.y, e.heading, e.speed, lane, target, e.x, e.acceleration or 0.0)

    def _scene(self, e: EgoSpec, state: EgoState, cars):
        return self.scene.scene(Car(state.front, state.speed, frozenset(), self.scene.vehicle.length, "ego",
                                    e.announces), cars)

    def lane_change(self, q: LaneChangeQuery) -> dict:
        state = self.state(q.ego)
        allowed, reason = self.guard.policy_lane_change(state, self._scene(q.ego, state, q.cars), q.to)
        return {"allowed": bool(allowed), "reason": reason}

    def decide(self, req: SceneStep):
        if req.lead is not None:
            raise ServiceError(422, "field 'lead' applies to point-mass sessions only (a bicycle's cars are all "
                                    "traffic)")
        state = self.state(req.ego)
        applied, d = self.guard.step(state, self._scene(req.ego, state, req.cars), req.input)
        e = req.ego
        moved_by = np.array(applied, float)   # a copy: the model moves the car by what its actuator applies
        if self.actuator is not None:
            moved_by[0] = self.actuator.follows(state.acceleration, float(applied[0]), self.scene.vehicle.dt)
        return applied, d, {"applied": moved_by, "ego": (e.x, e.speed, e.heading)}


class _PointMass:
    """The overtake point mass among traffic: ``guardian.decide.overtake.PointMassGuardian`` (the gymnasium
    wrapper's ``HighwayOvertake-v0``). Its lanes are the road's two rightmost (y_e = 0 the right lane's centre,
    growing to the left); the state is ``[v_ex, y_e, h, v_Lx]`` with ``h`` the lead's centre ahead of the ego's."""

    def __init__(self, scene: SceneGuardian, library):
        from guardian.decide.overtake import PointMassGuardian
        from guardian.service.sessions import ModelDomain

        v, c, road = scene.vehicle, scene.config, scene.road
        self.scene, self.params = scene, library.params
        self.y_right = (road.n_lanes - 1) * road.lane_width  # a straight road (VehicleSpec.refusal): y0 = 0
        self.guard = PointMassGuardian(library, road.n_lanes, v.width / 2 / v.lateral_scale, True, c)
        self.coverage = ModelCoverage(v.dt, (-c.traffic_accel, c.traffic_accel), c.v_max, library.params,
                                      {n: library.models[n] for n in ("aggressive", "cautious")},
                                      ego_stops_at_zero=True, reversing=c.reversing)
        self.domain = ModelDomain.of(library)

    def lane_change(self, q: LaneChangeQuery) -> dict:
        raise ServiceError(409, "a point-mass session judges lane changes in its steps (the lateral speed v_ey)")

    def state(self, req: SceneStep) -> tuple[np.ndarray, list]:
        """The overtake state and the traffic (every car but the lead)."""
        e = req.ego
        inapplicable = [n for n in ("front", "lane", "target_lane", "acceleration") if getattr(e, n) is not None]
        if e.heading != 0.0:
            inapplicable.append("heading")
        if inapplicable:
            raise ServiceError(422, f"ego field(s) {', '.join(inapplicable)} do not apply to a point mass "
                                    "(it has no heading and its lanes are its body's)")
        lead = next((c for c in req.cars if c.id == req.lead), None)
        if lead is None:
            raise ServiceError(422, "a point-mass step names its lead: field 'lead' must be the id of one of 'cars'"
                               + (f" (no car {req.lead!r})" if req.lead is not None else ""))
        x = np.array([e.speed, (self.y_right - e.y) / self.scene.vehicle.lateral_scale, lead.x - e.x, lead.speed])
        bad = self.domain.violations(x)
        if bad:
            raise ServiceError(422, "state outside the model domain: " + "; ".join(bad))
        return x, [c for c in req.cars if c is not lead]

    def decide(self, req: SceneStep):
        x, traffic = self.state(req)
        e, length = req.ego, self.scene.vehicle.length
        scene = self.scene.scene(Car(e.x + length / 2, e.speed, frozenset(), length, "ego", e.announces), traffic)
        applied, d = self.guard.step(x, scene, req.input)
        return applied, d, {"applied": np.asarray(applied, float), "ego": (e.x, e.speed, 0.0), "x": x}
