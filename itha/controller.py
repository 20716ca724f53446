"""The ego's receding-horizon controller on the highway (7.7): track ``v_nom`` within the allowed inputs.

For each triggering choice the ego solves

    min Σ_{t=1}^{H} (v_t - v_nom)^2   s.t. u_0 in the choice's responsible inputs,
                                           u_t in [u_min, u_max] afterwards,

and takes the cheapest feasible choice (``choose``).
"""
from __future__ import annotations

from itha.road import HighwayParams


def tracking_cost(v1: float, v_nom: float, horizon: int, dt: float, u_min: float, u_max: float) -> float:
    """Optimal value of ``Σ_{t=1}^{H} (v_t - v_nom)^2`` given ``v_1`` and ``u in [u_min, u_max]`` afterwards.

    The speed is an integrator with a box input, so moving towards ``v_nom`` as
    fast as possible reaches the closest reachable speed at every step at once.
    """
    cost, v = 0.0, v1
    for _ in range(horizon):
        cost += (v - v_nom) ** 2
        v += dt * min(max((v_nom - v) / dt, u_min), u_max)
    return cost


def best_input(intervals, v: float, prm: HighwayParams):
    """The QP of (7.7) for one triggering choice: ``(u_0, cost)``, or None if infeasible.

    The cost only depends on the speeds, and the (7.7) constraints at the first
    step are the feasible intervals; the cost is convex in ``v_1``, so the
    optimum is the feasible input closest to ``(v_nom - v) / dt``.
    """
    if not intervals:
        return None
    cf = prm.car_following
    want = (prm.v_nom - v) / cf.dt
    best = None
    for lo, hi in intervals:
        u = min(max(want, lo), hi)
        c = tracking_cost(v + cf.dt * u, prm.v_nom, prm.horizon, cf.dt, cf.u_min, cf.u_max)
        if best is None or c < best[1] - 1e-12:
            best = (u, c)
    return best


def choose(verdicts, v: float, prm: HighwayParams):
    """Best feasible triggering choice: lowest cost; ties keep the lane (then left, then right)."""
    best = None
    for vd in verdicts:
        sol = best_input(vd.inputs, v, prm)
        if sol is not None and (best is None or sol[1] < best[2] - 1e-9):
            best = (vd.trigger, sol[0], sol[1])
    return best
