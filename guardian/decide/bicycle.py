"""highway-env's own vehicles among traffic: ITHA (Chapter 7) for a kinematic-bicycle ego.

A decision object without a simulator: ``BicycleGuardian.step(ego, scene, proposed)`` takes the ego's
bicycle state (``EgoState``), the other cars as ITHA agents and the proposed ``[acceleration,
steering]``, and returns the input to apply and a ``Decision``.

* Acceleration: self-safety (7.4) towards the nearest car ahead in every lane the body occupies or
  may occupy within the step (its swept body, widened by ``BicycleEgo.LATERAL_MARGIN``: highway-env's
  collision test extrapolates velocities over a step), and, while an entry lasts, the entered lane's
  follower kept in its set.
* Steering (continuous agents): the proposed angle if the body, after one step with it and then the
  straightening steering until the heading is back to 0 (``BicycleEgo.path``), enters no lane whose
  entry was not ρ̂-responsible (7.5) and stays on the road; else the nearest angle that does. Only the
  agent's own angle may begin an entry: the guardian never starts a lane change.
* Meta agents: lane changes are judged once per policy step (``policy_lane_change``); a lane change
  under way whose target the body has not reached yet is re-judged every step and abandoned
  (``Decision.refused``) when it is no longer responsible.
* Lanes the road brings to the body: where a lane begins beside the ego or an on-ramp's strip closes in,
  the (widened) body can overlap a lane it never entered. Only lanes the body holds (where it began,
  the lane it is in alone, entries judged responsible) are its own; a lane it touches beyond them is
  judged as an entry (7.5) the moment it is touched and, when that is not responsible, is a lane the
  steering must not enter further (no path may overlap it) until the body is clear of it.
* Fail-safe: the hardest braking down to standstill (never reversing), steering straight.
* An actuator that limits the acceleration's change (``Actuator(jerk, lag, profile="hold")``, declared by the
  world: ``envs.actuator.Actuated``): the ego's own set is ``itha.actuator.RateLimitedSet`` bound to its speed and
  acceleration now, the accelerations are those the actuator applies next (``Actuator.reach``: ``[a - jerk dt,
  a + jerk dt] ∩ U`` without a lag; the speed stopping at 0), and the fail-safe brakes as hard as the actuator
  allows. A proposal beyond the reach is a clip to the model (the actuator could not follow it either), not a
  safety override. Under a lag the driver's command is judged by the acceleration the lag makes of it, and a
  changed one is answered as the command that applies the acceleration chosen (``Actuator.asks``); the
  admissible accelerations are reported as commands too.
"""
from __future__ import annotations

import math

import numpy as np

from guardian.decide.kinematics import BicycleEgo
from guardian.decide.traffic import TrafficSupervisor
from guardian.model.decision import Decision, Entry
from guardian.model.lanes import LaneNumbering
from guardian.model.scene import EgoState, Scene
from itha.actuator import RateLimitedSet
from itha.car_following import CarFollowingParams
from rcis.intervals import intersect_intervals, nearest_in_intervals

UNCHANGED = 1e-9          # [m/s^2] an acceleration moved less than this is the proposal's (not an override)
UNCHANGED_LAGGED = 2e-9   # under a lag: full throttle asks the reach's very end, which the intervals' rounding
#                           shrink (kinematics.ROUNDING, 1e-9) leaves just outside, by float noise more or less


class BicycleGuardian:
    """The traffic part alone, for a ``highway-v0``-family ego (see the module docstring).

    Parameters
    ----------
    kin : BicycleEgo or RoadMapEgo
        The ego's kinematics (step, lanes, steering limits) on its road.
    config : guardian.config.GuardianConfig
    meta : bool
        The agent gives meta actions (the vehicle's controller steers).
    actuator : itha.actuator.Actuator, optional
        The ego's actuator, when it limits how fast the acceleration changes (see the module docstring).
    """

    def __init__(self, kin: BicycleEgo, config, meta: bool, actuator=None):
        c = config
        cf = CarFollowingParams(dt=kin.dt, v_max=c.v_max, h_min=c.h_min, u_min=-c.traffic_accel,
                                u_max=c.traffic_accel, d_min=-c.traffic_accel, d_max=c.traffic_accel)
        self.plain = TrafficSupervisor(cf, None, c.overapprox, c.wreck_margin)
        self.traffic = self.plain   # bound to the ego's state at each decision when an actuator is declared
        if actuator is not None and actuator.delay:
            raise ValueError("BicycleGuardian: an actuator with a reaction delay is not supervised yet: the traffic "
                             "rules judge the ego's next speed, which a delay has already fixed (entries and their "
                             "followers would have to be judged over the queued steps)")
        self.actuator = actuator
        self.ego_set = None if actuator is None else RateLimitedSet(cf, actuator)
        self.reach = None           # the accelerations the actuator reaches now (None: ±traffic_accel)
        self.kin, self.config, self.meta = kin, config, meta
        self.lanes = LaneNumbering(kin.n_lanes)   # the kinematics' slots, the scene's and decisions' ITHA lanes
        self.reset()

    def reset(self) -> None:
        self.home = None
        self.held = None          # slots the body may overlap: the start's, home, responsible entries
        self.authorized = set()   # slots being entered after a responsible entry

    def _bind(self, ego: EgoState) -> None:
        """The ego's own set and reach for this decision (an actuated ego's depend on its state now)."""
        if self.ego_set is not None:
            bound = self.ego_set.bound(ego.speed, ego.acceleration)
            self.traffic, self.reach = self.plain.with_ego_set(bound), bound.commands

    def _applies(self, ego: EgoState, command: float) -> float:
        """The acceleration the ego's actuator applies over the next step for ``command`` (itself without a lag;
        beyond the reach a proposal stays beyond it: the clip is the model's, and said)."""
        act = self.actuator
        return command if act is None else act.lagged(ego.acceleration, command, self.kin.dt)

    def _command(self, ego: EgoState, applied: float) -> float:
        """The command that makes the actuator apply ``applied`` (an acceleration of its reach)."""
        act, bound = self.actuator, self.config.traffic_accel
        return applied if act is None else act.asks(ego.acceleration, applied, -bound, bound, self.kin.dt)

    def _in_model(self, ego: EgoState) -> bool:
        """Is the ego's acceleration now one its actuator can apply (within U)?"""
        return -self.config.traffic_accel <= ego.acceleration <= self.config.traffic_accel

    def _accels(self, ego: EgoState, speeds) -> list:
        return self.kin.accel_for_speeds(ego.speed, speeds, self.reach)

    def inside(self, ego: EgoState, scene: Scene) -> bool:
        """Is ``ego`` inside its invariant set: some acceleration self-safe (7.4) towards the cars ahead in
        every lane its body overlaps?"""
        self._bind(ego)
        lanes = self.lanes.itha_set(set(self.kin.body_lanes(ego)) or {ego.lane})
        speeds, _ = self.traffic.self_safe_speeds(scene.with_ego_lanes(lanes))
        return bool(self._accels(ego, speeds))

    def speed_limits(self, ego: EgoState, gaps, lead_speed: float) -> list:
        """The slice of the ego's car-following set behind a car at ``lead_speed`` (with an actuator, at the ego's
        acceleration now): for each gap [m], the highest ego speed inside the set (None where none is). What a
        recording draws; the decisions ask the set in next speeds."""
        if self.ego_set is not None:
            return [self.ego_set.speed_limit(float(h), lead_speed, ego.acceleration) for h in gaps]
        out = []
        for h in gaps:
            speeds = self.plain.S.speed_intervals(float(h), lead_speed)
            out.append(speeds[-1][1] if speeds else None)
        return out

    # ---- policy level (meta agents) ------------------------------------------------------------------
    def policy_lane_change(self, ego: EgoState, scene: Scene, target: int) -> tuple[bool, str]:
        """Is a meta agent's lane change from ``ego.lane`` to ``target`` ρ̂-responsible now (7.5), with an
        acceleration that also keeps self-safety?"""
        self._bind(ego)
        if ego.lane != ego.target_lane:
            return False, "a lane change is already under way"
        if not 0 <= target < self.kin.n_lanes:
            return False, "no such lane"
        if target == ego.lane:
            return False, "not a lane change: that is the ego's own lane"
        if abs(target - ego.lane) != 1:
            return False, (f"lane {self.lanes.itha(target)} is not next to the ego's lane {self.lanes.itha(ego.lane)}: "
                           "one lane at a time")
        if not self.kin.lane_here(target, ego):
            return False, "no lane there at this point of the road"
        lane, home = self.lanes.itha(target), self.lanes.itha(ego.lane)
        verdict = self.traffic.entry(scene.with_ego_lanes({home}), lane)
        if not verdict.responsible:
            return False, verdict.reason
        both = {home, lane}
        speeds, why = self.traffic.self_safe_speeds(scene.with_ego_lanes(both))
        ok = bool(self._accels(ego, intersect_intervals(speeds, verdict.speeds)))
        return ok, "" if ok else (why or "no input reaches a responsible and self-safe speed")

    # ---- one simulation step -----------------------------------------------------------------------------
    def step(self, ego: EgoState, scene: Scene, proposed) -> tuple[np.ndarray, Decision]:
        """Supervise one simulation step.

        Parameters
        ----------
        ego : EgoState
            The bicycle ego now.
        scene : Scene
            The other cars as ITHA agents.
        proposed : pair of floats
            ``[acceleration, steering]`` as the vehicle computed it from the agent's action.

        Returns
        -------
        applied : ndarray
            ``[acceleration, steering]`` with the acceleration in ``[-a_max, a_max]`` and never below
            ``-speed / dt`` (no reversing); with an actuator, within its reach (the speed stops at 0).
        decision : Decision
            ``refused`` holds the target of a meta lane change to abandon.
        """
        a_prop, asked = (float(v) for v in proposed)
        if not (math.isfinite(a_prop) and math.isfinite(asked)):
            raise ValueError(f"the proposal [{a_prop}, {asked}] is not finite: a supervisor acts only on what it "
                             "checked")
        kin = self.kin
        self._bind(ego)
        d = Decision(proposed=[a_prop, asked], applied=[], changed="none")
        steer_prop = min(max(asked, -kin.max_steering), kin.max_steering)  # a client may ask beyond the bound
        if steer_prop != asked:
            d.note(f"steering clipped to the model's bound ±{kin.max_steering:g} rad")
        now = set(kin.occupied(ego)) or {ego.lane}
        if self.held is None:
            self.held = set(now)  # the start: every lane the body overlaps when supervision begins
        if len(now) == 1:
            self.home = next(iter(now))
        elif self.home not in now:
            self.home = ego.lane
        self.authorized &= now - {self.home}
        self.held = (self.held & now) | {self.home} | self.authorized
        touched, touched_speeds = self._touched(ego, scene, now, d)
        held = self.held & now or now  # where the body is and may be: the start of any entry
        if self.meta:
            occupied, entry = self._meta_lanes(ego, scene, now, held, d)
            steer = self._meta_steering(ego, scene, occupied - touched, steer_prop, d)
        else:
            steer, occupied, entry = self._steering(ego, scene, now, held, steer_prop, d, touched)
        entry = intersect_intervals(entry, touched_speeds)
        accel, limits = self._accelerations(ego, scene, occupied, entry, d)
        if accel and self.reach is not None and not self._in_model(ego):
            accel = []
            d.note(f"the acceleration now, {ego.acceleration:g} m/s^2, is outside the actuator's bounds "
                   f"±{self.config.traffic_accel:g}: outside the model")
        wanted = self._applies(ego, a_prop)   # judged in the accelerations the actuator applies
        unchanged = UNCHANGED if self.actuator is None or not self.actuator.lag else UNCHANGED_LAGGED
        if accel:
            chosen = nearest_in_intervals(accel, wanted)
            if abs(chosen - wanted) > unchanged:
                self._explain(ego, wanted, chosen, limits, d)
        elif self.reach is not None:
            chosen = self.reach[0]   # the hardest braking the actuator allows; the speed stops at 0
            d.level, d.changed = "failsafe", "failsafe"
            d.note("failsafe: no self-safe acceleration; braking as hard as the actuator allows, down to standstill")
        else:
            bound = self.config.traffic_accel  # a reversing ego (speed < 0) is stopped no harder than the bound
            chosen = min(max(-bound, -ego.speed / kin.dt), bound)
            d.level, d.changed = "failsafe", "failsafe"
            d.note("failsafe: no self-safe acceleration; braking as hard as the model allows, down to standstill")
        a = a_prop if chosen == wanted else self._command(ego, chosen)   # under a lag, the command that applies it
        if not accel and self.reach is not None and not self._in_model(ego):
            a = -self.config.traffic_accel   # the actuator's state is outside the model: the hardest command
        throttled = abs(chosen - wanted) > unchanged
        d.applied = [a, steer]
        self.authorized |= self.lanes.slot_set(_entered(d))
        self.held |= self.authorized
        d.entered = sorted(self.lanes.itha_set(self.authorized))
        d.lanes = sorted(self.lanes.itha_set(self.held))  # never a lane entered unchecked
        d.touched = sorted(self.lanes.itha_set(touched - self.held))
        d.admissible_acceleration = [[self._command(ego, lo), self._command(ego, hi)] for lo, hi in accel]
        d.in_invariant_set = bool(accel)
        if d.changed == "none" and (throttled or abs(steer - asked) > 1e-12):
            d.changed = "throttle" if abs(steer - asked) <= 1e-12 else ("steering" if not throttled else "both")
            if steer_prop != asked and steer == steer_prop and (not throttled or d.clipped_to_model):
                d.clipped_to_model = True  # the only change: clips to the model's bounds
        return np.array([a, steer]), d

    def _touched(self, ego: EgoState, scene: Scene, now: set, d: Decision) -> tuple[set, list]:
        """Lanes the body overlaps but does not hold: each judged as an entry (7.5) now (the body is in it
        for the cars there). Returns those not responsible (the steering must not enter them further) and
        the next speeds of the responsible ones' entries; the responsible ones are held from now on."""
        speeds_all = [(0.0, np.inf)]
        refused = set()
        for lane_id in sorted(now - self.held):
            lane = self.lanes.itha(lane_id)
            d.note(f"the road brings lane {lane} to the body")
            speeds = self._entry(ego, scene, self.held, lane_id, d)
            if speeds is None:
                d.note(f"lane {lane} touched, its entry refused: {d.entries[-1].reason}")
                refused.add(lane_id)
                continue
            speeds_all = intersect_intervals(speeds_all, speeds)
            self.authorized.add(lane_id)
            self.held.add(lane_id)
        return refused, speeds_all

    def _entry(self, ego: EgoState, scene: Scene, now: set, lane_id: int, d: Decision) -> list | None:
        """Next speeds making the entry into highway lane ``lane_id`` responsible (7.5) and self-safe in
        both lanes; None (and the refusal recorded) when there are none."""
        lane = self.lanes.itha(lane_id)
        start = now if len(now) == 1 else {ego.lane}  # straddling: judged from the lane it is closest to
        if abs(next(iter(start)) - lane_id) != 1:
            d.entries.append(Entry(lane, False, "not next to the lane the ego is in"))
            d.refused.append(lane)
            return None
        if not self.kin.lane_here(lane_id, ego):
            d.entries.append(Entry(lane, False, "no lane there at this point of the road"))
            d.refused.append(lane)
            return None
        verdict = self.traffic.entry(scene.with_ego_lanes(self.lanes.itha_set(start)), lane)
        speeds = verdict.speeds
        if verdict.responsible:
            safe, _ = self.traffic.self_safe_speeds(scene.with_ego_lanes(self.lanes.itha_set(now) | {lane}))
            speeds = intersect_intervals(speeds, safe)
        ok = verdict.responsible and bool(self._accels(ego, speeds))
        reason = verdict.reason or ("" if ok else "no acceleration reaches a responsible, self-safe speed")
        d.entries.append(Entry(lane, ok, reason))
        if not ok:
            d.refused.append(lane)
            return None
        return speeds

    def _meta_lanes(self, ego: EgoState, scene: Scene, now: set, held: set, d: Decision):
        """Lanes the meta ego occupies this step and the entry's next speeds; a lane change not yet
        begun is re-judged, and abandoned (``d.refused``) when it is no longer responsible."""
        if ego.target_lane != ego.lane and ego.target_lane not in self.held:
            speeds = self._entry(ego, scene, held, ego.target_lane, d)
            if speeds is None:
                d.changed = "lane_change"
                d.note(f"lane change to lane {self.lanes.itha(ego.target_lane)} abandoned: {d.entries[-1].reason}")
                return now | {ego.lane}, [(0.0, np.inf)]
            return now | {ego.lane, ego.target_lane}, speeds
        return now | {ego.lane, ego.target_lane}, [(0.0, np.inf)]

    def _meta_steering(self, ego: EgoState, scene: Scene, occupied: set, proposed: float, d: Decision) -> float:
        """The controller's steering when its path (steering, then straightening) keeps the body in the
        lanes the meta lane change holds (``occupied``); else the nearest steering whose path does. At low
        speed highway-env's controller turns a lane change steeply, and the rotated body would reach past
        the target lane."""
        kin = self.kin
        for k, steer in enumerate(kin.candidates(ego, proposed)):
            if k > 0 and kin.turns_too_far(ego, kin.after(ego, steer)):
                continue
            lanes, _ = kin.path_lanes_of(ego, steer)
            beyond = lanes - occupied
            near = "" if beyond else self._closes_in(ego, scene, steer)
            if not beyond and not near:
                return float(steer)
            if k == 0:
                d.note(f"steering {proposed:.3f} rad refused: " + (
                    f"the lane change's path would reach lanes {sorted(self.lanes.itha_set(beyond))} beyond the "
                    "lanes it holds" if beyond else f"the body would close in sideways on {near} beside it"))
        d.level, d.changed = "failsafe", "failsafe"
        d.note("failsafe: no steering keeps the body in the lanes the lane change holds; straightening")
        return float(kin.recovery(ego))

    def _steering(self, ego: EgoState, scene: Scene, now: set, held: set, proposed: float, d: Decision,
                  touched: set):
        """The steering nearest to the proposal whose path enters no lane irresponsibly (a lane the body
        only touches, ``touched``, counts as not entered: its path may not overlap it)."""
        kin = self.kin
        depth_now = kin.depth_of(ego)
        for k, steer in enumerate(kin.candidates(ego, proposed)):
            why = f"steering {proposed:.3f} rad refused: " if k == 0 else ""  # only the proposal's refusal is said
            nxt = kin.after(ego, steer)
            if kin.turns_too_far(ego, nxt):
                d.note(why and why + f"the heading would pass the bound of {kin.MAX_HEADING} rad")
                continue
            lanes, depth = kin.path_lanes_of(ego, steer)
            if depth > depth_now + 1e-9:
                d.note(why and why + "the body would leave the road before its heading is straightened")
                continue  # leaves the road, or further than it already is
            new = lanes - held
            entry = [(0.0, np.inf)]
            if new & touched:
                d.note(why and why + f"the body would stay in lanes {sorted(self.lanes.itha_set(new & touched))}"
                       ", whose entry is refused")
                continue
            if new:
                if k > 0 or len(held) != 1 or len(new) != 1:
                    d.note(why and why + (f"it would enter lanes {sorted(self.lanes.itha_set(new))} at once"
                                          if len(held) == 1 else "it would enter another lane while the body "
                                          f"straddles lanes {sorted(self.lanes.itha_set(held))}"))
                    continue
                entry = self._entry(ego, scene, held, next(iter(new)), d)
                if entry is None:
                    d.note(f"entering lane {d.entries[-1].lane} refused: {d.entries[-1].reason}")
                    continue
            near = self._closes_in(ego, scene, steer)
            if near:
                d.note(why and why + f"the body would close in sideways on {near} beside it")
                continue
            return float(steer), now | set(kin.lanes_after(ego, nxt)) | set(lanes), entry
        d.level, d.changed = "failsafe", "failsafe"
        d.note("failsafe: no steering keeps the body out of lanes it may not enter and clear of the cars beside it; "
               "straightening")
        steer = kin.recovery(ego)
        lanes, _ = kin.path_lanes_of(ego, steer)
        return steer, now | set(lanes), [(0.0, np.inf)]

    def _closes_in(self, ego: EgoState, scene: Scene, steering: float) -> str:
        """The name of a car beside the ego (its body alongside, or able to come alongside before the path of
        ``steering`` is done) whose body the path would reach further into sideways than the ego's body reaches
        now; "" when there is none. The traffic rules order cars along a lane; a body over a lane line beside
        the ego is not ordered, and only the ego's own sideways motion can close that gap."""
        index = scene.lane_index
        if not index.any_across:
            return ""
        across, horizon = self.kin.path_across_of(ego, steering)
        (now_lo, now_hi), accel = across[0], self.config.traffic_accel
        # a car further along the road than any closing speed, the traffic's acceleration and both bodies reach is
        # skipped below: only the cars within that distance are read
        reach = ((abs(ego.speed) + index.fastest) * horizon + accel * horizon ** 2 + index.longest + self.kin.length
                 + 1.0)
        for car in (index.cars[i] for i in index.near(ego.front, reach, scene.own)):
            if not car.across:
                continue
            gap = max(car.front - car.length - ego.front, ego.front - self.kin.length - car.front)
            if gap > abs(ego.speed - car.speed) * horizon + accel * horizon ** 2:
                continue
            lo, hi = car.across
            depth_now = max(min(now_hi, hi) - max(now_lo, lo), 0.0)
            if max(min(h1, hi) - max(l1, lo) for l1, h1 in across) > depth_now + 1e-9:
                return car.name or "a car"
        return ""

    def _accelerations(self, ego: EgoState, scene: Scene, occupied: set, entry: list, d: Decision) -> tuple:
        """Self-safe accelerations (7.4) in every occupied lane, within the entry's responsible speeds,
        keeping each entered lane's follower while that is possible; and the limits on the next speed, named
        (``[(name, speeds), ...]``, for ``_explain``)."""
        kin = self.kin
        itha = self.lanes.itha_set(occupied)
        ego_scene = scene.with_ego_lanes(itha)
        limits = [(f"self-safety towards {car.name} ahead in lane {lane}" + self._risk_note(ego_scene, car), sp)
                  for lane, car, sp in self.traffic.leader_speeds(ego_scene)]
        speeds, why = self.traffic.self_safe_speeds(ego_scene)
        d.note(why)
        speeds = intersect_intervals(speeds, entry)
        entered = _entered(d)
        if entered:
            limits.append((f"the entry into lane {entered[-1]} (7.5)", entry))
        progress = kin.progress_of(ego)
        for lane in sorted(itha - {self.lanes.itha(self.home)}):
            fs, why = self.traffic.follower_speeds(ego_scene, lane, ego_progress_min=progress)
            kept = intersect_intervals(speeds, fs)
            if self._accels(ego, kept):
                speeds = kept
                limits.append((f"keeping the follower in lane {lane} safe while entering it", fs))
            else:
                d.level = "follower_dropped"
                d.note(why)
                d.note("responsibility for a follower not kept (it was responsible when the entry began)")
        return self._accels(ego, speeds), limits

    def _risk_note(self, scene: Scene, car) -> str:
        risk = self.traffic.at_risk(scene, car)
        return f" (at risk of a crash, kept as if it may stop at once: {risk})" if risk else ""

    def _explain(self, ego: EgoState, a_prop: float, a: float, limits: list, d: Decision) -> None:
        """Say which part limited the acceleration; a clip at the speed bound alone is a modelling clip."""
        v_prop = ego.speed + self.kin.dt * a_prop
        if a_prop > a and v_prop > self.config.v_max and a >= (self.config.v_max - ego.speed) / self.kin.dt - 1e-6:
            d.clipped_to_model = True
            d.note(f"acceleration clipped at the model's top speed {self.config.v_max:g} m/s")
            return
        if abs(a_prop) > self.kin.accel and abs(a) >= self.kin.accel - 1e-9:
            d.clipped_to_model = True
            d.note(f"acceleration clipped to the model's bound ±{self.kin.accel:g} m/s^2")
            return
        if self.reach is not None:
            lo, hi = self.reach
            if (a_prop > hi and a >= hi - 1e-8) or (a_prop < lo and a <= lo + 1e-8):   # speeds' rounding aside
                d.clipped_to_model = True
                d.note(f"acceleration clipped to what the actuator reaches from {ego.acceleration:.2f} m/s^2: "
                       f"[{lo:.2f}, {hi:.2f}] ({self._actuator_named()})")
                return
        for name, speeds in limits:
            if not any(lo <= v_prop <= hi for lo, hi in speeds):
                bound = max((hi for lo, hi in speeds if hi < v_prop), default=None)
                d.note(f"acceleration limited by {name}" + (f": next speed at most {bound:.2f} m/s" if bound is not None
                                                             else ""))

    def _actuator_named(self) -> str:
        act = self.actuator
        return ", ".join(([] if math.isinf(act.jerk) else [f"jerk {act.jerk:g} m/s^3"]) +
                         ([f"lag {act.lag:g} s"] if act.lag else []))


def _entered(d: Decision) -> list:
    """The ITHA lanes whose entry was judged responsible so far in this step, in the order judged."""
    return [e.lane for e in d.entries if e.responsible]
