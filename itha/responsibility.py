"""The ego's responsibility-sensitive input sets on the highway ITHA (7.4, 7.5, Definition 22).

Responsibility (7.5) of a lane change by the ego E into lane ℓ*:

* E itself: for every car that can lead E at t+1, the reset state
  ``(v_E + dt u, gap, slowest lead speed)`` must be in the RCIS;
* every car that can get E as its leader at t+1 (behind E in ℓ*): its reset
  ``(v_c + dt u_c, gap, v_E + dt u)`` must be in the RCIS for every ``u_c``
  (the worst is the hardest acceleration), a lower bound on E's speed;
* every car behind E in E's lane that can lose E as its leader: for every car
  that can then lead it, the reset must be in the RCIS for every ``u_c``.

Which cars "can" lead or follow depends on ``ρ̂``:

* ``trivial`` (7.6): any other car may change lanes, so every car that can be
  in the lane at t+1 (from the lane or its neighbours) can lead or follow E,
  and every car behind can be exposed (all those in between may leave). As
  (7.5) reads, E also answers for a car that moves in behind it at the same
  time, although that car's own (7.5) covers it as well;
* ``ordered`` (Algorithm 1 with Example 8's order, ``itha.road.example8_order``:
  ahead first, on ties the slower lane first): the cars before E in the order
  have announced their triggers; the cars after E yield (they must be
  responsible towards E), so only the actual leader and the nearest follower matter.
  Cars that take no part in the order (``silent``: traffic that announces nothing,
  such as highway-env's IDM cars) are over-approximated as ``trivial`` does: they
  may be in their lane or a neighbouring one at t+1, and each may be the one that
  leads, follows or leaves, up to the nearest car that takes part. Where bodies of
  different lengths overlap along the road, a car that takes part hides only the
  cars wholly beyond it: the others may still be met first and count as well.

The road (global and local states, resolution) is ``itha.road``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from itha.car_following import INNER, MaximalSet, _floor, admissible_inputs, speeds_to_inputs
from itha.road import LANE_SHIFT, LEFT, RIGHT, STAY, HighwayParams, local_state
from rcis.intervals import intersect_intervals

OVERAPPROXIMATIONS = ("trivial", "ordered")


@dataclass
class ChoiceVerdict:
    """What one triggering choice allows and why."""

    trigger: str
    inputs: list            # feasible ego inputs (intervals); [] if the choice is not allowed
    reason: str = ""        # the first constraint that emptied it


FAR_SLACK = 1.0   # [m] beyond the least gap that is safe at every speed, against rounding in the floor


def far_enough(S) -> float:
    """A gap beyond which every state of the closed-form set ``S`` with both speeds in ``[0, v_max]`` is inside it
    (the floor grows with the gap and the lead's speed and falls with the ego's: its least value is at the ego's
    ``v_max`` behind a standing lead): a car that far away constrains nothing, and the checks may skip it without
    changing an answer. ``inf`` for any other set (nothing skipped)."""
    if type(S) is not MaximalSet:
        return float("inf")
    if "_far_enough" not in S.__dict__:
        p = S.params
        least = _floor(p, p.v_max, 0.0, 0.0)   # the scalar kernel ITHA's checks load anyway
        S._far_enough = p.h_min + INNER - least + FAR_SLACK
    return S._far_enough


class EgoSupervisor:
    """Self-safe and ρ̂-responsible input sets of the ego for each triggering choice."""

    def __init__(self, params: HighwayParams, invariant, overapprox: str = "ordered", others_invariant=None):
        """``invariant`` is the ego's RCIS; ``others_invariant`` (default: the same) the other cars',
        whose parameters also give their acceleration bound ``u_max``."""
        if overapprox not in OVERAPPROXIMATIONS:
            raise ValueError(f"unknown over-approximation {overapprox!r}; choose from {OVERAPPROXIMATIONS}")
        if any(prm.exact for prm in (params.car_following, invariant.params, getattr(others_invariant, "params", None))
               if prm is not None):
            raise ValueError("responsibility (7.5) moves every car by (7.3)'s Euler step (the reset maps of "
                             "itha.road); exact integration is not implemented there")
        self.params = params
        self.S = invariant
        self.S_others = invariant if others_invariant is None else others_invariant
        self.overapprox = overapprox

    def choices(self, p, v, lane, ego: int = 0, next_lanes=None) -> list[ChoiceVerdict]:
        """Verdicts for stay, left, right. ``next_lanes[k]`` are the triggers announced by cars before
        the ego in the order (ordered ρ̂); cars absent from it have not decided."""
        out = [ChoiceVerdict(STAY, admissible_inputs(self.S, local_state(self.params, p, v, lane, ego)))]
        if not out[0].inputs:
            out[0].reason = "no self-safe input (state outside the invariant set)"
        for trig in (LEFT, RIGHT):
            out.append(self.lane_change(p, v, lane, ego, trig, next_lanes or {}))
        return out

    def lane_change(self, p, v, lane, ego, trig, announced, lengths=None, silent=()) -> ChoiceVerdict:
        """Is the ego's lane change ``trig`` ρ̂-responsible, and with which inputs?

        ``p`` are front-bumper positions along the direction of travel; ``lengths`` the cars'
        lengths (default: ``car_length`` for all); ``announced`` maps car index to its trigger for
        the cars before the ego in the order (ordered ρ̂); ``silent`` are the cars that take no part in
        the order (over-approximated as ``trivial`` does, see the module docstring).
        """
        speeds, reason = self.lane_change_speeds(p, v, lane, ego, trig, announced, lengths, silent)
        if not speeds:
            return ChoiceVerdict(trig, [], reason)
        inputs = [iv for lo, hi in speeds for iv in speeds_to_inputs(self.params.car_following, v[ego], [(lo, hi)])]
        return ChoiceVerdict(trig, inputs, "" if inputs else "no input of U reaches a responsible speed")

    def lane_change_speeds(self, p, v, lane, ego, trig, announced, lengths=None, silent=(), labels=None):
        """The ego's next speeds that make the lane change ``trig`` ρ̂-responsible, and why none do.

        Speeds rather than inputs, so that an ego whose input maps to its next speed otherwise
        than (7.3) (drag, noise) converts them exactly. Returns ``(intervals, reason)``; the reason names a car
        by ``labels[k]`` (default: its index ``k``), for a caller that hands over part of a longer list.
        """
        label = (lambda k: k) if labels is None else labels.__getitem__
        prm, cf = self.params, self.params.car_following
        target = lane[ego] + LANE_SHIFT[trig]
        if not 1 <= target <= prm.n_lanes:
            return [], "no such lane"
        dt, n = cf.dt, len(p)
        lengths = [prm.car_length] * n if lengths is None else lengths
        pn = [p[k] + dt * v[k] for k in range(n)]
        trivial = self.overapprox == "trivial"
        allowed = [(0.0, cf.v_max)]

        def may_be_in(k, ln):
            """Can car k be on lane ln at t+1 (under ρ̂)?"""
            if k in announced:
                return lane[k] + LANE_SHIFT[announced[k]] == ln
            if trivial or k in silent:
                return abs(lane[k] - ln) <= 1
            return lane[k] == ln  # later cars yield: they stay as far as E is concerned

        def unhidden(cands, ahead: bool):
            """Ordered ρ̂: the candidates that can be the one the ego meets first. A car that takes part in
            the order is where it says at t+1 and hides every candidate wholly beyond it along the road (ahead:
            its front at or behind the candidate's rear; behind: its rear at or ahead of the candidate's front);
            a silent car may be elsewhere and hides none. Without overlapping bodies: the candidates up to the
            nearest car that takes part."""
            sure = [j for j in cands if j not in silent]
            if ahead:
                return [k for k in cands if not any(j != k and pn[j] <= pn[k] - lengths[k] for j in sure)]
            return [k for k in cands if not any(j != k and pn[j] - lengths[j] >= pn[k] for j in sure)]

        free, free_others = far_enough(self.S), far_enough(self.S_others)
        # 1. the ego's own reset: every car that can lead it in the target lane.
        leads = [k for k in range(n) if k != ego and pn[k] >= pn[ego] and may_be_in(k, target)]
        if not trivial:
            leads = unhidden(leads, ahead=True)
        for k in leads:
            vL = float(cf.worst_lead_speed(v[k]))
            if pn[k] - lengths[k] - pn[ego] >= free and 0.0 <= vL <= cf.v_max:
                continue   # every ego speed keeps the ego in C towards it: [0, v_max], nothing cut
            speeds = self.S.speed_intervals(pn[k] - lengths[k] - pn[ego], vL)
            allowed = intersect_intervals(allowed, speeds)
            if not allowed:
                return [], f"ego too close to car {label(k)} ahead in lane {target}"
        # 2. cars that can get the ego as leader: in the target lane behind it at t+1.
        followers = [k for k in range(n) if k != ego and pn[k] < pn[ego] and may_be_in(k, target)]
        if not trivial:
            followers = unhidden(followers, ahead=False)
        So, co = self.S_others, self.S_others.params
        for k in followers:
            v_fast = min(v[k] + dt * co.u_max, co.v_max)
            if pn[ego] - lengths[ego] - pn[k] >= free_others and v_fast >= 0.0:
                continue   # inside its set behind any ego speed: [0, v_max], nothing cut
            allowed = intersect_intervals(allowed, So.lead_speed_intervals(v_fast, pn[ego] - lengths[ego] - pn[k]))
            if not allowed:
                return [], f"car {label(k)} behind in lane {target} could not stay safe"
        # 3. cars behind the ego in its lane that lose it as their leader.
        old = lane[ego]
        behind = [k for k in range(n) if k != ego and pn[k] < pn[ego] and may_be_in(k, old)]
        if not trivial:
            behind = unhidden(behind, ahead=False)
        for c in behind:
            v_fast = min(v[c] + dt * co.u_max, co.v_max)
            new_leads = [k for k in range(n) if k not in (ego, c) and pn[k] >= pn[ego] and may_be_in(k, old)]
            if not trivial:
                new_leads = unhidden(new_leads, ahead=True)
            for k in new_leads:
                x = (v_fast, pn[k] - lengths[k] - pn[c], float(co.worst_lead_speed(v[k])))
                if x[1] >= free_others and 0.0 <= x[0] <= co.v_max and 0.0 <= x[2] <= co.v_max:
                    continue   # inside the set: too far to matter
                if not So.contains(np.array([x]))[0]:
                    return [], f"car {label(c)} behind in lane {old} would be exposed to car {label(k)}"
        return allowed, ""
