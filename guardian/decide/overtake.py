"""The overtake ego among traffic: the lead part (Chapter 6) composed with ITHA (Chapter 7).

A decision object without a simulator: ``PointMassGuardian.step(x, scene, u)`` takes the overtake
state ``x = [v_ex, y_e, h, v_Lx]`` (6.3), the other cars as ITHA agents (``guardian.model.scene.Scene``; the
lead is not among them, ``x`` describes it) and the proposed input ``u = [a_ex, v_ey]``, and returns the
input to apply and a ``Decision``.

**The composed invariant set.** The overtake sets ``C_a``, ``C_c``, ``C_bnd`` (Section 6.4.1) are grown
inside-out from ``C_left``: every state of them can reach the left lane within a bounded number of
steps, so behind a slower lead they can only steer left. With traffic in the left lane that escape may
be taken by another car for as long as it likes; no guarantee may rest on it. With traffic the guardian
therefore keeps the ego in

    K = F_R ∪ (C ∩ {the body overlaps the left lane, entered responsibly}) ∪ (C ∩ {the lead is behind})

* ``F_R`` (``lead_following_params``): the ego in its own (right) lane behind the lead, self-safe
  towards it as in (7.4) with both cars' drag of (6.3), the ego's hardest braking ``a_ex^min + w_ex^max``
  and the lead's ``a_L^min`` (every intention model's lead brakes no harder: the saturation (6.6)
  keeps ``a_L + w_Δ + w_Lx >= a_L^min``), and ``h >= h_min`` of (6.8). The set is the maximal RCIS of
  that pair (``itha.car_following.MaximalSet`` with drag), so the ego can wait behind the lead for
  ever, down to standstill, without the left lane: this needs a safe set whose speed floor is 0, not
  the dissertation's 16 m/s. With the intention in use the guardian keeps ``F_R^M`` instead
  (``guardian.decide.lead_following``): ``F_R`` grown by the states from which braking reaches it under every
  lead of the intentions ``M`` the estimator has not ruled out, an RCIS of each of them; ``M`` only
  shrinks, so the set only grows, and with every intention ruled out it is ``F_R`` again.
* ``C``: the active intention-aware set (Theorem 4), used while the body overlaps the left lane: the
  entry into it was ρ̂-responsible (7.5), so from then on the cars behind in it answer for themselves,
  and ``C_left ⊆ C`` is invariant with any braking (speed floor 0), so self-safety towards a car
  ahead in the left lane and ``C`` do not exclude each other.

Inputs are chosen per lateral sub-interval of ``U_e`` (``PointMassEgo.lateral_partition``): inputs
whose body stays in the right lane (lead ahead) must land in ``F_R``; inputs whose body surely
overlaps the left lane must land in ``C``; inputs for which the noise ``w_ey`` decides must land in
both (whichever way the noise goes, the next state is in ``K``). If the left lane is new to the body,
the entry must be responsible for the applied input's next speed. Without traffic (the two cars of Section 6.5) the guardian is
exactly ``IntentionAwareGuardian``.

When the parts do not intersect, they are dropped in the order of ``guardian.model.decision.LEVELS``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from guardian.model.decision import Decision, Entry
from guardian.decide.kinematics import PointMassEgo
from guardian.decide.lead_following import LeadFollowing, lead_following_params  # noqa: F401 - re-exported
from guardian.model.scene import Scene
from guardian.decide.lead import FAILSAFE_INPUT, IntentionAwareGuardian
from guardian.decide.traffic import TrafficSupervisor
from intention.params import OvertakeParams
from itha.car_following import CarFollowingParams, MaximalSet
from rcis.admissible import AdmissibleQuery
from rcis.intervals import intersect_intervals, nearest_in_intervals
from rcis.pwa import RUNTIME_MARGIN
from rcis.validate import finite_vector

RIGHT_LANE = 1   # ITHA lane of the lead (and of the ego at the start)
STANDSTILL_OFFSET = RUNTIME_MARGIN * 1.001  # [m/s] see PointMassGuardian._standstill_aware
LEFT_LANE = 2


def lead_as_follower_params(p: OvertakeParams) -> CarFollowingParams:
    """The lead behind the ego, as an ITHA follower: its sure braking ``a_L^min + w^max`` with its drag;
    the ego ahead of it brakes at most ``a_ex^min + w_ex^min`` with its drag."""
    w_hi = p.w_delta_bounds[1] + p.w_Lx_bounds[1]
    return CarFollowingParams(dt=p.dt, v_max=max(p.v_ex_bounds[1], p.v_Lx_bounds[1]), h_min=p.h_min,
                              u_min=p.a_L_bounds[0] + w_hi, u_max=p.a_L_bounds[1] + w_hi,
                              d_min=p.a_ex_bounds[0] + p.w_ex_bounds[0], d_max=p.a_ex_bounds[1] + p.w_ex_bounds[1],
                              drag=p.b_L, lead_drag=p.b_e)


@dataclass
class _Part:
    """One lateral sub-interval of ``U_e`` and what its inputs must satisfy (next speeds)."""

    lateral: tuple           # (lo, hi) of v_ey
    lanes: frozenset         # lanes the body may overlap next step
    new: frozenset           # of them, lanes it does not overlap now
    self_safe: list          # next speeds: self-safety (7.4) towards traffic in every lane of now | next
    entry: list              # next speeds: the entry (7.5) of the new lane (all speeds when none)
    followers: list          # next speeds: the followers of lanes being entered stay in their sets
    target: str              # "follow" (F_R) | "C" | "both" (the noise decides whether the body leaves the lane)
    follow: list             # next speeds into F_R (target "follow")
    lead_as_car: list        # next speeds: the lead as an ordinary car (level "conflict")


class PointMassGuardian:
    """The overtake ego of ``guardian/HighwayOvertake-v0`` among traffic (see the module docstring).

    Parameters
    ----------
    library : intention.library.OvertakeLibrary
        The lead part's sets; with traffic they must allow the ego to stop (``v_ex^min = 0``).
    n_lanes : int
        Lanes of the road (ITHA lane 1 is the lead's).
    half_width : float
        Half the ego's width in units of ``y_e``.
    traffic : bool
        Other cars may share the road: compose with ITHA and keep ``K``; False gives the two-car
        guardian of Section 6.5 unchanged.
    config : guardian.config.GuardianConfig
    stops_at_zero : bool
        The simulator clips the ego's speed at 0 (``HighwayOvertake-v0`` does).
    """

    def __init__(self, library, n_lanes: int, half_width: float, traffic: bool, config, stops_at_zero: bool = True):
        p = library.params
        if traffic and p.v_ex_bounds[0] > 0:
            raise ValueError(f"with traffic the ego must be able to wait behind the lead: the library's safe set "
                             f"needs v_ex >= 0, not v_ex >= {p.v_ex_bounds[0]:g} (the dissertation's floor assumes a "
                             f"free left lane); build it with OvertakeParams(v_ex_bounds=(0, {p.v_ex_bounds[1]:g}))")
        self.params, self.config, self.traffic_on = p, config, traffic
        self.lead = IntentionAwareGuardian(library, use_intention=config.use_intention, horizon=config.horizon,
                                           priority=config.priority, ego_stops_at_zero=stops_at_zero)
        self.traffic = overtake_traffic_supervisor(p, config)
        self.kin = PointMassEgo(p, half_width, n_lanes, stops_at_zero)
        y_right = (p.y_e_bounds[0], self.kin.centre(RIGHT_LANE) + self.kin.lane_width / 2 - half_width)
        self.following = LeadFollowing(p, library.models, y_right, self.kin.centre(RIGHT_LANE), stops_at_zero)
        self.follow = self.following.set
        self.lead_follower = MaximalSet(lead_as_follower_params(p))
        self.reset()

    def reset(self) -> None:
        self.lead.reset()
        self.home = None

    # ---- the composed invariant set -----------------------------------------------------------------
    def intentions(self) -> tuple:
        """The lead's intention models not ruled out (none with ``use_intention`` off): ``F_R^M``'s M."""
        return tuple(self.lead.estimator.valid) if self.config.use_intention else ()

    def in_follow_set(self, x) -> bool:
        """``x`` in ``F_R^M``: the body in the right lane only, the lead ahead, self-safe towards it for
        every lead of the intentions not ruled out (``guardian.decide.lead_following``)."""
        x = np.asarray(x, float)
        return (self.kin.lanes_at(float(x[1])) == {RIGHT_LANE} and x[2] > 0 and x[1] >= self.params.y_e_bounds[0]
                and self.following.contains(x, self.intentions()))

    def inside(self, x, scene: Scene | None = None) -> bool:
        """``x`` in the composed invariant set ``K`` (and self-safe towards traffic when a scene is given)."""
        x = finite_vector(x, 4, "state")
        lanes = self.kin.lanes_at(x[1])
        if self.traffic_on and lanes == {RIGHT_LANE} and x[2] > 0:
            lead_ok = self.in_follow_set(x)
        else:
            lead_ok = bool(self.lead.library.region(self.lead.active_set).contains(x))
        if not lead_ok or scene is None or not self.traffic_on:
            return lead_ok
        return bool(self.traffic.self_safe_speeds(scene.with_ego_lanes(lanes))[0])

    # ---- one step -------------------------------------------------------------------------------------
    def step(self, x, scene: Scene, u) -> tuple[np.ndarray, Decision]:
        """Supervise one step.

        Parameters
        ----------
        x : array of 4 floats
            The overtake state.
        scene : Scene
            The ego and the other cars (the lead excluded); ignored without traffic.
        u : array of 2 floats
            The proposed input ``[a_ex, v_ey]`` in ``U_e``.

        Returns
        -------
        applied : ndarray
            Always inside ``U_e``.
        decision : Decision
        """
        u = finite_vector(u, 2, "proposed input")
        if not self.traffic_on:
            return self._two_cars(x, u)
        view = self.lead.observe(x)
        x = view.x
        lanes = self.kin.lanes_at(x[1])
        if len(lanes) == 1:
            self.home = next(iter(lanes))
        elif self.home not in lanes:
            self.home = min(lanes, key=lambda k: abs(self.kin.centre(k) - x[1]))
        d = Decision(proposed=u.tolist(), applied=[], changed="none", active_set=view.name)
        parts = self._parts(x, scene, lanes, view, d, u)
        applied = self._choose(x, u, lanes, view, parts, d)
        d.applied = applied.tolist()
        d.entered = sorted(self.kin.next_lanes(x[1], applied[1]) - lanes)
        d.lanes = sorted(lanes | self.kin.next_lanes(x[1], applied[1]))
        d.refused = sorted((self.kin.next_lanes(x[1], u[1]) - lanes) - set(d.entered))
        d.in_invariant_set = self.inside(x, scene)
        self.lead.commit(x, applied)
        return applied, d

    def _two_cars(self, x, u) -> tuple[np.ndarray, Decision]:
        applied, r = self.lead.step(x, u)
        lanes = self.kin.lanes_at(x[1]) | self.kin.next_lanes(x[1], applied[1])
        d = Decision(proposed=u.tolist(), applied=applied.tolist(), changed=r.changed,
                     level="failsafe" if r.failsafe else "composed", active_set=r.active_set, lead_target="C",
                     in_invariant_set=r.in_invariant_set,
                     entered=sorted(lanes - self.kin.lanes_at(x[1])), lanes=sorted(lanes))
        if r.failsafe:
            d.note("failsafe: the state is outside the active invariant set")
        else:
            if r.overridden:
                d.note(f"outside S(x) of the active set {r.active_set} (Theorem 4)")
            q = self.lead.library.admissible(r.active_set).at(r.state)
            d.admissible_acceleration, d.admissible_lateral = q.ranges(0, applied[1]), q.ranges(1, applied[0])
        return applied, d

    def _parts(self, x, scene: Scene, lanes: frozenset, view, d: Decision, u) -> list[_Part]:
        p, kin = self.params, self.kin
        v, y, h, vL = (float(a) for a in x)
        proposed_new = kin.next_lanes(y, float(u[1])) - lanes  # a refusal is said when the proposal would enter
        full = [(0.0, math.inf)]
        self_cache, follower_cache, entries, follow_speeds = {}, {}, {}, []
        parts = []
        for lo, hi, nxt in kin.lateral_partition(y):
            new = nxt - lanes
            occupied = lanes | nxt
            if len(new) > 1 or (new and len(lanes) != 1):
                continue  # the body cannot begin two lanes at once, nor a third from two
            entry = full
            if new:
                (lane,) = new
                if lane not in entries:
                    verdict = self.traffic.entry(scene.with_ego_lanes(lanes), lane)
                    entries[lane] = verdict
                    d.entries.append(Entry(lane, verdict.responsible, verdict.reason))
                verdict = entries[lane]
                if not verdict.responsible:
                    if lane in proposed_new:
                        d.note(f"entering lane {lane} refused: {verdict.reason}")
                    continue
                entry = verdict.speeds
            if occupied not in self_cache:
                speeds, why = self.traffic.self_safe_speeds(scene.with_ego_lanes(occupied))
                self_cache[occupied] = speeds
            followers = full
            for lane in sorted(occupied - {self.home}):
                if lane not in follower_cache:
                    follower_cache[lane] = self.traffic.follower_speeds(scene.with_ego_lanes(lanes), lane)[0]
                followers = intersect_intervals(followers, follower_cache[lane])
            target = "C"
            if h > 0 and nxt == {RIGHT_LANE}:
                target = "follow"
            elif h > 0 and RIGHT_LANE in nxt and kin.may_stay_in(y, (lo + hi) / 2, frozenset({RIGHT_LANE})):
                target = "both"  # the noise decides whether the body is still in the right lane only: K needs
                # F_R if it is, C if it is not, so the input must serve both
            if target != "C" and not follow_speeds:
                follow_speeds.append(self.following.next_speeds(x, self.intentions(), wanted=float(u[0])))
            follow = follow_speeds[0] if target != "C" else full
            lat_lo, lat_hi = kin.lateral_within(y, p.y_e_bounds[0], p.y_e_bounds[1])
            within = (max(lo, lat_lo), min(hi, lat_hi))  # (6.8)'s lateral bounds; C's polygons hold them too
            if within[0] > within[1]:
                continue
            parts.append(_Part(within, nxt, new, self_cache[occupied], entry, followers, target, follow,
                               self._lead_as_car(v, h, vL, lanes, nxt)))
        return parts

    def _follow_speeds(self, v: float, h: float, vL: float) -> list:
        """Next ego speeds keeping ``(v, h, v_L)`` in ``F_R`` for every lead its physical bounds allow (7.4)."""
        return self.following.next_speeds([v, 0.0, h, vL])

    def _lead_as_car(self, v: float, h: float, vL: float, lanes: frozenset, nxt: frozenset) -> list:
        """Next ego speeds treating the lead as an ordinary car of lane 1 with its physical bounds."""
        if RIGHT_LANE not in nxt:
            return [(0.0, math.inf)]
        if h > 0:
            return self._follow_speeds(v, h, vL)
        if RIGHT_LANE in lanes:
            return [(0.0, math.inf)]  # the lead behind in the ego's lane answers for itself
        prm = self.lead_follower.params  # entering the lead's lane in front of it: can it stay safe?
        vL_fast = min(prm.keep * vL + prm.dt * prm.u_max, prm.v_max)
        return self.lead_follower.lead_speed_intervals(vL_fast, -(h + prm.dt * (vL - v)))

    def _choose(self, x, u, lanes, view, parts: list[_Part], d: Decision) -> np.ndarray:
        adm, pr, kin, v = view.admissible, self.config.priority, self.kin, float(x[0])
        c_query = self._standstill_aware(view, v)

        def query(level: str) -> AdmissibleQuery:
            c_boxes, plain = [], []
            for part in parts:
                speeds = intersect_intervals(part.self_safe, part.entry)
                if level == "composed":
                    speeds = intersect_intervals(speeds, part.followers)
                if level == "conflict":
                    speeds = intersect_intervals(speeds, part.lead_as_car)
                elif part.target in ("follow", "both"):
                    speeds = intersect_intervals(speeds, part.follow)
                boxes = [(a, part.lateral) for a in kin.accel_for_speeds(v, speeds)]
                if level != "conflict" and part.target in ("C", "both"):
                    c_boxes += boxes
                else:
                    plain += boxes
            q = c_query.restricted(c_boxes) if c_boxes else AdmissibleQuery.of_boxes(adm, [])
            return q.union(AdmissibleQuery.of_boxes(adm, plain)) if plain else q

        for level in ("composed", "follower_dropped", "conflict"):
            q = query(level)
            if not q.polygons:
                continue
            result = adm.override(x, u, pr, query=q)
            d.level = level
            d.changed = result.changed if level != "conflict" else ("none" if not result.overridden else "conflict")
            d.lead_target = self._target_of(parts, result.applied[1]) if level != "conflict" else "lead_as_car"
            d.admissible_acceleration = q.ranges(0, result.applied[1])
            d.admissible_lateral = q.ranges(1, result.applied[0])
            if level != "conflict" and result.overridden:
                self._explain(x, u, parts, c_query, d)
            if level == "follower_dropped":
                d.note("responsibility for a follower not kept (it was responsible when the entry began)")
            if level == "conflict":
                d.note("conflict: the lead's set and the traffic's admissible sets do not intersect; "
                       "the lead is kept as an ordinary car")
            return result.applied
        return self._failsafe(x, u, lanes, d)

    def _standstill_aware(self, view, v: float) -> AdmissibleQuery:
        """``S_C(x)`` for the simulator that stops the ego at 0.

        ``S_C(x)`` keeps (6.3)'s next speed at or above 0 for every ``w_ex``, i.e. ``a_ex >= a_0 =
        -(1 - b_e dt) v / dt - w_ex^min``. With the clip, any ``a_ex < a_0`` reaches a subset of the next
        states ``a_0`` reaches (``W`` is a box and only ``w_ex`` moves the speed: the speeds become
        ``[0, s]`` with ``s`` at most ``a_0``'s largest, the other coordinates are the same), so
        ``(a_ex, v_ey)`` is admissible whenever ``(a_0, v_ey)`` is. ``S_C(x)`` is eroded by
        ``RUNTIME_MARGIN`` (its speeds start at that margin), so ``a_0`` is taken that far (in speed)
        higher: the speeds ``[0, margin)`` it adds lie within the margin of reached states, and the set's
        rows are unit-norm, so they are in ``C`` itself, where inputs exist (``PRE_MARGIN`` exceeds it).
        """
        q, p = view.query, self.params
        a0 = -(1 - p.b_e * p.dt) * v / p.dt - p.w_ex_bounds[0] + STANDSTILL_OFFSET / p.dt
        if not self.kin.stops_at_zero or a0 <= p.a_ex_bounds[0] or a0 > p.a_ex_bounds[1]:
            return q
        lateral = q.ranges(1, a0)
        if not lateral:
            return q
        return q.union(AdmissibleQuery.of_boxes(view.admissible, [((p.a_ex_bounds[0], a0), iv) for iv in lateral]))

    def _explain(self, x, u, parts: list[_Part], c_query, d: Decision) -> None:
        """Say which part refused the proposed input."""
        kin, v = self.kin, float(x[0])
        part = next((q for q in parts if q.lateral[0] <= u[1] <= q.lateral[1]), None)
        if part is None:
            if not d.refused:
                d.note("lateral input limited: it would leave the lanes (6.8) allows or enter a lane unchecked")
            return

        def refuses(speeds) -> bool:
            return not any(lo <= u[0] <= hi for lo, hi in kin.accel_for_speeds(v, speeds))

        named = [("self-safety towards the traffic ahead", part.self_safe), ("the entry's responsibility (7.5)", part.entry),
                 ("keeping the followers of the lanes being entered safe", part.followers)]
        if part.target in ("follow", "both"):
            models = self.intentions()
            lead = f"as the intentions not ruled out ({', '.join(models)}) let it" if models else "within its bounds"
            named.append((f"F_R: self-safety behind the lead, whatever it brakes {lead}", part.follow))
        for name, speeds in named:
            if refuses(speeds):
                d.note(f"acceleration limited by {name}")
        if part.target in ("C", "both") and not c_query.contains(np.asarray(u, float)):
            d.note(f"outside S(x) of the active set {d.active_set} (Theorem 4)")

    @staticmethod
    def _target_of(parts, lateral: float) -> str:
        near = min(parts, key=lambda part: max(part.lateral[0] - lateral, lateral - part.lateral[1]), default=None)
        return near.target if near is not None else ""

    def _failsafe(self, x, u, lanes, d: Decision) -> np.ndarray:
        """The hardest braking (the simulator stops the ego at 0) and back towards the home lane's centre,
        never into a lane the body does not overlap."""
        p, kin, y = self.params, self.kin, float(x[1])
        lateral = [kin.lateral_within(y, p.y_e_bounds[0], p.y_e_bounds[1])]
        for lane in range(1, kin.n_lanes + 1):
            if lane not in lanes:
                lateral = intersect_intervals(lateral, [kin.lateral_keep_out(y, lane)])
        want = (kin.centre(self.home) - y) / p.dt
        v_ey = nearest_in_intervals(lateral, want)
        if v_ey is None:
            v_ey = float(np.clip(want, *p.v_ey_bounds))
        a = p.a_ex_bounds[0] if kin.stops_at_zero else FAILSAFE_INPUT[0]
        d.level, d.changed = "failsafe", "failsafe"
        d.note("failsafe: no input keeps self-safety; braking as hard as the model allows towards the own lane")
        return np.array([a, v_ey])


def overtake_traffic_supervisor(p: OvertakeParams, c) -> TrafficSupervisor:
    """The traffic part for the overtake ego (6.3) among highway-env traffic.

    The ego's speed falls by at least ``|a_min| - w_ex^max`` per second under full braking, plus its
    drag ``b_e`` (modelled exactly); as a leader of traffic it may brake by up to ``|a_min| + b_e v_max
    - w_ex^min`` (a constant bound: the same set also judges traffic leading traffic, ITHA's case 3).
    """
    ego = CarFollowingParams(dt=p.dt, v_max=c.v_max, h_min=c.h_min, u_min=p.a_ex_bounds[0] + p.w_ex_bounds[1],
                             u_max=p.a_ex_bounds[1] + p.w_ex_bounds[1], d_min=-c.traffic_accel,
                             d_max=c.traffic_accel, drag=p.b_e)
    ego_hardest = p.a_ex_bounds[0] - p.b_e * c.v_max + p.w_ex_bounds[0]
    others = CarFollowingParams(dt=p.dt, v_max=c.v_max, h_min=c.h_min, u_min=-c.traffic_accel,
                                u_max=c.traffic_accel, d_min=min(-c.traffic_accel, ego_hardest),
                                d_max=c.traffic_accel)
    return TrafficSupervisor(ego, others, c.overapprox, c.wreck_margin)
