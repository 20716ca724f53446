"""The independent fault judge on hand-built collisions (guardian.judge): each rule, and its ties."""
from types import SimpleNamespace

import numpy as np
import pytest

from guardian.judge import ENTRY_WINDOW, FaultJudge, body_lanes

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
