"""RSS (Shalev-Shwartz, Shammah and Shashua 2017), the industry reference beside ITHA's responsibility.

Longitudinal safe distance, same direction (Definition 1): a rear car at ``v_r`` and a front car at
``v_f`` are at a safe distance if the gap (bumper to bumper) is at least

    d_min = [ v_r ρ + ½ a_accel ρ² + (v_r + ρ a_accel)² / (2 b_min) − v_f² / (2 b_max) ]₊,

the rear car accelerating by up to ``a_accel`` during its response time ``ρ`` and then braking by at
least ``b_min``, while the front car brakes by at most ``b_max``. (ad-rss also caps the speed reached
during the response at ``max_speed_on_acceleration`` = 100 m/s; no car in the data comes near it.)

Cut-in (the lateral rule, reduced to the longitudinal consequence): a lane change is RSS-safe if, in the
target lane, the ego is at a safe distance behind its new leader and its new follower is at a safe
distance behind the ego.

Defaults: ad-rss's vehicle dynamics as CARLA's RSS integration sets them
(``LibCarla/source/carla/rss/RssCheck.cpp``, ``RssCheck::GetDefaultVehicleDynamics``): ρ = 1 s,
``alphaLon.accelMax`` = 3.5 m/s², ``brakeMin`` = 4 m/s², ``brakeMax`` = 8 m/s².
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from itha import _kernels


@dataclass(frozen=True)
class RSSParams:
    response_time: float = 1.0   # ρ [s]
    accel_max: float = 3.5       # a_accel [m/s^2], the rear car during ρ
    brake_min: float = 4.0       # b_min [m/s^2], the rear car afterwards, at least
    brake_max: float = 8.0       # b_max [m/s^2], the front car, at most

    def __post_init__(self):
        for name in ("response_time", "brake_min", "brake_max"):
            if not getattr(self, name) > 0:
                raise ValueError(f"RSSParams.{name} must be positive, got {getattr(self, name)}")
        if self.accel_max < 0:
            raise ValueError(f"RSSParams.accel_max must be >= 0, got {self.accel_max}")


def safe_distance(p: RSSParams, v_rear, v_front):
    """``d_min`` of Definition 1 (vectorised)."""
    v_rear, v_front = np.asarray(v_rear, float), np.asarray(v_front, float)
    rho, a = p.response_time, p.accel_max
    d = v_rear * rho + 0.5 * a * rho ** 2 + (v_rear + rho * a) ** 2 / (2 * p.brake_min) - v_front ** 2 / (2 * p.brake_max)
    return np.maximum(d, 0.0)


def longitudinal_violations(p: RSSParams, v, h, v_lead) -> np.ndarray:
    """Per data point: a leader exists (finite gap ``h``) and ``h < d_min(v, v_lead)``.

    Compiled (``itha._kernels.rss_violations``: ``safe_distance``'s arithmetic in its order, equal bit
    for bit, tested); arrays of any one shape.
    """
    shape, flat = _kernels.flat_floats(v, h, v_lead)
    return _kernels.rss_violations(p.response_time, p.accel_max, p.brake_min, p.brake_max, *flat).reshape(shape)


def cut_in_safe(p: RSSParams, pos, v, lane, length, ego: int, target_lane: int) -> bool:
    """Is the ego's lane change into ``target_lane`` RSS-safe (both new neighbours at a safe distance)?

    ``pos`` are front bumpers along the direction of travel.
    """
    others = [k for k in range(len(pos)) if k != ego and lane[k] == target_lane]
    ahead = [k for k in others if pos[k] >= pos[ego]]
    behind = [k for k in others if pos[k] < pos[ego]]
    if ahead:
        k = min(ahead, key=lambda j: pos[j])
        if pos[k] - length[k] - pos[ego] < safe_distance(p, v[ego], v[k]):
            return False
    if behind:
        k = max(behind, key=lambda j: pos[j])
        if pos[ego] - length[ego] - pos[k] < safe_distance(p, v[k], v[ego]):
            return False
    return True
