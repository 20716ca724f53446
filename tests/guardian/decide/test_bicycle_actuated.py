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


def _guard(jerk=None) -> BicycleGuardian:
    kin = BicycleEgo(DT, CONFIG.traffic_accel, 5.0, 2.0, W, N, math.pi / 4)
    return BicycleGuardian(kin, CONFIG, False, None if jerk is None else Actuator(jerk=jerk, profile="hold"))


def _scene(ego: EgoState, lead_front: float, lead_speed: float) -> Scene:
    lead = Car(lead_front, lead_speed, frozenset({N - ego.lane}), 5.0, "lead")
    return Scene(Car(ego.front, ego.speed, frozenset(), 5.0, "ego"), (lead,), N)


def _follow(g: BicycleGuardian, jerk: float, rng, steps: int = 300) -> float:
    """The ego proposing full throttle behind a lead that brakes at the bound at a random moment; the world
    limits the acceleration's change to ``jerk`` (the speed stops at 0). Returns the least gap seen; asserts
    the applied acceleration was always within the actuator's reach."""
    fall = jerk * DT
    v, vL = rng.uniform(15, 28), rng.uniform(15, 28)
    ego = EgoState(100.0, 4.0, 0.0, v, 1, 1, 0.0, 0.0)
    lead_front, least = 100.0 + 5.0 + rng.uniform(40, 80), math.inf
    brake_at = rng.integers(0, 120)
    for t in range(steps):
        applied, _ = g.step(ego, _scene(ego, lead_front, vL), [CONFIG.traffic_accel, 0.0])
        a = float(applied[0])
        lo, hi = ego.acceleration - fall, ego.acceleration + fall
        assert lo - 1e-12 <= a <= hi + 1e-12 or g.actuator is None
        a = min(max(a, lo), hi)   # the world's actuator
        d_lead = -CONFIG.traffic_accel if t >= brake_at else rng.uniform(-1, 1)
        lead_front += DT * vL
        vL = min(max(vL + DT * d_lead, 0.0), CONFIG.v_max)
        ego = EgoState(ego.front + DT * ego.speed, 4.0, 0.0, max(ego.speed + DT * a, 0.0), 1, 1, 0.0, a)
        least = min(least, lead_front - 5.0 - ego.front)
    return least


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
