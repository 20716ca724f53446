"""A bicycle ego whose actuator limits the change of its acceleration (``BicycleGuardian(actuator=...)``), on
hand-built scenes: the applied acceleration stays within the actuator's reach, the car ahead braking hardest
never brings the gap below h_min, and the guardian that ignores the jerk limit does."""
import math

import numpy as np
import pytest

from guardian.config import GuardianConfig
from guardian.decide.bicycle import BicycleGuardian
from guardian.decide.kinematics import BicycleEgo
from guardian.model.scene import Car, EgoState, Scene
from itha.actuator import Actuator

W, N, DT = 4.0, 3, 1 / 15
CONFIG = GuardianConfig()


def _guard(jerk=None, lag=0.0) -> BicycleGuardian:
    kin = BicycleEgo(DT, CONFIG.traffic_accel, 5.0, 2.0, W, N, math.pi / 4)
    actuator = None if jerk is None and not lag else Actuator(jerk=math.inf if jerk is None else jerk, lag=lag,
                                                              profile="hold")
    return BicycleGuardian(kin, CONFIG, False, actuator)


def _scene(ego: EgoState, lead_front: float, lead_speed: float) -> Scene:
    lead = Car(lead_front, lead_speed, frozenset({N - ego.lane}), 5.0, "lead")
    return Scene(Car(ego.front, ego.speed, frozenset(), 5.0, "ego"), (lead,), N)


def _follow(g: BicycleGuardian, jerk: float, rng) -> float:
    """The ego proposing full throttle behind a lead that brakes at the bound at a random moment; the world
    limits the acceleration's change to ``jerk`` (the speed stops at 0). Returns the least gap seen."""
    return _follow_lagged(g, Actuator(jerk=jerk, profile="hold"), rng, lambda t: CONFIG.traffic_accel)


@pytest.mark.parametrize("jerk", [10.0, 5.0])
def test_the_actuated_guardian_keeps_h_min_behind_a_lead_that_brakes_at_the_bound(jerk):
    rng = np.random.default_rng(4)
    g = _guard(jerk)
    for _ in range(20):
        g.reset()
        assert _follow(g, jerk, rng) >= CONFIG.h_min - 1e-6


def test_the_guardian_that_lets_the_acceleration_jump_loses_h_min_behind_a_jerk_limited_actuator():
    """The same runs with today's guardian (no actuator declared) in the jerk-limited world: the test above would
    fail without the actuated set."""
    rng = np.random.default_rng(4)
    g = _guard(None)
    least = min(_follow(g, 5.0, rng) for _ in range(20))
    assert least < CONFIG.h_min - 0.1


def test_the_actuated_failsafe_brakes_as_hard_as_the_actuator_allows_and_says_so():
    g = _guard(5.0)
    ego = EgoState(100.0, 4.0, 0.0, 20.0, 1, 1, 0.0, 2.0)
    applied, d = g.step(ego, _scene(ego, 110.0, 0.0), [3.0, 0.0])   # a standing car 5 m ahead
    assert d.level == "failsafe" and applied[0] == pytest.approx(2.0 - 5.0 * DT)
    assert "actuator" in " ".join(d.reasons)


def test_a_proposal_beyond_the_reach_is_a_clip_to_the_model_not_an_override():
    g = _guard(5.0)
    ego = EgoState(100.0, 4.0, 0.0, 20.0, 1, 1, 0.0, 0.0)
    applied, d = g.step(ego, _scene(ego, 400.0, 20.0), [3.0, 0.0])   # free road, the proposal a jump of 3
    assert applied[0] == pytest.approx(5.0 * DT)
    assert d.clipped_to_model and "actuator" in " ".join(d.reasons)


def test_at_the_sets_edge_the_hardest_braking_the_actuator_allows_is_admissible_not_a_failsafe():
    """Found in SUMO: near the top speed with the acceleration still rising, only the hardest braking keeps the
    speed below v_max; the next speeds it leaves were narrower than the rounding shrink of the accelerations, so
    the guardian found no acceleration and called a fail-safe (the same command, but a false alarm)."""
    kin = BicycleEgo(0.1, CONFIG.traffic_accel, 5.0, 2.0, W, N, math.pi / 4)
    g = BicycleGuardian(kin, CONFIG, False, Actuator(jerk=5.0, profile="hold"))
    ego = EgoState(100.0, 4.0, 0.0, 39.89812143589666, 1, 1, 0.0, 1.2593928190166714)
    assert g.ego_set.contains((ego.speed, math.inf, 0.0, ego.acceleration))
    applied, d = g.step(ego, Scene(Car(ego.front, ego.speed, frozenset(), 5.0, "ego"), (), N), [3.0, 0.0])
    assert d.level != "failsafe" and d.in_invariant_set
    assert applied[0] == pytest.approx(ego.acceleration - 0.5, abs=1e-8) and applied[0] >= ego.acceleration - 0.5


# ---- a first-order lag (sampled each step): the guardian answers commands, the lag applies part of each -----
def _follow_lagged(g: BicycleGuardian, world: Actuator, rng, propose, steps: int = 300) -> float:
    """As ``_follow``, the world's actuator ``world`` (``Actuator.follows``), the ego proposing ``propose(t)``;
    asserts every answer is a command within U and, behind the declared actuator, that the acceleration applied
    is one the guardian admitted."""
    v, vL = rng.uniform(15, 28), rng.uniform(15, 28)
    ego = EgoState(100.0, 4.0, 0.0, v, 1, 1, 0.0, 0.0)
    lead_front, least = 100.0 + 5.0 + rng.uniform(40, 80), math.inf
    brake_at = rng.integers(0, 120)
    for t in range(steps):
        applied, d = g.step(ego, _scene(ego, lead_front, vL), [propose(t), 0.0])
        u = float(applied[0])
        assert -CONFIG.traffic_accel <= u <= CONFIG.traffic_accel
        a = world.follows(ego.acceleration, u, DT)
        if d.level != "failsafe" and g.actuator == world:
            assert any(lo - 1e-9 <= u <= hi + 1e-9 for lo, hi in d.admissible_acceleration), (u, d)
        d_lead = -CONFIG.traffic_accel if t >= brake_at else rng.uniform(-1, 1)
        lead_front += DT * vL
        vL = min(max(vL + DT * d_lead, 0.0), CONFIG.v_max)
        ego = EgoState(ego.front + DT * ego.speed, 4.0, 0.0, max(ego.speed + DT * a, 0.0), 1, 1, 0.0, a)
        least = min(least, lead_front - 5.0 - ego.front)
    return least


@pytest.mark.parametrize("jerk,lag", [(None, 0.5), (None, 0.2), (5.0, 0.3)])
def test_the_lagged_guardian_keeps_h_min_behind_a_lead_that_brakes_at_the_bound(jerk, lag):
    rng = np.random.default_rng(6)
    g = _guard(jerk, lag)
    drivers = [lambda t: CONFIG.traffic_accel, lambda t: CONFIG.traffic_accel * (1 if (t // 7) % 2 else -1),
               lambda t: float(rng.uniform(-CONFIG.traffic_accel, CONFIG.traffic_accel))]
    for k in range(24):
        g.reset()
        assert _follow_lagged(g, g.actuator, rng, drivers[k % 3]) >= CONFIG.h_min - 1e-6


@pytest.mark.parametrize("declared", [None, 5.0])
def test_a_guardian_that_ignores_the_lag_loses_h_min_behind_it(declared):
    """The same runs, the world lagging 0.5 s, the guardian declaring no actuator or the jerk bound alone: the test
    above would fail without the lag in the set."""
    rng = np.random.default_rng(6)
    g, world = _guard(declared), Actuator(lag=0.5, profile="hold")
    least = min(_follow_lagged(g, world, rng, lambda t: CONFIG.traffic_accel) for _ in range(24))
    assert least < CONFIG.h_min - 0.1


def test_under_a_lag_an_admissible_command_passes_unchanged_and_a_changed_one_is_a_command():
    g = _guard(lag=0.5)
    ego = EgoState(100.0, 4.0, 0.0, 20.0, 1, 1, 0.0, 1.0)
    free = Scene(Car(ego.front, ego.speed, frozenset(), 5.0, "ego"), (), N)
    applied, d = g.step(ego, free, [2.5, 0.0])
    assert applied[0] == 2.5 and d.changed == "none"
    applied, d = g.step(ego, free, [CONFIG.traffic_accel, 0.0])   # full throttle: not an override
    assert d.changed == "none" and not d.clipped_to_model
    for dt in (0.0667, 0.05, 0.1, 1 / 15, 0.2):   # at any period (the reach's end lies on the rounding shrink)
        kin = BicycleEgo(dt, CONFIG.traffic_accel, 5.0, 2.0, W, N, math.pi / 4)
        other = BicycleGuardian(kin, CONFIG, False, g.actuator)
        for a_now in (-3.0, 0.0, 1.0, 4.5):
            now = EgoState(100.0, 4.0, 0.0, 20.0, 1, 1, 0.0, a_now)
            assert other.step(now, free, [CONFIG.traffic_accel, 0.0])[1].changed == "none", (dt, a_now)
            assert other.step(now, free, [-CONFIG.traffic_accel, 0.0])[1].changed == "none", (dt, a_now)
    assert applied[0] <= CONFIG.traffic_accel and g.ego_set.contains(
        (ego.speed + DT * g.actuator.follows(ego.acceleration, applied[0], DT), math.inf, 0.0,
         g.actuator.follows(ego.acceleration, applied[0], DT)))
    applied, d = g.step(ego, _scene(ego, 144.0, 10.0), [2.5, 0.0])   # closing on a slower car 39 m ahead
    u = float(applied[0])
    assert u < 2.5 and d.changed == "throttle" and -CONFIG.traffic_accel <= u <= CONFIG.traffic_accel
    assert [[u, u]] != d.admissible_acceleration and d.admissible_acceleration[0][1] == u   # the top command
    lagged = g.actuator.follows(ego.acceleration, u, DT)
    assert g.ego_set.contains((max(ego.speed + DT * lagged, 0.0), 144.0 - 5.0 - ego.front + DT * (10.0 - ego.speed),
                               max(10.0 - DT * CONFIG.traffic_accel, 0.0), lagged))


def test_under_a_lag_the_failsafe_asks_the_hardest_command_and_says_so():
    g = _guard(lag=0.5)
    ego = EgoState(100.0, 4.0, 0.0, 20.0, 1, 1, 0.0, 2.0)
    applied, d = g.step(ego, _scene(ego, 110.0, 0.0), [3.0, 0.0])   # a standing car 5 m ahead
    assert d.level == "failsafe" and applied[0] == -CONFIG.traffic_accel
    assert "actuator" in " ".join(d.reasons)


def test_a_proposal_that_is_not_finite_is_refused_by_name():
    for g in (_guard(), _guard(lag=0.5)):
        ego = EgoState(100.0, 4.0, 0.0, 20.0, 1, 1, 0.0, 0.0)
        for bad in ([math.nan, 0.0], [0.0, math.inf], [-math.inf, 0.0]):
            with pytest.raises(ValueError, match="not finite"):
                g.step(ego, _scene(ego, 400.0, 20.0), bad)


@pytest.mark.parametrize("jerk,lag", [(5.0, 0.0), (None, 0.5), (5.0, 0.5)])
def test_an_acceleration_now_outside_the_actuators_bounds_is_outside_the_model_and_brakes_hardest(jerk, lag):
    """Found by a helper: a reading of 10 m/s^2 (beyond U = ±6) under a lag and a jerk bound was answered with full
    throttle at the fail-safe level (the same applied acceleration as braking under the model, but none to spare)."""
    g = _guard(jerk, lag)
    for a_now in (10.0, 1e6, -1e20):
        ego = EgoState(100.0, 4.0, 0.0, 20.0, 1, 1, 0.0, a_now)
        applied, d = g.step(ego, _scene(ego, 400.0, 20.0), [0.0, 0.0])
        assert d.level == "failsafe" and applied[0] == -CONFIG.traffic_accel, (a_now, applied, d.reasons)
