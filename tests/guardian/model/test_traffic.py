"""One reading of the road for every guarded car (``Traffic``): each guarded car's scene, and every decision taken on
it, is the one its own reading of every other body gives (``scene_of``); the entry's window and the sideways check's
window read only the cars that can matter and name the cars as the full lists do; a window set short is seen."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from guardian.config import GuardianConfig
from guardian.decide.bicycle import BicycleGuardian
from guardian.decide.kinematics import BicycleEgo
from guardian.decide.traffic import TrafficSupervisor
from guardian.model.roads import Road
from guardian.model.scene import Car, EgoState, LaneIndex, Scene
from guardian.model.sensing import Sensed, Traffic, scene_of
from itha.car_following import CarFollowingParams

LANES, WIDTH_LANE, LENGTH, WIDTH, DT = 4, 4.0, 5.0, 2.0, 1 / 15


def reading(road, name, x, y, speed, heading=0.0, length=LENGTH) -> Sensed:
    lanes = road.body_slots(x, y, heading, length, WIDTH)
    return Sensed(name, x, y, heading, speed, length, WIDTH, x + length / 2, road.nearest_slot(x, y), lanes,
                  road.beside(lanes, x))


def dense_road(rng, n: int, road) -> list:
    """About 10 m apart, some over a line or turned, none slow enough to reverse (GuardianConfig.reverse_horizon)."""
    out = []
    for i in range(n):
        lane = int(rng.integers(0, LANES))
        y = lane * WIDTH_LANE + (rng.uniform(-1.6, 1.6) if rng.random() < 0.3 else 0.0)
        out.append(reading(road, f"car {i}", float(rng.uniform(0, 40 * n / LANES)), y, float(rng.uniform(6.5, 30)),
                           heading=float(rng.uniform(-0.2, 0.2)) if rng.random() < 0.2 else 0.0))
    return out


def ego_of(s: Sensed) -> Car:
    return Car(s.front, s.speed, frozenset(), s.length, "ego")


def decide(scene, s: Sensed, proposal):
    guard = BicycleGuardian(BicycleEgo(DT, GuardianConfig().traffic_accel, LENGTH, WIDTH, WIDTH_LANE, LANES,
                                       np.pi / 4), GuardianConfig(), meta=False)
    applied, d = guard.step(EgoState(s.front, s.y, s.heading, s.speed, s.own, s.own, s.x), scene, proposal)
    return tuple(float(a) for a in applied), repr(d)


@pytest.mark.parametrize("seed", range(6))
def test_every_guarded_cars_scene_and_decision_are_those_of_its_own_reading(seed):
    rng, road, config = np.random.default_rng(seed), Road(LANES, WIDTH_LANE), GuardianConfig()
    cars = dense_road(rng, 60, road)
    traffic = Traffic(road, cars, config.reversing, BicycleEgo.LATERAL_MARGIN)
    for s in cars[:: 6]:
        alone = scene_of(road, ego_of(s), [o for o in cars if o is not s], config.reversing, BicycleEgo.LATERAL_MARGIN)
        shared = traffic.scene_for(ego_of(s), s.name)
        assert shared.index is traffic.index and shared.others == alone.others and shared.sensed == alone.sensed
        for proposal in (np.array([2.0, 0.0]), np.array([-1.0, 0.3]), np.array([0.5, -0.3])):
            assert decide(shared, s, proposal) == decide(alone, s, proposal)


def test_a_reading_patched_by_an_announcement_is_read_as_announced():
    rng, road, config = np.random.default_rng(1), Road(LANES, WIDTH_LANE), GuardianConfig()
    cars = dense_road(rng, 20, road)
    traffic = Traffic(road, cars, config.reversing, BicycleEgo.LATERAL_MARGIN)
    me, other = cars[0], cars[1]
    same = replace(other, announced=frozenset())                       # changes nothing: the index is shared
    moved = replace(other, announced=frozenset({1, 2, 3, 4}))          # changes its lanes: a scene of its own
    for patch, shared in ((same, True), (moved, False)):
        want = scene_of(road, ego_of(me), [patch if o is other else o for o in cars if o is not me], config.reversing,
                        BicycleEgo.LATERAL_MARGIN)
        got = traffic.scene_for(ego_of(me), me.name, [patch])
        assert got.others == want.others and got.sensed == want.sensed
        assert (got.index is traffic.index) == shared


def test_a_car_that_may_reverse_gives_every_guarded_car_its_own_scene():
    road, config = Road(LANES, WIDTH_LANE), GuardianConfig(reverse_horizon=1.0)
    cars = [reading(road, "a", 0.0, 0.0, 20.0), reading(road, "b", 30.0, 0.0, -0.5), reading(road, "c", 60.0, 4.0, 20.0)]
    traffic = Traffic(road, cars, config.reversing, BicycleEgo.LATERAL_MARGIN)
    got = traffic.scene_for(ego_of(cars[0]), "a")
    want = scene_of(road, ego_of(cars[0]), cars[1:], config.reversing, BicycleEgo.LATERAL_MARGIN)
    assert got.index is None and got.others == want.others


def test_names_are_unique_and_known():
    road, config = Road(LANES, WIDTH_LANE), GuardianConfig()
    a = reading(road, "a", 0.0, 0.0, 20.0)
    with pytest.raises(ValueError, match="share a name"):
        Traffic(road, [a, a], config.reversing, 0.0)
    with pytest.raises(ValueError, match="no reading named 'b'"):
        Traffic(road, [a], config.reversing, 0.0).scene_for(ego_of(a), "b")


# ---- the entry's window ---------------------------------------------------------------------------------------
def _queue(n: int, gap: float, speed: float, lane: int, start: float, name: str) -> list:
    return [Car(start + k * gap, speed, frozenset({lane}), 5.0, f"{name} {k}") for k in range(n)]


def test_the_entrys_window_reads_what_matters_and_names_cars_as_the_full_lists_do(monkeypatch):
    """Thirty cars listed first (in lane 4, two lanes from the entry), then a fast car close behind in lane 2 that
    refuses the entry: the reason names it "car 31", its place in the full lists (the ego first); the window gives
    the same verdict and name, a window set too short (the fast car left out) another verdict."""
    c = GuardianConfig()
    sup = TrafficSupervisor(CarFollowingParams(dt=DT, v_max=c.v_max, h_min=c.h_min, u_min=-c.traffic_accel,
                                               u_max=c.traffic_accel, d_min=-c.traffic_accel, d_max=c.traffic_accel))
    ego = Car(500.0, 20.0, frozenset({1}), 5.0, "ego")
    far = _queue(40, 25.0, 25.0, 4, 0.0, "far")
    fast = Car(498.0, 35.0, frozenset({2}), 5.0, "fast")
    scene = Scene(ego, tuple(far[:30]) + (fast,) + tuple(far[30:]), 4)
    windowed = sup.entry(scene, 2)
    assert not windowed.responsible and windowed.reason == "car 31 behind in lane 2 could not stay safe"
    monkeypatch.setattr(TrafficSupervisor, "_entry_reach", lambda self, index, ego: None)
    assert sup.entry(scene, 2) == windowed
    monkeypatch.setattr(TrafficSupervisor, "_entry_reach", lambda self, index, ego: 1.0)
    assert sup.entry(scene, 2).responsible


def test_the_sideways_window_reads_the_car_alongside(monkeypatch):
    """A car alongside with its body over the line: steering towards it is refused; with no car read (a window that
    misses it) it would not be."""
    road, config = Road(LANES, WIDTH_LANE), GuardianConfig()
    me, beside = reading(road, "me", 100.0, 4.0, 20.0), reading(road, "beside", 97.0, 6.4, 20.0)
    toward = np.array([0.0, 0.3])

    def steering():
        return decide(scene_of(road, ego_of(me), [beside], config.reversing, BicycleEgo.LATERAL_MARGIN), me, toward)[0][1]

    assert steering() < 0.3
    monkeypatch.setattr(LaneIndex, "near", lambda self, front, reach, skip=None: [])
    assert steering() == 0.3


def test_an_ego_faster_than_the_traffics_model_reads_every_car_for_its_entry():
    """With the ego's top speed above the traffic's, a car far ahead driving faster than the traffic's model allows
    leaves the car behind the ego outside its set however far it is: the entry is refused, as when every car is
    read (a window would miss the far car)."""
    sup = TrafficSupervisor(CarFollowingParams(v_max=40.0), CarFollowingParams(v_max=30.0), "ordered")
    ego = Car(0.0, 20.0, frozenset({2}), 5.0, "ego")
    others = (Car(-20.0, 20.0, frozenset({2}), 5.0, "behind"), Car(1000.0, 40.0, frozenset({2}), 5.0, "far ahead"))
    verdict = sup.entry(Scene(ego, others, 3), 1)
    assert not verdict.responsible and verdict.reason == "car 1 behind in lane 2 would be exposed to car 2"


@pytest.mark.parametrize("front, length", [(float("nan"), 5.0), (10.0, -1.0), (10.0, float("nan"))])
def test_a_car_without_a_position_or_with_a_negative_length_is_refused_by_name(front, length):
    """A front that is not a number would break the lane's order (and the leader it finds); a negative length the
    bounds of what a query reads: refused, naming the car, never ordered somewhere."""
    ego = Car(0.0, 20.0, frozenset({1}), 5.0, "ego")
    scene = Scene(ego, (Car(30.0, 20.0, frozenset({1}), 5.0, "real"), Car(front, 20.0, frozenset({1}), length, "odd")), 2)
    with pytest.raises(ValueError, match="odd: front"):
        scene.leaders(1)
