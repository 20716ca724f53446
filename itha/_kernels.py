"""Compiled run-time queries of the closed-form car-following set: the floor, its bisections, the
self-safety of recorded inputs, and RSS's longitudinal check beside them.

The same arithmetic, in the same order, as ``car_following._floor_scalar`` and ``_boundary``, as the
array expressions of ``headway_floor`` and of the replay's self-safety check, and as
``rss.safe_distance`` (tests check them equal bit for bit); only the interpreter's and the
temporaries' cost is gone. The guardian asks these a few times per simulation step, the HighD
replay once per lane change and ρ̂, and once per test data point (8 M on HighD's size).
"""
from __future__ import annotations

import math

import numpy as np
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
def floor_many(ae, aL, dt, v, h, vL):
    """``floor`` of each state: ``headway_floor`` of 1-D arrays with finite speeds."""
    out = np.empty(v.shape[0])
    for i in range(v.shape[0]):
        out[i] = floor(ae, aL, dt, v[i], h[i], vL[i])
    return out


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


@njit(cache=True)
def floor_drag(rho_e, beta_e, rho_L, beta_L, dt, v, h, vL):
    """``min_t Φ_t`` when each car's speed under full braking follows ``s+ = max(rho s - beta, 0)``
    (linear drag ``rho = 1 - b dt`` and a constant braking ``beta = -dt u``): the braking sequences are
    stepped until the ego stands (afterwards the headway cannot shrink)."""
    best = h
    phi = h
    while v > 0.0:
        phi += dt * (vL - v)
        if phi < best:
            best = phi
        v = max(rho_e * v - beta_e, 0.0)
        vL = max(rho_L * vL - beta_L, 0.0)
    return best


@njit(cache=True)
def _bisect_drag(rho_e, beta_e, rho_L, beta_L, dt, a, b, threshold, top, iterations, over_lead):
    """``_bisect`` for ``floor_drag``."""
    lo, hi = 0.0, top
    for _ in range(iterations):
        mid = (lo + hi) / 2
        if over_lead:
            safe = floor_drag(rho_e, beta_e, rho_L, beta_L, dt, a, b, mid) >= threshold
        else:
            safe = floor_drag(rho_e, beta_e, rho_L, beta_L, dt, mid, a, b) >= threshold
        if safe != over_lead:
            lo = mid
        else:
            hi = mid
    return lo, hi


def flat_floats(*arrays):
    """The arrays broadcast together, as contiguous 1-D float64 arrays for the loops below, and
    the shape to give their answers back in."""
    arrays = [np.asarray(a, float) for a in np.broadcast_arrays(*arrays)]
    return arrays[0].shape, [np.ascontiguousarray(a).ravel() for a in arrays]


@njit(cache=True)
def _finite(x):
    """``np.nan_to_num`` of one float: NaN -> 0, ±inf -> ±the largest double."""
    if math.isnan(x):
        return 0.0
    if math.isinf(x):
        return 1.7976931348623157e308 if x > 0 else -1.7976931348623157e308
    return x


@njit(cache=True)
def unsafe_inputs(ae, aL, dt, u_min, u_max, d_min, v_max, h_min, v, h, vL, u):
    """Per recorded point: the input is not self-safe (7.4), i.e. outside ``U`` or ``f(x, u, D) ⊄ C``.

    ``h = inf`` is a free road (``vL`` then ignored). The vectorised form is the test's referee.
    """
    out = np.empty(v.shape[0], dtype=np.bool_)
    for i in range(v.shape[0]):
        v_next = v[i] + dt * u[i]
        ok = u[i] >= u_min and u[i] <= u_max and v_next >= 0 and v_next <= v_max
        if math.isfinite(h[i]):
            lead = _finite(vL[i])
            h_next = h[i] + dt * (lead - v[i])
            lead_next = max(lead + dt * d_min, 0.0)
            inside = floor(ae, aL, dt, min(max(v_next, 0.0), v_max), h_next, min(lead_next, v_max)) >= h_min
            ok = ok and inside and lead <= v_max
        out[i] = not ok
    return out


@njit(cache=True)
def rss_violations(rho, accel, brake_min, brake_max, v, h, v_lead):
    """Per point: a leader (finite ``h``) nearer than RSS's safe distance (``rss.safe_distance``)."""
    offset = 0.5 * accel * rho ** 2
    out = np.zeros(v.shape[0], dtype=np.bool_)
    for i in range(v.shape[0]):
        if math.isfinite(h[i]):
            d = v[i] * rho + offset + (v[i] + rho * accel) ** 2 / (2 * brake_min) - v_lead[i] ** 2 / (2 * brake_max)
            out[i] = h[i] < max(d, 0.0)
    return out


@njit(cache=True)
def floor_rate_limited(fall, keep, u_min, lead_step, dt, v_max, v, h, vL, a):
    """``min_t Φ_t`` of (7.3) for an ego whose acceleration changes by at most ``fall`` (= jerk dt) a step and,
    under a lag, keeps the share ``keep`` of the last one (0: none): from acceleration ``a`` the hardest braking
    goes to ``max(a - fall, keep a + (1 - keep) u_min)`` a step (down to ``u_min``), the speed stopping at 0; the lead's
    speed falls by ``lead_step`` a step down to 0. Stepped until both stand for good (the ego stands, its
    acceleration not positive: it only falls from there). ``-inf`` when even this braking takes the ego's speed
    above ``v_max`` (an acceleration that cannot fall in time overshoots the top speed)."""
    best = h
    phi = h
    if v > v_max:
        return -math.inf
    while v > 0.0 or vL > 0.0 or a > 0.0:
        phi += dt * (vL - v)
        if phi < best:
            best = phi
        a = max(a - fall, min(max(keep * a + (1.0 - keep) * u_min, min(a, u_min)), max(a, u_min)))   # lagged(a, u_min)
        v = max(v + dt * a, 0.0)
        if v > v_max:
            return -math.inf
        vL = max(vL - lead_step, 0.0)
    return best


@njit(cache=True)
def highest_safe_command(fall, keep, u_min, lead_step, dt, v_max, v, h, vL, lo, hi, threshold, iterations):
    """Bisection on ``[lo, hi]`` (``lo`` safe, ``hi`` not) of ``floor_rate_limited`` at the next state ``(max(v +
    dt c, 0), h, vL, c)`` ``>= threshold``, which falls with the command ``c``: the last safe command."""
    for _ in range(iterations):
        mid = (lo + hi) / 2
        if floor_rate_limited(fall, keep, u_min, lead_step, dt, v_max, max(v + dt * mid, 0.0), h, vL, mid) >= threshold:
            lo = mid
        else:
            hi = mid
    return lo
