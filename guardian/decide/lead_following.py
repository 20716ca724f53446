"""Following the lead in the ego's own lane: ``F_R`` and its intention-aware growth ``F_R^M``.

``F_R`` (``lead_following_params``) is the maximal RCIS of the ego behind the lead in the right lane
when the lead may brake as hard as its physical bound ``a_L^min`` allows (7.4 with the drag of (6.3)).
It needs no intention, so it is the same set with ``--no-intention``; it is the set among traffic
because the overtake sets ``C`` are "reach the left lane" sets (see ``guardian.decide.overtake``).

**Intention-aware.** The lead drives by one of the intention models (6.5)/(6.7); the estimator rules
models out and never back in (6.9). For the models ``M`` not ruled out, the lead's next speed is
bounded by ``intention.models.next_lead_speed_bounds`` rather than by ``a_L^min``: both the aggressive
lead (it matches the ego's speed) and the cautious one (it speeds up when the ego is close behind) brake
far less than ``a_L^min`` in most states. With ``T_0 = F_R`` and, for ``j >= 1``,

    T_j = {x in the right lane, h >= h_min : braking as hard as the ego surely can for j steps keeps
           h >= h_min under every lead of M and ends in F_R},

``F_R^M = T_0 ∪ ... ∪ T_J`` is an RCIS of every model of ``M``: from ``T_j`` (``j >= 1``) the hardest
braking lands in ``T_{j-1}``; from ``T_0`` some input keeps ``F_R`` (it is an RCIS for every lead with
the physical bound, and every model keeps ``a_L + w_Δ + w_Lx >= a_L^min`` (6.6)). A smaller ``M`` (the
estimator only removes models) gives a larger set, so the state stays inside when a model is ruled
out; when every model is ruled out (a lead that follows none, a model violation) ``M`` is empty and
``F_R^M = F_R``.

Membership is decided soundly by interval arithmetic: the plan's states are boxes (the ego's noise,
every lead of ``M``, the ego anywhere in the right lane, held there by steering to its centre), each
box checked for ``h >= h_min`` and, at its worst corner (``F_R`` grows with ``h`` and ``v_L`` and
shrinks with ``v``: the module docstring of ``itha.car_following``), for ``F_R``. The interval
extension is inclusion-monotone, so every state of a box that passes passes from itself: the set
decided is exactly the one the argument above is about. Run-time next speeds are the union of the
one-step ``F_R`` speeds for the leads of ``M`` and the next-speed ranges of a grid of accelerations
whose boxes pass; the grid holds ``a_ex^min``, so a state decided inside always has an input
(``tests/guardian/decide/test_lead_following.py`` falsifies all of it).
"""
from __future__ import annotations

import numpy as np

from intention.lead_bounds import next_lead_speed_bounds
from intention.params import OvertakeParams
from itha.car_following import CarFollowingParams, MaximalSet
from rcis.intervals import merge_intervals

PLAN_STEPS = 80      # J: the longest braking plan tried (8 s at dt = 0.1)
ACCEL_GRID = 0.25    # [m/s^2] spacing of the accelerations tried beyond the one-step speeds
LEAD_SLACK = 1e-6    # [m/s] the estimator accepts a transition this far outside a model (LP_BAND)
SPEED_EPS = 1e-9     # [m/s] see LeadFollowing.lands


def lead_following_params(p: OvertakeParams) -> CarFollowingParams:
    """``F_R``: (7.3) for the overtake ego behind the lead, with the drag and noise of (6.3).

    Ego: ``v+ = (1 - b_e dt) v + dt (a_ex + w_ex)``, so its hardest sure braking is ``a_ex^min +
    w_ex^max``; lead: ``v_L+ = max((1 - b_L dt) v_L + dt (a_L + w_Δ + w_Lx), 0)`` with ``a_L + w_Δ + w_Lx
    >= a_L^min`` (6.6). ``h`` is centre to centre and ``h_min`` that of (6.8).
    """
    return CarFollowingParams(dt=p.dt, v_max=max(p.v_ex_bounds[1], p.v_Lx_bounds[1]), h_min=p.h_min,
                              u_min=p.a_ex_bounds[0] + p.w_ex_bounds[1], u_max=p.a_ex_bounds[1] + p.w_ex_bounds[1],
                              d_min=p.a_L_bounds[0], d_max=p.a_L_bounds[1] + p.w_delta_bounds[1] + p.w_Lx_bounds[1],
                              drag=p.b_e, lead_drag=p.b_L)


class LeadFollowing:
    """``F_R`` and ``F_R^M`` (module docstring) for one set of overtake parameters.

    Parameters
    ----------
    params : OvertakeParams
    models : dict
        The intention models by name (``intention.models.intention_models``).
    y_range : (float, float)
        The ego's lateral positions with its body in the right lane only; the plan steers to
        ``y_centre`` inside it.
    stops_at_zero : bool
        The simulator holds the ego at ``v_ex = 0`` under braking; without it only ``F_R`` with the
        one-step intention bound is used (the plan needs braking that never reverses).
    """

    def __init__(self, params: OvertakeParams, models: dict, y_range, y_centre: float = 0.0,
                 stops_at_zero: bool = True):
        self.p, self.models, self.stops_at_zero = params, models, stops_at_zero
        self.set = MaximalSet(lead_following_params(params))
        self.y_range, self.y_centre = (float(y_range[0]), float(y_range[1])), float(y_centre)
        w_ey = max(-params.w_ey_bounds[0], params.w_ey_bounds[1]) * params.dt
        reach = params.v_ey_bounds[1] * params.dt
        if not (self.y_range[0] + w_ey <= y_centre <= self.y_range[1] - w_ey and w_ey < reach):
            raise ValueError(f"LeadFollowing: the ego cannot be held in y in {self.y_range} around {y_centre}")

    # ---- the lead ------------------------------------------------------------------------------
    def lead_next(self, models, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        """The lead's next speeds over state boxes for the models named (physical bounds for none)."""
        lo, hi = np.atleast_2d(np.asarray(lo, float)), np.atleast_2d(np.asarray(hi, float))
        prm = self.set.params
        worst = prm.worst_lead_speed(lo[:, 3])
        if not models:
            best = np.minimum((1 - prm.lead_drag * prm.dt) * hi[:, 3] + prm.dt * prm.d_max, prm.v_max)
            return worst, best
        bounds = [next_lead_speed_bounds(self.models[m], lo, hi) for m in models]
        n_lo = np.minimum.reduce([b[0] for b in bounds]) - LEAD_SLACK
        n_hi = np.maximum.reduce([b[1] for b in bounds]) + LEAD_SLACK
        return np.maximum(n_lo, worst), n_hi

    # ---- the plan ------------------------------------------------------------------------------
    def lands(self, models, v, h, vL) -> np.ndarray:
        """For boxes ``v, h, vL`` (each a pair of arrays lo, hi; the ego anywhere in ``y_range``): is the
        box in ``T_j`` for some ``j <= PLAN_STEPS`` (``j = 0`` only without models)?

        Every box's speeds are widened by ``SPEED_EPS`` at every step: a candidate's range handed out
        widened so that ``accel_for_speeds``' rounding keeps it is still inside what the plan of its
        predecessor checked.
        """
        p = self.p
        v_lo, v_hi = (np.asarray(a, float).copy() for a in v)
        h_lo, h_hi = (np.asarray(a, float).copy() for a in h)
        L_lo, L_hi = (np.asarray(a, float).copy() for a in vL)
        n = len(v_lo)
        ok, alive = np.zeros(n, bool), np.ones(n, bool)
        steps = PLAN_STEPS if models and self.stops_at_zero else 0
        y_lo, y_hi = np.full(n, self.y_range[0]), np.full(n, self.y_range[1])
        brake_lo, brake_hi = p.a_ex_bounds[0] + p.w_ex_bounds[0], p.a_ex_bounds[0] + p.w_ex_bounds[1]
        keep = 1 - p.b_e * p.dt
        for t in range(steps + 1):
            v_lo, v_hi = np.maximum(v_lo - SPEED_EPS, 0.0), v_hi + SPEED_EPS
            alive &= (h_lo >= p.h_min) & (v_hi <= p.v_ex_bounds[1])
            if alive.any():
                inside = np.zeros(n, bool)
                inside[alive] = self.set.contains(np.column_stack([v_hi, h_lo, L_lo])[alive])
                ok |= inside
                alive &= ~inside
            if t == steps or not alive.any():
                break
            lo = np.column_stack([v_lo, y_lo, h_lo, L_lo])
            hi = np.column_stack([v_hi, y_hi, h_hi, L_hi])
            nL_lo, nL_hi = self.lead_next(models, lo, hi)
            h_lo, h_hi = h_lo + p.dt * (L_lo - v_hi), h_hi + p.dt * (L_hi - v_lo)
            v_lo = np.maximum(keep * v_lo + p.dt * brake_lo, 0.0)
            v_hi = np.maximum(keep * v_hi + p.dt * brake_hi, 0.0)
            L_lo, L_hi = nL_lo, nL_hi
        return ok

    def contains(self, x, models=()) -> bool:
        """``(v_ex, ., h, v_L)`` in ``F_R^M`` (the caller checks the lane: ``y`` in ``y_range``)."""
        v, _, h, vL = (float(a) for a in x)
        if self.set.contains([[v, h, vL]])[0]:
            return True
        if not models:
            return False
        one = np.array([1.0])
        return bool(self.lands(models, (one * v, one * v), (one * h, one * h), (one * vL, one * vL))[0])

    def next_speeds(self, x, models=(), wanted: float | None = None) -> list:
        """Next ego speeds that keep ``x``'s successor in ``F_R^M`` for every lead of ``M``.

        ``wanted``: the proposed acceleration; the plan is tried only when the one-step speeds refuse it,
        and only up to it (a smaller admissible set than the whole, never a larger one).
        """
        p = self.p
        v, y, h, vL = (float(a) for a in x)
        h_next = h + p.dt * (vL - v)
        L_lo, L_hi = self.lead_next(models, [v, y, h, vL], [v, y, h, vL])
        base = self.set.speed_intervals(h_next, float(L_lo[0]))
        if not models or not self.stops_at_zero or wanted is None:
            return base
        keep = (1 - p.b_e * p.dt) * v

        def ranges(a):
            return (np.maximum(keep + p.dt * (a + p.w_ex_bounds[0]), 0.0),
                    np.maximum(keep + p.dt * (a + p.w_ex_bounds[1]), 0.0))

        wanted = min(max(float(wanted), p.a_ex_bounds[0]), p.a_ex_bounds[1])
        w_lo, w_hi = ranges(wanted)
        if any(lo <= w_lo and w_hi <= hi for lo, hi in base):
            return base
        accel = np.append(np.arange(p.a_ex_bounds[0], wanted, ACCEL_GRID), wanted)
        s_lo, s_hi = ranges(accel)
        todo = np.array([not any(lo <= a and b <= hi for lo, hi in base) for a, b in zip(s_lo, s_hi)], bool)
        m = int(todo.sum())
        if m == 0:
            return base
        s_lo, s_hi = s_lo[todo], s_hi[todo]
        passed = self.lands(models, (s_lo, s_hi), (np.full(m, h_next), np.full(m, h_next)),
                            (np.full(m, L_lo[0]), np.full(m, L_hi[0])))
        grown = [(max(float(a) - SPEED_EPS, 0.0), float(b) + SPEED_EPS) for a, b in zip(s_lo[passed], s_hi[passed])]
        return merge_intervals(list(base) + grown) if grown else base
