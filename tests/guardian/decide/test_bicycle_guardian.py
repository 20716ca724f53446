"""highway-env's bicycle ego on hand-built scenes, without a simulator (guardian.decide.bicycle)."""
import math
from dataclasses import replace

import numpy as np
import pytest

from guardian.decide.bicycle import BicycleGuardian
from guardian.model.scene import EgoState
from guardian.config import GuardianConfig
from guardian.decide.kinematics import BicycleEgo
from guardian.model.scene import Car, Scene

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


def test_a_reversing_ego_gets_an_acceleration_inside_its_bounds():
    """An ego rolling backwards (outside the model, e.g. pushed by a crash): the fail-safe stops it no harder
    than the bound (it gave +15 m/s^2 for -1 m/s at dt 1/15)."""
    g = BicycleGuardian(BicycleEgo(1 / 15, 6.0, 5.0, 2.0, W, N, math.pi / 4), GuardianConfig(), False)
    for speed in (-1.0, -0.1, -30.0):
        ego = EgoState(100.0, 4.0, 0.0, speed, 1, 1)
        applied, d = g.step(ego, _scene(ego, [(101.0, 0.0, 1)]), [0.0, 0.0])
        assert -6.0 <= applied[0] <= 6.0


def test_a_steering_beyond_the_bound_is_clipped_to_it_and_said():
    """A client of the service may ask any steering: the applied one stays within ±max_steering."""
    g = _guard()
    ego = EgoState(100.0, 4.0, 0.0, 20.0, 1, 1)
    for asked in (1.0, -1.4, 3.0):
        applied, d = g.step(ego, _scene(ego, []), [0.0, asked])
        assert abs(applied[1]) <= g.kin.max_steering and d.proposed[1] == asked
        assert d.changed != "none" and d.clipped_to_model == (abs(applied[1]) == g.kin.max_steering)


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


def test_a_slow_meta_lane_change_keeps_the_body_out_of_the_lane_beyond_its_target():
    """Merging off a ramp at 1 m/s, highway-env's controller turns the car steeply and keeps turning: the
    rotated body's corner would cross the far line of the target lane (found at scale: N = 4 guarded cars on
    guardian/Merge-v0). The guardian straightens in time: the path stays in the lanes the change holds."""
    g = _guard(dt=1 / 15, meta=True)
    kin = g.kin
    ego = EgoState(300.0, 5.4, -0.5, 1.0, 1, 1)  # centre in lane 1, tail still over lane 2
    refused = 0
    for _ in range(45):
        applied, d = g.step(ego, _scene(ego, []), [0.0, -0.6])  # the controller keeps turning left
        refused += applied[1] != -0.6
        assert 3 not in d.lanes
        ego = _bicycle(kin, ego, applied[0], applied[1])
        assert 0 not in kin.lanes_at(ego.y, ego.heading)
    assert refused  # left alone, the body would have crossed into lane 0


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


def _stops_behind_a_standing_wreck(g: BicycleGuardian, gap: float, v: float, v_lead: float, a: float) -> bool:
    """After ``a`` for one step and the hardest braking after it, does the ego stay ``h_min`` behind a car
    that stands still from its next position on, pushed back by ``wreck_margin``?"""
    dt, c = g.kin.dt, g.config
    wreck = gap + dt * v_lead - c.wreck_margin
    ego, speed = dt * v, v + dt * a
    while speed > 0:
        ego += dt * speed
        speed = max(speed - dt * c.traffic_accel, 0.0)
    return wreck - ego >= c.h_min - 1e-6


def _platoon(ego: EgoState, gap: float, v_lead: float, gap2: float, v_lead2: float, crashed=False) -> Scene:
    lead_front = ego.front + gap + 5.0
    others = (Car(lead_front, v_lead, frozenset({N - 1}), 5.0, "car 1"),
              Car(lead_front + gap2 + 5.0, v_lead2, frozenset({N - 1}), 5.0, "car 2", crashed=crashed))
    return Scene(Car(ego.front, ego.speed, frozenset(), 5.0, "ego"), others, N)


@pytest.mark.parametrize("seed", range(3))
def test_behind_a_car_at_risk_of_a_crash_the_ego_can_stop_if_it_stops_at_once(seed):
    """Falsifier: platoons where the car ahead tailgates another (or follows a wreck). Every applied input
    lets the ego stop behind that car standing still from its next position on; and the rule matters:
    the same input is not always safe with the car ahead's leader removed from the scene."""
    rng = np.random.default_rng(seed)
    g = _guard(dt=1 / 15)
    checked = stricter = 0
    for _ in range(400):
        v, v_lead = rng.uniform(5, 30), rng.uniform(5, 30)
        ego = EgoState(100.0, 4.0, 0.0, v, 1, 1)
        gap, gap2 = rng.uniform(2, 80), rng.uniform(0, 1.9)  # closer than h_min: outside its set
        scene = _platoon(ego, gap, v_lead, gap2, v_lead - rng.uniform(0, 5), crashed=rng.random() < 0.3)
        assert g.traffic.at_risk(scene, scene.others[0])
        applied, d = g.step(ego, scene, [6.0, 0.0])
        if d.level == "failsafe":
            continue
        checked += 1
        assert _stops_behind_a_standing_wreck(g, gap, v, v_lead, applied[0]), (v, v_lead, gap, applied)
        alone = Scene(scene.ego, scene.others[:1], N)
        assert not g.traffic.at_risk(alone, alone.others[0]) or v_lead > g.config.v_max
        free, _ = g.step(ego, alone, [6.0, 0.0])
        stricter += free[0] > applied[0] + 1e-9 and not _stops_behind_a_standing_wreck(g, gap, v, v_lead, free[0])
    assert checked > 100 and stricter >= 3


def test_who_is_at_risk():
    """Crashed cars, cars outside their car-following set, and cars that cannot stop behind a car at risk
    are at risk; a car following safely a car that is not, a standing obstacle and a lane's end are not."""
    g = _guard(dt=1 / 15)
    ego = EgoState(100.0, 4.0, 0.0, 20.0, 1, 1)
    lane = frozenset({N - 1})
    far = Scene(Car(105.0, 20.0, frozenset(), 5.0, "ego"),
                (Car(160.0, 20.0, lane, 5.0, "a"), Car(260.0, 20.0, lane, 5.0, "b")), N)
    assert not g.traffic.at_risk(far, far.others[0])
    assert g.traffic.at_risk(_platoon(ego, 30.0, 20.0, 80.0, 20.0, crashed=True), _platoon(ego, 30.0, 20.0, 80.0, 20.0,
                                                                                         crashed=True).others[1])
    tail = _platoon(ego, 30.0, 25.0, 1.0, 20.0)
    assert "outside its car-following set" in g.traffic.at_risk(tail, tail.others[0])
    # a chain: c follows a at a distance safe under the model, but a tailgates b: c cannot stop behind a
    chain = Scene(far.ego, (Car(150.0, 25.0, lane, 5.0, "c"), Car(170.0, 25.0, lane, 5.0, "a"),
                            Car(176.0, 25.0, lane, 5.0, "b")), N)
    assert g.traffic.S_others.contains([[25.0, 15.0, 25.0]])[0]   # c is inside its set behind a
    assert "cannot stop behind a" in g.traffic.at_risk(chain, chain.others[0])
    fixed = Scene(far.ego, (Car(150.0, 0.0, lane, 2.0, "obstacle", fixed=True), Car(150.5, 0.0, lane, 0.0, "end",
                                                                                    fixed=True)), N)
    assert not g.traffic.at_risk(fixed, fixed.others[0])


@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf")])
def test_a_wreck_margin_that_is_not_a_finite_distance_is_refused(bad):
    from guardian.errors import ConfigError

    with pytest.raises(ConfigError, match="wreck_margin"):
        GuardianConfig(wreck_margin=bad)


def test_a_body_over_the_line_beside_the_ego_is_never_closed_in_on_sideways():
    """A car in lane 0 keeps its body 0.6 m over the line into the ego's lane 1, alongside the ego. Steering
    towards it stays inside lane 1 (no lane entry), so the lanes alone would allow it; stepped in closed loop
    with the agent steering hard towards it, the ego's body never reaches into the car's, and the guardian
    says why it refused. Steering away is let through."""
    g = _guard(dt=1 / 15)
    kin = g.kin
    ego = EgoState(100.0, 4.9, 0.0, 5.0, 1, 1)
    hugging = Car(99.5, 5.0, frozenset({N - 0, N - 1}), 5.0, "car 7", across=(0.6, 2.6))  # alongside, 0.5 m back
    scene = Scene(Car(ego.front, ego.speed, frozenset(), 5.0, "ego"), (hugging,), N)
    state, said = ego, False
    for _ in range(60):
        applied, d = g.step(state, scene, [0.0, -0.35])   # hard towards lane 0
        said |= any("close in sideways on car 7" in r for r in d.reasons)
        state = _bicycle(kin, state, applied[0], applied[1])
        hugging = replace(hugging, front=hugging.front + kin.dt * hugging.speed)   # it keeps alongside
        scene = Scene(Car(state.front, state.speed, frozenset(), 5.0, "ego"), (hugging,), N)
        assert state.y - kin.half_extent(state.heading) > 2.6   # never into the car's body
    assert said
    g.reset()
    away, d = g.step(ego, scene, [0.0, 0.1])
    assert away[1] == pytest.approx(0.1) and d.changed == "none"
