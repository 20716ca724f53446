"""The guardian: one gymnasium wrapper between any highway-env agent and the vehicle.

Each simulation step it composes

* the **lead part** (Chapter 6, ``guardian/HighwayOvertake-v0`` only): the LP
  intention estimator on the lead's observed transitions and the admissible set
  ``S(x)`` of the active RCIS (``C_a`` / ``C_c`` once identified, ``C_bnd`` before;
  Theorem 4) — ``IntentionAwareGuardian``;
* the **traffic part** (Chapter 7): self-safety (7.4) against the nearest car
  ahead in every lane the ego's body occupies, and responsibility (7.5) when the
  ego's body would enter another lane (trivial ρ̂: highway-env traffic announces
  nothing); while an entry lasts the ego also keeps the entered lane's follower
  in its RCIS — ``TrafficSupervisor``;

into one admissible input set, keeps the agent's input when it is admissible and
otherwise applies the nearest admissible input (throttle first, then steering,
then both). On the ``highway-v0`` family no car is a lead in the overtake sense
(its vehicles do not follow (6.3)), so the traffic part is the guardian
(``active_set = "itha"``).

Agents: ``ContinuousAction`` (acceleration, steering) and ``DiscreteMetaAction``.
On ``highway-v0`` a refused meta lane change becomes ``IDLE`` and a refused
continuous steering is replaced by the nearest steering that keeps the body out
of the lane (and the heading within ``BicycleEgo.MAX_HEADING``); on
``HighwayOvertake-v0`` the lateral velocity is limited so the body stays out,
and a meta agent's lane change is abandoned.

Fail-safes (each counted). The parts' sets do not intersect (``conflict``): first
the responsibility for an entered lane's follower is dropped (the lead's set and
self-safety are kept); if self-safety against the car ahead and ``S(x)`` still do
not intersect, ``GuardianConfig.conflict`` decides: ``"traffic"`` (default) brakes
for the car ahead with the lateral input of ``S(x)`` — the pair may then leave the
safe set (6.8) by its speed bound —, ``"lead"`` keeps ``S(x)``. The active set's
``S(x)`` is empty (``failsafe``): full braking, no lateral motion; the traffic
part alone is empty on ``highway-v0``: full braking.

``info["guardian"]`` (the key is asserted free)::

    {"proposed": [a, lateral] | "LANE_LEFT" ...,  # the agent's action (decoded for continuous agents)
     "applied": [a, lateral] | "IDLE" ...,         # what the vehicle received (last simulation step)
     "overridden": bool, "changed": "none" | "throttle" | "steering" | "both" | "lane_change"
                                   | "conflict" | "failsafe",
     "reasons": [str, ...],            # why, part by part
     "refused_lane_change": bool,
     "active_set": "aggressive" | "cautious" | "bounded_velocity" | "itha",
     "valid_intentions": [str, ...], "identified": str | None,
     "in_invariant_set": bool,         # Theorem 4's assumption held (lead part)
     "sim_steps": int, "clipped_steps": int, "conflict_steps": int, "failsafe_steps": int,
     "model_violations": {"ego": int, "lead": int, "traffic": int},
     "admissible_acceleration": [[lo, hi], ...]}   # at the applied lateral input, last simulation step
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.road.lane import StraightLane
from highway_env.vehicle.controller import ControlledVehicle

from envs.highway_overtake import ConfigError, HighwayOvertakeEnv
from envs.vehicles import OvertakeEgo
from guardian.ego import BicycleEgo, PointMassEgo
from guardian.monitor import ModelMonitor
from guardian.supervisor import FAILSAFE_INPUT, IntentionAwareGuardian
from guardian.traffic import Car, Scene, TrafficSupervisor
from itha.car_following import CarFollowingParams
from rcis.intervals import intersect_intervals, nearest_in_intervals

LANE_CHANGES = ("LANE_LEFT", "LANE_RIGHT")
ACTION_TYPES = ("ContinuousAction", "DiscreteMetaAction")


@dataclass(frozen=True)
class GuardianConfig:
    """Bounds of the traffic part and choices of the lead part (highway-env's limits as defaults)."""

    h_min: float = 2.0            # [m] bumper to bumper, against traffic
    v_max: float = 40.0           # [m/s] highway-env's Vehicle.MAX_SPEED
    traffic_accel: float = 6.0    # [m/s^2] |a| of the traffic (IDMVehicle.ACC_MAX): their D and U
    overapprox: str = "trivial"   # highway-env traffic announces no lane change
    use_intention: bool = True    # lead part: switch to C_a / C_c once identified (Theorem 4)
    horizon: int = 10             # lead part: the estimator's window N
    priority: tuple = (0, 1)      # change throttle before steering
    conflict: str = "traffic"     # when self-safety against a car ahead and the lead's set do not intersect,
                                  # which wins: "traffic" (brake for the car ahead) | "lead"

    def __post_init__(self):
        if self.conflict not in ("lead", "traffic"):
            raise ConfigError(f"GuardianConfig.conflict must be 'lead' or 'traffic', got {self.conflict!r}")
        if self.overapprox not in ("trivial", "ordered"):
            raise ConfigError(f"GuardianConfig.overapprox must be 'trivial' or 'ordered', got {self.overapprox!r}")


def _action_kind(base) -> str:
    kind = type(base.action_type).__name__
    if kind not in ACTION_TYPES:
        raise ConfigError(f"Guardian: config 'action.type' {kind!r} cannot be supervised; use one of {ACTION_TYPES}")
    if kind == "ContinuousAction" and not (base.action_type.longitudinal and base.action_type.lateral):
        raise ConfigError("Guardian: config 'action' must control both axes ('longitudinal' and 'lateral' true)")
    if kind == "DiscreteMetaAction" and list(base.action_type.actions.values()) != \
            ["LANE_LEFT", "IDLE", "LANE_RIGHT", "FASTER", "SLOWER"]:
        raise ConfigError("Guardian: config 'action' must offer all five meta actions "
                          "('longitudinal' and 'lateral' true)")
    return kind


def _straight_lanes(base) -> tuple[int, float]:
    """The road's lanes as parallel straight lanes along x, equally spaced; else a ConfigError."""
    graph = base.road.network.graph
    lanes = [lane for _from in graph.values() for group in _from.values() for lane in group]
    ok = bool(lanes) and all(isinstance(lane, StraightLane) and abs(lane.heading) < 1e-9 for lane in lanes)
    if ok:
        ys = sorted(float(lane.start[1]) for lane in lanes)
        widths = {round(lane.width, 9) for lane in lanes}
        gaps = {round(b - a, 9) for a, b in zip(ys, ys[1:])}
        ok = len(graph) == 1 and len(widths) == 1 and (len(ys) == 1 or gaps == widths) and abs(ys[0]) < 1e-9
    if not ok:
        raise ConfigError("Guardian: the road must be one straight multi-lane road along x with equal lanes "
                          "(highway-env's 'highway-v0' family, config 'lanes_count'); this env's road is not")
    return len(lanes), float(lanes[0].width)


def overtake_traffic_supervisor(p, c: GuardianConfig) -> TrafficSupervisor:
    """The traffic part for the overtake ego (6.3) among highway-env traffic.

    The ego's speed falls by at least ``|a_min| - w_ex^max`` per second under full braking
    (drag only helps); as a leader it may brake by up to ``|a_min| + b_e v_max - w_ex^min``.
    """
    ego_brake = p.a_ex_bounds[0] + p.w_ex_bounds[1]
    ego_hardest = p.a_ex_bounds[0] - p.b_e * c.v_max + p.w_ex_bounds[0]
    ego = CarFollowingParams(dt=p.dt, v_max=c.v_max, h_min=c.h_min, u_min=ego_brake,
                             u_max=p.a_ex_bounds[1] + p.w_ex_bounds[1], d_min=-c.traffic_accel,
                             d_max=c.traffic_accel)
    others = CarFollowingParams(dt=p.dt, v_max=c.v_max, h_min=c.h_min, u_min=-c.traffic_accel,
                                u_max=c.traffic_accel, d_min=min(-c.traffic_accel, ego_hardest),
                                d_max=c.traffic_accel)
    return TrafficSupervisor(ego, others, c.overapprox)


def road_scene(base, ego_lanes, n_lanes: int) -> Scene:
    """The road as ITHA agents: the ego (in ``ego_lanes``) and every car but the overtake lead.

    A car changing lanes (``lane_index != target_lane_index``) occupies both; ITHA lane = n - id.
    """
    ego, lead = base.vehicle, getattr(base, "lead", None)
    others = []
    for k, veh in enumerate(base.road.vehicles):
        if veh is ego or veh is lead:
            continue
        lane = veh.lane_index[2]
        target = veh.target_lane_index[2] if _is_controlled(type(veh)) else lane
        others.append(Car(float(veh.position[0]) + veh.LENGTH / 2, float(veh.speed),
                          _itha_lanes(n_lanes, lane, target), veh.LENGTH, f"car {k}"))
    me = Car(float(ego.position[0]) + ego.LENGTH / 2, float(ego.speed), frozenset(ego_lanes), ego.LENGTH, "ego")
    return Scene(me, tuple(others), n_lanes)


@functools.lru_cache(maxsize=None)
def _is_controlled(vehicle_type) -> bool:
    return issubclass(vehicle_type, ControlledVehicle)


@functools.lru_cache(maxsize=None)
def _itha_lanes(n_lanes: int, lane: int, target: int) -> frozenset:
    """ITHA lanes (``n - id``) of a car in ``lane`` heading for ``target``."""
    return frozenset({n_lanes - lane, n_lanes - target})


class EntryLedger:
    """Which of the overtake ego's lane entries were ρ̂-responsible (7.5) when they began.

    Kept alongside any rollout (guarded or not) so that a collision's fault follows ITHA: a car
    that hits the ego after the ego entered its lane responsibly is the one at fault.
    """

    def __init__(self, base, config: GuardianConfig = GuardianConfig()):
        self.n_lanes, _ = _straight_lanes(base)
        self.traffic = overtake_traffic_supervisor(base.params, config)
        self.kin = PointMassEgo(base.params, OvertakeEgo.WIDTH / 2 / base.config["lateral_scale"], self.n_lanes)
        self.responsible = {}
        self._before = None

    def before_step(self, base) -> None:
        lanes = self.kin.lanes_at(base.overtake_state()[1])
        self._before = (lanes, road_scene(base, lanes, self.n_lanes))

    def after_step(self, base) -> None:
        lanes_before, scene = self._before
        lanes = self.kin.lanes_at(base.overtake_state()[1])
        for lane in lanes - lanes_before:
            ok = len(lanes_before) == 1 and self.traffic.entry(scene, lane).responsible
            self.responsible[lane] = ok
        for lane in set(self.responsible) - set(lanes):
            del self.responsible[lane]

    def entered_responsibly(self, lane_id: int) -> bool:
        return self.responsible.get(self.n_lanes - lane_id, False)


class Guardian(gym.Wrapper):
    """Supervises the ego of ``guardian/HighwayOvertake-v0`` or a ``highway-v0``-family environment.

    Parameters
    ----------
    env : gymnasium.Env
        The environment (possibly wrapped); its ``unwrapped`` is a highway-env ``AbstractEnv``.
    library : intention.library.OvertakeLibrary, optional
        The overtake RCIS library; required on ``HighwayOvertake-v0`` (the lead part), unused elsewhere.
    config : GuardianConfig
    """

    def __init__(self, env: gym.Env, library=None, config: GuardianConfig = GuardianConfig()):
        super().__init__(env)
        base = env.unwrapped
        if not isinstance(base, AbstractEnv):
            raise ConfigError(f"Guardian: {type(base).__name__} is not a highway-env environment")
        self.config = config
        self.kind = _action_kind(base)
        self.scenario = "overtake" if isinstance(base, HighwayOvertakeEnv) else "highway"
        self.n_lanes, self.lane_width = _straight_lanes(base)
        self.dt = 1.0 / base.config["simulation_frequency"]
        self.lead = None
        if self.scenario == "overtake":
            self._init_overtake(base, library)
        else:
            self._init_highway(base)
        self._stats = None
        self._view = {}
        self._last_record = None

    # ---- construction ----------------------------------------------------------------------------
    def _init_overtake(self, base, library) -> None:
        if library is None:
            raise ConfigError("Guardian: HighwayOvertake needs the overtake RCIS library (intention.library.build_library)")
        p = base.params
        if library.params != p:
            raise ConfigError("Guardian: the library was computed for other OvertakeParams than the env's "
                              "config 'params'; rebuild it with the env's parameters")
        c = self.config
        self.lead = IntentionAwareGuardian(library, use_intention=c.use_intention, horizon=c.horizon,
                                           priority=c.priority)
        self.traffic = overtake_traffic_supervisor(p, c)
        half = OvertakeEgo.WIDTH / 2 / base.config["lateral_scale"]
        self.ego_kin = PointMassEgo(p, half, self.n_lanes)
        self.monitor = ModelMonitor(self.dt, (-c.traffic_accel, c.traffic_accel), c.v_max, p,
                                    {n: library.models[n] for n in ("aggressive", "cautious")})

    def _init_highway(self, base) -> None:
        c = self.config
        cf = CarFollowingParams(dt=self.dt, v_max=c.v_max, h_min=c.h_min, u_min=-c.traffic_accel,
                                u_max=c.traffic_accel, d_min=-c.traffic_accel, d_max=c.traffic_accel)
        self.traffic = TrafficSupervisor(cf, None, c.overapprox)
        ego = base.vehicle
        max_steer = float(getattr(ego, "MAX_STEERING_ANGLE", np.pi / 3))
        if self.kind == "ContinuousAction":
            max_steer = float(max(abs(s) for s in base.action_type.steering_range))
        self.ego_kin = BicycleEgo(self.dt, c.traffic_accel, ego.LENGTH, ego.WIDTH, self.lane_width, self.n_lanes,
                                  max_steer)
        self.monitor = ModelMonitor(self.dt, (-c.traffic_accel, c.traffic_accel), c.v_max,
                                    ego_kinematics=self.ego_kin)

    # ---- the road as ITHA agents ---------------------------------------------------------------------
    def _itha_lane(self, lane_id: int) -> int:
        return self.n_lanes - lane_id

    def _scene(self, base, ego_lanes) -> Scene:
        return road_scene(base, ego_lanes, self.n_lanes)

    # ---- gym API --------------------------------------------------------------------------------------
    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        base = self.env.unwrapped
        ego = base.vehicle
        self._original_act = ego.act
        ego.act = self._supervised_act
        self._agent_command = dict(ego.action)
        self._home = None
        self._authorized = frozenset()
        if self.lead is not None:
            self.lead.reset()
        self.monitor.reset()
        self._new_stats()
        self._last_record = None
        assert "guardian" not in info
        info["guardian"] = {"enabled": True, "scenario": self.scenario, "action": self.kind}
        return obs, info

    def _new_stats(self) -> None:
        self._stats = {"sim_steps": 0, "clipped_steps": 0, "conflict_steps": 0, "failsafe_steps": 0,
                       "reasons": [], "refused_lane_change": False, "changed": "none",
                       "model_violations": {"ego": 0, "lead": 0, "traffic": 0}}

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
            the guardian did (proposed and applied inputs, overrides and their reasons, model
            violations, conflicts, fail-safe steps).
        """
        base = self.env.unwrapped
        self._new_stats()
        proposed, applied_action = self._policy_level(base, action)
        obs, reward, terminated, truncated, info = self.env.step(applied_action)
        assert "guardian" not in info
        info["guardian"] = self._record(base, proposed)
        return obs, reward, terminated, truncated, info

    def _policy_level(self, base, action):
        """Meta lane changes on highway-v0 are decided here, once per policy step (issue 4's rule)."""
        if self.kind != "DiscreteMetaAction":
            return np.asarray(action, dtype=float).tolist(), action
        names = base.action_type.actions
        proposed = names[int(action)]
        if self.scenario == "highway" and proposed in LANE_CHANGES:
            ego = base.vehicle
            if ego.lane_index[2] != ego.target_lane_index[2]:
                return proposed, self._refuse(base, "a lane change is already under way")
            target = ego.lane_index[2] + (-1 if proposed == "LANE_LEFT" else 1)
            scene = self._scene(base, {self._itha_lane(ego.lane_index[2])})
            verdict = self.traffic.entry(scene, self._itha_lane(target)) if 0 <= target < self.n_lanes else None
            ok = verdict is not None and verdict.responsible and \
                self.ego_kin.accel_for_speeds(float(ego.speed), verdict.speeds)
            if not ok:
                return proposed, self._refuse(base, verdict.reason if verdict else "no such lane")
        return proposed, action

    def _refuse(self, base, reason: str) -> int:
        self._stats["refused_lane_change"] = True
        self._stats["changed"] = "lane_change"
        self._stats["reasons"].append(f"lane change refused: {reason}")
        return base.action_type.actions_indexes["IDLE"]

    # ---- the per-simulation-step supervision ------------------------------------------------------------
    def _supervised_act(self, action=None):
        base = self.env.unwrapped
        ego = base.vehicle
        if action is not None:  # the agent's action, decoded once per policy step
            self._original_act(action)
            self._agent_command = dict(ego.action)
            return
        if not isinstance(ego, (ControlledVehicle, OvertakeEgo)):
            ego.action = dict(self._agent_command)  # a plain Vehicle keeps the last command
        self._original_act(None)
        if self.scenario == "overtake":
            self._supervise_overtake(base, ego)
        else:
            self._supervise_highway(base, ego)
        self._stats["sim_steps"] += 1

    def _count_model(self, base, applied) -> None:
        for k, n in self.monitor.observe(base, applied).items():
            self._stats["model_violations"][k] += n

    def _note(self, reason: str) -> None:
        if reason and reason not in self._stats["reasons"]:
            self._stats["reasons"].append(reason)

    # overtake: lead part ∩ traffic part in the (a_ex, v_ey) plane
    def _supervise_overtake(self, base, ego) -> None:
        x = base.overtake_state()
        u = ego.input.copy()
        view = self.lead.observe(x)
        lanes = self.ego_kin.lanes_at(x[1])
        if len(lanes) == 1:
            self._home = next(iter(lanes))
            self._authorized = frozenset()
        scene = self._scene(base, lanes)
        self._accel_self, accel = self._traffic_accelerations(scene, x[0], lanes - {self._home})
        lateral, entering = [tuple(base.params.v_ey_bounds)], None
        for lane in sorted(self.ego_kin.next_lanes(x[1], u[1]) - lanes - self._authorized):
            verdict = self.traffic.entry(scene, lane) if len(lanes) == 1 else None
            if verdict is not None and verdict.responsible:
                entering = (lane, self.ego_kin.accel_for_speeds(x[0], verdict.speeds))
            else:
                lateral = self._keep_out(lateral, x[1], lane, verdict.reason if verdict else "")
        self._refused_now = False
        applied, changed = self._compose(view, x, u, accel, lateral, entering)
        if self._refused_now and applied[1] != u[1]:
            if ego.meta is not None:
                ego.keep_lane()
            self._stats["refused_lane_change"] = True
        self._finish(base, ego, x, u, applied, changed, view, accel)

    def _traffic_accelerations(self, scene, v: float, entering_lanes, progress_min=None):
        """``(self-safe, self-safe and keeping each entered lane's follower safe)`` accelerations (7.4)."""
        speeds, why = self.traffic.self_safe_speeds(scene)
        self._note(why)
        self_safe = self.ego_kin.accel_for_speeds(v, speeds)
        for lane in sorted(entering_lanes):  # an entry under way: its follower stays safe
            fs, why = self.traffic.follower_speeds(scene, lane, ego_progress_min=progress_min)
            speeds = intersect_intervals(speeds, fs)
            self._note(why)
        return self_safe, self.ego_kin.accel_for_speeds(v, speeds)

    def _keep_out(self, lateral, y, lane, reason):
        lo, hi = self.ego_kin.lateral_keep_out(y, lane)
        self._refused_now = True
        self._note(f"entering lane {lane} refused: {reason}" if reason else f"entering lane {lane} refused")
        return intersect_intervals(lateral, [(lo, hi)])

    def _compose(self, view, x, u, accel, lateral, entering):
        """The nearest input of ``S(x) ∩ traffic``; an entry is tried first and refused if it cannot hold."""
        adm, pr = view.admissible, self.config.priority
        if entering is not None:
            lane, entry_accel = entering
            boxes = [(a, v) for a in intersect_intervals(accel, entry_accel) for v in lateral]
            result = adm.override(x, u, pr, query=view.query.restricted(boxes))
            if result.feasible:
                self._authorized = self._authorized | {lane}
                return result.applied, result.changed
            lateral = self._keep_out(lateral, x[1], lane, "no input keeps both parts' sets")
        boxes = [(a, v) for a in accel for v in lateral]
        result = adm.override(x, u, pr, query=view.query.restricted(boxes))
        if result.feasible:
            return result.applied, result.changed
        if view.query.polygons:
            self._stats["conflict_steps"] += 1
            self._note("conflict: the lead's and the traffic's admissible sets do not intersect")
            if self._accel_self:  # 1. responsibility for followers yields to both sets
                full = [tuple(self.env.unwrapped.params.v_ey_bounds)]
                result = adm.override(x, u, pr, query=view.query.restricted(
                    [(a, v) for a in self._accel_self for v in full]))
                if result.feasible:
                    self._note("responsibility for a follower not kept (the lead's set and self-safety come first)")
                    return result.applied, "conflict"
            return self._resolve_conflict(view, x, u, self._accel_self, lateral), "conflict"
        self._stats["failsafe_steps"] += 1
        self._note("failsafe: the state is outside the active invariant set")
        return np.array(FAILSAFE_INPUT, dtype=float), "failsafe"

    def _resolve_conflict(self, view, x, u, accel, lateral) -> np.ndarray:
        """Self-safety against a car ahead and ``S(x)`` do not intersect.

        ``conflict = "traffic"``: the lateral input of ``S(x)`` nearest to the agent's, and the
        self-safe acceleration nearest to it (the ego brakes for the car ahead; the pair may leave the
        safe set (6.8) by its speed bound); ``"lead"``: the input of ``S(x)`` nearest to the traffic
        part's set (Theorem 4 holds; the car ahead may be hit if it brakes hard)."""
        target = u.copy()
        if accel:
            target[0] = nearest_in_intervals(accel, u[0])
        if lateral:
            target[1] = nearest_in_intervals(lateral, u[1])
        near = view.admissible.override(x, target, self.config.priority, query=view.query).applied
        if self.config.conflict == "lead" or not accel:
            return near
        self._note("the lead's set yields to self-safety against the car ahead")
        return np.array([nearest_in_intervals(accel, near[0]), near[1]])

    def _finish(self, base, ego, x, u, applied, changed, view, accel) -> None:
        applied = np.asarray(applied, dtype=float)
        self._count_model(base, applied)
        ego.action = {"acceleration": float(applied[0]), "steering": float(applied[1])}
        self.lead.commit(x, applied)
        self._stats["clipped_steps"] += int(not np.array_equal(applied, u))
        if changed != "none":
            self._stats["changed"] = changed
        self._stats["proposed_input"], self._stats["applied_input"] = u.tolist(), applied.tolist()
        self._view = {"active_set": view.name, "inside": view.inside,
                      "admissible_acceleration": [list(r) for r in intersect_intervals(
                          view.query.ranges(0, applied[1]), accel)] if accel else []}

    # highway-v0: traffic part alone, highway-env's bicycle
    def _supervise_highway(self, base, ego) -> None:
        a_prop = float(ego.action["acceleration"])
        steer_prop = float(ego.action["steering"])
        heading, y = float(ego.heading), float(ego.position[1])
        if self.kind == "DiscreteMetaAction":
            ids = {ego.lane_index[2], ego.target_lane_index[2]}
            crossing = {self._itha_lane(ego.target_lane_index[2])} - {self._itha_lane(ego.lane_index[2])}
        else:
            ids = set(self.ego_kin.lanes_at(y, heading)) or {ego.lane_index[2]}
            if len(ids) == 1:
                self._home, self._authorized = next(iter(ids)), frozenset()
            crossing = {self._itha_lane(i) for i in ids - {self._home}}
        scene = self._scene(base, {self._itha_lane(i) for i in ids})
        _, accel = self._traffic_accelerations(scene, float(ego.speed), crossing,
                                               self.ego_kin.min_progress(float(ego.speed), heading))
        steer = steer_prop
        if self.kind == "ContinuousAction":
            steer = self._guard_steering(base, ego, scene, ids, steer_prop, accel)
            accel = self._accel_after_entry
        if accel:
            a = nearest_in_intervals(accel, a_prop)
        else:
            a = -self.config.traffic_accel
            self._stats["failsafe_steps"] += 1
            self._note("failsafe: no self-safe acceleration (outside the car-following RCIS)")
        self._count_model(base, (a, steer))
        ego.action = {"acceleration": a, "steering": steer}
        clipped = abs(a - a_prop) > 1e-9 or abs(steer - steer_prop) > 1e-12
        self._stats["clipped_steps"] += int(clipped)
        if clipped and self._stats["changed"] == "none":
            self._stats["changed"] = "throttle" if abs(steer - steer_prop) <= 1e-12 else "steering"
        self._stats["proposed_input"], self._stats["applied_input"] = [a_prop, steer_prop], [a, steer]
        self._view = {"active_set": "itha", "inside": bool(accel), "admissible_acceleration": [list(r) for r in accel]}

    def _guard_steering(self, base, ego, scene, ids, proposed, accel) -> float:
        """The steering nearest to the proposal that enters no lane irresponsibly and keeps the heading small."""
        kin = self.ego_kin
        self._accel_after_entry = accel
        y, heading, v = float(ego.position[1]), float(ego.heading), float(ego.speed)
        allowed = set(ids) | set(self._authorized)
        for k, steer in enumerate(kin.steering_candidates(proposed, heading)):
            y1, h1 = kin.predict(y, heading, v, steer)
            if abs(h1) > kin.MAX_HEADING and abs(h1) > abs(heading):
                continue
            if kin.off_road(y1, h1) and not kin.off_road(y, heading):
                continue
            new = set(kin.lanes_at(y1, h1)) - allowed
            if new:
                if k > 0 or len(ids) != 1 or len(new) != 1:
                    continue
                verdict = self.traffic.entry(scene, self._itha_lane(next(iter(new))))
                entry_accel = intersect_intervals(accel, kin.accel_for_speeds(v, verdict.speeds))
                if not (verdict.responsible and entry_accel):
                    self._stats["refused_lane_change"] = True
                    self._note(f"entering lane {self._itha_lane(next(iter(new)))} refused: "
                               f"{verdict.reason or 'no self-safe input'}")
                    continue
                self._authorized = frozenset(set(self._authorized) | new)
                self._accel_after_entry = entry_accel
            return float(steer)
        self._stats["failsafe_steps"] += 1
        self._note("failsafe: no steering keeps the body in its lanes; steering straight")
        return float(kin.steering_candidates(0.0, heading)[1])

    # ---- rendering -------------------------------------------------------------------------------
    def render(self):
        """highway-env's frame with the guardian's panel below it (``rgb_array``); other modes unchanged."""
        frame = self.env.render()
        if not isinstance(frame, np.ndarray):
            return frame
        from guardian.panel import with_panel

        a = self.config.traffic_accel if self.scenario == "highway" else self.env.unwrapped.params.a_ex_bounds[1]
        return with_panel(frame, self._last_record or {"active_set": "-", "reasons": ["episode start"]}, (-a, a))

    # ---- info --------------------------------------------------------------------------------------
    def _record(self, base, proposed) -> dict:
        s = self._stats
        applied = proposed
        if self.kind == "DiscreteMetaAction":
            applied = "IDLE" if s["refused_lane_change"] and self.scenario == "highway" else proposed
        else:
            applied = s.get("applied_input", proposed)
            proposed = s.get("proposed_input", proposed)
        lead = self.lead
        out = {"proposed": proposed, "applied": applied,
               "overridden": bool(s["clipped_steps"] or s["refused_lane_change"]),
               "changed": s["changed"], "reasons": list(s["reasons"]),
               "refused_lane_change": s["refused_lane_change"],
               "active_set": self._view.get("active_set", "itha"),
               "valid_intentions": list(lead.estimator.valid) if lead else [],
               "identified": lead.identified if lead else None,
               "in_invariant_set": bool(self._view.get("inside", True)),
               "admissible_acceleration": self._view.get("admissible_acceleration", []),
               **{k: s[k] for k in ("sim_steps", "clipped_steps", "conflict_steps", "failsafe_steps")},
               "model_violations": dict(s["model_violations"])}
        if self.kind == "DiscreteMetaAction":
            out["proposed_input"] = s.get("proposed_input")
            out["applied_input"] = s.get("applied_input")
        self._last_record = dict(out, proposed_input=s.get("proposed_input"), applied_input=s.get("applied_input"))
        return out
