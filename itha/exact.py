"""The car-following step integrated exactly: each car holds its acceleration over the step.

(7.3) moves the gap by an Euler step, ``h+ = h + dt (v_L - v)``: exact for highway-env (a vehicle moves by its
speed before the step), not for a vehicle that moves continuously (a real one, SUMO's ballistic update,
recorded traffic). There the gap after a step differs by ``dt^2/2 (a_L - a)``, and the gap inside a step can dip
below both its ends. With ``CarFollowingParams(integration="exact")`` the closed-form set and the self-safe
inputs use the kinematics below instead:

* a car at speed ``s`` holding acceleration ``a`` covers ``s t + a t^2 / 2`` in time ``t``; a braking car that
  reaches standstill stays there (no reversing);
* the gap ``g(t) = h + X_L(t) - X_E(t)`` is then piecewise quadratic, its slope ``v_L(t) - v(t)`` piecewise
  linear with kinks where a car stops. Its minimum over an interval is at an end, at a stop, or where the
  slope is zero while both cars move: ``gap_min`` evaluates ``g`` at exactly those times (an extra candidate
  costs nothing: every value is a true value of ``g``);
* the floor of a state is ``gap_min`` over all time with both cars braking as hard as they may: the maximal
  RCIS is ``{floor >= h_min}`` by the same monotonicity argument as the Euler set's (any lead within
  ``[d_min, d_max]`` is ahead of the one braking hardest at every instant, any other ego input behind it).

Scalar functions, compiled with numba like ``itha._kernels``.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def travel(s, a, t):
    """Distance covered in time ``t`` from speed ``s >= 0`` holding acceleration ``a``, stopping at standstill."""
    if a < 0.0:
        t = min(t, s / -a)
    return s * t + 0.5 * a * t * t


@njit(cache=True)
def speed_after(s, a, t):
    """Speed after time ``t`` from ``s`` holding ``a`` (a braking car stays at standstill)."""
    return max(s + a * t, 0.0)


@njit(cache=True)
def _gap(h, v, a, vL, aL, t):
    return h + travel(vL, aL, t) - travel(v, a, t)


@njit(cache=True)
def gap_min(h, v, a, vL, aL, T):
    """``min_{0 <= t <= T} g(t)`` for the ego at ``v`` holding ``a`` behind a lead at ``vL`` holding ``aL``."""
    best = min(_gap(h, v, a, vL, aL, 0.0), _gap(h, v, a, vL, aL, T))
    if a < 0.0 and v / -a < T:
        best = min(best, _gap(h, v, a, vL, aL, v / -a))
    if aL < 0.0 and vL / -aL < T:
        best = min(best, _gap(h, v, a, vL, aL, vL / -aL))
    if aL != a:
        t0 = (v - vL) / (aL - a)
        if 0.0 < t0 < T:
            best = min(best, _gap(h, v, a, vL, aL, t0))
    return best


@njit(cache=True)
def floor(be, bL, v, h, vL):
    """The least gap over all time when the ego brakes at ``be`` and the lead at ``bL`` (both > 0) to standstill."""
    return gap_min(h, v, -be, vL, -bL, max(v / be, vL / bL))


@njit(cache=True)
def next_state(dt, v, h, vL, a, aL):
    """``(v+, h+, v_L+)`` after a step with the ego holding ``a`` and the lead ``aL``."""
    return speed_after(v, a, dt), h + travel(vL, aL, dt) - travel(v, a, dt), speed_after(vL, aL, dt)


@njit(cache=True)
def keeps_set(be, bL, dt, v_max, threshold, v, h, vL, a):
    """Input ``a`` at ``(v, h, vL)`` keeps the gap at or above ``threshold`` through the step and the next state
    in ``{floor >= threshold}``, whatever the lead does (the worst lead brakes at ``bL`` all along)."""
    if gap_min(h, v, a, vL, -bL, dt) < threshold:
        return False
    v1, h1, vL1 = next_state(dt, v, h, vL, a, -bL)
    return v1 <= v_max and floor(be, bL, v1, h1, vL1) >= threshold


@njit(cache=True)
def highest_input(be, bL, dt, v_max, threshold, v, h, vL, lo, hi, iterations):
    """The last input of ``[lo, hi]`` that ``keeps_set`` (it is monotone: more throttle is worse); NaN if ``lo``
    does not."""
    if not keeps_set(be, bL, dt, v_max, threshold, v, h, vL, lo):
        return math.nan
    if keeps_set(be, bL, dt, v_max, threshold, v, h, vL, hi):
        return hi
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        if keeps_set(be, bL, dt, v_max, threshold, v, h, vL, mid):
            lo = mid
        else:
            hi = mid
    return lo


@njit(cache=True)
def floor_many(be, bL, v, h, vL):
    out = np.empty(v.shape[0])
    for i in range(v.shape[0]):
        out[i] = floor(be, bL, v[i], h[i], vL[i])
    return out


@njit(cache=True)
def bisect_speed(be, bL, a, b, threshold, top, iterations, over_lead):
    """``_kernels._bisect`` for the exact floor: over the ego speed (state ``(s, a, b)``) or the lead speed
    (``(a, b, s)``); ``(last safe, first unsafe)`` for the ego, ``(last unsafe, first safe)`` for the lead."""
    lo, hi = 0.0, top
    for _ in range(iterations):
        mid = (lo + hi) / 2
        safe = floor(be, bL, a, b, mid) >= threshold if over_lead else floor(be, bL, mid, a, b) >= threshold
        if safe != over_lead:
            lo = mid
        else:
            hi = mid
    return lo, hi


@njit(cache=True)
def unsafe_inputs(be, bL, dt, u_min, u_max, v_max, h_min, v, h, vL, u):
    """Per recorded point: the input is outside ``U``, or it does not keep the set whatever the lead does
    (``keeps_set``), or the lead is faster than ``v_max``. ``h = inf`` is a free road."""
    out = np.empty(v.shape[0], dtype=np.bool_)
    for i in range(v.shape[0]):
        ok = u_min <= u[i] <= u_max and 0.0 <= v[i] <= v_max and speed_after(v[i], u[i], dt) <= v_max
        if ok and math.isfinite(h[i]):
            ok = 0.0 <= vL[i] <= v_max and keeps_set(be, bL, dt, v_max, h_min, v[i], h[i], vL[i], u[i])
        out[i] = not ok
    return out
