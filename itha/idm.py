"""The Intelligent Driver Model (7.8), one implementation for every traffic in the product.

    a = a_max [1 - (v / v_desired)^delta - (s*(v, v_lead) / gap)^2],
    s* = s0 + v T + v (v - v_lead) / (2 sqrt(a_max b)),

with no interaction term when there is no leader (``gap = inf``). Vectorised: every argument may
be a scalar or an array (per-vehicle parameters in the HighD generator, scalars on the highway).
"""
from __future__ import annotations

import numpy as np


def idm_acceleration(v, gap, v_lead, v_desired, a_max, b, s0, time_gap, delta: float = 4.0,
                     gap_floor: float = 1e-3):
    """IDM acceleration (7.8).

    Parameters
    ----------
    v, v_lead, v_desired : float or array
        Speed, leader's speed and desired speed (m/s).
    gap : float or array
        Bumper-to-bumper gap to the leader (m); ``inf`` when there is none.
    a_max, b : float or array
        Maximum acceleration and comfortable deceleration (m/s^2).
    s0, time_gap : float or array
        Jam distance (m) and desired time gap (s).
    delta : float
        Acceleration exponent.
    gap_floor : float
        Smallest gap divided by (keeps a touching pair finite).

    Returns
    -------
    float or ndarray
        The acceleration, a float when every argument is a scalar.
    """
    v, gap, v_lead = np.asarray(v, float), np.asarray(gap, float), np.asarray(v_lead, float)
    free = 1.0 - (v / v_desired) ** delta
    s_star = s0 + v * time_gap + v * (v - v_lead) / (2 * np.sqrt(a_max * b))
    with np.errstate(invalid="ignore"):
        inter = np.where(np.isfinite(gap), (np.maximum(s_star, 0.0) / np.maximum(gap, gap_floor)) ** 2, 0.0)
    out = a_max * (free - inter)
    return float(out) if np.ndim(out) == 0 else out
