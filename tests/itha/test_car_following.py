"""The car-following RCIS of (7.3): closed form vs rcis, invariance by falsification, no-lead handling."""
import math

import numpy as np
import pytest

from itha.car_following import (CarFollowingParams, MaximalSet, admissible_inputs, headway_floor,
                                load_or_build)

P = CarFollowingParams()


@pytest.fixture(scope="module")
def poly(tmp_path_factory):
    return load_or_build(P, cache_dir=tmp_path_factory.mktemp("cf-cache"))


def _samples(n, rng, p=P, h_max=80.0):
    return np.column_stack([rng.uniform(0, p.v_max, n), rng.uniform(0, h_max, n), rng.uniform(0, p.v_max, n)])


def test_rcis_outside_in_converges_to_the_closed_form(poly):
    assert poly.info["iterations"] > 1 and len(poly.region) > 1
    X = _samples(100_000, np.random.default_rng(0))
    a, b = MaximalSet(P).contains(X), poly.contains(X)
    off_boundary = np.abs(headway_floor(P, X[:, 0], X[:, 1], X[:, 2]) - P.h_min) > 1e-4
    assert np.array_equal(a[off_boundary], b[off_boundary])
    assert 0.2 < a.mean() < 0.95  # neither trivial nor empty


def _falsify(S, p, rng, n=3000, d_min=None):
    """Sample states in S, apply a random admissible input and lead acceleration; count escapes."""
    d_min = p.d_min if d_min is None else d_min
    X = _samples(20 * n, rng, p)
    X = X[S.contains(X)][:n]
    escapes = 0
    for v, h, vL in X:
        ivs = admissible_inputs(S, (v, h, vL))
        assert ivs, f"no admissible input at {(v, h, vL)} inside the set"
        lo, hi = ivs[rng.integers(len(ivs))]
        for u in (lo, hi, rng.uniform(lo, hi)):
            d = rng.choice([d_min, p.d_max, rng.uniform(d_min, p.d_max)])
            nxt = (v + p.dt * u, h + p.dt * (vL - v), min(max(vL + p.dt * d, 0.0), p.v_max))
            escapes += not S.contains(np.array([nxt]))[0]
    return escapes


@pytest.mark.parametrize("kind", ["closed-form", "polyhedral"])
def test_falsifier_finds_no_escape(kind, poly):
    S = MaximalSet(P) if kind == "closed-form" else poly
    assert _falsify(S, P, np.random.default_rng(1)) == 0


def test_falsifier_catches_a_lead_braking_harder_than_assumed():
    assert _falsify(MaximalSet(P), P, np.random.default_rng(2), d_min=3 * P.d_min) > 0


@pytest.mark.parametrize("params", [CarFollowingParams(dt=0.04, v_max=45, u_min=-6, u_max=3, d_min=-1.2, d_max=1.0),
                                    CarFollowingParams(dt=0.04, v_max=45, u_min=-2, u_max=2, d_min=-5, d_max=3)])
def test_closed_form_is_invariant_at_25_hz(params):
    assert _falsify(MaximalSet(params), params, np.random.default_rng(3)) == 0


def test_no_lead_car_is_handled_explicitly(poly):
    for S in (MaximalSet(P), poly):
        free = np.array([[10.0, math.inf, P.v_max], [P.v_max, math.inf, P.v_max], [31.0, math.inf, P.v_max]])
        assert S.contains(free).tolist() == [True, True, False]
        (lo, hi), = admissible_inputs(S, (29.5, math.inf, P.v_max))
        assert lo == P.u_min and hi == pytest.approx(5.0)  # the speed stays <= v_max
        (lo, hi), = admissible_inputs(S, (0.5, math.inf, P.v_max))
        assert lo == pytest.approx(-5.0)  # the speed stays >= 0


def test_known_points():
    M = MaximalSet(P)
    # ego stopped behind a stopped lead, headway h_min: safe; closer: not.
    assert M.contains([[0, P.h_min, 0], [0, P.h_min - 0.01, 0]]).tolist() == [True, False]
    # 15 m/s towards a stopped car: braking 10 m/s^2 in 0.1 s steps covers 0.1*(15+14+...+1) = 12 m.
    assert M.contains([[15, P.h_min + 12.0, 0], [15, P.h_min + 11.9, 0]]).tolist() == [True, False]


def test_params_are_validated():
    with pytest.raises(ValueError, match="u_min"):
        CarFollowingParams(u_min=1.0)
    with pytest.raises(ValueError, match="d_min"):
        CarFollowingParams(d_min=0.0)


def test_cache_is_keyed_by_parameters(tmp_path, poly):
    from itha import car_following
    from rcis.cache import code_fingerprint, load_region
    from rcis.errors import StaleCacheError
    a = load_or_build(P, cache_dir=tmp_path)
    files = list(tmp_path.glob("car-following-*.npz"))
    assert len(files) == 1 and len(a.region) == len(poly.region)
    other = CarFollowingParams(h_min=6.0)
    with pytest.raises(StaleCacheError, match="h_min"):
        load_region(files[0], {"set": "car-following", "params": __import__("dataclasses").asdict(other),
                               "tighten": 1e-6, "code": code_fingerprint(car_following.__name__)})


@pytest.mark.parametrize("params", [CarFollowingParams(), CarFollowingParams(dt=0.04, u_min=-6.0, u_max=4.0,
                                                                             d_min=-0.5, d_max=0.5, v_max=60.0,
                                                                             h_min=2.0),
                                    CarFollowingParams(u_min=-3.0, d_min=-8.0)])
def test_compiled_bisections_are_the_python_ones_bit_for_bit(params):
    """itha._kernels replaces the interpreted floor and bisections; every answer must be identical."""
    from itha import _kernels
    from itha.car_following import INNER, SPEED_BISECTIONS, _boundary, _floor_scalar

    p = params
    rng = np.random.default_rng(3)
    thr = p.h_min + INNER
    for v, h, vL in zip(rng.uniform(0, p.v_max, 400), rng.uniform(-5, 150, 400), rng.uniform(0, p.v_max, 400)):
        assert _kernels.floor(p.ego_step, p.lead_step, p.dt, v, h, vL) == _floor_scalar(p, v, h, vL)
        speed = _boundary(lambda s: _floor_scalar(p, s, h, vL) >= thr, p.v_max)[0]
        assert _kernels.highest_safe_speed(p.ego_step, p.lead_step, p.dt, h, vL, thr, p.v_max, SPEED_BISECTIONS) == speed
        lead = _boundary(lambda s: not _floor_scalar(p, v, h, s) >= thr, p.v_max)[1]
        assert _kernels.lowest_safe_lead_speed(p.ego_step, p.lead_step, p.dt, v, h, thr, p.v_max,
                                               SPEED_BISECTIONS) == lead


def test_contains_of_one_state_is_the_vectorised_answer():
    """The single-state fast path of MaximalSet.contains agrees with the vectorised test everywhere."""
    rng = np.random.default_rng(8)
    S = MaximalSet(CarFollowingParams(dt=0.04, u_min=-6.0, u_max=4.0, d_min=-0.5, d_max=0.5, v_max=60.0, h_min=2.0))
    X = np.column_stack([rng.uniform(-5, 65, 3000), rng.uniform(-10, 200, 3000), rng.uniform(-5, 65, 3000)])
    X[::50, 1] = np.inf
    X[1::50] = np.nan
    batch = S.contains(X)
    assert batch.any() and not batch.all()
    assert [bool(S.contains(x[None])[0]) for x in X] == batch.tolist()


@pytest.mark.parametrize("params", [CarFollowingParams(), CarFollowingParams(dt=0.04, u_min=-6.0, u_max=4.0,
                                                                             d_min=-0.5, d_max=0.5, v_max=60.0,
                                                                             h_min=2.0),
                                    CarFollowingParams(u_min=-3.0, d_min=-8.0)])
def test_the_compiled_headway_floor_is_the_array_expression_bit_for_bit(params):
    """headway_floor's compiled loop (finite 1-D speeds) against its array expression, on random
    states and on speeds that are whole multiples of a braking step (where the candidates tie)."""
    from itha.car_following import _headway_floor_arrays

    p, rng, n = params, np.random.default_rng(5), 200_000
    v, vL = rng.uniform(0, p.v_max, n), rng.uniform(0, p.v_max, n)
    v[::3] = p.ego_step * rng.integers(0, int(p.v_max / p.ego_step), len(v[::3]))
    vL[::4] = p.lead_step * rng.integers(0, int(p.v_max / p.lead_step), len(vL[::4]))
    h = rng.uniform(-5, 150, n)
    h[::7] = np.inf  # no lead
    fast, reference = headway_floor(p, v, h, vL), _headway_floor_arrays(p, v, h, vL)
    assert np.array_equal(fast, reference) and np.array_equal(np.signbit(fast), np.signbit(reference))
