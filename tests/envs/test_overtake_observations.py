"""Every observation type highway-env offers, on guardian/HighwayOvertake-v0 under the guardian; the ones
that cannot apply are refused with the reason."""
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs  # noqa: F401
from guardian import Guardian
from guardian.errors import ConfigError
from guardian.evaluation.rollouts import OVERTAKE_ENV

OBSERVATIONS = {
    "Kinematics": {"type": "Kinematics"},
    "OccupancyGrid": {"type": "OccupancyGrid"},
    "TimeToCollision": {"type": "TimeToCollision"},
    "LidarObservation": {"type": "LidarObservation"},
    "AttributesObservation": {"type": "AttributesObservation", "attributes": ["state"]},
    "GrayscaleObservation": {"type": "GrayscaleObservation", "observation_shape": (128, 64), "stack_size": 4,
                             "weights": [0.2989, 0.5870, 0.1140], "scaling": 1.75},
    "MultiAgentObservation": {"type": "MultiAgentObservation", "observation_config": {"type": "TimeToCollision"}},
    "TupleObservation": {"type": "TupleObservation",
                         "observation_configs": [{"type": "Kinematics"}, {"type": "TimeToCollision"}]},
    "OvertakeState": {"type": "OvertakeState"},
}


@pytest.mark.parametrize("action", ["ContinuousAction", "DiscreteMetaAction"])
@pytest.mark.parametrize("name", list(OBSERVATIONS))
def test_every_observation_type_passes_check_env_and_is_supervised(traffic_library, name, action):
    render = "rgb_array" if name == "GrayscaleObservation" else None
    config = {"observation": OBSERVATIONS[name], "duration": 3}
    if action == "DiscreteMetaAction":
        config["action"] = {"type": action}
    env = Guardian(gym.make(OVERTAKE_ENV, config=config, render_mode=render), traffic_library)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*(unwrapped version|infinity).*")
        check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    first = obs
    for _ in range(5):
        obs, _, _, _, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
        g = info["guardian"]
        assert g["sim_steps"] == 1 and g["unsupervised_steps"] == 0
    if name == "GrayscaleObservation":  # frames drawn, and they move
        assert obs.std() > 0 and not np.array_equal(obs, first)
    env.close()


def test_time_to_collision_sees_the_lead_at_the_egos_target_speeds():
    """The grid's rows are the ego's target speeds around the one it tracks; closing on a slower lead in
    its own lane shows a predicted collision in the middle column (the ego's lane), none on the empty
    left lane."""
    env = gym.make(OVERTAKE_ENV, config={"observation": {"type": "TimeToCollision", "horizon": 5},
                                         "traffic_count": 0, "traffic_from_behind": 0,
                                         "action": {"type": "DiscreteMetaAction"}})
    obs, _ = env.reset(seed=0)
    ego, lead = env.unwrapped.vehicle, env.unwrapped.lead
    lead.position[0], lead.speed = ego.position[0] + 30.0, 10.0
    ego.speed = 25.0
    env.unwrapped.vehicle.target_speed_index = 2
    obs, *_ = env.step(env.unwrapped.action_type.actions_indexes["IDLE"])
    assert obs.shape == (3, 3, 50)
    assert ego.speed_index == 2 and ego.index_to_speed(ego.speed_index) == ego.target_speeds[2]
    own, left = obs[:, 1, :], obs[:, 0, :]  # lanes around the ego: left, own, right (the right padded)
    assert own.max() > 0 and left.max() == 0


@pytest.mark.parametrize("observation,match", [
    ({"type": "KinematicsGoal", "scales": [100, 100, 5, 5, 1, 1]}, "observes a goal"),
    ({"type": "ExitObservation"}, "exit"),
    ({"type": "AttributesObservation", "attributes": ["goal"]}, "attributes this env offers"),
    ({"type": "TupleObservation", "observation_configs": [{"type": "OvertakeState"}]}, "only as the observation"),
    ({"type": "MultiAgentObservation", "observation_config": {"type": "KinematicsGoal"}}, "observes a goal"),
    ({"type": "Nothing"}, "not supported"),
])
def test_observation_types_that_cannot_apply_are_refused_with_the_reason(observation, match):
    with pytest.raises(ConfigError, match=match):
        gym.make(OVERTAKE_ENV, config={"observation": observation})
