"""Bodies that overlap along the road (cars straddling into a lane, a car standing just past a lane's end, a wreck):
every car no other car hides counts, in self-safety (7.4), for the cars behind, for the cars at risk and for
entries (7.5) under both over-approximations."""
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
    assert scene.leaders(1) == (near,) and scene.leader(1) is near
    assert _fastest([far, near]) == _fastest([near])


def _car(front, speed, length, name, lanes=(1,), announces=False):
    return Car(front, speed, frozenset(lanes), length, name, announces=announces)


def test_every_car_ahead_whose_body_overlaps_the_leaders_counts_not_only_the_nearest_rear():
    """Three bodies overlap along lane 1 (cars straddling into it): the leader (front nearest), a long car whose
    rear is nearest, and between them a standing car. The standing one limits the ego most; a rule that weighs
    the leader and the nearest rear alone misses it."""
    leader, long_car = _car(130.0, 20.0, 5.0, "leader"), _car(140.0, 20.0, 20.0, "long")
    standing = _car(135.0, 0.0, 12.0, "standing")
    assert _fastest([leader, long_car, standing]) == _fastest([standing]) < _fastest([leader, long_car])


def test_a_car_behind_whose_body_overlaps_the_followers_counts_for_the_entry_too():
    """Entering lane 2: the nearest car behind is slow, a long fast car beside it (its front 2 m further back)
    is not hidden by it, and the ego must keep it in its set as well."""
    ego = _car(100.0, 20.0, 5.0, "ego")
    near, fast = _car(90.0, 15.0, 5.0, "near", (2,)), _car(88.0, 35.0, 20.0, "fast", (2,))
    sup = TrafficSupervisor(PARAMS)
    both, _ = sup.follower_speeds(Scene(ego, (near, fast), 2).with_ego_lanes({1, 2}), 2)
    alone, _ = sup.follower_speeds(Scene(ego, (fast,), 2).with_ego_lanes({1, 2}), 2)
    only_near, _ = sup.follower_speeds(Scene(ego, (near,), 2).with_ego_lanes({1, 2}), 2)
    assert both == alone != only_near
    assert Scene(ego, (near, _car(80.0, 35.0, 5.0, "behind near", (2,))), 2).followers(2) == (near,)


def test_a_car_is_at_risk_when_a_body_overlapping_the_one_it_follows_is_too_close():
    """Car x follows, 25 m back, a car that a standing long car overlaps along the lane: that car is at risk,
    and x could stop behind it; but the long car's rear lies 10 m ahead of x, too close at 12 m/s. x may run
    into it, so it is at risk too; weighing only the car with the nearest front ahead of x misses it."""
    x = _car(130.0, 12.0, 5.0, "x")
    ahead, truck = _car(160.0, 20.0, 5.0, "ahead"), _car(170.0, 0.0, 30.0, "truck")
    scene = Scene(_car(50.0, 20.0, 5.0, "ego", (2,)), (x, ahead, truck), 2)
    assert scene.leads_of(x, 1) == (ahead, truck)
    sup = TrafficSupervisor(PARAMS)
    assert "behind truck" in sup.at_risk(scene, x) and "truck" in sup.at_risk(scene, ahead)
    assert sup.at_risk(Scene(scene.ego, (x, _car(160.0, 0.0, 5.0, "ahead alone")), 2), x) == ""


def _entry_top(sup, others) -> float:
    ego = _car(100.0, 20.0, 5.0, "ego")
    verdict = sup.entry(Scene(ego, tuple(others), 2), 2)
    return max((hi for _, hi in verdict.speeds), default=-1.0)


def test_an_ordered_entry_weighs_a_standing_body_that_overlaps_the_announced_leader():
    """Under the ordered over-approximation a car that takes part in the order is where it says and hides the
    cars wholly beyond it; a standing long car whose rear lies nearer than that car's front is not hidden: the
    entry's speeds are the ones it allows, as under the trivial over-approximation."""
    leader = _car(130.0, 20.0, 5.0, "leader", (2,), announces=True)
    truck = _car(140.0, 0.0, 20.0, "truck", (2,), announces=True)
    beyond = _car(160.0, 0.0, 5.0, "beyond", (2,), announces=True)
    for overapprox in ("trivial", "ordered"):
        sup = TrafficSupervisor(PARAMS, overapprox=overapprox)
        assert _entry_top(sup, [leader, truck]) == _entry_top(sup, [truck, leader]) == _entry_top(sup, [truck])
        assert _entry_top(sup, [truck]) < _entry_top(sup, [leader])
    ordered = TrafficSupervisor(PARAMS, overapprox="ordered")
    assert _entry_top(ordered, [leader, beyond]) == _entry_top(ordered, [leader])   # hidden: wholly beyond it


def test_a_queue_of_a_thousand_cars_is_judged_without_recursion_and_as_the_rule_says():
    """A crashed car heads a queue of 1,000 cars in one lane, each 8 m (3 m bumper to bumper) behind the next at
    10 m/s: none can stop behind the wreck ahead of it, so every one is at risk, the reason naming the car it
    follows. The chain is deeper than Python's recursion limit; with a gap of 60 m the same queue is safe."""
    def queue(spacing):
        wreck = Car(10_000.0, 0.0, frozenset({1}), 5.0, "wreck", crashed=True)
        cars = tuple(_car(10_000.0 - spacing * (k + 1), 10.0, 5.0, f"car {k}") for k in range(1000))
        return Scene(_car(0.0, 10.0, 5.0, "ego", (2,)), (wreck,) + cars, 2), cars

    scene, cars = queue(8.0)
    sup = TrafficSupervisor(PARAMS)
    assert sup.at_risk(scene, cars[-1]) == "car 999 cannot stop behind car 998 in lane 1, which is at risk"
    assert all(sup.at_risk(scene, c) for c in cars)
    scene, cars = queue(65.0)
    assert sup.at_risk(scene, cars[-1]) == "" and sup.at_risk(scene, cars[0]) == ""


def test_the_at_risk_chain_stops_at_a_car_far_enough_ahead_with_the_same_verdicts(monkeypatch):
    """A car far enough behind the car it follows (``far_enough``: inside its set at any speed, even behind a car
    standing still from its next position on) does not ask for that car's verdict. On random roads with wrecks, cars
    outside the model's speeds, bodies over two lanes and cars near and far, every verdict equals the one that
    walks the whole chain, and the shortcut was taken."""
    import numpy as np

    import guardian.decide.traffic as traffic
    from itha.responsibility import far_enough

    rng, far = np.random.default_rng(8), far_enough(TrafficSupervisor(PARAMS).S_others)
    taken = 0
    for _ in range(200):
        n = int(rng.integers(3, 30))
        cars = tuple(Car(float(rng.uniform(0, 8 * far)), float(rng.uniform(-1, 42)),
                         frozenset(rng.choice([1, 2], size=int(rng.integers(1, 3)), replace=False).tolist()),
                         float(rng.uniform(0, 10)), f"car {k}", crashed=bool(rng.random() < 0.1)) for k in range(n))
        scene = Scene(_car(float(rng.uniform(0, 8 * far)), 20.0, 5.0, "ego", (1,)), cars, 2)
        short = [TrafficSupervisor(PARAMS, wreck_margin=3.0).at_risk(scene, c) for c in cars]
        with monkeypatch.context() as m:
            m.setattr(traffic, "far_enough", lambda _: float("inf"))
            assert [TrafficSupervisor(PARAMS, wreck_margin=3.0).at_risk(scene, c) for c in cars] == short
        fronts = sorted(c.front for c in cars)
        taken += any(b - a > far + 12 for a, b in zip(fronts, fronts[1:]))
    assert taken > 100
