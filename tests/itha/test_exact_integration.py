"""The car-following set under exact integration (``itha.exact``): its kinematics against a dense numerical
referee, its invariance under any lead within its bounds, and the probe of a lead that brakes at once."""

import numpy as np
import pytest

from itha import exact
from itha.car_following import (CarFollowingParams, MaximalSet, admissible_inputs, compute_polyhedral,
                                headway_floor, unsafe_inputs)
from itha.responsibility import EgoSupervisor
from itha.road import HighwayParams

GRID = 4001


def dense_gap(h, v, a, vL, aL, T, n=GRID):
    """The gap on a grid of ``n`` instants, by integrating each car's speed (piecewise linear, stopped at 0)
    with the trapezoid rule between grid points and the standstill instants: an independent referee."""
    times = np.union1d(np.linspace(0.0, T, n), [t for t in (v / -a if a < 0 else -1, vL / -aL if aL < 0 else -1)
                                                 if 0 < t < T])

    def position(s, acc):
        speed = np.maximum(s + acc * times, 0.0)
        return np.concatenate([[0.0], np.cumsum(np.diff(times) * (speed[1:] + speed[:-1]) / 2)])

    return times, h + position(vL, aL) - position(v, a)


def test_gap_min_is_the_least_gap_of_a_dense_referee():
    rng = np.random.default_rng(1)
    for _ in range(400):
        v, vL = rng.uniform(0, 30, 2)
        a, aL = rng.choice([rng.uniform(-10, 10), -10.0, 0.0, 10.0], 2)
        T, h = rng.uniform(0.01, 6.0), rng.uniform(-5, 20)
        _, g = dense_gap(h, v, a, vL, aL, T)
        m = exact.gap_min(h, v, a, vL, aL, T)
        step = T / (GRID - 1)
        assert m <= g.min() + 1e-9                                   # every grid value is a true gap
        assert m >= g.min() - abs(aL - a) * step ** 2 / 8 - 1e-9     # no dip between grid points is deeper


def test_the_exact_floor_is_the_least_gap_with_both_cars_braking_to_standstill():
    rng = np.random.default_rng(2)
    for _ in range(300):
        be, bL = rng.uniform(2, 10, 2)
        v, vL, h = *rng.uniform(0, 30, 2), rng.uniform(0, 40)
        T = max(v / be, vL / bL) + 1.0
        _, g = dense_gap(h, v, -be, vL, -bL, T)
        assert exact.floor(be, bL, v, h, vL) == pytest.approx(g.min(), abs=max(be, bL) * (T / GRID) ** 2 + 1e-9)


def test_exact_integration_is_declared_and_refused_where_the_euler_step_is_built_in():
    with pytest.raises(ValueError, match="integration"):
        CarFollowingParams(integration="ballistic")
    with pytest.raises(ValueError, match="without drag"):
        CarFollowingParams(drag=0.1, integration="exact")
    p = CarFollowingParams(integration="exact")
    with pytest.raises(ValueError, match="Euler"):
        compute_polyhedral(p)
    with pytest.raises(ValueError, match="Euler"):
        MaximalSet(p).input_intervals(10.0, 20.0, 10.0)
    with pytest.raises(ValueError, match="Euler"):
        EgoSupervisor(HighwayParams(car_following=p), MaximalSet(p))


def test_the_euler_model_is_untouched_by_the_option():
    """The default is (7.3): the same floor and inputs as before the option existed (the compiled Euler path)."""
    p = CarFollowingParams()
    assert p.integration == "euler" and not p.exact
    assert admissible_inputs(MaximalSet(p), (20.0, 30.0, 15.0)) == MaximalSet(p).input_intervals(
        20.0, 30.0 + p.dt * (15.0 - 20.0), float(p.worst_lead_speed(15.0)))


CASES = [dict(u_min=-8.0, d_min=-8.0, u_max=3.0, d_max=3.0), dict(u_min=-6.0, d_min=-9.0, u_max=2.0, d_max=4.0),
         dict(u_min=-10.0, d_min=-5.0, u_max=10.0, d_max=10.0)]


@pytest.mark.parametrize("bounds", CASES, ids=["equal", "weaker ego", "stronger ego"])
def test_exact_set_is_invariant_under_any_lead_within_its_bounds(bounds):
    """Falsifier: from states at the set's edge, any self-safe input and a lead whose acceleration changes
    ten times a step (within ``[d_min, d_max]``, mostly at its ends), integrated exactly: the gap never goes
    below ``h_min`` inside any step and each next state has a self-safe input again, for 20 steps."""
    p = CarFollowingParams(dt=0.1, v_max=30.0, h_min=0.5, integration="exact", **bounds)
    S, rng = MaximalSet(p), np.random.default_rng(3)
    for _ in range(150):
        v, vL = rng.uniform(0, 30, 2)
        if rng.uniform() < 0.5:  # closing slowly: the gap's least value may fall inside a step
            vL = max(v - rng.uniform(0, 1), 0.0)
        h = p.h_min - float(headway_floor(p, [v], [0.0], [vL])[0]) + rng.choice([0.0, 1e-6, rng.uniform(0, 2)])
        if not S.contains([[v, h, vL]])[0]:   # on the edge, rounding put it a hair outside
            continue
        for _ in range(20):
            inputs = admissible_inputs(S, (v, h, vL))
            assert inputs, f"no self-safe input at {(v, h, vL)}"
            lo, hi = inputs[0]
            u = rng.choice([lo, hi, rng.uniform(lo, hi)])
            for piece in range(10):
                aL = rng.choice([p.d_min, p.d_max, rng.uniform(p.d_min, p.d_max)])
                _, g = dense_gap(h, v, u, vL, aL, p.dt / 10, n=41)
                assert g.min() >= p.h_min - 1e-9
                v, h, vL = exact.next_state(p.dt / 10, v, h, vL, u, aL)
            vL = min(vL, p.v_max)   # a lead beyond the model's speeds is taken at v_max (it is only further ahead)
            assert v <= p.v_max + 1e-9
            v = min(v, p.v_max)     # ten pieces round the ego's speed a hair past v_max + dt u
            assert S.contains([[v, h, vL]])[0]


def test_self_safe_recorded_inputs_under_exact_integration():
    """``unsafe_inputs`` with exact integration says what ``admissible_inputs`` does, point by point."""
    p = CarFollowingParams(integration="exact", h_min=2.0)
    S, rng = MaximalSet(p), np.random.default_rng(4)
    v, vL, h = rng.uniform(0, 30, 500), rng.uniform(0, 30, 500), rng.uniform(0, 60, 500)
    u = rng.uniform(-12, 12, 500)
    flags = unsafe_inputs(p, v, h, vL, u)
    assert 50 < flags.sum() < 450
    for i in range(500):
        inputs = admissible_inputs(S, (v[i], h[i], vL[i]))
        inside = any(lo <= u[i] <= hi for lo, hi in inputs)
        if flags[i] == inside:   # they may differ only at the bisection's end of the interval
            assert abs(u[i] - inputs[0][1]) < 1e-6


def test_a_lead_braking_at_once_touches_the_euler_guardian_and_never_the_exact_one(benchmark_module):
    """The probe of ``benchmarks/exact_integration.py`` (h_min = 1 mm, the ego proposing +1.5 m/s^2): under exact
    integration the Euler set's gap misses ``dt^2/2 (a_L - a)`` a step and the bumpers meet; the exact set keeps
    every instant's gap at or above 1 mm."""
    probe = benchmark_module("exact_integration").probe
    euler, exact_ = probe("euler", 300, seed=5), probe("exact", 300, seed=5)
    assert euler["contacts"] > 0 and euler["floor_deficits"] > 0
    assert exact_["contacts"] == 0 and exact_["floor_deficits"] == 0
    assert exact_["least_gap_m"] >= 0.001 and exact_["steps_without_self_safe_input"] == 0
