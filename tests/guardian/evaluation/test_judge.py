"""The independent fault judge on hand-built collisions (guardian.evaluation.judge): each rule, and its ties."""
from types import SimpleNamespace

import numpy as np
import pytest

from guardian.evaluation.judge import ENTRY_WINDOW, FaultJudge, body_lanes

LANE = 4.0  # [m]; lane 0 centred on y = 0


class Car:
    LENGTH, WIDTH = 5.0, 2.0

    def __init__(self, x, y, speed=20.0, heading=0.0):
        self.position = np.array([x, y], dtype=float)
        self.speed, self.heading, self.crashed = speed, heading, False


def _scene(ego, *others):
    return SimpleNamespace(vehicle=ego, road=SimpleNamespace(vehicles=[ego, *others]))


def _judge(base, dt=0.1):
    j = FaultJudge(LANE, 3, dt)
    j.start(base)
    return j


def _crash(j, base, *cars):
    for c in cars:
        c.crashed = True
    return j.observe(base)


def test_rear_end_is_the_followers_fault():
    ego, ahead = Car(0.0, 0.0), Car(6.0, 0.0)
    base = _scene(ego, ahead)
    j = _judge(base)
    ego.position[0] = 1.5
    crash = _crash(j, base, ego, ahead)
    assert (crash.fault, crash.rule) == ("ego", "rear_end")

    ego, behind = Car(0.0, 0.0), Car(-6.0, 0.0)
    base = _scene(ego, behind)
    j = _judge(base)
    behind.position[0] = -4.5
    crash = _crash(j, base, ego, behind)
    assert (crash.fault, crash.rule) == ("other", "rear_end")


def test_a_car_ahead_reversing_into_the_ego_is_at_fault():
    ego, ahead = Car(0.0, 0.0, speed=0.0), Car(6.0, 0.0, speed=-3.0)
    base = _scene(ego, ahead)
    j = _judge(base)
    ahead.position[0] = 4.8
    assert _crash(j, base, ego, ahead).fault == "other"


@pytest.mark.parametrize("seconds_ago, fault", [(1.0, "ego"), (ENTRY_WINDOW + 1.0, "other")])
def test_contact_soon_after_the_ego_entered_the_lane_is_the_egos(seconds_ago, fault):
    """The ego moves from lane 1 into lane 0 in front of a follower; the follower hits it from behind."""
    dt = 0.1
    ego, follower = Car(0.0, LANE), Car(-20.0, 0.0)
    base = _scene(ego, follower)
    j = _judge(base, dt)
    ego.position[1] = 0.0  # entered lane 0
    j.observe(base)
    for _ in range(int(round(seconds_ago / dt)) - 1):
        j.observe(base)
    follower.position[0] = -4.6
    crash = _crash(j, base, ego, follower)
    assert crash.fault == fault
    assert crash.rule == ("entry" if fault == "ego" else "rear_end")


def test_a_car_cutting_in_is_at_fault_and_both_entering_counts_against_the_ego():
    ego, cutter = Car(0.0, 0.0), Car(5.5, LANE)
    base = _scene(ego, cutter)
    j = _judge(base)
    cutter.position[1] = 1.0  # its body now overlaps lane 0
    j.observe(base)
    crash = _crash(j, base, ego, cutter)
    assert (crash.fault, crash.rule) == ("other", "entry")

    ego, other = Car(0.0, 0.0), Car(0.0, 2 * LANE)
    base = _scene(ego, other)
    j = _judge(base)
    ego.position[1], other.position[1] = 2.5, 5.5  # both now overlap lane 1
    crash = _crash(j, base, ego, other)
    assert (crash.fault, crash.rule) == ("ego", "entry")


@pytest.mark.parametrize("ego_dy, other_dy, fault", [(1.0, 0.0, "ego"), (0.0, -1.0, "other"), (0.5, -0.5, "ego")])
def test_side_contact_is_the_fault_of_whoever_moved_sideways(ego_dy, other_dy, fault):
    ego, other = Car(0.0, 1.4), Car(1.0, 4.4)  # both already overlap lane 1 (no new entry)
    base = _scene(ego, other)
    j = _judge(base)
    ego.position[1] += ego_dy
    other.position[1] += other_dy
    crash = _crash(j, base, ego, other)
    assert (crash.fault, crash.rule) == (fault, "side")


def test_a_crash_with_nothing_else_crashed_is_the_egos():
    ego = Car(0.0, 0.0)
    base = _scene(ego, Car(50.0, 0.0))
    j = _judge(base)
    assert _crash(j, base, ego).rule == "alone" and j.observe(base) is None  # counted once


def test_body_lanes_follow_the_heading():
    car = Car(0.0, 1.5)
    assert body_lanes(car, LANE, 3) == {0, 1}  # reaches 2.5 > 2 (the border)
    car.position[1] = 0.5
    assert body_lanes(car, LANE, 3) == {0}
    car.heading = 0.5  # a yawed body reaches further sideways
    assert body_lanes(car, LANE, 3) == {0, 1}


# ---- roads beyond one straight segment: highway-env's own lanes, grouped into lines ------------------------
from highway_env.road.lane import CircularLane, SineLane, StraightLane  # noqa: E402
from highway_env.road.road import RoadNetwork  # noqa: E402

from guardian.evaluation.judge import Lines  # noqa: E402


def _merge_network():
    """merge-v0's shape: one main lane (y = 4) in three segments and an on-ramp whose parallel part (y = 8,
    x 230..310) continues a sine taper."""
    net = RoadNetwork()
    net.add_lane("a", "b", StraightLane([0, 4], [230, 4]))
    net.add_lane("b", "c", StraightLane([230, 4], [310, 4]))
    net.add_lane("c", "d", StraightLane([310, 4], [460, 4]))
    net.add_lane("j", "k", StraightLane([0, 14.5], [150, 14.5]))
    net.add_lane("k", "b", SineLane([150, 11.25], [230, 11.25], 3.25, 2 * np.pi / 160, np.pi / 2))
    net.add_lane("b", "c", StraightLane([230, 8], [310, 8]))
    return net


class LaneCar(Car):
    def __init__(self, x, y, speed=20.0, heading=0.0, lane_index=("a", "b", 0)):
        super().__init__(x, y, speed, heading)
        self.lane_index = lane_index


def _network_judge(base, net, dt=0.1, guarded=None):
    j = FaultJudge(4.0, 0, dt, Lines(net))
    j.start(base, guarded)
    return j


def test_lines_join_lanes_that_continue_each_other():
    lines = Lines(_merge_network())
    main = {lines.line[("a", "b", 0)], lines.line[("b", "c", 0)], lines.line[("c", "d", 0)]}
    ramp = {lines.line[("j", "k", 0)], lines.line[("k", "b", 0)], lines.line[("b", "c", 1)]}
    assert len(main) == 1 and len(ramp) == 1 and main != ramp


def test_driving_on_across_segments_is_no_lane_entry():
    """The ego drives from segment a-b into b-c along the main lane and runs into a car ahead: a rear-end,
    its fault, not an entry by either."""
    net = _merge_network()
    ego, ahead = LaneCar(226.0, 4.0, lane_index=("a", "b", 0)), LaneCar(232.0, 4.0, lane_index=("b", "c", 0))
    base = _scene(ego, ahead)
    j = _network_judge(base, net)
    ego.position[0], ego.lane_index = 227.5, ("b", "c", 0)
    crash = _crash(j, base, ego, ahead)
    assert (crash.fault, crash.rule) == ("ego", "rear_end") and not j.ego_entries


def test_a_car_merging_from_the_ramp_is_the_entrant():
    net = _merge_network()
    ego, merger = LaneCar(250.0, 4.0, lane_index=("b", "c", 0)), LaneCar(256.0, 8.0, lane_index=("b", "c", 1))
    base = _scene(ego, merger)
    j = _network_judge(base, net)
    merger.position[1] = 6.5  # its body now overlaps the main lane's strip
    j.observe(base)
    ego.position[0] = 251.5
    crash = _crash(j, base, ego, merger)
    assert (crash.fault, crash.rule) == ("other", "entry")
    # the same contact judged with the merging car in the ego's place: its fault
    ego, merger = LaneCar(250.0, 4.0, lane_index=("b", "c", 0)), LaneCar(256.0, 8.0, lane_index=("b", "c", 1))
    base = _scene(merger, ego)
    j = _network_judge(base, net)
    merger.position[1] = 6.5
    j.observe(base)
    crash = _crash(j, base, ego, merger)
    assert (crash.fault, crash.rule) == ("ego", "entry")


def test_rear_end_along_a_curve_follows_the_lane():
    """On an exit's curve where the lane heads 60 degrees off x: the car further along the lane is ahead."""
    arc = CircularLane([500, 174], 150, 3 * np.pi / 2, 2 * np.pi)
    net = RoadNetwork()
    net.add_lane("2", "exit", arc)
    s_behind, s_ahead = 150 * np.pi / 3 - 6.0, 150 * np.pi / 3
    (xb, yb), (xa, ya) = arc.position(s_behind, 0), arc.position(s_ahead, 0)
    follower = LaneCar(xb, yb, heading=float(arc.heading_at(s_behind)), lane_index=("2", "exit", 0))
    leader = LaneCar(xa, ya, heading=float(arc.heading_at(s_ahead)), lane_index=("2", "exit", 0))
    for ego, other, fault in ((follower, leader, "ego"), (leader, follower, "other")):
        base = _scene(ego, other)
        j = _network_judge(base, net)
        crash = _crash(j, base, ego, other)
        assert (crash.fault, crash.rule) == (fault, "rear_end")
        ego.crashed = other.crashed = False


def test_a_crash_between_two_guarded_cars_is_judged_once():
    net = _merge_network()
    a, b, idm = (LaneCar(100.0, 4.0, lane_index=("a", "b", 0)), LaneCar(106.0, 4.0, lane_index=("a", "b", 0)),
                 LaneCar(300.0, 4.0, lane_index=("b", "c", 0)))
    base = _scene(a, b, idm)
    j = _network_judge(base, net, guarded=[a, b])
    a.position[0] = 101.5
    a.crashed = b.crashed = True
    (crash,) = j.observe_all(base)
    assert (crash.car, crash.partner_car, crash.fault, crash.rule) == (0, 1, "ego", "rear_end")
    assert crash.guarded_at_fault
    assert j.observe_all(base) == []


def test_the_straight_road_keeps_its_judge():
    import gymnasium as gym
    import highway_env  # noqa: F401

    env = gym.make("highway-v0", config={"lanes_count": 3})
    env.reset(seed=0)
    j = FaultJudge.for_env(env.unwrapped, 1.0)
    assert j.lines is None and (j.lane_width, j.n_lanes) == (4.0, 3)
    env = gym.make("merge-v0")
    env.reset(seed=0)
    assert FaultJudge.for_env(env.unwrapped, 1.0).lines is not None


def test_sideways_on_a_curve_is_measured_against_the_lane():
    """Two lanes curving 60 degrees off x, both bodies already over the border (no new entry): the ego only
    follows its lane (its world y changes by 1.7 m), the other cuts 1 m towards it across its lane: the
    other moved sideways. (World y alone would blame the ego.)"""
    outer, inner = CircularLane([500, 174], 150, 3 * np.pi / 2, 2 * np.pi), CircularLane([500, 174], 146, 3 * np.pi / 2, 2 * np.pi)
    net = RoadNetwork()
    net.add_lane("2", "x", outer)
    net.add_lane("2", "x", inner)
    phase = 11 * np.pi / 6

    def at(radius, ds=0.0):
        phi = phase + ds / radius
        return np.array([500 + radius * np.cos(phi), 174 + radius * np.sin(phi)]), float(phi + np.pi / 2)

    (pe, he), (po, ho) = at(148.6), at(145.6)
    ego = LaneCar(*pe, heading=he, lane_index=("2", "x", 0))
    other = LaneCar(*po, heading=ho, lane_index=("2", "x", 1))
    base = _scene(ego, other)
    j = _network_judge(base, net)
    (pe, he), (po, ho) = at(148.6, 2.0), at(146.6, 2.0)   # the ego along its lane, the other 1 m outwards
    ego.position, ego.heading, other.position, other.heading = pe, he, po, ho
    assert abs(pe[1] - j.pos[id(ego)][1]) > 1.5
    crash = _crash(j, base, ego, other)
    assert (crash.fault, crash.rule) == ("other", "side")


class _SteppedRoad:
    """A road whose ``step`` plays one scripted frame per call: ``frames[i](cars)`` moves and crashes them."""

    def __init__(self, cars, frames):
        self.vehicles, self.frames = list(cars), list(frames)

    def step(self, dt):
        self.frames.pop(0)(self.vehicles)


def _policy_step(base, frames_per_step, sim_dt):
    for _ in range(frames_per_step):
        base.road.step(sim_dt)


def _cut_in_then_slide(cars):
    ego, cutter = cars
    return [lambda c: cutter.position.__setitem__(1, LANE - 1.2),                  # its body enters the ego's lane
            lambda c: [setattr(v, "crashed", True) for v in c],                    # contact, the ego in its own lane
            lambda c: ego.position.__setitem__(1, 1.4)]                            # the crash slides the ego across


def test_a_crash_inside_a_policy_step_is_judged_on_the_bodies_at_contact():
    """At 1 Hz a crash may begin a second before the policy step ends; what the bodies did after contact
    (here the crash slides the ego across its lane line) is not a lane entry. Judged at the step's end,
    both would have entered and the ego would be at fault."""
    ego, cutter = Car(0.0, 0.0), Car(-1.0, LANE)
    road = _SteppedRoad([ego, cutter], [])
    base = SimpleNamespace(vehicle=ego, road=road)
    j = FaultJudge(LANE, 3, dt=1.0)
    j.start(base)
    road.frames = _cut_in_then_slide(road.vehicles)
    _policy_step(base, 3, 1 / 3)
    assert 1 in body_lanes(ego, LANE, 3)  # at the step's end the ego overlaps the cutter's lane
    crash = j.observe(base)
    assert (crash.fault, crash.rule) == ("other", "entry"), crash
    assert crash.detail == {"ego_entered": False, "other_entered": True}


def test_without_a_road_step_the_bodies_after_the_step_are_judged():
    ego, cutter = Car(0.0, 0.0), Car(-1.0, LANE)
    base = _scene(ego, cutter)
    j = FaultJudge(LANE, 3, dt=1.0)
    j.start(base)
    for frame in _cut_in_then_slide([ego, cutter]):
        frame([ego, cutter])
    crash = j.observe(base)
    assert (crash.fault, crash.detail) == ("ego", {"ego_entered": True, "other_entered": True})  # counted against it


def test_the_judge_of_the_current_episode_hears_the_road_once():
    ego, other = Car(0.0, 0.0), Car(20.0, 0.0)
    road = _SteppedRoad([ego, other], [lambda c: None] * 4)
    base = SimpleNamespace(vehicle=ego, road=road)
    first, second = FaultJudge(LANE, 3, dt=1.0), FaultJudge(LANE, 3, dt=1.0)
    first.start(base)
    second.start(base)  # a new episode on the same road object: the step is wrapped once, for the new judge
    road.step(0.5)
    assert (first.since_seen, second.since_seen) == (0.0, 0.5)


class _Body(Car):
    """A hand-built car with highway-env's body (its polygon and velocity), for the contact test."""

    diagonal = float(np.hypot(Car.LENGTH, Car.WIDTH))

    @property
    def velocity(self):
        return self.speed * np.array([np.cos(self.heading), np.sin(self.heading)])

    def polygon(self):
        from highway_env.vehicle.kinematics import Vehicle

        return Vehicle.polygon(self)


def _wreck_then(move):
    """Two cars crash in one policy step (the wreck, ahead of the ego, and a third car); in the next, ``move``
    brings the wreck and the standing ego into contact, and the ego's crash begins."""
    ego, wreck, third = _Body(0.0, 0.0, speed=0.0), _Body(6.5, 0.0, speed=-1.0), _Body(6.5, LANE, speed=0.0)
    road = _SteppedRoad([ego, wreck, third], [])
    base = SimpleNamespace(vehicle=ego, road=road)
    j = FaultJudge(LANE, 3, dt=1.0)
    j.start(base)
    road.frames = [lambda c: [setattr(v, "crashed", True) for v in (wreck, third)]]
    _policy_step(base, 1, 1.0)
    first = j.observe_all(base)
    assert first == []  # no guarded car crashed yet
    road.frames = [lambda c: move(ego, wreck), lambda c: setattr(ego, "crashed", True)]
    _policy_step(base, 2, 0.5)
    return j.observe_all(base)


def test_a_wreck_backing_into_a_standing_ego_is_the_wrecks_fault():
    """The partner crashed a step earlier: the ego's crash is still judged against it, not as 'alone'."""
    (crash,) = _wreck_then(lambda ego, wreck: wreck.position.__setitem__(0, 4.9))
    assert (crash.fault, crash.rule, crash.partner) == ("other", "rear_end", "car 1"), crash


def test_driving_into_a_standing_wreck_is_the_egos_fault():
    def drive_in(ego, wreck):
        wreck.speed, ego.speed = 0.0, 3.0
        ego.position[0] = 1.6

    (crash,) = _wreck_then(drive_in)
    assert (crash.fault, crash.rule, crash.partner) == ("ego", "rear_end", "car 1"), crash


def test_a_wreck_the_ego_does_not_touch_is_not_its_partner():
    (crash,) = _wreck_then(lambda ego, wreck: None)   # the ego's crash began with nothing touching it
    assert (crash.fault, crash.rule) == ("ego", "alone"), crash
