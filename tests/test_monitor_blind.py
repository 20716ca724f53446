"""Traffic that does not see the guarded car (``guardian.monitor.traffic_blind_to``), on a hand-built
road of two segments: highway-env's v0 search looks on the car's own segment only."""
import pytest
from highway_env.road.lane import StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.kinematics import Vehicle

from guardian.monitor import ModelMonitor, traffic_blind_to


def _road(connected: bool) -> Road:
    net = RoadNetwork()
    net.add_lane("a", "b", StraightLane([0.0, 0.0], [100.0, 0.0]))
    net.add_lane("b", "c", StraightLane([100.0, 0.0], [400.0, 0.0]))
    road = Road(network=net)
    road.neighbour_vehicles_connected_lanes = connected
    return road


def _scene(connected: bool, ego_x: float):
    road = _road(connected)
    follower = IDMVehicle(road, [90.0, 0.0], speed=20.0)   # near the end of segment a-b
    ego = Vehicle(road, [ego_x, 0.0], speed=5.0)           # on segment b-c
    road.vehicles += [follower, ego]
    return road, follower, ego


def test_a_follower_that_cannot_see_past_its_segment_is_counted_blind():
    road, follower, ego = _scene(False, 120.0)   # 20 m past the segment's end: beyond the v0 search
    assert road.neighbour_vehicles(follower)[0] is None
    assert traffic_blind_to(road, ego)
    assert road.neighbour_vehicles_connected_lanes is False   # the road is left as it was


@pytest.mark.parametrize("connected, ego_x", [(True, 120.0), (False, 102.0)])
def test_a_follower_that_sees_the_guarded_car_is_not_counted(connected, ego_x):
    """With the connected search (merge-v1), or with the car within the v0 search's reach (a vehicle's
    length past the segment's end), the follower sees it."""
    road, follower, ego = _scene(connected, ego_x)
    assert road.neighbour_vehicles(follower)[0] is ego
    assert not traffic_blind_to(road, ego)


def test_the_monitor_counts_blind_simulation_steps():
    road, follower, ego = _scene(False, 120.0)

    class Base:
        pass

    base = Base()
    base.road, base.vehicle = road, ego
    monitor = ModelMonitor(0.1, (-6.0, 6.0), 40.0, ego_kinematics=None)
    monitor._compare = lambda prev, now: {"ego": 0, "lead": 0, "traffic": 0}
    assert monitor.observe(base, [0.0, 0.0])["traffic_blind"] == 1
    ego.position[0] = 102.0
    assert monitor.observe(base, [0.0, 0.0])["traffic_blind"] == 0
    assert monitor.totals["traffic_blind"] == 1
