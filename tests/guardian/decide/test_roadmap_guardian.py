"""The bicycle guardian on roads beyond one straight segment, on hand-built scenes without a simulator
(guardian.decide.bicycle with guardian.decide.kinematics.RoadMapEgo on the RoadMaps of merge-v0 and exit-v0)."""
import math
import warnings

import gymnasium as gym
import highway_env  # noqa: F401
import pytest

from guardian.decide.bicycle import BicycleGuardian
from guardian.model.scene import EgoState
from guardian.config import GuardianConfig
from guardian.decide.kinematics import RoadMapEgo
from guardian.model.scene import Car, Scene
from guardian.adapters.highway_env.road import read_road

warnings.filterwarnings("ignore", message=".*out of date.*")
DT = 1 / 15


def _road(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    return read_road(env.unwrapped)


@pytest.fixture(scope="module")
def merge():
    return _road("merge-v0")


@pytest.fixture(scope="module")
def exit_road():
    return _road("exit-v0")


def _guard(road, meta=False):
    kin = RoadMapEgo(DT, 6.0, 5.0, 2.0, road, math.pi / 4)
    return BicycleGuardian(kin, GuardianConfig(), meta)


def _state(road, x, y, heading, speed, target=None):
    """An EgoState at world ``(x, y)`` as guardian.adapters.highway_env.scene reads one (lane = slot, front along the lane)."""
    strip = road.on_branch(x, y)
    if strip is None:
        lane, front = int(round((y - road.y0) / road.lane_width)), x + 2.5
    else:
        s, _ = strip.local(x, y)
        lane, front = strip.slot, strip.s0 + float(s) + 2.5
    return EgoState(front, y, heading, speed, lane, lane if target is None else target, x)


def _scene(road, ego: EgoState, cars=()):
    """Traffic as ``(front, speed, slot)``, the road's dead ends as standing cars."""
    others = tuple(Car(f, v, frozenset({road.numbering.itha(k)}), 5.0, f"car {i}") for i, (f, v, k) in enumerate(cars))
    return Scene(Car(ego.front, ego.speed, frozenset(), 5.0, "ego"), others + road.end_cars(), road.n_lanes)


def _step(road, ego: EgoState, a: float, steer: float) -> EgoState:
    """One ``Vehicle.step`` of highway-env (the same arithmetic)."""
    beta = math.atan(0.5 * math.tan(steer))
    x = ego.x + DT * ego.speed * math.cos(ego.heading + beta)
    y = ego.y + DT * ego.speed * math.sin(ego.heading + beta)
    heading = ego.heading + DT * ego.speed * math.sin(beta) / 2.5
    return _state(road, x, y, heading, max(ego.speed + DT * a, 0.0), ego.target_lane)


def test_a_car_on_a_lane_that_ends_stops_before_its_end(merge):
    """The ramp's parallel part ends at x = 310 (a dead end): full throttle towards it is held back so the
    car stops at least h_min before the end, never passing it."""
    g = _guard(merge)
    ego = _state(merge, 250.0, 8.0, 0.0, 20.0)
    for _ in range(200):
        applied, d = g.step(ego, _scene(merge, ego), [6.0, 0.0])
        ego = _step(merge, ego, *applied)
        assert ego.front <= 310.0 - GuardianConfig().h_min + 1e-6
    assert ego.speed == pytest.approx(0.0, abs=1e-6) and ego.front > 300.0
    assert any("the end of lane 1" in r for r in d.reasons) or d.level == "failsafe"


def test_merging_from_the_ramp_is_a_lane_entry_judged_by_7_5(merge):
    g = _guard(merge, meta=True)
    ego = _state(merge, 240.0, 8.0, 0.0, 20.0)
    ok, why = g.policy_lane_change(ego, _scene(merge, ego), 1)
    assert ok, why
    late = _state(merge, 265.0, 8.0, 0.0, 25.0)  # 42 m before the end at 25 m/s: it could not stop in its lane
    ok, why = g.policy_lane_change(late, _scene(merge, late), 1)
    assert not ok
    alongside = _scene(merge, ego, [(ego.front + 1.0, 25.0, 1)])
    ok, why = g.policy_lane_change(ego, alongside, 1)
    assert not ok and "ahead in lane 2" in why
    closing = _scene(merge, ego, [(ego.front - 12.0, 33.0, 1)])
    ok, why = g.policy_lane_change(ego, closing, 1)
    assert not ok and "behind in lane 2" in why


def test_no_lane_change_from_the_ramps_approach(merge):
    g = _guard(merge, meta=True)
    ego = _state(merge, 100.0, 14.5, 0.0, 25.0)
    assert ego.lane == 2
    ok, why = g.policy_lane_change(ego, _scene(merge, ego), 1)
    assert not ok and "no lane there" in why


def test_steering_into_an_exit_lane_before_it_begins_is_refused(exit_road):
    """Slot 6 begins at x = 400: a hard right turn from slot 5 at x = 330 would leave the road; the applied
    steering keeps every step on the road, while at x = 430 the same turn enters slot 6 (checked, free)."""
    g = _guard(exit_road)
    kin = g.kin
    ego = _state(exit_road, 330.0, 20.5, 0.0, 25.0)
    for _ in range(40):
        applied, d = g.step(ego, _scene(exit_road, ego), [0.0, 0.3])
        ego = _step(exit_road, ego, *applied)
        assert kin.depth_of(ego) == 0.0
    assert ego.x < 400.0 and 6 not in kin.body_lanes(ego)
    g = _guard(exit_road)
    ego = _state(exit_road, 430.0, 20.5, 0.0, 25.0)
    entered = set()
    for _ in range(20):
        applied, d = g.step(ego, _scene(exit_road, ego), [0.0, 0.3])
        entered |= set(d.entered)
        ego = _step(exit_road, ego, *applied)
    assert 1 in entered and 6 in kin.body_lanes(ego)                     # ITHA lane 1 = slot 6


def test_a_continuous_agent_on_the_exits_curve_is_kept_on_it(exit_road):
    """On the curve (radius 150 m) an agent steering straight ahead would leave the road within a few
    seconds; the guardian keeps the body on the curve's strip."""
    g = _guard(exit_road)
    arc = exit_road.branches[0]
    x, y = arc.position(20.0, 0.0)
    ego = _state(exit_road, x, y, float(arc.heading_at(20.0)), 20.0)
    for _ in range(120):
        applied, d = g.step(ego, _scene(exit_road, ego), [0.0, 0.0])
        ego = _step(exit_road, ego, *applied)
        assert g.kin.depth_of(ego) == 0.0
    s, r = arc.local(ego.x, ego.y)
    assert float(s) > 100.0 and abs(float(r)) < 1.0


def test_self_safety_along_the_exits_curve(exit_road):
    """A standing car 43 m further along the curve: full throttle is held back (fronts along the lane)."""
    g = _guard(exit_road, meta=True)
    arc = exit_road.branches[0]
    x, y = arc.position(20.0, 0.0)
    ego = _state(exit_road, x, y, float(arc.heading_at(20.0)), 20.0)
    applied, d = g.step(ego, _scene(exit_road, ego, [(ego.front + 43.0, 0.0, 6)]), [6.0, 0.0])
    assert applied[0] < 6.0 and any("car 0 ahead in lane 1" in r for r in d.reasons)
    free, _ = g.step(ego, _scene(exit_road, ego, [(ego.front + 200.0, 0.0, 6)]), [6.0, 0.0])
    assert free[0] == 6.0



def _ride(road, x, y, cars, steps, steer=math.pi / 4):
    """A continuous agent at ``(x, y)`` asking for the same steering (full right by default) every step,
    beside traffic ``(front, speed, slot)`` driving at constant speed."""
    g = _guard(road)
    ego = _state(road, x, y, 0.0, 17.85)
    run = []
    for k in range(steps):
        moved = [(f + k * DT * v, v, slot) for f, v, slot in cars]
        applied, d = g.step(ego, _scene(road, ego, moved), [0.0, steer])
        ego = _step(road, ego, *applied)
        run.append((d, ego))
    return run


def _in_ramp_lane(road, ego) -> bool:
    return 2 in road.body_slots(ego.x, ego.y, ego.heading, 5.0, 2.0)


def test_the_body_is_kept_inside_the_roads_edge_by_the_margin(merge):
    """Full right steering along the main road before the ramp joins: the body may come to the road's
    edge but no nearer than ``LATERAL_MARGIN`` (riding the edge itself, the ramp's lane would begin
    under the body when its parallel part starts)."""
    run = _ride(merge, 150.0, 4.0, [], 80)
    edge = max(ego.y + 1.0 for _, ego in run if ego.x < 220.0)
    assert 6.0 - RoadMapEgo.LATERAL_MARGIN - 0.01 < edge <= 6.0 - RoadMapEgo.LATERAL_MARGIN + 1e-6


def test_a_lane_the_road_brings_to_the_body_is_judged_before_it_is_entered(merge):
    """A body within the margin of the line between slots 1 and 2 (as a start may place it) touches the
    ramp's lane when its parallel part begins (x = 230) without steering. The touch is judged as an
    entry (7.5) and the body enters the lane only after an entry judged responsible (without the
    judgment the touched lane was taken as held and full right steering went into it unjudged)."""
    run = _ride(merge, 222.0, 4.98, [], 60)
    assert any("the road brings lane 1 to the body" in r for d, _ in run for r in d.reasons)
    first = next(k for k, (_, ego) in enumerate(run) if _in_ramp_lane(merge, ego))
    assert any(e.lane == 1 and e.responsible for d, _ in run[:first + 1] for e in d.entries)
    assert run[-1][1].y > 7.0  # it merged, through the judged entry


def test_a_touched_lane_whose_entry_is_not_responsible_is_not_entered(merge):
    """The same ride with a faster car on the ramp just behind: entering its lane is not responsible;
    the body touches the lane (it is in it for the cars there: ``touched``) but does not enter it."""
    run = _ride(merge, 222.0, 4.98, [(222.0 + 2.5 - 8.0, 24.0, 2)], 40)
    assert any(1 in d.touched for d, _ in run)
    assert not any(_in_ramp_lane(merge, ego) for _, ego in run)
