"""Traffic that does not see the guarded car (``guardian.adapters.highway_env.blindness.traffic_blind_to``), on a hand-built
road of two segments: highway-env's v0 search looks on the car's own segment only."""
import pytest
from highway_env.road.lane import StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.kinematics import Vehicle

from guardian.adapters.highway_env.monitor import ModelMonitor
from guardian.adapters.highway_env.blindness import traffic_blind_to


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


# ---- the guardian's cover: a car that cannot see the ego neither brakes for it nor weighs it ----------
def _two_lane_road(connected: bool):
    from highway_env.road.lane import LineType

    net = RoadNetwork()
    for k in range(2):
        for start, end, a, b in ((0.0, 100.0, "a", "b"), (100.0, 400.0, "b", "c")):
            net.add_lane(a, b, StraightLane([start, 4.0 * k], [end, 4.0 * k],
                                            line_types=(LineType.CONTINUOUS, LineType.CONTINUOUS)))
    road = Road(network=net)
    road.neighbour_vehicles_connected_lanes = connected
    return road


class _Base:
    def __init__(self, road, ego):
        self.road, self.vehicle, self.config = road, ego, {"policy_frequency": 1}


def _scene_of(road, ego, ego_slot):
    from guardian.adapters.highway_env.road import read_road_map
    from guardian.adapters.highway_env.scene import road_scene

    road_map = read_road_map(road.network)
    return road_scene(_Base(road, ego), road_map, frozenset({road_map.numbering.itha(ego_slot)}), ego), road_map


def _ego_and_one_car(connected: bool, car_x: float, car_speed: float, ego_x: float):
    """The ego in slot 0 at ``ego_x`` and one IDM car in slot 1: (road, ego, road map, the car's Car)."""
    road = _two_lane_road(connected)
    car = IDMVehicle(road, [car_x, 4.0], speed=car_speed)
    ego = Vehicle(road, [ego_x, 0.0], speed=20.0)
    road.vehicles += [car, ego]
    scene, road_map = _scene_of(road, ego, 0)
    (seen,) = scene.others
    return road, ego, road_map, scene, seen


@pytest.mark.parametrize("connected", [False, True])
def test_an_entry_in_front_of_a_follower_that_cannot_see_the_ego_is_refused(connected):
    """The ego 20 m past a segment's end in lane 0 asks for lane 1, where an IDM car on the previous
    segment is 30 m behind: with the v0 search it would not brake for the ego (the crashes of
    docs/roads.md), so the entry is refused; with the connected search it sees the ego."""
    from guardian.decide.traffic import TrafficSupervisor
    from itha.car_following import CarFollowingParams

    _, _, road_map, scene, car = _ego_and_one_car(connected, 90.0, 20.0, 120.0)
    assert car.blind is not connected
    params = CarFollowingParams(dt=0.1, v_max=40.0, h_min=2.0, u_min=-6.0, u_max=6.0, d_min=-6.0, d_max=6.0)
    verdict = TrafficSupervisor(params, params, "trivial").entry(scene, road_map.numbering.itha(1))
    assert verdict.responsible is connected
    if not connected:
        assert "does not see the ego" in verdict.reason


def test_a_car_ahead_that_cannot_see_the_ego_counts_in_the_lanes_it_may_change_into():
    """An IDM car ahead on the next segment, in the lane beside the ego's: its MOBIL looks for its new
    follower on its own segment and would change in front of the ego unseen, so the ego keeps room from
    it as if it were in its lane too; a car that sees the ego stays in its own lane."""
    road, ego, road_map, scene, car = _ego_and_one_car(False, 130.0, 15.0, 70.0)
    assert car.blind and car.lanes == {road_map.numbering.itha(0), road_map.numbering.itha(1)}
    assert scene.leader(road_map.numbering.itha(0)) is car
    ego.position[0] = 125.0   # now on the same segment: it sees the ego and stays in its own lane
    scene, _ = _scene_of(road, ego, 0)
    (car,) = scene.others
    assert not car.blind and car.lanes == {road_map.numbering.itha(1)}
