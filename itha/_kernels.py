"""Compiled run-time queries of the closed-form car-following set: the floor and its bisections.

The same arithmetic, in the same order, as ``car_following._floor_scalar`` and ``_boundary`` (a test
checks them equal bit for bit); only the interpreter's cost is gone. The guardian asks these a few
times per simulation step, and the HighD replay once per lane change and ρ̂.
"""
from __future__ import annotations

import math

from numba import njit


@njit(cache=True)
def _dist(s, a, t):
    n = min(t, math.ceil(s / a))
    return n * s - a * n * (n - 1) / 2


@njit(cache=True)
def floor(ae, aL, dt, v, h, vL):
    """``min_t Φ_t`` for one state (``_floor_scalar``)."""
    ke, kL = math.ceil(v / ae), math.ceil(vL / aL)
    t1, t_end = min(ke, kL), max(ke, kL)
    n_cands = 3
    t4 = 0
    if ae > aL:
        t4 = min(math.ceil(max(v - vL, 0.0) / (ae - aL)), t1)
        n_cands = 4
    best = h + dt * (_dist(vL, aL, 0) - _dist(v, ae, 0))
    for k in range(1, n_cands):
        t = t1 if k == 1 else (t_end if k == 2 else t4)
        val = h + dt * (_dist(vL, aL, t) - _dist(v, ae, t))
        if val < best:  # Python's min keeps the first of equals, and a NaN only if it came first
            best = val
    return best


@njit(cache=True)
def _bisect(ae, aL, dt, a, b, threshold, top, iterations, over_lead):
    """Bisection on ``[0, top]`` of ``floor >= threshold``, over the ego speed (state ``(s, a, b)`` =
    ``(v, h, vL)``) or over the lead speed (``(a, b, s)`` = ``(v, h, vL)``); ``(last safe, first unsafe)``
    for the ego, ``(last unsafe, first safe)`` for the lead, as ``_boundary`` gives them."""
    lo, hi = 0.0, top
    for _ in range(iterations):
        mid = (lo + hi) / 2
        safe = floor(ae, aL, dt, a, b, mid) >= threshold if over_lead else floor(ae, aL, dt, mid, a, b) >= threshold
        if safe != over_lead:
            lo = mid
        else:
            hi = mid
    return lo, hi


def highest_safe_speed(ae, aL, dt, h, vL, threshold, top, iterations):
    """The last ego speed with ``floor >= threshold`` (``_boundary(safe, top)[0]``)."""
    return _bisect(ae, aL, dt, h, vL, threshold, top, iterations, False)[0]


def lowest_safe_lead_speed(ae, aL, dt, v, h, threshold, top, iterations):
    """The first lead speed with ``floor >= threshold`` (``_boundary(not safe, top)[1]``)."""
    return _bisect(ae, aL, dt, v, h, threshold, top, iterations, True)[1]
