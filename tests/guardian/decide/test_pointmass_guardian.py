"""The overtake ego's decisions on hand-built scenes, without a simulator (guardian.decide.overtake).

The scenes are stepped by the model itself ((6.3)-(6.7), the ego's speed held at 0 as the simulator
does) and by traffic moving as (7.3), so every claim is checked in closed loop.
"""
import numpy as np
import pytest

from guardian.config import GuardianConfig
from guardian.decide.overtake import PointMassGuardian, lead_following_params
from guardian.model.scene import Car, Scene
from itha.car_following import CarFollowingParams, MaximalSet

HALF = 0.875 / 2  # the ego's half width in units of y_e (1.75 m at 2 m per unit)
SCALE = 2.0        # [m per unit of y_e]
LANE = 1.8         # [units of y_e]


def _guard(lib, n_lanes=3) -> PointMassGuardian:
    return PointMassGuardian(lib, n_lanes, HALF, traffic=True, config=GuardianConfig())


def _scene(x, cars, n_lanes=3, ego_at=100.0) -> Scene:
    """Traffic as ``(centre, speed, itha_lane)``; the ego's centre at ``ego_at``."""
    others = tuple(Car(c + 2.5, v, frozenset({lane}), 5.0, f"car {k}") for k, (c, v, lane) in enumerate(cars))
    return Scene(Car(ego_at + 2.5, float(x[0]), frozenset(), 5.0, "ego"), others, n_lanes)


def _step(lib, intention, x, u, rng, mode="random"):
    from envs.overtake import draw_disturbance

    w = draw_disturbance(lib.params, mode, x, rng)
    nxt = lib.models[intention].system.step(x, u, w)
    nxt[0] = max(nxt[0], 0.0)
    return nxt


def test_a_car_cutting_in_ahead_is_braked_for_never_driven_into(traffic_library):
    """The ego in the left lane at 25 m/s, the lead well behind; a car cuts in 29 m ahead at 17 m/s while
    the agent holds full throttle. The guardian brakes (never the agent's throttle) and never touches it."""
    lib, rng = traffic_library, np.random.default_rng(0)
    g = _guard(lib)
    x = np.array([25.0, LANE, -40.0, 20.0])
    ego_at, car_at, car_v = 100.0, 129.0, 17.0
    for t in range(80):
        applied, d = g.step(x, _scene(x, [(car_at, car_v, 2)], ego_at=ego_at), [3.0, 0.0])
        if t == 0:
            assert applied[0] < 0 and d.changed != "none"
        if d.level == "failsafe":
            assert applied[0] == lib.params.a_ex_bounds[0]  # the hardest braking, not S(x)'s nearest input
        ego_at += 0.1 * x[0]
        car_at += 0.1 * car_v
        x = _step(lib, "aggressive", x, applied, rng)
        assert car_at - 5.0 > ego_at, f"step {t}: drove into the car ahead"
        assert x[0] >= 0.0


def test_no_self_safe_input_means_the_hardest_braking_towards_the_own_lane(traffic_library):
    """A car cuts in 8 m ahead at 5 m/s while the ego does 25 m/s: nothing is self-safe any more."""
    g = _guard(traffic_library)
    x = np.array([25.0, LANE + 0.2, -40.0, 20.0])
    applied, d = g.step(x, _scene(x, [(108.0, 5.0, 2)]), [3.0, 1.0])
    assert d.level == "failsafe" and d.changed == "failsafe"
    assert applied[0] == traffic_library.params.a_ex_bounds[0]
    assert applied[1] < 0  # back towards the centre of its own lane
    assert g.kin.next_lanes(x[1], applied[1]) <= g.kin.lanes_at(x[1])  # and into no new lane


def test_an_entry_in_front_of_a_car_closing_from_behind_is_refused(traffic_library):
    """The ego at the right lane's edge asks to go left; a car 8 m behind in the left lane closes at 15 m/s."""
    lib = traffic_library
    g = _guard(lib)
    x = np.array([25.0, 0.45, 60.0, 25.0])
    applied, d = g.step(x, _scene(x, [(92.0, 40.0, 2)]), [0.0, 1.8])
    assert g.kin.next_lanes(x[1], applied[1]) == {1} and d.refused == [2]
    assert [(e.lane, e.responsible) for e in d.entries] == [(2, False)]
    far = _guard(lib)  # the same request with the left lane empty is let through
    applied, d = far.step(x, _scene(x, []), [0.0, 1.8])
    assert d.entered == [2] and [(e.lane, e.responsible) for e in d.entries] == [(2, True)]


def test_the_entry_check_holds_for_the_applied_input_not_the_proposed_one(traffic_library):
    """A right-lane state close behind a slower lead (in C_bnd, outside F_R): the lead's set alone would
    steer left. With a car alongside in the left lane, no applied input may enter that lane, whatever
    the agent proposed (the old guardian checked only the proposal's lateral input)."""
    lib, rng = traffic_library, np.random.default_rng(1)
    bnd = lib.region("bounded_velocity")
    g = _guard(lib)
    found = 0
    while found < 20:
        x = np.array([rng.uniform(20, 30), rng.uniform(0.25, 0.46), rng.uniform(10.5, 25), rng.uniform(5, 20)])
        if not bnd.contains(x) or g.in_follow_set(x):
            continue
        found += 1
        g.reset()
        for proposed in ([0.0, 0.0], [3.0, -1.8], [-3.0, 1.8]):
            applied, d = g.step(x, _scene(x, [(101.0, x[0], 2)]), proposed)
            assert g.kin.next_lanes(x[1], applied[1]) == {1}, (x, proposed, applied)
            assert all(e.responsible for e in d.entries if e.lane in d.entered)


@pytest.mark.parametrize("intention", ["aggressive", "cautious"])
def test_behind_a_slower_lead_with_the_left_lane_taken_the_ego_waits(traffic_library, intention):
    """A slow lead, the left lane full of traffic for 40 s, an agent on full throttle steering left: the
    ego stays in its lane, inside F_R, never closer to the lead than h_min."""
    lib, rng = traffic_library, np.random.default_rng(2)
    g = _guard(lib, n_lanes=2)
    x = np.array([24.0, 0.0, 60.0, 18.0])
    assert g.in_follow_set(x)
    ego_at = 100.0
    stream = [ego_at - 60.0 + 15.0 * k for k in range(12)]  # a car every 15 m, alongside and around
    for t in range(400):
        scene = _scene(x, [(c, x[0], 2) for c in stream], n_lanes=2, ego_at=ego_at)
        applied, d = g.step(x, scene, [3.0, 1.8])
        assert not d.entered and d.level == "composed"
        ego_at += 0.1 * x[0]
        stream = [c + 0.1 * x[0] for c in stream]  # the stream keeps pace with the ego
        x = _step(lib, intention, x, applied, rng, "adversarial")
        assert g.kin.lanes_at(x[1]) == {1} and x[2] >= lib.params.h_min
        assert g.in_follow_set(x), f"step {t}: left F_R at {x}"


def test_at_standstill_behind_a_stopped_lead_the_ego_stops_and_never_reverses(traffic_library):
    lib, rng = traffic_library, np.random.default_rng(3)
    g = _guard(lib, n_lanes=2)
    x = np.array([8.0, 0.0, 25.0, 0.0])
    for _ in range(150):
        applied, d = g.step(x, _scene(x, [], n_lanes=2), [3.0, 0.0])
        x = _step(lib, "aggressive", x, applied, rng, "adversarial")
        x[3] = 0.0  # the lead stays stopped (its physical bounds allow it; no intention model does)
        assert x[0] >= 0.0 and x[2] >= lib.params.h_min
    assert x[0] == 0.0 and d.lead_target == "follow"


def test_follow_set_is_invariant_under_every_lead_its_bounds_allow(traffic_library):
    """F_R as a falsifier: states drawn in it, the lead braking or speeding as (6.6) allows, the ego's
    noise at its box's corners, the guardian's input: every successor is in F_R again. The lead follows no
    intention, so the guardian is told not to use one (F_R^M with intentions: tests/guardian/decide/test_lead_following.py)."""
    lib, rng = traffic_library, np.random.default_rng(4)
    p = lib.params
    g = PointMassGuardian(lib, 2, HALF, traffic=True, config=GuardianConfig(use_intention=False))
    S = g.follow
    drawn = 0
    while drawn < 300:
        x = np.array([rng.uniform(0, 33), rng.uniform(-0.5, 0.4), rng.uniform(10, 120), rng.uniform(0, 33)])
        if not g.in_follow_set(x):
            continue
        drawn += 1
        g.reset()
        for _ in range(30):
            keep_lane = float(np.clip(-x[1] / p.dt + rng.uniform(-1, 1), *p.v_ey_bounds))
            applied, d = g.step(x, _scene(x, [], n_lanes=2), [rng.uniform(-3, 3), keep_lane])
            assert d.lead_target == "follow" and d.level == "composed"
            a_lead = rng.choice([p.a_L_bounds[0], rng.uniform(*p.a_L_bounds)])
            w_ex = rng.choice(p.w_ex_bounds)
            v = max((1 - p.b_e * p.dt) * x[0] + p.dt * (applied[0] + w_ex), 0.0)
            y = x[1] + p.dt * (applied[1] + rng.uniform(*p.w_ey_bounds))
            h = x[2] + p.dt * (x[3] - x[0])
            vL = min(max((1 - p.b_L * p.dt) * x[3] + p.dt * a_lead, 0.0), p.v_Lx_bounds[1])
            x = np.array([v, y, h, vL])
            assert S.contains([[v, h, vL]])[0] and g.in_follow_set(x), x


def test_the_falsifier_rejects_a_follow_set_that_trusts_the_lead_too_much(traffic_library):
    """The same falsifier on a set computed for a lead braking at 1 m/s^2 (it brakes at 3): counterexamples."""
    p = traffic_library.params
    wrong = MaximalSet(CarFollowingParams(**{**lead_following_params(p).__dict__, "d_min": -1.0}))
    rng = np.random.default_rng(5)
    failures = 0
    for _ in range(300):
        v, h, vL = rng.uniform(10, 30), rng.uniform(10, 60), rng.uniform(10, 30)
        if not wrong.contains([[v, h, vL]])[0]:
            continue
        for _ in range(200):  # the ego brakes as hard as it surely can, the lead as hard as it may
            h += p.dt * (vL - v)
            v = max((1 - p.b_e * p.dt) * v + p.dt * (p.a_ex_bounds[0] + p.w_ex_bounds[1]), 0.0)
            vL = max((1 - p.b_L * p.dt) * vL + p.dt * p.a_L_bounds[0], 0.0)
            if h < p.h_min:
                failures += 1
                break
    assert failures > 0


def test_without_traffic_the_decision_is_the_two_car_guardian(library):
    """traffic=False: the composed object answers exactly as IntentionAwareGuardian (Section 6.5)."""
    from guardian.decide.lead import IntentionAwareGuardian

    g = PointMassGuardian(library, 2, HALF, traffic=False, config=GuardianConfig(), stops_at_zero=False)
    twin = IntentionAwareGuardian(library)
    rng = np.random.default_rng(6)
    x = np.array([25.0, 0.0, 30.0, 20.0])
    for _ in range(50):
        u = rng.uniform([-3, -1.8], [3, 1.8])
        applied, d = g.step(x, _scene(x, [], n_lanes=2), u)
        expected, r = twin.step(x, u)
        assert np.array_equal(applied, expected) and d.active_set == r.active_set
        x = _step(library, "cautious", x, applied, rng)


def test_traffic_with_the_dissertations_speed_floor_is_refused(library):
    with pytest.raises(ValueError, match="wait behind the lead"):
        PointMassGuardian(library, 2, HALF, traffic=True, config=GuardianConfig())


def test_on_the_lane_line_the_noise_cannot_take_the_ego_out_of_k(traffic_library):
    """Found by the campaign (seek agent, 12 fast cars): the ego just right of the lane line, closing on
    the lead at full throttle with a lateral input whose noise decides whether the body touches the left
    lane. Such an input must keep F_R (the body may stay right) and C (it may not): drawn states near the
    line, full throttle and random laterals, the lead and the noise at their worst or at random, every
    successor lies in K again."""
    lib, rng = traffic_library, np.random.default_rng(7)
    p = lib.params
    g = _guard(lib, n_lanes=2)
    drawn = 0
    while drawn < 200:
        x = np.array([rng.uniform(15, 33), rng.uniform(0.3, 0.46), rng.uniform(10, 40), rng.uniform(10, 30)])
        if not g.inside(x):
            continue
        drawn += 1
        g.reset()
        for _ in range(15):
            proposal = [3.0, float(rng.choice([rng.uniform(*p.v_ey_bounds), -1.66, 0.0]))]
            applied, d = g.step(x, _scene(x, [], n_lanes=2), proposal)
            if d.level == "failsafe":
                break
            x = _step(lib, "aggressive", x, applied, rng, str(rng.choice(["random", "adversarial"])))
            assert g.inside(x), f"left K at {x} after {applied} ({d.lead_target})"

