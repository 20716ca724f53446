"""Self-safety (7.4) when bodies ahead overlap along the road: the car whose rear is nearest counts too."""
from guardian.decide.traffic import TrafficSupervisor
from guardian.model.scene import Car, Scene
from itha.car_following import CarFollowingParams

PARAMS = CarFollowingParams(dt=0.1, v_max=40.0, h_min=2.0, u_min=-6.0, u_max=6.0, d_min=-6.0, d_max=6.0)


def _fastest(others) -> float:
    ego = Car(100.0, 5.0, frozenset({1}), 5.0, "ego")
    speeds, _ = TrafficSupervisor(PARAMS).self_safe_speeds(Scene(ego, tuple(others), 2))
    return max(hi for _, hi in speeds)


def test_a_car_standing_with_its_front_just_past_a_lanes_end_is_not_hidden_by_the_end():
    """The merge road's case: a car stands at the acceleration lane's end, its front 1 cm past it, 3.6 m ahead of
    the ego. The end (a standing car of length 0) is the nearest front, but the car's rear is 8.6 m nearer; the
    ego must keep to what the car allows, as if the end were not there."""
    end = Car(110.0, 0.0, frozenset({1}), 0.0, "the end of lane 1", fixed=True)
    car = Car(110.01, 0.0, frozenset({1}), 5.0, "car")
    alone = _fastest([car])
    assert _fastest([end, car]) == alone == _fastest([car, end])
    assert alone < _fastest([end])   # the end alone would let the ego go faster: it is not the limit


def test_without_overlaps_the_leader_alone_decides():
    near, far = Car(115.0, 10.0, frozenset({1}), 5.0, "near"), Car(140.0, 0.0, frozenset({1}), 5.0, "far")
    scene = Scene(Car(100.0, 5.0, frozenset({1}), 5.0, "ego"), (far, near), 2)
    assert scene.nearest_rear_ahead(1) is scene.leader(1) is near
    assert _fastest([far, near]) == _fastest([near])
