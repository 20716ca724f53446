"""The highway ITHA: responsibility by brute force over the other cars' triggers, (7.7), Section 7.4.1."""
import itertools

import numpy as np
import pytest

from itha.car_following import CarFollowingParams, MaximalSet, load_or_build
from itha.controller import best_input
from itha.highway_experiment import highway_experiment, initial_traffic
from itha.responsibility import EgoSupervisor
from itha.road import LANE_SHIFT, LEFT, STAY, HighwayParams, example8_order, leader, local_states, reset_state, resolution

CF = CarFollowingParams()
SMALL = HighwayParams(n_lanes=3, n_cars=5, ego_lane=2, road_window=(-30.0, 60.0))


@pytest.fixture(scope="module")
def S(tmp_path_factory):
    return load_or_build(CF, cache_dir=tmp_path_factory.mktemp("hw-cache"))


def _next(p, v, lane, triggers, acc):
    dt = CF.dt
    return ([p[k] + dt * v[k] for k in range(len(p))], [v[k] + dt * acc[k] for k in range(len(p))],
            [lane[k] + LANE_SHIFT[triggers[k]] for k in range(len(p))])


def _violations(S, prm, p, v, lane, trig, u_ego, triggers):
    """Cars the ego answers for, reset outside the RCIS in this scenario (worst inputs and braking)."""
    n = len(p)
    acc = [u_ego] + [0.0] * (n - 1)
    pn, vn, ln = _next(p, v, lane, [trig] + list(triggers), acc)
    stay_ln = list(ln)
    stay_ln[0] = lane[0]  # the counterfactual: the ego keeps its lane
    bad = []
    for i in range(n):
        L = leader(pn, ln, i)
        if i != 0 and L == leader(pn, stay_ln, i):
            continue  # the ego's trigger did not change who i follows
        if i != 0 and triggers[i - 1] != STAY and prm is not None and prm == "ordered":
            continue  # a later car moving in answers for itself under the ordered contract
        v_i = vn[i] if i == 0 else min(v[i] + CF.dt * CF.u_max, CF.v_max)
        if L < 0:
            continue
        v_L = vn[0] if L == 0 else float(CF.worst_lead_speed(v[L]))
        x = (v_i, pn[L] - pn[i] - SMALL.car_length, v_L)
        if not S.contains(np.array([x]))[0]:
            bad.append((i, x))
    return bad



def _traffic_in_set(S, rng, trials: int):
    """Of ``trials`` random traffic scenes (speeds in [0, 20] m/s), those whose every local state is in S."""
    for _ in range(trials):
        p, v, lane, _ = initial_traffic(SMALL, S, rng)
        v = [float(rng.uniform(0, 20)) for _ in v]
        if S.contains(local_states(SMALL, p, v, lane)).all():
            yield p, v, lane

@pytest.mark.parametrize("overapprox", ["trivial", "ordered"])
def test_allowed_lane_changes_are_responsible_by_brute_force(S, overapprox):
    rng = np.random.default_rng(7)
    checked = 0
    for p, v, lane in _traffic_in_set(S, rng, 60):
        order = example8_order(p, lane)
        ahead = set(order[:order.index(0)])
        sup = EgoSupervisor(SMALL, S, overapprox)
        for vd in sup.choices(p, v, lane, 0, {k: STAY for k in ahead} if overapprox == "ordered" else {}):
            if vd.trigger == STAY or not vd.inputs:
                continue
            others = range(1, len(p))
            options = [[STAY] if (overapprox == "ordered" and k in ahead) else
                       [t for t in LANE_SHIFT if 1 <= lane[k] + LANE_SHIFT[t] <= SMALL.n_lanes] for k in others]
            for lo, hi in vd.inputs:
                for u in (lo, hi, (lo + hi) / 2):
                    for triggers in itertools.product(*options):
                        bad = _violations(S, overapprox, p, v, lane, vd.trigger, u, triggers)
                        assert not bad, (vd.trigger, u, triggers, bad)
                        checked += 1
    assert checked > 300


def test_the_brute_force_check_can_fail(S):
    """Without the responsibility rule (every lane change allowed) the same check finds violations."""
    rng = np.random.default_rng(8)
    for trial in range(60):
        p, v, lane, _ = initial_traffic(SMALL, S, rng)
        for trig in ("left", "right"):
            if not 1 <= lane[0] + LANE_SHIFT[trig] <= SMALL.n_lanes:
                continue
            if _violations(S, "trivial", p, v, lane, trig, 0.0, [STAY] * (len(p) - 1)):
                return
    pytest.fail("no unsafe lane change found among random traffic")


def test_trivial_is_more_conservative_than_ordered(S):
    rng = np.random.default_rng(9)
    more = 0
    for trial in range(80):
        p, v, lane, _ = initial_traffic(SMALL, S, rng)
        order = example8_order(p, lane)
        ann = {k: STAY for k in order[:order.index(0)]}
        t = EgoSupervisor(SMALL, S, "trivial").choices(p, v, lane, 0, ann)
        o = EgoSupervisor(SMALL, S, "ordered").choices(p, v, lane, 0, ann)
        for a, b in zip(t, o):
            assert not (a.inputs and not b.inputs), "trivial allowed what ordered refused"
            more += bool(b.inputs) and not a.inputs
    assert more > 0


def test_silent_cars_are_over_approximated_as_trivial_does_by_brute_force(S):
    """Ordered ρ̂ with cars that announce nothing (highway-env's IDM traffic): those may do anything and the
    ego answers for them; the cars that take part announce (ahead of the ego: they stay) or yield (behind it
    in the order: a mover answers for itself). Every allowed lane change survives every joint trigger."""
    rng = np.random.default_rng(17)
    checked = 0
    for p, v, lane in _traffic_in_set(S, rng, 200):
        silent = {k for k in range(1, len(p)) if rng.uniform() < 0.5}
        order = example8_order(p, lane)
        ahead = {k for k in order[:order.index(0)] if k not in silent}
        sup = EgoSupervisor(SMALL, S, "ordered")
        for vd in sup.choices(p, v, lane, 0, {k: STAY for k in ahead}):
            if vd.trigger == STAY:
                continue
            vd = sup.lane_change(p, v, lane, 0, vd.trigger, {k: STAY for k in ahead}, silent=silent)
            if not vd.inputs:
                continue
            options = [[STAY] if k in ahead else [t for t in LANE_SHIFT if 1 <= lane[k] + LANE_SHIFT[t] <= SMALL.n_lanes]
                       for k in range(1, len(p))]
            for lo, hi in vd.inputs:
                for u in (lo, hi):
                    for triggers in itertools.product(*options):
                        movers_answer = {k for k in range(1, len(p)) if k not in silent}
                        bad = [(i, x) for i, x in _violations(S, "trivial", p, v, lane, vd.trigger, u, triggers)
                               if not (i in movers_answer and triggers[i - 1] != STAY)]
                        assert not bad, (vd.trigger, u, triggers, silent, bad)
                        checked += 1
    assert checked > 3000


def test_with_every_car_silent_ordered_allows_what_trivial_allows(S):
    rng = np.random.default_rng(19)
    differ = 0
    for trial in range(60):
        p, v, lane, _ = initial_traffic(SMALL, S, rng)
        everyone = set(range(1, len(p)))
        for trig in ("left", "right"):
            t = EgoSupervisor(SMALL, S, "trivial").lane_change_speeds(p, v, lane, 0, trig, {})
            o = EgoSupervisor(SMALL, S, "ordered").lane_change_speeds(p, v, lane, 0, trig, {}, silent=everyone)
            plain = EgoSupervisor(SMALL, S, "ordered").lane_change_speeds(p, v, lane, 0, trig, {})
            assert o == t
            differ += plain != t
    assert differ > 0  # the silent cars are what made the difference


def test_a_silent_car_ahead_does_not_hide_the_car_behind_it(S):
    """Target lane: a silent car 16 m ahead at 25 m/s (it may leave) and a standing car that takes part 32 m
    ahead: the ego's speed must keep it safe towards the standing car too (as trivial does); with the silent
    car taking part, only the nearer car matters."""
    p, v, lane = [0.0, 16.0, 32.0], [20.0, 25.0, 0.0], [2, 3, 3]
    sup = EgoSupervisor(SMALL, S, "ordered")
    silent, _ = sup.lane_change_speeds(p, v, lane, 0, LEFT, {}, silent={1})
    taking_part, _ = sup.lane_change_speeds(p, v, lane, 0, LEFT, {})
    trivial, _ = EgoSupervisor(SMALL, S, "trivial").lane_change_speeds(p, v, lane, 0, LEFT, {})
    assert silent == trivial and max(hi for _, hi in silent) < max(hi for _, hi in taking_part) - 5.0


def test_qp_of_7_7_matches_cvxpy():
    cp = pytest.importorskip("cvxpy")
    prm = HighwayParams()
    rng = np.random.default_rng(0)
    for _ in range(15):
        v0 = float(rng.uniform(0, 25))
        lo = float(rng.uniform(-10, 5))
        hi = float(rng.uniform(lo, 10))
        u, cost = best_input([(lo, hi)], v0, prm)
        U = cp.Variable(prm.horizon)
        vs = v0 + CF.dt * cp.cumsum(U)
        prob = cp.Problem(cp.Minimize(cp.sum_squares(vs - prm.v_nom)),
                          [U[0] >= lo, U[0] <= hi, U >= CF.u_min, U <= CF.u_max])
        prob.solve()
        assert cost == pytest.approx(prob.value, rel=1e-5, abs=1e-5)
        assert u == pytest.approx(float(U.value[0]), abs=1e-3)


def test_resolution_and_resets_of_appendix_b():
    prm = HighwayParams(n_lanes=3, car_length=5.0)
    # car 0 in lane 2 behind car 1; car 2 in lane 3 behind car 0's position; car 3 in lane 2 behind car 0
    p, v, lane = [0.0, 30.0, -5.0, -40.0], [10.0, 10.0, 10.0, 10.0], [2, 2, 3, 2]
    rho = resolution(prm, p, v, lane, [LEFT, STAY, STAY, STAY])
    assert rho[0] == {0}                   # the ego resets itself
    assert rho[2] == {0}                   # it becomes car 2's leader in lane 3
    assert rho[3] == {0}                   # car 3 loses it as leader (now follows car 1)
    assert rho[1] == frozenset()           # car 1 is ahead: its leader does not change
    assert resolution(prm, p, v, lane, [STAY] * 4) == [frozenset()] * 4  # Assumption 2
    x = reset_state(prm, p, v, lane, [1.0, 0.0, 0.0, 0.0], [LEFT, STAY, STAY, STAY], 2)
    assert x == pytest.approx((10.0, 5.0 - 5.0 + 0.0 + 0.1 * 10 - 0.1 * 10, 10.1))
    x3 = reset_state(prm, p, v, lane, [0.0] * 4, [LEFT, STAY, STAY, STAY], 3)
    assert x3 == pytest.approx((10.0, 30.0 + 40.0 - 5.0, 10.0))


def test_order_of_example_8():
    p, lane = [10.0, 30.0, 10.0, 0.0], [2, 1, 1, 3]
    assert example8_order(p, lane) == [1, 2, 0, 3]  # ahead first; aligned: slower (lower) lane first


def test_section_7_4_1_runs_are_safe(S):
    r = highway_experiment(runs=3, steps=150, seed=0, S=S)
    for oa in ("trivial", "ordered"):
        assert r[oa]["unsafe_steps"] == 0 and r[oa]["collisions"] == 0 and r[oa]["infeasible_steps"] == 0
        assert r[oa]["distance_mean"] > 0


def test_closed_form_set_runs_the_same_experiment():
    r = highway_experiment(runs=1, steps=60, seed=1, S=MaximalSet(CF))
    assert r["ordered"]["unsafe_steps"] == 0


def test_cars_beyond_any_reach_are_skipped_without_changing_an_answer(monkeypatch):
    """``lane_change_speeds`` skips a car farther than ``far_enough`` (the closed-form set holds at every speed
    there): on crowded random roads with cars near and far, every answer (speeds and reason, both ρ̂) equals the
    answer that checks every car, and the skip did happen."""
    import itha.responsibility as responsibility

    S, prm = MaximalSet(CarFollowingParams()), HighwayParams(n_lanes=3, n_cars=40, ego_lane=2)
    far = responsibility.far_enough(S)
    rng, skipped = np.random.default_rng(4), 0
    for _ in range(150):
        n = int(rng.integers(5, 40))
        p = [0.0] + list(rng.uniform(-4 * far, 4 * far, n))
        v = [float(rng.uniform(0, 30))] + list(rng.uniform(-1, 31, n))    # some outside [0, v_max]: never skipped
        lane = [2] + list(rng.integers(1, 4, n))
        lengths = list(rng.uniform(0, 12, n + 1))
        for overapprox, trig in itertools.product(("trivial", "ordered"), ("left", "right")):
            silent = set(rng.choice(np.arange(1, n + 1), size=n // 2, replace=False).tolist())
            sup = EgoSupervisor(prm, S, overapprox)
            fast = sup.lane_change_speeds(p, v, lane, 0, trig, {}, lengths, silent)
            with monkeypatch.context() as m:
                m.setattr(responsibility, "far_enough", lambda _: float("inf"))
                assert sup.lane_change_speeds(p, v, lane, 0, trig, {}, lengths, silent) == fast
            skipped += any(abs(x) > far + 12 for x in p[1:])
    assert skipped > 100
