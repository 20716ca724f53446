"""guardian/HighwayOvertake-v0: highway-env's parts, the intention model driving, strict config."""
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs  # noqa: F401
from envs.highway_overtake import ConfigError, HighwayOvertakeEnv
from intention.models import intention_models


def test_check_env_passes():
    check_env(gym.make("guardian/HighwayOvertake-v0").unwrapped, skip_render_check=True)


@pytest.mark.parametrize("intention", ["aggressive", "cautious"])
@pytest.mark.parametrize("disturbance", ["random", "adversarial"])
def test_every_step_is_the_intention_models_pwa_step(intention, disturbance):
    """The env moves the ego and the lead exactly as ``PWASystem.step`` (6.3)-(6.7) says."""
    env = gym.make("guardian/HighwayOvertake-v0", config={"intention": intention, "disturbance": disturbance})
    base = env.unwrapped
    model = intention_models(base.params)[intention]
    env.reset(seed=4)
    rng = np.random.default_rng(0)
    base.vehicle.speed = 0.4  # slow enough that braking meets the standstill clip
    stopped = 0
    for _ in range(40):
        _, _, term, trunc, info = env.step(rng.uniform(-1, 0.2, 2))
        tr = base.last_transition
        expected = model.system.step(tr["state"], tr["input"], tr["disturbance"])
        stopped += int(expected[0] < 0)
        expected[0] = max(expected[0], 0.0)  # the one addition: a car held by its brake does not reverse
        assert np.allclose(base.overtake_state(), expected, atol=1e-9)
        assert np.allclose(info["overtake_state"], expected, atol=1e-9)
        if term or trunc:
            break
    assert stopped > 0  # the clip was exercised


def test_continuous_actions_map_onto_U_e():
    env = gym.make("guardian/HighwayOvertake-v0")
    env.reset(seed=0)
    env.step(np.array([1.0, -1.0], dtype=np.float32))
    assert np.allclose(env.unwrapped.last_transition["input"], [3.0, -1.8], atol=1e-6)


def test_adversarial_disturbance_is_the_vertex_against_the_ego():
    env = gym.make("guardian/HighwayOvertake-v0", config={"disturbance": "adversarial"})
    env.reset(seed=0)
    env.step(np.zeros(2))
    w = env.unwrapped.last_transition["disturbance"]
    assert w.tolist() == [0.15, -0.09, -0.05, -0.1]  # ego behind: pushed on, lead brakes


def test_meta_lane_left_moves_the_ego_to_the_left_lane():
    env = gym.make("guardian/HighwayOvertake-v0", config={"action": {"type": "DiscreteMetaAction"},
                                                          "traffic_count": 0, "traffic_from_behind": 0})
    env.reset(seed=2)
    for _ in range(30):
        env.step(0)  # LANE_LEFT
    assert env.unwrapped.overtake_state()[1] > 1.5


def test_traffic_never_enters_the_scenarios_right_lane():
    env = gym.make("guardian/HighwayOvertake-v0", config={"lanes_count": 3, "traffic_count": 8,
                                                          "traffic_from_behind": 2, "duration": 20})
    base = env.unwrapped
    env.reset(seed=1)
    for _ in range(150):
        _, _, term, trunc, _ = env.step(np.zeros(2))
        for v in base.road.vehicles[2:]:
            assert v.lane_index[2] != base.right_lane and v.target_lane_index[2] != base.right_lane
        if term or trunc:
            break


@pytest.mark.parametrize("config,match", [
    ({"simulation_frequency": 15}, "simulation_frequency"),
    ({"policy_frequency": 1}, "policy_frequency"),
    ({"action": {"type": "MultiAgentAction"}}, "action.type"),
    ({"action": {"type": "ContinuousAction", "acceleration_range": [-5, 5], "steering_range": [-1.8, 1.8]}},
     "acceleration_range"),
    ({"lanes_count": 1}, "lanes_count"),
    ({"intention": "sleepy"}, "intention"),
    ({"disturbance": "gusty"}, "disturbance"),
    ({"traffic_from_behind": 9, "traffic_count": 2}, "traffic_from_behind"),
    ({"no_such_key": 1}, "unknown config keys"),
    ({"lead_departure": {"after": 1, "behaviour": "teleport"}}, "lead_departure.behaviour"),
    ({"lead_departure": {"after": -1, "behaviour": "stop"}}, "lead_departure.after"),
    ({"lead_departure": {"after": 1, "behaviour": "brake"}}, "lead_departure.decel"),
    ({"lead_departure": {"after": 1, "behaviour": "stop", "decel": 4}}, "lead_departure.decel"),
    ({"lead_departure": {"behaviour": "stop"}}, "must be null or"),
    ({"terminate_when_unsafe": "no"}, "terminate_when_unsafe"),
])
def test_configs_it_cannot_simulate_are_refused(config, match):
    with pytest.raises(ConfigError, match=match):
        HighwayOvertakeEnv(config)


def test_render_shows_the_scene():
    env = gym.make("guardian/HighwayOvertake-v0", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.std() > 0
    env.close()


@pytest.mark.parametrize("action", [{"type": "DiscreteAction"}, {"type": "ContinuousAction", "lateral": False},
                                    {"type": "ContinuousAction", "longitudinal": False}, {"type": "ContinuousAction"}])
def test_every_action_type_acts_on_U_e_and_is_supervised(action, traffic_library):
    """DiscreteAction's grid and one-axis continuous actions: the ranges default to U_e, the other axis is 0."""
    from guardian.wrappers.guardian import Guardian

    env = Guardian(gym.make("guardian/HighwayOvertake-v0", config={"action": dict(action), "duration": 3}),
                   traffic_library)
    env.reset(seed=0)
    p = env.unwrapped.params
    for _ in range(10):
        _, _, _, _, info = env.step(env.action_space.sample())
        u = env.unwrapped.last_transition["input"]
        assert p.a_ex_bounds[0] <= u[0] <= p.a_ex_bounds[1] and p.v_ey_bounds[0] <= u[1] <= p.v_ey_bounds[1]
        assert info["guardian"]["sim_steps"] == 1 and env.action_space.contains(
            np.asarray(info["guardian"]["applied_action"], dtype=env.action_space.dtype)
            if not isinstance(info["guardian"]["applied_action"], int) else info["guardian"]["applied_action"])



@pytest.mark.parametrize("departure,next_speed", [
    ({"behaviour": "hardest"}, lambda v, dt: max(v - 3.0 * dt, 0.0)),
    ({"behaviour": "brake", "decel": 6.0}, lambda v, dt: max(v - 6.0 * dt, 0.0)),
    ({"behaviour": "stop"}, lambda v, dt: 0.0),
    ({"behaviour": "random"}, None),
])
def test_a_departed_lead_drives_by_its_behaviour_and_the_episode_goes_on_past_an_exit(departure, next_speed):
    env = gym.make("guardian/HighwayOvertake-v0", config={"lead_departure": {"after": 1.0, **departure},
                                                          "terminate_when_unsafe": False, "traffic_count": 0,
                                                          "traffic_from_behind": 0})
    obs, info = env.reset(seed=3)
    base, dt, exited = env.unwrapped, env.unwrapped.dt, False
    for k in range(80):
        v = float(base.overtake_state()[3])
        obs, _, terminated, truncated, info = env.step(np.array([3.0, 0.0]))   # full throttle, own lane
        departed = k * dt >= 1.0 - 1e-9   # this step's transition: from 1 s on
        assert info["lead_departed"] == departed
        if departed and next_speed is not None:
            assert info["overtake_state"][3] == pytest.approx(next_speed(v, dt), abs=1e-9)
        elif departed:   # random: an acceleration within U_o each step
            assert -3.0 * dt - 1e-9 <= info["overtake_state"][3] - v <= 3.0 * dt + 1e-9 or info["overtake_state"][3] == 0
        exited = exited or info["unsafe"]
        assert not terminated or info["crashed"]   # only a crash ends it, not the exit
        if terminated or truncated:
            break
    if departure["behaviour"] == "stop":
        assert exited   # full throttle into a lead that stood at once: out of the safe set, and on


def test_by_default_a_safe_set_exit_ends_the_episode():
    env = gym.make("guardian/HighwayOvertake-v0", config={"lead_departure": {"after": 0.5, "behaviour": "stop"},
                                                          "traffic_count": 0, "traffic_from_behind": 0})
    env.reset(seed=3)
    for _ in range(80):
        _, _, terminated, truncated, info = env.step(np.array([3.0, 0.0]))
        if terminated or truncated:
            break
    assert terminated and info["unsafe"]
