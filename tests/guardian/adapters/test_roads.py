"""Roads beyond one straight segment (guardian.model.roads, guardian.adapters.highway_env.road.read_road): highway-env's networks read
as a corridor with branches, the geometry checked against highway-env's own lanes, and refusals."""
import math
import warnings

import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np
import pytest
from highway_env.road.lane import CircularLane, SineLane, StraightLane
from highway_env.road.road import RoadNetwork

import envs  # noqa: F401 - registers guardian/Merge-v0
from guardian.errors import ConfigError
from guardian.model.roads import RoadMap, outline
from guardian.model.roads import Road
from guardian.adapters.highway_env.road import read_road, read_road_map

warnings.filterwarnings("ignore", message=".*out of date.*")


def _base(env_id, **config):
    env = gym.make(env_id, config=config)
    env.reset(seed=0)
    return env.unwrapped


@pytest.fixture(scope="module")
def merge():
    return read_road(_base("merge-v0"))


@pytest.fixture(scope="module")
def exit_road():
    return read_road(_base("exit-v0"))


def test_merge_v0_is_a_corridor_with_an_on_ramp_that_ends(merge):
    assert isinstance(merge, RoadMap) and merge.n_lanes == 3 and merge.lane_width == 4.0 and merge.y0 == 0.0
    assert merge.spans[0] == merge.spans[1] == ((-math.inf, math.inf),)   # the main road goes on at both ends
    assert merge.spans[2] == ((230.0, 310.0),)                          # the ramp's parallel part
    assert merge.ends == ((2, 310.0),)                                   # ... ends: a dead end
    kinds = [(b.kind, b.slot, b.s0, b.length) for b in merge.branches]
    assert kinds == [("straight", 2, 0.0, 150.0), ("sine", 2, 150.0, 80.0)]
    assert merge.branches[0].open_before and not merge.branches[1].open_after
    assert merge.slot_of(("j", "k", 0)) == merge.slot_of(("k", "b", 0)) == merge.slot_of(("b", "c", 2)) == 2
    assert merge.numbering.itha(2) == 1 and merge.numbering.itha(0) == 3
    (end,) = merge.end_cars()
    assert (end.front, end.speed, end.length, end.lanes) == (310.0, 0.0, 0.0, frozenset({1}))


def test_merge_generic_v0_fits_the_same_reading():
    road = read_road(_base("merge-generic-v0", lanes_count=3))
    assert road.n_lanes == 4 and road.spans[3] == ((230.0, 310.0),) and road.ends == ((3, 310.0),)


def test_exit_v0_is_a_corridor_with_an_exit_lane_and_its_curve(exit_road):
    assert exit_road.n_lanes == 7 and exit_road.ends == ()
    assert all(exit_road.spans[k] == ((-math.inf, math.inf),) for k in range(6))
    assert exit_road.spans[6] == ((400.0, 500.0),)                       # begins at 400, the curve continues it
    (arc,) = exit_road.branches
    assert (arc.kind, arc.slot, arc.s0, arc.open_after) == ("arc", 6, 500.0, True)
    assert arc.length == pytest.approx(150 * math.pi / 2)


def test_the_straight_highway_stays_a_road():
    road = read_road(_base("highway-v0", lanes_count=3))
    assert road == Road(3, 4.0)


@pytest.mark.parametrize("env_id, why", [
    ("roundabout-v0", "runs against the direction of travel"),
    ("two-way-v0", "runs against the direction of travel"),
    ("racetrack-v0", "runs against the direction of travel"),
    ("lane-keeping-v0", "no lane runs straight along"),
])
def test_roads_it_cannot_reason_about_are_refused_with_the_reason(env_id, why):
    # (not intersection-v0: making it sets IDMVehicle's class attributes for the whole process)
    with pytest.raises(ConfigError, match=f"cannot reason about this env's road: .*{why}"):
        read_road(_base(env_id))


def _net(*lanes):
    net = RoadNetwork()
    for f, t, lane in lanes:
        net.add_lane(f, t, lane)
    return net


def test_hand_built_networks_refused_for_their_reason():
    wide = _net(("a", "b", StraightLane([0, 0], [100, 0])), ("a", "b", StraightLane([0, 4], [100, 4], width=5)))
    with pytest.raises(ConfigError, match="different widths"):
        read_road_map(wide)
    loose = _net(("a", "b", StraightLane([0, 0], [100, 0])), ("x", "y", SineLane([0, 20], [50, 40], 1.0, 0.1, 0.0)))
    with pytest.raises(ConfigError, match="not chained to the straight lanes"):
        read_road_map(loose)
    bypass = _net(("a", "b", StraightLane([0, 0], [100, 0])), ("b", "c", StraightLane([100, 0], [200, 0])),
                  ("c", "d", StraightLane([200, 0], [300, 0])),
                  ("b", "x", StraightLane([100, 0], [150, 10])), ("x", "c", StraightLane([150, 10], [200, 0])))
    with pytest.raises(ConfigError, match="leave the straight lanes and join them again"):
        read_road_map(bypass)


@pytest.mark.parametrize("lane", [
    StraightLane([10, 14.5], [150, 20.0]),
    SineLane([150, 11.25], [230, 11.25], 3.25, 2 * np.pi / 160, np.pi / 2),
    CircularLane([500, 174], 150, 3 * np.pi / 2, 2 * np.pi),
    CircularLane([0, -50], 50, np.pi / 2, 0.0, clockwise=False),
])
def test_strip_geometry_agrees_with_highway_envs_lanes(lane):
    """Local coordinates, headings and positions of our own strips against highway-env's lane objects."""
    from guardian.adapters.highway_env.road import _strip

    strip = _strip(lane, 4.0, 0, 0.0, False, False)
    rng = np.random.default_rng(0)
    for _ in range(50):
        s, r = rng.uniform(-5, lane.length + 5), rng.uniform(-3, 3)
        p = lane.position(s, r)
        ours = strip.local(p[0], p[1])
        theirs = lane.local_coordinates(p)
        assert np.allclose([float(ours[0]), float(ours[1])], theirs, atol=1e-9)
        assert float(strip.heading_at(s)) == pytest.approx(float(lane.heading_at(s)), abs=1e-12)
        assert np.allclose(strip.position(s, r), p, atol=1e-9)


def test_longitudinal_coordinates_follow_the_lanes(merge, exit_road):
    assert merge.longitudinal(("k", "b", 0), 200.0, 10.0) == pytest.approx(200.0)   # along x on the ramp
    assert merge.longitudinal(("a", "b", 1), 123.4, 4.0) == 123.4
    arc = exit_road.branches[0]
    x, y = arc.position(30.0, 0.0)
    assert exit_road.longitudinal(("2", "exit", 0), x, y) == pytest.approx(530.0)
    assert 0.0 < 530.0 - x < 0.25                                        # x lags by 0.2 m after 30 m


def test_depth_says_where_the_road_is(merge):
    on = merge.depth([100.0, 250.0, 250.0, 100.0, 200.0], [0.0, 8.0, 5.9, 14.5, 10.0])
    assert np.all(on == 0.0)                                              # main, ramp parallel, border, approach
    off = merge.depth([100.0, 320.0, 100.0], [9.0, 8.0, -3.0])
    assert off[0] == pytest.approx(3.0)       # between main lane 1 and the ramp's approach (y 12.5-16.5)
    assert off[1] == pytest.approx(2.0)       # past the ramp's dead end: 2 m beside main lane 1
    assert off[2] == pytest.approx(1.0)


def test_body_slots_count_a_slot_only_where_it_is(exit_road, merge):
    # a car hugging the right edge of slot 5 before the exit lane begins does not overlap slot 6 ...
    assert exit_road.body_slots(350.0, 21.2, 0.0, 5.0, 2.0, 0.05) == {5}
    # ... but does where it is present
    assert exit_road.body_slots(450.0, 21.2, 0.0, 5.0, 2.0, 0.05) == {5, 6}
    # a car on the exit's curve is in slot 6, a car on the ramp's approach in slot 2
    x, y = exit_road.branches[0].position(60.0, 0.0)
    assert exit_road.body_slots(x, y, exit_road.branches[0].heading_at(60.0), 5.0, 2.0) == {6}
    assert merge.body_slots(100.0, 14.5, 0.0, 5.0, 2.0) == {2}
    # a yawed body reaches into the next slot
    assert merge.body_slots(100.0, 4.0, 0.0, 5.0, 2.0) == {1}
    assert merge.body_slots(100.0, 3.0, -0.6, 5.0, 2.0) == {0, 1}
    assert merge.body_slots(100.0, 4.9, -0.6, 5.0, 2.0) == {1}     # reaches y = 7.1, where no slot 2 is yet
    assert merge.body_slots(250.0, 4.9, -0.6, 5.0, 2.0) == {1, 2}


def test_outline_is_the_corners_and_side_midpoints():
    xs, ys = outline([0.0], [0.0], [0.0], 4.0, 2.0)
    assert sorted(zip(xs[0].round(9), ys[0].round(9))) == sorted(
        [(2, 1), (2, -1), (-2, 1), (-2, -1), (2, 0), (-2, 0), (0, 1), (0, -1)])


@pytest.mark.parametrize("env_id", ["merge-v0", "exit-v0"])
def test_one_body_is_read_as_the_array_path_reads_it(env_id):
    """``body_slots`` answers one body in float arithmetic (and from a memo); it must give the array path's
    slots, corners and sweeps included."""
    env = gym.make(env_id)
    env.reset(seed=0)
    road = read_road(env.unwrapped)
    rng = np.random.default_rng(3)
    for _ in range(2000):
        x, y, h = float(rng.uniform(-50, 600)), float(rng.uniform(-5, 30)), float(rng.normal(0, 0.5))
        margin, dx, dy = float(rng.choice([0.0, 0.3])), float(rng.uniform(-1, 3)), float(rng.uniform(-1, 1))
        one = road.body_slots(x, y, h, 5.0, 2.0, margin, dx, dy)
        assert one == road.body_slots(np.array([x]), np.array([y]), np.array([h]), 5.0, 2.0, margin, dx, dy)
        assert one == road.body_slots(x, y, h, 5.0, 2.0, margin, dx, dy)  # the memo's answer


def test_a_straight_strip_answers_floats_as_it_answers_arrays():
    """Scalars take a float path in ``Strip.local`` and ``heading_at`` (the same arithmetic): bit for bit."""
    from guardian.model.roads import Strip

    strip = Strip("straight", (-300.0, 14.0), (0.0, 8.0), 3.2, math.dist((-300.0, 14.0), (0.0, 8.0)), 3, -300.0,
                  open_before=True)
    rng = np.random.default_rng(1)
    for x, y in rng.uniform([-400, -5], [100, 30], (500, 2)):
        fast = strip.local(float(x), float(y))
        slow = strip.local(np.float64(x), np.float64(y))
        assert all(type(v) is float for v in fast) and fast == tuple(float(v) for v in slow)
        assert strip.heading_at(float(x)) == float(strip.heading_at(np.float64(x)))


def test_a_branch_is_skipped_only_for_bodies_clear_of_it():
    """A body whose centre lies beyond any reach across a branch skips that branch's turning: the turned,
    widened and swept body would not have reached the branch's strip either, and its slots are what they were."""
    from guardian.model.body import half_extents
    from guardian.model.roads import Strip, road_as_dict, road_from_dict

    ramp = Strip("straight", (-300.0, 14.0), (0.0, 8.0), 3.2, math.dist((-300.0, 14.0), (0.0, 8.0)), 2, -300.0,
                 open_before=True)
    road = road_from_dict({**road_as_dict(RoadMap(3.2, 3, 0.0, (((-np.inf, np.inf),),) * 2 + (((0.0, 500.0),),),
                                                  (), (), ())), "branches": [road_as_dict(RoadMap(3.2, 3, 0.0, (), (ramp,), (), ()))["branches"][0]]})
    strip, rng, skipped = road.branches[0], np.random.default_rng(2), 0
    for _ in range(3000):
        x, y, h = float(rng.uniform(-320, 20)), float(rng.uniform(0, 20)), float(rng.normal(0, 0.4))
        margin, dx, dy = float(rng.choice([0.0, 0.3])), float(rng.uniform(0, 3)), float(rng.uniform(-1, 1))
        sweep = float(np.hypot(dx, dy))
        _, r = strip.local(x, y)
        if abs(r) <= 3.2 / 2 + 5.0 / 2 + 2.0 / 2 + margin + sweep + 1e-6:
            continue
        skipped += 1
        rr = half_extents(5.0, 2.0, h - strip.heading_at(float(strip.local(x, y)[0])))[1] + margin + sweep
        assert not (r - rr < 3.2 / 2 and r + rr > -3.2 / 2)
        corridor = RoadMap(3.2, 3, 0.0, road.spans, (), (), ())
        assert road.body_slots(x, y, h, 5.0, 2.0, margin, dx, dy) == corridor.body_slots(x, y, h, 5.0, 2.0, margin,
                                                                                          dx, dy)
    assert skipped > 500


def test_a_reading_is_turned_into_a_car_once_and_a_new_reading_anew():
    """``scene_of`` remembers each sensed car's ``Car`` on the road (every guarded car's scene reads the same
    bodies in a step): the same reading gives the same car, any change to it (a speed, a lateral position that
    reaches another lane, an announcement) gives the car of the new reading."""
    from dataclasses import replace

    from guardian.model.reversing import ReversingCover
    from guardian.model.scene import Car
    from guardian.model.sensing import Sensed, car_of, scene_of

    for road in (Road(3, 4.0), RoadMap(4.0, 3, 0.0, (((-np.inf, np.inf),),) * 3, (), (), ())):
        ego = Car(0.0, 20.0, frozenset({2}), 5.0, "ego")
        s = Sensed("car", 20.0, 4.0, 0.0, 25.0, 5.0, 2.0, 22.5, 1)
        first = scene_of(road, ego, [s], ReversingCover(0.0), 0.3).others[0]
        assert scene_of(road, ego, [s], ReversingCover(0.0), 0.3).others[0] is first == car_of(road, s, 0.3)
        for changed in (replace(s, speed=5.0), replace(s, y=6.2), replace(s, announced=frozenset({3}))):
            car = scene_of(road, ego, [changed], ReversingCover(0.0), 0.3).others[0]
            assert car == car_of(road, changed, 0.3) != first


@pytest.mark.parametrize("env_id", ["merge-v0", "exit-v0"])
def test_a_road_in_use_is_written_as_its_fields_and_read_back(env_id):
    """A road remembers answers (bodies, readings, a strip's chord) beside its fields; what the service is sent is
    the fields alone, and reads back as the same road (the service refused a road whose strips carried their chord)."""
    import dataclasses
    import json

    from guardian.model.roads import road_as_dict, road_from_dict

    env = gym.make(env_id)
    env.reset(seed=0)
    road = read_road(env.unwrapped)
    for strip in road.branches:
        strip.local(1.0, 2.0), strip.local(np.array([1.0]), np.array([2.0]))
    road.body_slots(100.0, 4.0, 0.1, 5.0, 2.0, 0.3)
    spec = json.loads(json.dumps(road_as_dict(road)))
    assert all(set(b) == set(road_as_dict(road_from_dict(spec))["branches"][0]) for b in spec["branches"])
    assert not any(k.startswith("_") for b in spec["branches"] for k in b)
    assert road_from_dict(spec) == dataclasses.replace(road, lane_table=())   # highway-env's lane ids stay home
