"""highway-env's bicycle ego on hand-built scenes, without a simulator (guardian.bicycle)."""
import math

import numpy as np
import pytest

from guardian.bicycle import BicycleGuardian, EgoState
from guardian.config import GuardianConfig
from guardian.ego import BicycleEgo
from guardian.scene import Car, Scene

W = 4.0      # [m] highway-env's lane width; lane 0 at y = 0
N = 3


def _guard(dt=0.2, meta=False, max_steering=math.pi / 4) -> BicycleGuardian:
    kin = BicycleEgo(dt, 6.0, 5.0, 2.0, W, N, max_steering)
    return BicycleGuardian(kin, GuardianConfig(), meta)


def _scene(ego: EgoState, cars) -> Scene:
    """Traffic as ``(front, speed, highway lane id)``."""
    others = tuple(Car(f, v, frozenset({N - lane}), 5.0, f"car {k}") for k, (f, v, lane) in enumerate(cars))
    return Scene(Car(ego.front, ego.speed, frozenset(), 5.0, "ego"), others, N)


def _bicycle(kin: BicycleEgo, ego: EgoState, a: float, steer: float) -> EgoState:
    """One ``Vehicle.step`` of highway-env (the same arithmetic)."""
    beta = math.atan(0.5 * math.tan(steer))
    front = ego.front + kin.dt * ego.speed * math.cos(ego.heading + beta)
    y = ego.y + kin.dt * ego.speed * math.sin(ego.heading + beta)
    heading = ego.heading + kin.dt * ego.speed * math.sin(beta) / (kin.length / 2)
    lane = int(round(y / W))
    return EgoState(front, y, heading, ego.speed + kin.dt * a, min(max(lane, 0), N - 1), ego.target_lane)


def test_the_failsafe_brakes_to_standstill_and_never_reverses():
    g = _guard()
    ego = EgoState(100.0, 4.0, 0.0, 0.5, 1, 1)
    applied, d = g.step(ego, _scene(ego, [(101.0, 0.0, 1)]), [3.0, 0.0])  # a stopped car touching ahead
    assert d.level == "failsafe" and applied[0] == pytest.approx(-ego.speed / g.kin.dt)
    assert ego.speed + g.kin.dt * applied[0] >= 0.0
    fast = EgoState(100.0, 4.0, 0.0, 25.0, 1, 1)
    applied, d = g.step(fast, _scene(fast, [(103.0, 0.0, 1)]), [3.0, 0.0])
    assert d.level == "failsafe" and applied[0] == -6.0


def test_steering_is_checked_over_the_horizon_that_undoes_the_heading():
    """Heading towards lane 0 where a car drives alongside: one step of the proposed steering keeps the
    body out, but no straightening afterwards can: it is refused, and the applied steering's whole
    straightening path stays out of lane 0 in closed loop."""
    g = _guard()
    kin = g.kin
    ego = EgoState(100.0, 5.3, -0.12, 30.0, 1, 1)
    scene = _scene(ego, [(100.0, 30.0, 0)])
    y1, h1 = kin.predict(ego.y, ego.heading, ego.speed, -0.05)
    assert 0 not in kin.lanes_at(y1, h1)  # one step alone would not see it
    assert 0 in kin.path_lanes(ego.y, ego.heading, ego.speed, -0.05)[0]
    for _ in range(30):
        applied, d = g.step(ego, _scene(ego, [(ego.front, 30.0, 0)]), [0.0, -0.05])
        ego = _bicycle(kin, ego, applied[0], applied[1])
        assert 0 not in kin.lanes_at(ego.y, ego.heading)
    assert scene is not None


def test_an_entry_needs_a_speed_the_ego_can_reach():
    """A follower 9.8 m back doing 20.4 m/s in the target lane and the ego at 9.5 m/s: the entry would be
    responsible only at a next speed of 21 m/s and more, which one step cannot reach: refused."""
    g = _guard()
    ego = EgoState(568.9, 3.19, -0.036, 9.5, 1, 1)
    scene = _scene(ego, [(559.2, 20.4, 0)])
    applied, d = g.step(ego, scene, [3.95, -0.3])
    assert 3 in d.refused and not d.entered
    assert 0 not in g.kin.path_lanes(ego.y, ego.heading, ego.speed, applied[1])[0]


def test_a_meta_lane_change_no_longer_responsible_is_abandoned_before_the_body_crosses():
    g = _guard(meta=True)
    ego = EgoState(100.0, 4.2, -0.05, 25.0, 1, 0)  # heading for lane 0, body still in lane 1
    free = _scene(ego, [])
    _, d = g.step(ego, free, [0.0, -0.05])
    assert not d.refused and d.entered == [3]
    g.reset()
    closing = _scene(ego, [(96.0, 38.0, 0)])  # a fast car appears just behind in lane 0
    _, d = g.step(ego, closing, [0.0, -0.05])
    assert d.refused == [3] and d.changed == "lane_change"


def test_policy_level_lane_changes_are_responsible_and_self_safe():
    g = _guard(meta=True)
    ego = EgoState(100.0, 4.0, 0.0, 25.0, 1, 1)
    assert g.policy_lane_change(ego, _scene(ego, []), 0)[0]
    assert not g.policy_lane_change(ego, _scene(ego, [(92.0, 35.0, 0)]), 0)[0]  # fast follower
    assert not g.policy_lane_change(ego, _scene(ego, [(108.0, 0.0, 0)]), 0)[0]  # stopped car just ahead
    assert g.policy_lane_change(ego, _scene(ego, []), -1) == (False, "no such lane")
    busy = EgoState(100.0, 3.0, -0.1, 25.0, 1, 0)
    assert g.policy_lane_change(busy, _scene(busy, []), 2) == (False, "a lane change is already under way")


@pytest.mark.parametrize("seed", range(3))
def test_random_steering_never_enters_an_occupied_lane_or_leaves_the_road(seed):
    """Closed loop on a three-lane road with cars alongside on both sides, random proposals."""
    rng = np.random.default_rng(seed)
    g = _guard()
    kin = g.kin
    ego = EgoState(100.0, 4.0, 0.0, 25.0, 1, 1)
    for _ in range(150):
        cars = [(ego.front + 2.0, ego.speed, 0), (ego.front - 1.0, ego.speed, 2)]
        applied, d = g.step(ego, _scene(ego, cars), [rng.uniform(-6, 6), rng.uniform(-0.78, 0.78)])
        ego = _bicycle(kin, ego, applied[0], applied[1])
        assert kin.lanes_at(ego.y, ego.heading) == {1}
        assert kin.off_road_depth(ego.y, ego.heading) == 0.0
