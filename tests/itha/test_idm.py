"""One IDM (7.8): its limits, and the same numbers for scalars and arrays."""
import numpy as np

from itha.idm import idm_acceleration


def test_free_road_close_leader_and_equilibrium():
    kw = dict(a_max=1.5, b=2.0, s0=2.0, time_gap=1.2)
    assert idm_acceleration(0.0, np.inf, 0.0, 30.0, **kw) == 1.5               # standing start, free road
    assert abs(idm_acceleration(30.0, np.inf, 0.0, 30.0, **kw)) < 1e-12         # at the desired speed
    assert idm_acceleration(20.0, 5.0, 20.0, 30.0, **kw) < -5                   # far too close: hard braking
    v = 10.0  # equilibrium gap for equal speeds: s* = s0 + v T, where the free term balances
    gap = (2.0 + v * 1.2) / np.sqrt(1 - (v / 30.0) ** 4)
    assert abs(idm_acceleration(v, gap, v, 30.0, **kw)) < 1e-12


def test_arrays_give_the_scalar_answers():
    rng = np.random.default_rng(0)
    v, gap, vl, vd = rng.uniform(0, 30, 50), np.r_[rng.uniform(1, 80, 49), np.inf], rng.uniform(0, 30, 50), 33.0
    T = rng.uniform(0.6, 1.6, 50)
    vec = idm_acceleration(v, gap, vl, vd, 1.5, 2.0, 2.0, T)
    assert np.array_equal(vec, [idm_acceleration(*args, vd, 1.5, 2.0, 2.0, t) for *args, t in zip(v, gap, vl, T)])
