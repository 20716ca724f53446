"""How the ego's input maps to its next state: one class per kinematics the guardian supervises.

The ITHA part answers in next speeds and lane footprints; these classes turn such
answers into input constraints, exactly for the model that moves the ego.

* ``PointMassEgo``: the overtake ego of ``guardian/HighwayOvertake-v0`` (6.3):
  ``v+ = (1 - b_e dt) v + dt a_ex + dt w_ex`` and ``y+ = y + dt v_ey + dt w_ey``
  with ``w`` unknown in its box, so a next-speed interval ``[lo, hi]`` holds for
  every ``w_ex`` iff ``a_ex in [(lo - (1 - b_e dt) v)/dt - w_ex^min,
  (hi - (1 - b_e dt) v)/dt - w_ex^max]``.
* ``BicycleEgo``: highway-env's own vehicles: ``speed+ = speed + dt a`` and the
  position moves by ``dt speed (cos, sin)(heading + beta)``, ``beta =
  atan(tan(steering) / 2)``; the heading turns by ``dt speed sin(beta) / (L/2)``.
"""
from __future__ import annotations

import math

import numpy as np

from intention.params import OvertakeParams

ROUNDING = 1e-9  # input intervals are shrunk by this so that a rounded step stays inside


def _lanes_overlapped(lo: float, hi: float, n_lanes: int, width: float) -> frozenset:
    """Lanes k = 0.. (centre ``k * width``) that the open interval ``(lo, hi)`` overlaps."""
    return frozenset(k for k in range(n_lanes) if lo < (k + 0.5) * width and hi > (k - 0.5) * width)


class PointMassEgo:
    """The ego of (6.3); lateral coordinates in units of ``y_e`` (lane k's centre at ``2 k y_left``)."""

    def __init__(self, params: OvertakeParams, half_width: float, n_lanes: int):
        self.p = params
        self.half_width = half_width          # the ego's half width in units of y_e
        self.lane_width = 2 * params.left_lane_y
        self.n_lanes = n_lanes                # k = 0 is the right lane (ITHA lane 1)

    def accel_for_speeds(self, v: float, speeds) -> list:
        p = self.p
        keep = (1 - p.b_e * p.dt) * v
        out = []
        for lo, hi in speeds:
            a_lo = (lo - keep) / p.dt - p.w_ex_bounds[0] + ROUNDING
            a_hi = (hi - keep) / p.dt - p.w_ex_bounds[1] - ROUNDING
            a_lo, a_hi = max(a_lo, p.a_ex_bounds[0]), min(a_hi, p.a_ex_bounds[1])
            if a_lo <= a_hi:
                out.append((a_lo, a_hi))
        return out

    def lanes_at(self, y: float) -> frozenset:
        """ITHA lanes (1 = right) the ego's body overlaps at lateral position ``y``."""
        ks = _lanes_overlapped(y - self.half_width, y + self.half_width, self.n_lanes, self.lane_width)
        return frozenset(k + 1 for k in ks)

    def next_lanes(self, y: float, v_ey: float) -> frozenset:
        """Lanes the body may overlap after one step with lateral input ``v_ey`` (any ``w_ey``)."""
        p = self.p
        lo = y + p.dt * (v_ey + p.w_ey_bounds[0]) - self.half_width
        hi = y + p.dt * (v_ey + p.w_ey_bounds[1]) + self.half_width
        return frozenset(k + 1 for k in _lanes_overlapped(min(lo, y - self.half_width),
                                                          max(hi, y + self.half_width),
                                                          self.n_lanes, self.lane_width))

    def lateral_keep_out(self, y: float, lane: int) -> tuple[float, float]:
        """Lateral inputs that keep the body out of ITHA ``lane`` next step, for every ``w_ey``."""
        p = self.p
        k = lane - 1
        lo, hi = p.v_ey_bounds
        if (k - 0.5) * self.lane_width >= y:  # the lane is to the left (larger y)
            hi = min(hi, ((k - 0.5) * self.lane_width - self.half_width - y) / p.dt - p.w_ey_bounds[1] - ROUNDING)
        else:
            lo = max(lo, ((k + 0.5) * self.lane_width + self.half_width - y) / p.dt - p.w_ey_bounds[0] + ROUNDING)
        return lo, hi


class BicycleEgo:
    """highway-env's kinematic bicycle (``Vehicle.step``); lanes are ``lane_width`` apart, lane 0 at y = 0."""

    MAX_HEADING = 0.3     # [rad] the lateral guard keeps |heading| below this (so one step can stop sideways motion)
    CANDIDATES = 41       # steering angles tried when the proposed one is refused

    def __init__(self, dt: float, accel: float, length: float, width: float, lane_width: float, n_lanes: int,
                 max_steering: float):
        self.dt, self.accel = dt, accel
        self.length, self.width = length, width
        self.lane_width, self.n_lanes = lane_width, n_lanes
        self.max_steering = max_steering

    def accel_for_speeds(self, v: float, speeds) -> list:
        out = []
        for lo, hi in speeds:
            a_lo = max((lo - v) / self.dt + ROUNDING, -self.accel)
            a_hi = min((hi - v) / self.dt - ROUNDING, self.accel)
            if a_lo <= a_hi:
                out.append((a_lo, a_hi))
        return out

    def half_extent(self, heading: float) -> float:
        """Half the lateral reach of the body at ``heading``."""
        return self.length / 2 * abs(math.sin(heading)) + self.width / 2 * abs(math.cos(heading))

    def lanes_at(self, y: float, heading: float) -> frozenset:
        """highway-env lane ids (0 = leftmost) the body overlaps."""
        r = self.half_extent(heading)
        return _lanes_overlapped(y - r, y + r, self.n_lanes, self.lane_width)

    def off_road(self, y: float, heading: float) -> bool:
        r = self.half_extent(heading)
        return y - r < -self.lane_width / 2 or y + r > (self.n_lanes - 0.5) * self.lane_width

    def predict(self, y: float, heading: float, speed: float, steering: float) -> tuple[float, float]:
        """``(y+, heading+)`` after one ``Vehicle.step`` with ``steering``."""
        beta = math.atan(0.5 * math.tan(steering))
        y_next = y + self.dt * speed * math.sin(heading + beta)
        return y_next, heading + self.dt * speed * math.sin(beta) / (self.length / 2)

    def min_progress(self, speed: float, heading: float) -> float:
        """The least distance along the road one step can cover (any steering)."""
        beta_max = math.atan(0.5 * math.tan(self.max_steering))
        return self.dt * speed * math.cos(min(abs(heading) + beta_max, math.pi / 2))

    def steering_candidates(self, proposed: float, heading: float) -> list:
        """The proposed steering first, then the one that stops sideways motion, then a grid by distance."""
        straight = math.atan(2 * math.tan(-heading)) if abs(heading) < math.pi / 2 else 0.0
        grid = np.linspace(-self.max_steering, self.max_steering, self.CANDIDATES)
        rest = sorted([float(s) for s in grid] + [float(np.clip(straight, -self.max_steering, self.max_steering))],
                      key=lambda s: abs(s - proposed))
        return [proposed] + rest
