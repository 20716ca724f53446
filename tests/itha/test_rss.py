"""RSS beside ITHA: the longitudinal safe distance against ad-rss's own primitives, the cut-in check, replay."""
import numpy as np
import pytest

from itha.rss import RSSParams, cut_in_safe, longitudinal_violations, safe_distance
from project import SHARED_DATA


def test_safe_distance_by_hand():
    # 20 m/s behind 20 m/s, defaults: 20 + 1.75 + 23.5^2 / 8 - 20^2 / 16
    assert np.isclose(safe_distance(RSSParams(), 20.0, 20.0), 21.75 + 23.5 ** 2 / 8 - 25.0)
    assert safe_distance(RSSParams(), 0.0, 40.0) == 0.0  # a fast leader needs no gap


def test_safe_distance_agrees_with_ad_rss():
    ad_rss = pytest.importorskip("ad_rss")
    from ad_rss import physics as ph

    core = ad_rss.rss.core
    p = RSSParams()
    rng = np.random.default_rng(0)
    for v_r, v_f in rng.uniform(0, 40, size=(200, 2)):
        speed, offset, stop_r, stop_f = ph.Speed(0.0), ph.Distance(0.0), ph.Distance(0.0), ph.Distance(0.0)
        assert core.calculateSpeedAndDistanceOffset(ph.Duration(p.response_time), ph.Speed(v_r),
                                                    ph.Duration(p.response_time), ph.Speed(100.0),
                                                    ph.Acceleration(p.accel_max), ph.Acceleration(-p.brake_min),
                                                    speed, offset)
        assert core.calculateStoppingDistance(speed, ph.Acceleration(-p.brake_min), stop_r)
        assert core.calculateStoppingDistance(ph.Speed(v_f), ph.Acceleration(-p.brake_max), stop_f)
        theirs = max(offset.toBaseType + stop_r.toBaseType - stop_f.toBaseType, 0.0)  # properties here
        assert np.isclose(safe_distance(p, v_r, v_f), theirs, atol=1e-6)


def test_violations_need_a_leader():
    p = RSSParams()
    out = longitudinal_violations(p, [20.0, 20.0, 20.0], [10.0, np.inf, 200.0], [20.0, 40.0, 20.0])
    assert out.tolist() == [True, False, False]


def test_cut_in_checks_both_new_neighbours():
    p = RSSParams()
    pos, v, length = [100.0, 200.0, 60.0], [20.0, 20.0, 30.0], [5.0, 5.0, 5.0]
    assert cut_in_safe(p, pos, v, [1, 2, 1], length, ego=0, target_lane=2)   # leader 95 m ahead
    assert not cut_in_safe(p, pos, v, [1, 2, 2], length, ego=0, target_lane=2)  # a fast follower 35 m behind
    assert not cut_in_safe(p, [100.0, 120.0], [20.0, 20.0], [1, 2], [5.0, 5.0], ego=0, target_lane=2)


def test_replay_reports_rss_beside_itha():

    from guardian.highd.replay import ReplayConfig, replay

    folder = SHARED_DATA / "i80_sample"
    r = replay(folder, ReplayConfig(seed=0))
    rates = r["override_rates"]
    assert {"self_safety", "responsibility_trivial", "responsibility_ordered", "rss_longitudinal",
            "rss_longitudinal_calibrated", "rss_cut_in", "rss_cut_in_calibrated"} <= set(rates)
    assert rates["rss_longitudinal"] > rates["self_safety"]  # ρ = 1 s against one data step
    assert r["rss_params"]["default"] == {"response_time": 1.0, "accel_max": 3.5, "brake_min": 4.0, "brake_max": 8.0}


def test_the_compiled_check_is_safe_distance_bit_for_bit():
    """longitudinal_violations runs compiled; safe_distance's array expression is its referee."""
    rng = np.random.default_rng(9)
    n = 300_000
    v, v_lead = rng.uniform(0, 45, n), rng.uniform(0, 45, n)
    h = rng.uniform(0, 250, n)
    h[::5] = np.inf  # no leader
    for p in (RSSParams(), RSSParams(response_time=0.04, accel_max=2.0, brake_min=6.0, brake_max=7.5)):
        d = safe_distance(p, v, v_lead)
        h[1::5] = d[1::5]  # exactly at the safe distance: not a violation
        expected = np.isfinite(h) & (h < np.where(np.isfinite(h), d, 0.0))
        assert np.array_equal(longitudinal_violations(p, v, h, v_lead), expected)
        assert longitudinal_violations(p, v.reshape(-1, 2), h.reshape(-1, 2), v_lead.reshape(-1, 2)).shape == (n // 2, 2)
