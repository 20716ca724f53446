"""The one Guardian on HighwayOvertake-v0: the wrapper only reads, calls the decision object, applies.

The decisions themselves are tested without a simulator in tests/guardian/decide/test_pointmass_guardian.py.
"""
import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401
import highway_env  # noqa: F401
from guardian.errors import ConfigError
from guardian.adapters.highway_env.monitor import ModelMonitor
from guardian.evaluation.rollouts import OVERTAKE_ENV, Rollout, highway_env_config, highway_rollouts
from guardian.adapters.highway_env.scene import road_scene
from guardian.decide.lead import IntentionAwareGuardian
from guardian.wrappers.guardian import Guardian, GuardianConfig
from intention.models import intention_models
from intention.params import OvertakeParams

SHORT = {"duration": 10}


def _guarded(library, intention="aggressive", disturbance="adversarial", action=None, traffic=None, **extra):
    cfg = highway_env_config(Rollout(OVERTAKE_ENV, "", action=action, library=library, intention=intention,
                                     disturbance=disturbance, traffic=traffic, env_config={**SHORT, **extra}))
    return Guardian(gym.make(OVERTAKE_ENV, config=cfg), library)


@pytest.mark.parametrize("intention", ["aggressive", "cautious"])
def test_supervised_states_stay_in_the_composed_set_and_inputs_in_U(traffic_library, intention):
    """Theorem 4 composed with ITHA, as a falsifier: a random agent, adversarial noise, traffic on both
    other lanes; every state reached from a start inside the composed set K without a conflict lies in K,
    every applied input is in U_e, and the pair never leaves the safe set (6.8)."""
    lib = traffic_library
    env = _guarded(lib, intention, traffic=8, lanes_count=3, traffic_from_behind=3)
    base = env.unwrapped
    rng = np.random.default_rng(7)
    p = base.params
    checked = 0
    for ep in range(4):
        _, info = env.reset(seed=ep, options={"safe_start": True})
        assert info["guardian"]["start_inside"]
        done = False
        while not done:
            _, _, term, trunc, info = env.step(rng.uniform(-1, 1, 2))
            g = info["guardian"]
            u = base.last_transition["input"]
            assert p.a_ex_bounds[0] <= u[0] <= p.a_ex_bounds[1] and p.v_ey_bounds[0] <= u[1] <= p.v_ey_bounds[1]
            assert not info["unsafe"] and not base.vehicle.crashed
            assert g["unsupervised_steps"] == 0 and g["level"] in ("composed", "follower_dropped")
            assert env.guard.inside(base.overtake_state(), road_scene(base, env.road))
            assert sum(g["model_violations"].values()) == 0
            checked += 1
            done = term or trunc
    assert checked > 300


def test_without_traffic_it_is_the_two_car_guardian_of_section_6_5(library):
    """traffic_count 0 and the dissertation's parameters: the same inputs as IntentionAwareGuardian."""
    env = _guarded(library, "cautious", "random", traffic=0)
    base = env.unwrapped
    twin = IntentionAwareGuardian(library)
    rng = np.random.default_rng(3)
    env.reset(seed=5)
    twin.reset()
    for _ in range(60):
        x = base.overtake_state()
        _, _, term, trunc, info = env.step(rng.uniform(-1, 1, 2))
        applied, record = twin.step(x, info["guardian"]["proposed"])
        assert np.array_equal(applied, base.last_transition["input"])
        assert record.active_set == info["guardian"]["active_set"]
        if term or trunc:
            break


def test_info_layout(traffic_library):
    env = _guarded(traffic_library)
    _, info = env.reset(seed=0)
    assert info["guardian"]["scenario"] == "overtake" and isinstance(info["guardian"]["start_inside"], bool)
    _, _, _, _, info = env.step(np.array([1.0, 1.0]))
    g = info["guardian"]
    assert g["active_set"] in ("aggressive", "cautious", "bounded_velocity")
    assert set(g["valid_intentions"]) <= {"aggressive", "cautious"}
    assert len(g["proposed"]) == 2 and len(g["applied"]) == 2 and g["sim_steps"] == 1
    assert g["overridden"] == (g["proposed"] != g["applied"] or g["refused_lane_change"])
    assert g["level"] in ("composed", "follower_dropped", "conflict", "failsafe")
    assert set(g["entered"]) <= set(g["lanes"]) and g["unsupervised_steps"] == 0 and not g["reattached"]


def test_without_the_guardian_random_and_reckless_agents_fail(traffic_library):
    for agent in ("random", "reckless"):
        r = highway_rollouts(Rollout(OVERTAKE_ENV, agent, guarded=False, library=traffic_library,
                                     intention="aggressive", disturbance="adversarial", env_config=SHORT), 6, 0)
        assert r["safety_violations"] + r["collisions"] >= 4, agent


def test_with_the_guardian_the_same_agents_do_not(traffic_library):
    for agent in ("random", "reckless", "mpc", "brake_check", "trap"):
        r = highway_rollouts(Rollout(OVERTAKE_ENV, agent, library=traffic_library, intention="aggressive",
                                     disturbance="adversarial", env_config=SHORT,
                                     config=GuardianConfig(resample_unsafe_start=True)), 4, 0)
        assert r["collisions"] == 0 and r["safety_violations"] == 0 and r["starts_outside"] == 0, agent
        assert r["unchecked_entries"] == 0 and r["reversing_steps"] == 0, agent
        assert r["model_violation_steps"] == 0 and r["wrong_identifications"] == 0, agent


@pytest.mark.slow
def test_intention_awareness_overrides_less(traffic_library):
    """Behind the lead the guardian keeps F_R, which is the same for every intention; the identified
    intention's larger set pays off around the overtake (entering the left lane and passing)."""
    kw = dict(library=traffic_library, intention="cautious")
    aware = highway_rollouts(Rollout(OVERTAKE_ENV, "bad", **kw,
                                     config=GuardianConfig(resample_unsafe_start=True)), 6, 0)
    agnostic = highway_rollouts(Rollout(OVERTAKE_ENV, "bad", **kw, config=GuardianConfig(
        use_intention=False, resample_unsafe_start=True)), 6, 0)
    assert aware["override_steps"] < agnostic["override_steps"]
    assert aware["identified_fraction"] > 0 and aware["wrong_identifications"] == 0


def test_a_lane_entry_in_front_of_a_fast_follower_is_refused(traffic_library):
    """Meta agent asks LANE_LEFT with a fast car just behind in the left lane: ITHA (7.5) refuses."""
    env = _guarded(traffic_library, "cautious", "random", action="meta", traffic_count=1, traffic_from_behind=1)
    env.reset(seed=0, options={"safe_start": True})
    base = env.unwrapped
    car = base.road.vehicles[2]
    car.position = np.array([base.vehicle.position[0] - 12.0, car.position[1]])
    car.speed = base.vehicle.speed + 8.0
    names = list(base.action_type.actions.values())
    refused = False
    for _ in range(6):
        _, _, _, _, info = env.step(names.index("LANE_LEFT"))
        refused |= info["guardian"]["refused_lane_change"]
        assert env.guard.kin.lanes_at(base.overtake_state()[1]) == {1}  # the body never reaches lane 2
    assert refused


def test_the_library_is_loaded_on_demand_for_the_envs_parameters(traffic_library, monkeypatch):
    import intention.library

    asked = []
    monkeypatch.setattr(intention.library, "build_library",
                        lambda params, **kw: asked.append(params) or traffic_library)
    env = Guardian(gym.make(OVERTAKE_ENV))
    assert asked == [env.unwrapped.params] and env.library is traffic_library


def test_refusals_at_construction(library, traffic_library):
    with pytest.raises(ConfigError, match="OvertakeParams"):
        Guardian(gym.make(OVERTAKE_ENV, config={"params": OvertakeParams.among_traffic(h_min=12.0)}), traffic_library)
    with pytest.raises(ConfigError, match="wait behind the lead"):  # v_ex >= 16 with traffic: no guarantee
        Guardian(gym.make(OVERTAKE_ENV, config={"params": library.params, "traffic_count": 2}), library)
    with pytest.raises(ConfigError, match="overapprox"):
        GuardianConfig(overapprox="both")
    with pytest.raises(ConfigError, match="override_penalty"):
        GuardianConfig(override_penalty=-1.0)
    with pytest.raises(ConfigError, match="GuardianConfig"):
        Guardian(gym.make("highway-fast-v0"), config={"h_min": 3})


def test_the_model_monitor_catches_a_transition_the_model_does_not_cover():
    env = gym.make(OVERTAKE_ENV, config={"traffic_count": 1, "traffic_from_behind": 0})
    base = env.unwrapped
    env.reset(seed=0)
    models = intention_models(base.params)
    mon = ModelMonitor(0.1, (-6.0, 6.0), 40.0, base.params, {n: models[n] for n in ("aggressive", "cautious")},
                       ego_stops_at_zero=True)
    u = np.zeros(2)
    base.vehicle.act({"acceleration": 0.0, "steering": 0.0})
    mon.observe(base, u)
    env.step(np.zeros(2))
    assert mon.observe(base, u) == {"ego": 0, "lead": 0, "traffic": 0, "traffic_blind": 0,
                                    "traffic_reversing_uncovered": 0}
    env.step(np.zeros(2))
    base.lead.speed -= 0.5          # the lead brakes harder than any intention allows
    base.road.vehicles[2].position[0] -= 1.0  # a traffic car jumps back
    assert mon.observe(base, u) == {"ego": 0, "lead": 1, "traffic": 1, "traffic_blind": 0,
                                    "traffic_reversing_uncovered": 0}


def test_the_ego_stops_at_standstill_and_the_monitor_knows_it():
    """(6.3)'s noise would make a braking ego at rest reverse; the env holds it at 0, and the monitor
    counts that transition as covered, but a speed that rises without cause as not."""
    env = gym.make(OVERTAKE_ENV, config={"traffic_count": 0, "traffic_from_behind": 0})
    base = env.unwrapped
    env.reset(seed=0)
    mon = ModelMonitor(0.1, (-6.0, 6.0), 40.0, base.params, ego_stops_at_zero=True)
    x = base.overtake_state().copy()
    x[0] = 0.05
    assert mon.overtake_transition(x, [-3.0, 0.0], [0.0, x[1], x[2] + 0.1 * (x[3] - x[0]), x[3]])[0] == 0
    assert mon.overtake_transition(x, [-3.0, 0.0], [0.1, x[1], x[2] + 0.1 * (x[3] - x[0]), x[3]])[0] == 1
    base.vehicle.speed = 0.05
    for _ in range(5):
        env.step(np.array([-1.0, 0.0]))
        assert base.vehicle.speed >= 0.0


def test_render_adds_the_guardian_panel(traffic_library):
    from guardian.wrappers.panel import PANEL_HEIGHT

    env = Guardian(gym.make(OVERTAKE_ENV, render_mode="rgb_array",
                            config={"initial_region": traffic_library.region("bounded_velocity"),
                                    "params": traffic_library.params}), traffic_library)
    env.reset(seed=0)
    plain = env.env.render()
    env.step(np.array([1.0, 0.0]))
    framed = env.render()
    assert framed.shape[0] == plain.shape[0] + PANEL_HEIGHT
    assert not np.array_equal(framed[-PANEL_HEIGHT:], np.full_like(framed[-PANEL_HEIGHT:], 245))
    env.close()


def test_starts_are_reported_and_can_be_drawn_again_until_safe(traffic_library):
    """Without the intention K holds F_R, which many of the env's own starts (inside C_bnd) miss; with
    it, F_R^M holds almost all of them (the campaign: 1 start outside in 256)."""
    cfg = highway_env_config(Rollout(OVERTAKE_ENV, "", library=traffic_library, intention="aggressive", traffic=4,
                                     env_config=dict(SHORT)))
    env = Guardian(gym.make(OVERTAKE_ENV, config=cfg), traffic_library, GuardianConfig(use_intention=False))
    outside = [not env.reset(seed=s)[1]["guardian"]["start_inside"] for s in range(30)]
    assert any(outside)  # the env's own starts (inside C_bnd) are not all inside K
    for s in range(10):
        _, info = env.reset(seed=s, options={"safe_start": True})
        assert info["guardian"]["start_inside"] and info["guardian"]["start_attempts"] >= 1
        assert env.start_inside()
