"""Does each observed transition fit the model the sets assume? (counted, never assumed)

``ModelCoverage.observe(snapshot)`` is told the state once per decision period (``snapshot``: the ego, the
input applied, the other cars by id); it compares the previous snapshot with the present one and counts, for
the ego, the lead (overtake scenario) and the traffic, the transitions the model does not cover. A reader
makes the snapshots (``guardian.adapters.highway_env.monitor`` from highway-env; the service's scene sessions
from each step's request):

* overtake ego (6.3)-(6.4): the implied ``w_ex``, ``w_ey`` inside their box and
  ``h+ = h + dt (v_L - v_ex)`` (with ``ego_stops_at_zero``, a next speed of 0 fits when some ``w_ex``
  of the box gives a speed at or below 0);
* lead: the next speed explained by at least one intention model (6.5)/(6.7) with
  ``w_Delta``, ``w_Lx`` inside their box;
* highway-env ego (bicycle): ``speed+ = speed + dt a`` and a progress along the
  road in ``[BicycleEgo.min_progress, dt speed]`` (what the guardian covers);
* traffic (7.3): progress ``dt v``, acceleration in ``[d_min, d_max]``, speed in
  ``[0, v_max]``.
* traffic that does not see the guarded car (``traffic_blind``, counted at the state, once per
  simulation step): (7.3) has every car react to the car ahead in its lane, and the lane changes of
  highway-env's MOBIL cars weigh the car behind in the lane they enter. highway-env's v0 roads
  (``merge-v0``, ``exit-v0``; ``neighbour_vehicles_connected_lanes`` False) look for those cars on
  the car's own lane segment only, so near a segment's end a car may not see the guarded car on the
  next segment. A step counts when some traffic car's search, in its lane or a lane beside it, misses
  the guarded car that highway-env's connected-lane search (merge-v1, exit-v1) finds.
* traffic that backs up further than the guardian's cover (``traffic_reversing_uncovered``): at each
  simulation step the guardian takes a car that may be driving backwards (``ReversingCover.may_reverse``: slower
  than ``below``) to stay ahead of ``x - reach`` from then on, ``reach`` by ``ReversingCover.reaches``
  (``GuardianConfig.reversing``, more behind a car that may reverse too; here cars follow each other on
  highway-env's lane index); a step counts when some car is behind the furthest-forward of the bounds given
  since its cover began (it ends at a step seen at ``below`` or faster).

With several guarded cars each has its own monitor (``observe(..., ego=vehicle)``); only one of them
counts the traffic (``watch_traffic``), so that sums over the cars count each car once.
"""
from __future__ import annotations

import numpy as np

from guardian.config import GuardianConfig

TOL = 1e-6
COUNTS = ("ego", "lead", "traffic", "traffic_blind", "traffic_reversing_uncovered")  # per decision period


def no_counts() -> dict:
    return dict.fromkeys(COUNTS, 0)


class ModelCoverage:
    """The counts of transitions the model does not cover, for one guarded car (see the module docstring).

    Parameters
    ----------
    dt : float
        The decision period [s].
    d_bounds, v_max : tuple, float
        The traffic's acceleration bounds and top speed (7.3).
    overtake_params, intention_models : optional
        The overtake ego's model (6.3) and the lead's intention models (6.5)-(6.7).
    ego_kinematics : optional
        The bicycle ego's kinematics (``guardian.decide.kinematics``).
    ego_stops_at_zero, watch_traffic, reversing :
        The ego's speed clipped at 0; count the traffic; the reversing cover (``GuardianConfig.reversing``).
    """

    def __init__(self, dt: float, d_bounds: tuple, v_max: float, overtake_params=None, intention_models=None,
                 ego_kinematics=None, ego_stops_at_zero: bool = False, watch_traffic: bool = True,
                 reversing=GuardianConfig().reversing):
        self.dt, self.d_bounds, self.v_max = dt, d_bounds, v_max
        self.reversing = reversing
        self.watch_traffic = watch_traffic
        self.ego_stops_at_zero = ego_stops_at_zero
        self.p = overtake_params
        self.models = intention_models or {}
        self.ego_kin = ego_kinematics
        self.reset()

    def reset(self) -> None:
        self._prev = None
        self._bound = {}    # id(reversing traffic car) -> the x it was taken to stay ahead of (furthest forward)
        self._uncovered = 0
        self.totals = no_counts()
        self.worst = {"traffic_progress_shortfall_m": 0.0, "traffic_braking_excess": 0.0}

    def observe(self, snapshot: dict, blind: int = 0) -> dict:
        """Counts for the transition that ended at ``snapshot``; then remember it.

        ``snapshot``: ``{"traffic": (ids, x_v), "lanes": [the lane each car follows in, ...], "applied":
        the ego's input from now on, "ego": (x, speed, heading)}`` and, in the overtake scenario, ``"x"`` (the
        overtake state); ``ids`` are int64 identities of the other cars (the same car keeps its id), ``x_v``
        their positions along the road and speeds. ``blind``: the reader's count of traffic blind to the ego.
        """
        if self.watch_traffic:
            self._reversal_step(snapshot["traffic"][0], snapshot["traffic"][1], snapshot["lanes"])
        counts = self._compare(self._prev, snapshot) if self._prev is not None else no_counts()
        counts["traffic_reversing_uncovered"] = self._uncovered
        counts["traffic_blind"] = int(blind)
        for k, n in counts.items():
            self.totals[k] += n
        self._prev = snapshot
        return counts

    def _compare(self, prev, now) -> dict:
        counts = no_counts()
        dt = self.dt
        lo, hi = self.d_bounds
        (ids0, xv0), (ids1, xv1) = prev["traffic"], now["traffic"]
        _, i0, i1 = np.intersect1d(ids0, ids1, assume_unique=True, return_indices=True)  # cars seen both times
        if i0.size:
            (x0, v0), (x1, v1) = xv0[i0].T, xv1[i1].T
            a = (v1 - v0) / dt
            w = self.worst
            w["traffic_progress_shortfall_m"] = max(w["traffic_progress_shortfall_m"], float(np.max(dt * v0 - (x1 - x0))))
            w["traffic_braking_excess"] = max(w["traffic_braking_excess"], float(np.max(lo - a)))
            fits = (np.abs(x1 - x0 - dt * v0) <= TOL) & (lo - TOL <= a) & (a <= hi + TOL) & \
                (-TOL <= v1) & (v1 <= self.v_max + TOL)
            counts["traffic"] = int(np.count_nonzero(~fits))
        if "x" in prev:
            counts["ego"], counts["lead"] = self._overtake(prev["x"], prev["applied"], now["x"])
        else:
            counts["ego"] = int(not self._bicycle_fits(prev, now))
        return counts

    def _reversal_step(self, ids, x_v, lanes) -> None:
        """Keep each reversing car's bound; ``_uncovered``: 1 when some car is now behind its bound."""
        self._uncovered = 0
        cover = self.reversing
        if not cover.any_may(x_v[:, 1]):
            self._bound = {}
            return
        reach = cover.reaches(x_v[:, 0].tolist(), x_v[:, 1].tolist(), lanes)
        bound = {}
        for car, (x, speed), r in zip(ids.tolist(), x_v, reach):
            if cover.may_reverse(speed):
                b = bound[car] = max(self._bound.get(car, -np.inf), x - r)
                self._uncovered |= int(x < b - TOL)
        self._bound = bound

    def overtake_transition(self, x, u, x1) -> tuple[int, int]:
        """``(ego, lead)`` violations of one overtake transition ``x -> x1`` under input ``u`` (0 or 1 each)."""
        return self._overtake(np.asarray(x, float), np.asarray(u, float), np.asarray(x1, float))

    def _overtake(self, x, u, x1) -> tuple[int, int]:
        p, dt = self.p, self.dt
        w_ex = (x1[0] - (1 - p.b_e * dt) * x[0]) / dt - u[0]
        w_ey = (x1[1] - x[1]) / dt - u[1]
        if self.ego_stops_at_zero and x1[0] == 0.0 and w_ex >= p.w_ex_bounds[0] - TOL:
            w_ex = min(w_ex, p.w_ex_bounds[1])  # clipped at standstill: w_ex^min already gave a speed <= 0
        ego_ok = (p.w_ex_bounds[0] - TOL <= w_ex <= p.w_ex_bounds[1] + TOL
                  and p.w_ey_bounds[0] - TOL <= w_ey <= p.w_ey_bounds[1] + TOL
                  and abs(x1[2] - x[2] - dt * (x[3] - x[0])) <= TOL)
        w_lo = p.w_delta_bounds[0] + p.w_Lx_bounds[0]
        w_hi = p.w_delta_bounds[1] + p.w_Lx_bounds[1]
        residual = (x1[3] - (1 - p.b_L * dt) * x[3]) / dt
        lead_ok = any(w_lo - TOL <= residual - m.nominal_lead_acceleration(x) <= w_hi + TOL
                      for m in self.models.values())
        return int(not ego_ok), int(not lead_ok)

    def _bicycle_fits(self, prev, now) -> bool:
        x0, v0, heading = prev["ego"]
        x1, v1, _ = now["ego"]
        a = float(prev["applied"][0])
        progress = x1 - x0
        speed_ok = abs(v1 - v0 - self.dt * a) <= TOL or (self.ego_stops_at_zero and v1 == 0.0
                                                          and v0 + self.dt * a <= TOL)
        progress_ok = self.ego_kin.min_progress(v0, heading) - TOL <= progress <= self.dt * v0 + TOL
        return speed_ok and progress_ok

