"""Mistakes a user makes with the wrapper are refused in one line naming the value, never a bare traceback."""
import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np
import pytest

from guardian.errors import ConfigError
from guardian.wrappers.guardian import Guardian


def _guarded(**config):
    env = Guardian(gym.make("highway-fast-v0", config=config))
    env.reset(seed=0)
    return env


@pytest.mark.parametrize("action", [7, -1, 1.5, "left", None])
def test_an_action_outside_a_discrete_space_is_refused_naming_it(action):
    with pytest.raises(ValueError, match=rf"action {action!r} is not in the env's action space Discrete\(5\)"):
        _guarded().step(action)


@pytest.mark.parametrize("action", [[np.nan, 0.0], [0.1, 0.2, 0.3], "fast"])
def test_a_continuous_action_of_the_wrong_shape_or_not_finite_is_refused(action):
    env = _guarded(action={"type": "ContinuousAction"})
    with pytest.raises(ValueError, match="Guardian.step: action"):
        env.step(action)
    env.step([0.1, 0.0])   # a good one still goes through
    env.step(np.int64(1) * np.array([0.5, 0.0]))


def test_the_actions_an_agent_gives_pass():
    env = _guarded()
    for action in (1, np.int64(3), np.array(2)):
        env.step(action)


def test_wrapping_twice_is_refused():
    with pytest.raises(ConfigError, match="already wrapped in a Guardian"):
        Guardian(gym.wrappers.RecordEpisodeStatistics(Guardian(gym.make("highway-fast-v0"))))


def test_a_misspelt_config_key_is_refused_with_the_key_it_resembles():
    with pytest.raises(ConfigError, match="no config key 'lanes_cout' \\(did you mean 'lanes_count'\\?\\)"):
        Guardian(gym.make("highway-fast-v0", config={"lanes_cout": 3}))
