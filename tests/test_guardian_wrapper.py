"""The one Guardian on HighwayOvertake-v0: lead part (RCIS + estimator) composed with ITHA."""
import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401
from envs.agents import collision_fault
from envs.highway_overtake import ConfigError
from guardian.monitor import ModelMonitor
from guardian.rollout import OVERTAKE_ENV, highway_env_config, highway_rollouts
from guardian.wrapper import Guardian, GuardianConfig
from intention.models import intention_models
from intention.params import OvertakeParams

SHORT = {"duration": 10}


def _guarded(library, intention="aggressive", disturbance="adversarial", action=None, **extra):
    cfg = highway_env_config(OVERTAKE_ENV, action, intention, disturbance, None, library, {**SHORT, **extra})
    return Guardian(gym.make(OVERTAKE_ENV, config=cfg), library)


@pytest.mark.parametrize("intention", ["aggressive", "cautious"])
def test_supervised_states_stay_in_the_active_set_and_inputs_in_U(library, intention):
    """Theorem 4 as a falsifier: a random agent, adversarial noise; every state the guardian passes
    through without a conflict lies in the set that was active, and every applied input is in U_e."""
    env = _guarded(library, intention)
    base = env.unwrapped
    rng = np.random.default_rng(7)
    p = base.params
    checked = 0
    for ep in range(3):
        env.reset(seed=ep)
        done = False
        while not done:
            _, _, term, trunc, info = env.step(rng.uniform(-1, 1, 2))
            g = info["guardian"]
            u = base.last_transition["input"]
            assert p.a_ex_bounds[0] <= u[0] <= p.a_ex_bounds[1] and p.v_ey_bounds[0] <= u[1] <= p.v_ey_bounds[1]
            assert not info["unsafe"]
            if g["conflict_steps"] == 0 and g["failsafe_steps"] == 0:
                assert library.region(g["active_set"]).contains(base.overtake_state())
                checked += 1
            assert sum(g["model_violations"].values()) == 0
            done = term or trunc
    assert checked > 100


def test_info_layout(library):
    env = _guarded(library)
    _, info = env.reset(seed=0)
    assert info["guardian"]["scenario"] == "overtake"
    _, _, _, _, info = env.step(np.array([1.0, 1.0]))
    g = info["guardian"]
    assert g["active_set"] in ("aggressive", "cautious", "bounded_velocity")
    assert set(g["valid_intentions"]) <= {"aggressive", "cautious"}
    assert len(g["proposed"]) == 2 and len(g["applied"]) == 2 and g["sim_steps"] == 1
    assert g["overridden"] == (g["proposed"] != g["applied"] or g["refused_lane_change"])


def test_without_the_guardian_random_and_reckless_agents_fail(library):
    for agent in ("random", "reckless"):
        r = highway_rollouts(OVERTAKE_ENV, agent, 6, 0, guardian=False, library=library, intention="aggressive",
                             disturbance="adversarial", env_config=SHORT)
        assert r["safety_violations"] + r["collisions"] >= 4, agent


def test_with_the_guardian_the_same_agents_do_not(library):
    for agent in ("random", "reckless", "mpc"):
        r = highway_rollouts(OVERTAKE_ENV, agent, 4, 0, library=library, intention="aggressive",
                             disturbance="adversarial", env_config=SHORT)
        assert r["ego_at_fault_collisions"] == 0 and r["safety_violations"] == 0, agent
        assert r["model_violation_steps"] == 0 and r["wrong_identifications"] == 0, agent


def test_intention_awareness_overrides_less(library):
    aware = highway_rollouts(OVERTAKE_ENV, "bad", 4, 0, library=library, intention="cautious", env_config=SHORT)
    agnostic = highway_rollouts(OVERTAKE_ENV, "bad", 4, 0, library=library, intention="cautious",
                                use_intention=False, env_config=SHORT)
    assert aware["override_steps"] < agnostic["override_steps"]
    assert aware["identified_fraction"] > 0 and aware["wrong_identifications"] == 0


def test_a_lane_entry_in_front_of_a_fast_follower_is_refused(library):
    """Meta agent asks LANE_LEFT with a fast car just behind in the left lane: ITHA (7.5) refuses."""
    env = _guarded(library, "cautious", "random", action="meta", traffic_count=1, traffic_from_behind=1)
    env.reset(seed=0)
    base = env.unwrapped
    car = base.road.vehicles[2]
    car.position = np.array([base.vehicle.position[0] - 12.0, car.position[1]])
    car.speed = base.vehicle.speed + 8.0
    names = list(base.action_type.actions.values())
    refused = False
    for _ in range(5):
        _, _, _, _, info = env.step(names.index("LANE_LEFT"))
        refused |= info["guardian"]["refused_lane_change"]
        assert env.ego_kin.lanes_at(base.overtake_state()[1]) == {1}  # the body never reaches lane 2
    assert refused


def test_refusals_at_construction(library):
    with pytest.raises(ConfigError, match="library"):
        Guardian(gym.make(OVERTAKE_ENV))
    with pytest.raises(ConfigError, match="OvertakeParams"):
        Guardian(gym.make(OVERTAKE_ENV, config={"params": OvertakeParams(h_min=12.0)}), library)
    with pytest.raises(ConfigError, match="conflict"):
        GuardianConfig(conflict="both")


def test_the_model_monitor_catches_a_transition_the_model_does_not_cover(library):
    env = gym.make(OVERTAKE_ENV, config={"traffic_count": 1, "traffic_from_behind": 0})
    base = env.unwrapped
    env.reset(seed=0)
    models = intention_models()
    mon = ModelMonitor(0.1, (-6.0, 6.0), 40.0, base.params, {n: models[n] for n in ("aggressive", "cautious")})
    u = np.zeros(2)
    base.vehicle.act({"acceleration": 0.0, "steering": 0.0})
    mon.observe(base, u)
    env.step(np.zeros(2))
    assert mon.observe(base, u) == {"ego": 0, "lead": 0, "traffic": 0}
    env.step(np.zeros(2))
    base.lead.speed -= 0.5          # the lead brakes harder than any intention allows
    base.road.vehicles[2].position[0] -= 1.0  # a traffic car jumps back
    assert mon.observe(base, u) == {"ego": 0, "lead": 1, "traffic": 1}


def test_fault_follows_responsibility_of_the_entry():
    env = gym.make(OVERTAKE_ENV, config={"traffic_count": 1, "traffic_from_behind": 1})
    base = env.unwrapped
    env.reset(seed=0)
    ego, car = base.vehicle, base.road.vehicles[2]
    car.position = np.array([ego.position[0] - 2.0, ego.position[1] - 1.0])
    car.lane_index = ("0", "1", 0)
    ego.crashed = car.crashed = True
    y_before = float(ego.position[1]) + 0.2  # the ego moved towards the car (up the screen)
    assert collision_fault(env, y_before) == "ego"
    assert collision_fault(env, y_before, lambda lane: lane == 0) == "other"
    car.position[0] = ego.position[0] + 3.0
    assert collision_fault(env, y_before, lambda lane: True) == "ego"  # hitting a car ahead is always ours


def test_render_adds_the_guardian_panel(library):
    from guardian.panel import PANEL_HEIGHT

    env = Guardian(gym.make(OVERTAKE_ENV, render_mode="rgb_array",
                            config={"initial_region": library.region("bounded_velocity")}), library)
    env.reset(seed=0)
    plain = env.env.render()
    env.step(np.array([1.0, 0.0]))
    framed = env.render()
    assert framed.shape[0] == plain.shape[0] + PANEL_HEIGHT
    assert not np.array_equal(framed[-PANEL_HEIGHT:], np.full_like(framed[-PANEL_HEIGHT:], 245))
    env.close()


def test_a_conflict_is_said_counted_and_resolved_as_documented(library):
    """Ego straddling the lane line behind a slow lead at its lowest speed, a fast car just behind in the
    left lane: the follower's responsibility and S(x) do not intersect. The responsibility yields, the
    step is counted, and the applied input keeps the pair in the active set (Theorem 4)."""
    env = _guarded(library, "cautious", "random", traffic_count=1, traffic_from_behind=1)
    env.reset(seed=0)
    base = env.unwrapped
    ego, lead, car = base.vehicle, base.lead, base.road.vehicles[2]
    ego.speed, lead.speed = 16.0, 14.4
    ego.position = np.array([ego.position[0], ego.y_of(0.75)])
    lead.position = np.array([ego.position[0] + 10.3, lead.position[1]])
    car.position = np.array([ego.position[0] - 8.0, car.position[1]])
    car.speed = 26.0
    for v in (ego, lead, car):
        v.on_state_update()
    x = base.overtake_state()
    assert library.region("bounded_velocity").contains(x)
    _, _, _, _, info = env.step(np.array([0.0, 0.0]))
    g = info["guardian"]
    assert g["conflict_steps"] == 1 and g["changed"] == "conflict"
    assert any("responsibility for a follower not kept" in r for r in g["reasons"])
    assert library.region(g["active_set"]).contains(base.overtake_state())
