"""Scene sessions: the service decides with the gymnasium wrapper's decision objects, to the bit; vehicle models it
cannot guarantee are refused by name; the model coverage of each transition is counted and said."""
import importlib.util
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from project import ROOT

from guardian.client import GuardianClient, ServiceError
from guardian.config import GuardianConfig
from guardian.evaluation.episodes import run_episodes
from guardian.evaluation.rollouts import Rollout, make_env
from guardian.service import ServiceConfig, ServiceThread

ROAD = {"lanes": 3, "lane_width": 4.0}
BICYCLE = {"length": 5.0, "width": 2.0, "max_steering": 0.785, "max_acceleration": 6.0, "dt": 0.0667}


def _module(path: str):
    spec = importlib.util.spec_from_file_location(path.rsplit("/", 1)[-1][:-3], ROOT / path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def service(library):
    with ServiceThread(library, ServiceConfig(port=0)) as svc:
        yield svc


@pytest.fixture
def client(service):
    with GuardianClient(service.url) as c:
        yield c


def car(cid, x, y, speed, **kw):
    return {"id": cid, "x": x, "y": y, "speed": speed, "length": 5.0, "width": 2.0, **kw}


# ---- the same decisions as in process ----------------------------------------------------------------------

@pytest.mark.parametrize("rollout", [
    Rollout("highway-v0", "random", action="meta", env_config={"duration": 6}),
    Rollout("highway-v0", "random", action="continuous", env_config={"duration": 4}),
    Rollout("merge-v0", "random"),
    Rollout("highway-v0", "random", action="meta", controlled=4, config=GuardianConfig(overapprox="ordered"),
            env_config={"duration": 3}),
], ids=["highway-meta", "highway-continuous", "merge", "four-cars-ordered"])
def test_the_service_applies_the_in_process_decision_to_the_bit_over_http_and_the_stream(client, rollout):
    observer = _module("benchmarks/service_equivalence.py").ShadowObserver(client, rollout.config)
    run_episodes(make_env(rollout), rollout.agent, 2, 11, [observer])
    t = observer.totals
    assert t["decisions"] > 0 and t["http_steps"] == t["stream_steps"] == t["decisions"]
    assert t["unasked"] == 0
    assert t["disagreements"] == 0, observer.examples
    if rollout.action == "meta":
        assert t["lane_changes"] > 0


@pytest.mark.parametrize("stream", [False, True])
def test_the_example_drives_highway_env_through_the_service(client, stream):
    result = _module("examples/drive_through_service.py").drive(client, stream, steps=40)
    assert result["steps"] == 40 and result["safety_overrides"] > 0 and not result["crashed"]


def test_a_point_mass_session_decides_as_the_overtake_guardian_among_traffic(traffic_library):
    """HighwayOvertake-v0 with traffic: each step's bodies (the ego's and the lead's positions, the traffic's
    readings) sent to a point-mass session; the service's input equals PointMassGuardian's to the bit."""
    from guardian.client.bodies import car_body
    from guardian.client.shadow import same_bits

    p = traffic_library.params
    env = make_env(Rollout("guardian/HighwayOvertake-v0", "random", library=traffic_library, traffic=3,
                           env_config={"duration": 8}))
    base = env.unwrapped
    scale = base.config["lateral_scale"]
    vehicle = {"model": "point_mass", "length": base.vehicle.LENGTH, "width": base.vehicle.WIDTH, "dt": p.dt,
               "acceleration": list(p.a_ex_bounds), "lateral_speed": list(p.v_ey_bounds), "lateral_scale": scale}
    compared = []
    with ServiceThread(traffic_library, ServiceConfig(port=0)) as svc, GuardianClient(svc.url) as client:
        for episode in range(2):
            env.reset(seed=episode)
            session = client.create_scene_session({"lanes": base.config["lanes_count"],
                                                   "lane_width": 2 * p.left_lane_y * scale}, vehicle)
            guard = env.cars[0].guard

            def step(x, scene, u, guard=guard, session=session):
                applied, decision = guard.__class__.step(guard, x, scene, u)
                ego, lead = base.vehicle, base.lead
                record = session.step(ego={"x": float(ego.position[0]), "y": float(ego.position[1]),
                                           "speed": float(ego.speed)},
                                      cars=[car("lead", float(lead.position[0]), float(lead.position[1]),
                                                float(lead.speed))] + [car_body(s, env.road) for s in scene.sensed],
                                      lead="lead", input=[float(u[0]), float(u[1])])
                compared.append((all(same_bits(a, b) for a, b in zip(applied.tolist(), record["applied"])),
                                 record["state"] == [float(v) for v in x], decision.changed == record["changed"]))
                return applied, decision

            guard.step = step
            env.action_space.seed(episode)
            done = False
            while not done:
                _, _, terminated, truncated, _ = env.step(env.action_space.sample())
                done = terminated or truncated
            del guard.step
            session.close()
    env.close()
    assert len(compared) > 100
    assert all(all(c) for c in compared), [i for i, c in enumerate(compared) if not all(c)][:10]


# ---- models the guardian cannot guarantee -----------------------------------------------------------------

@pytest.mark.parametrize("vehicle, says", [
    ({**BICYCLE, "model": "dynamic_bicycle"}, "vehicle model 'dynamic_bicycle' is not supervised"),
    ({**BICYCLE, "max_acceleration": 5.0}, "differs from guardian.traffic_accel"),
    ({**BICYCLE, "lateral_scale": 2.0}, "lateral_scale do not apply to model 'bicycle'"),
    ({k: v for k, v in BICYCLE.items() if k != "max_steering"}, "needs max_steering"),
    ({"model": "point_mass", "length": 5.0, "width": 2.0, "dt": 0.1, "acceleration": [-3, 3],
      "lateral_speed": [-1.8, 1.8], "lateral_scale": 2.0}, "'guardian serve --ego-speed-min 0'"),
    ({"model": "point_mass", "length": 5.0, "width": 2.0, "dt": 0.2, "acceleration": [-3, 3],
      "lateral_speed": [-1.8, 1.8], "lateral_scale": 2.0}, "vehicle dt 0.2 is not the 0.1"),
    ({"model": "point_mass", "length": 5.0, "width": 2.0, "dt": 0.1, "acceleration": [-4, 3],
      "lateral_speed": [-1.8, 1.8], "lateral_scale": 2.0}, "vehicle acceleration (-4.0, 3.0) is not the (-3.0, 3.0)"),
    ({**BICYCLE, "max_steering": 1.6}, "max_steering"),
    ({"model": "point_mass", "length": 5.0, "width": 2.0, "dt": 0.1, "acceleration": [-3, 3],
      "lateral_speed": [-1.8, 1.8], "lateral_scale": 2.0, "max_jerk": 5.0}, "max_jerk do not apply"),
    ({**BICYCLE, "max_jerk": 0.0}, "max_jerk"),
    ({**BICYCLE, "lag": 0.0}, "lag"),
    ({"model": "point_mass", "length": 5.0, "width": 2.0, "dt": 0.1, "acceleration": [-3, 3],
      "lateral_speed": [-1.8, 1.8], "lateral_scale": 2.0, "lag": 0.3}, "lag do not apply"),
])
def test_a_vehicle_model_the_guardian_cannot_guarantee_is_refused_by_name(client, vehicle, says):
    with pytest.raises(ServiceError) as err:
        client.create_scene_session(ROAD, vehicle)
    assert err.value.status == 422 and says in err.value.message


def test_the_record_says_which_model_and_parameters_decided(client):
    with client.create_scene_session(ROAD, BICYCLE, {"h_min": 3.0}) as session:
        record = session.step(ego={"x": 0.0, "y": 4.0, "speed": 20.0}, cars=[], input=[0.0, 0.0])
    assert record["model"]["vehicle"] == {"model": "bicycle", **BICYCLE}
    assert record["model"]["guardian"]["h_min"] == 3.0 and record["model"]["guardian"]["overapprox"] == "trivial"


def test_fields_that_do_not_apply_are_refused(client, traffic_library):
    with client.create_scene_session(ROAD, BICYCLE) as session:
        with pytest.raises(ServiceError) as err:
            session.step(ego={"x": 0.0, "y": 4.0, "speed": 20.0}, cars=[car("L", 30.0, 4.0, 20.0)], lead="L",
                         input=[0.0, 0.0])
        assert err.value.status == 422 and "point-mass sessions only" in err.value.message
        assert session.step(ego={"x": 0.0, "y": 4.0, "speed": 20.0}, cars=[], input=[0.0, 0.0])["t"] == 0


def test_a_vehicle_that_declares_a_jerk_limit_gets_only_accelerations_its_actuator_reaches(client):
    """``max_jerk``: the in-process actuated guardian's decision, within ``[a - max_jerk dt, a + max_jerk dt]`` of the
    acceleration the step gives; the acceleration is required with it and refused without it."""
    from guardian.decide.bicycle import BicycleGuardian
    from guardian.decide.kinematics import BicycleEgo
    from guardian.model.scene import Car, EgoState, Scene
    from itha.actuator import Actuator

    jerky = {**BICYCLE, "max_jerk": 5.0}
    reach = 5.0 * BICYCLE["dt"]
    with client.create_scene_session(ROAD, jerky) as session:
        with pytest.raises(ServiceError) as err:
            session.step(ego={"x": 0.0, "y": 4.0, "speed": 20.0}, cars=[], input=[0.0, 0.0])
        assert err.value.status == 422 and "ego.acceleration is required" in err.value.message
        record = session.step(ego={"x": 0.0, "y": 4.0, "speed": 20.0, "acceleration": 1.0},
                              cars=[car("L", 30.0, 4.0, 10.0)], input=[6.0, 0.0])
    assert 1.0 - reach <= record["applied"][0] <= 1.0 + reach and record["overridden"]
    kin = BicycleEgo(BICYCLE["dt"], 6.0, 5.0, 2.0, 4.0, 3, BICYCLE["max_steering"])
    guard = BicycleGuardian(kin, GuardianConfig(), False, Actuator(jerk=5.0, profile="hold"))
    ego = EgoState(2.5, 4.0, 0.0, 20.0, 1, 1, 0.0, 1.0)
    scene = Scene(Car(2.5, 20.0, frozenset(), 5.0, "ego"), (Car(32.5, 10.0, frozenset({2}), 5.0, "L"),), 3)
    assert record["applied"][0] == float(guard.step(ego, scene, [6.0, 0.0])[0][0])
    with client.create_scene_session(ROAD, BICYCLE) as session:
        with pytest.raises(ServiceError) as err:
            session.step(ego={"x": 0.0, "y": 4.0, "speed": 20.0, "acceleration": 0.0}, cars=[], input=[0.0, 0.0])
        assert err.value.status == 422 and "max_jerk or lag only" in err.value.message


def test_a_vehicle_that_declares_a_lag_gets_the_in_process_command_and_its_coverage_fits(client):
    """``lag``: the in-process lagged guardian's command to the bit; the ego's next speed moved by what the lag
    applies fits the model (coverage), the command itself would not."""
    from guardian.decide.bicycle import BicycleGuardian
    from guardian.decide.kinematics import BicycleEgo
    from guardian.model.scene import Car, EgoState, Scene
    from itha.actuator import Actuator

    lagged, dt = {**BICYCLE, "lag": 0.5}, BICYCLE["dt"]
    kin = BicycleEgo(dt, 6.0, 5.0, 2.0, 4.0, 3, BICYCLE["max_steering"])
    guard = BicycleGuardian(kin, GuardianConfig(), False, Actuator(lag=0.5, profile="hold"))
    x, v, a = 0.0, 20.0, 1.0
    with client.create_scene_session(ROAD, lagged) as session:
        for _ in range(3):
            record = session.step(ego={"x": x, "y": 4.0, "speed": v, "acceleration": a},
                                  cars=[car("L", x + 42.0, 4.0, 10.0)], input=[6.0, 0.0])
            ego = EgoState(x + 2.5, 4.0, 0.0, v, 1, 1, x, a)
            scene = Scene(Car(x + 2.5, v, frozenset(), 5.0, "ego"), (Car(x + 44.5, 10.0, frozenset({2}), 5.0, "L"),), 3)
            assert record["applied"][0] == float(guard.step(ego, scene, [6.0, 0.0])[0][0])
            assert record["coverage"]["totals"]["ego"] == 0
            a = guard.actuator.follows(a, record["applied"][0], dt)
            x, v = x + dt * v, v + dt * a
    assert record["overridden"]
    for vehicle in (lagged, {**BICYCLE, "max_jerk": 5.0}):   # a reading the actuator cannot have applied
        with client.create_scene_session(ROAD, vehicle) as session:
            for a_now in (6.5, -1e6):
                with pytest.raises(ServiceError) as err:
                    session.step(ego={"x": 0.0, "y": 4.0, "speed": 20.0, "acceleration": a_now}, cars=[],
                                 input=[0.0, 0.0])
                assert err.value.status == 422 and "outside the vehicle's bounds" in err.value.message


# ---- lanes from bodies, lane changes, coverage ----------------------------------------------------------------

def test_a_body_over_the_line_holds_both_lanes_whatever_its_lane_index_says(client):
    """A car whose centre is 1.6 m right of lane 1's centre (its own lane index 1) blocks lane 2 too: the ego in
    lane 2 beside it may not accelerate into it, and a lane change into lane 1 is not allowed either."""
    with client.create_scene_session(ROAD, {**BICYCLE, "meta": True}) as session:
        ego = {"x": 0.0, "y": 8.0, "speed": 25.0}
        hugging = car("h", 9.0, 4.0 + 1.6, 10.0, own=1)
        record = session.step(ego=ego, cars=[hugging], input=[6.0, 0.0])
        assert record["applied"][0] < 6.0 and record["overridden"]
        verdict = session.lane_change(ego, [hugging], 1)
        assert verdict["allowed"] is False


@pytest.mark.parametrize("to, says", [(2, "own lane"), (0, "not next to"), (3, "no such lane"), (-1, "no such lane")])
def test_a_lane_change_query_the_ego_cannot_make_is_answered_not_refused(client, to, says):
    with client.create_scene_session(ROAD, {**BICYCLE, "meta": True}) as session:
        verdict = session.lane_change({"x": 0.0, "y": 8.0, "speed": 25.0}, [], to)
    assert verdict["allowed"] is False and says in verdict["reason"]


def test_a_transition_the_model_does_not_cover_is_counted_and_said(client):
    dt = BICYCLE["dt"]
    with client.create_scene_session(ROAD, BICYCLE) as session:
        first = session.step(ego={"x": 0.0, "y": 4.0, "speed": 20.0}, cars=[car("a", 30.0, 0.0, 20.0)],
                             input=[0.0, 0.0])
        assert first["coverage"]["ego"] == first["coverage"]["traffic"] == 0
        # the ego as the model says (same speed, dt * speed ahead); the car 8 m/s^2 slower: beyond the traffic model
        second = session.step(ego={"x": 20.0 * dt, "y": 4.0, "speed": 20.0},
                              cars=[car("a", 30.0 + 20.0 * dt, 0.0, 20.0 - 8.0 * dt)], input=[0.0, 0.0])
        assert second["coverage"]["ego"] == 0 and second["coverage"]["traffic"] == 1
        # the ego 3 m/s faster than its applied input allows
        third = session.step(ego={"x": 40.0 * dt, "y": 4.0, "speed": 23.0},
                             cars=[car("a", 30.0 + 20.0 * dt + (20.0 - 8.0 * dt) * dt, 0.0, 20.0 - 8.0 * dt)],
                             input=[0.0, 0.0])
        assert third["coverage"]["ego"] == 1 and third["coverage"]["totals"] == {
            "ego": 1, "traffic": 1, "traffic_reversing_uncovered": 0}


# ---- hostile scenes ---------------------------------------------------------------------------------------

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)
scene_car = st.fixed_dictionaries({
    "id": st.text(min_size=1, max_size=4), "x": finite, "y": finite, "speed": finite,
    "length": st.floats(min_value=0.1, max_value=30), "width": st.floats(min_value=0.1, max_value=5),
    "heading": st.floats(min_value=-math.pi, max_value=math.pi)},
    optional={"lanes": st.lists(st.integers(0, 5), max_size=3), "own": st.integers(0, 5),
              "announced": st.lists(st.integers(0, 5), max_size=2), "swings": st.booleans(),
              "crashed": st.booleans(), "fixed": st.booleans(), "blind": st.booleans()})


@settings(max_examples=80, deadline=None, suppress_health_check=list(HealthCheck))
@given(ego=st.fixed_dictionaries({"x": finite, "y": finite, "speed": finite,
                                  "heading": st.floats(min_value=-math.pi, max_value=math.pi)}),
       cars=st.lists(scene_car, max_size=6, unique_by=lambda c: c["id"]),
       proposed=st.tuples(finite, finite))
def test_any_scene_gets_an_answer_inside_the_input_bounds_never_a_5xx(service, ego, cars, proposed):
    with GuardianClient(service.url) as client, client.create_scene_session(ROAD, BICYCLE) as session:
        try:
            record = session.step(ego=ego, cars=cars, input=list(proposed))
        except ServiceError as exc:
            assert exc.status == 422, exc.message  # a lane number beyond the road's, say
            return
        a, steering = record["applied"]
        assert -BICYCLE["max_acceleration"] <= a <= BICYCLE["max_acceleration"]
        assert -BICYCLE["max_steering"] <= steering <= BICYCLE["max_steering"]


def test_the_record_names_lanes_as_slots_in_its_texts_too(client):
    """The decision objects say ITHA lanes (1 the rightmost); the wire speaks slots (0 the leftmost), texts too."""
    road = {"lanes": 4, "lane_width": 4.0}
    with client.create_scene_session(road, BICYCLE) as session:
        record = session.step(ego={"x": 0.0, "y": 12.0, "speed": 20.0}, cars=[car("c10", 25.5, 12.0, 14.0)],
                              input=[6.0, 0.0])
    assert record["lanes"] == [3] and record["overridden"]
    assert any("c10 ahead in lane 3" in r for r in record["reasons"]), record["reasons"]
