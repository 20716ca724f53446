"""What the guardian accepts of a highway-env config (``guardian.adapters.highway_env.checks``), on hand-built cases:
values of the wrong kind or out of range are refused naming the key and the value, every env's own
defaults pass, and the MergeEnv family's limits hold for the wrapper as for the command line."""
import gymnasium as gym
import highway_env  # noqa: F401 - registers the envs
import pytest

import envs  # noqa: F401 - registers guardian/Merge-v0
from guardian import Guardian
from guardian.adapters.highway_env.checks import check_config, discrete_reward, env_class, merge_limits, one_ego
from guardian.errors import ConfigError

DEFAULTS = {"simulation_frequency": 15, "policy_frequency": 1, "duration": 40, "vehicles_count": 50,
            "lanes_count": 4, "controlled_vehicles": 1, "vehicles_density": 1, "offroad_terminal": False,
            "other_vehicles_type": "x.IDMVehicle", "centering_position": [0.3, 0.5], "action": {"type": "A"},
            "initial_lane_id": None}

REFUSED = [  # (config, the words the message must hold)
    ({"policy_frequency": 0}, "'policy_frequency' must be a positive number, got 0"),
    ({"policy_frequency": -5}, "'policy_frequency' must be a positive number, got -5"),
    ({"policy_frequency": "abc"}, "'policy_frequency' must be a number, got 'abc'"),
    ({"policy_frequency": float("nan")}, "'policy_frequency' must be a number"),
    ({"simulation_frequency": 0}, "'simulation_frequency' must be a positive number"),
    ({"policy_frequency": 30}, "'policy_frequency' 30 is above 'simulation_frequency' 15"),
    ({"duration": "abc"}, "'duration' must be a number, got 'abc'"),
    ({"duration": -1}, "'duration' must be a positive number, got -1"),
    ({"vehicles_density": 0}, "'vehicles_density' must be a positive number"),
    ({"vehicles_count": -1}, "'vehicles_count' must be a whole number >= 0, got -1"),
    ({"vehicles_count": 2.5}, "'vehicles_count' must be a whole number >= 0, got 2.5"),
    ({"lanes_count": 0}, "'lanes_count' must be a whole number >= 1, got 0"),
    ({"controlled_vehicles": 0}, "'controlled_vehicles' must be a whole number >= 1, got 0"),
    ({"controlled_vehicles": True}, "'controlled_vehicles' must be a number, got True"),
    ({"offroad_terminal": "maybe"}, "'offroad_terminal' must be true or false, got 'maybe'"),
    ({"offroad_terminal": 0}, "'offroad_terminal' must be true or false, got 0"),
    ({"other_vehicles_type": 3}, "'other_vehicles_type' must be text, got 3"),
    ({"centering_position": 0.3}, "'centering_position' must be a list"),
    ({"action": "ContinuousAction"}, "'action' must be an object"),
]


@pytest.mark.parametrize("config,words", REFUSED, ids=[str(c) for c, _ in REFUSED])
def test_a_value_of_the_wrong_kind_or_range_is_refused_naming_key_and_value(config, words):
    with pytest.raises(ConfigError, match="^here: ") as err:
        check_config(DEFAULTS, config, "here")
    assert words in str(err.value)


def test_values_of_the_right_kind_and_keys_without_a_fixed_kind_pass():
    check_config(DEFAULTS, {"policy_frequency": 15, "vehicles_density": 2.5, "duration": 20.5, "lanes_count": 1,
                            "vehicles_count": 0, "initial_lane_id": ("a", "b", 0), "centering_position": (0.1, 0.5),
                            "not_a_default": "anything"}, "here")


ENV_IDS = ["highway-v0", "highway-fast-v0", "merge-v0", "merge-v1", "merge-generic-v0", "exit-v0", "exit-v1",
           "roundabout-v0", "intersection-v0", "racetrack-v0", "parking-v0", "two-way-v0", "lane-keeping-v0",
           "u-turn-v0", "guardian/Merge-v0", "guardian/HighwayOvertake-v0", "guardian/Overtake-v0"]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_every_envs_own_defaults_pass(env_id):
    cls = env_class(env_id)
    check_config(cls.default_config(), cls.default_config(), env_id)


def test_the_merge_family_is_told_apart_by_what_it_inherits():
    assert discrete_reward(env_class("merge-v0")) and one_ego(env_class("merge-v0"))
    assert discrete_reward(env_class("merge-generic-v0")) and one_ego(env_class("merge-generic-v0"))
    assert not discrete_reward(env_class("guardian/Merge-v0")) and not one_ego(env_class("guardian/Merge-v0"))
    assert not discrete_reward(env_class("exit-v0")) and not one_ego(env_class("exit-v0"))
    with pytest.raises(ConfigError, match="merge-generic-v0 fails with ContinuousAction.*guardian/Merge-v0"):
        merge_limits(env_class("merge-generic-v0"), "merge-generic-v0", True, False)
    with pytest.raises(ConfigError, match="merge-generic-v0 has one controlled car"):
        merge_limits(env_class("merge-generic-v0"), "merge-generic-v0", False, True)
    merge_limits(env_class("guardian/Merge-v0"), "guardian/Merge-v0", True, True)


# ---- the wrapper asks the same --------------------------------------------------------------------------
@pytest.mark.parametrize("config,words", [
    ({"policy_frequency": 0}, "'policy_frequency' must be a positive number"),
    ({"policy_frequency": -5}, "'policy_frequency' must be a positive number"),
    ({"policy_frequency": 10}, "'policy_frequency' 10 is above 'simulation_frequency' 5"),
    ({"duration": "abc"}, "'duration' must be a number"),
    ({"vehicles_count": -1}, "'vehicles_count' must be a whole number >= 0"),
])
def test_the_wrapper_refuses_a_bad_config_when_it_is_built(config, words):
    env = gym.make("exit-v0")
    env.unwrapped.configure(config)  # highway-env takes it unchecked (and would divide by zero, or never end)
    with pytest.raises(ConfigError, match="^Guardian: exit-v0: ") as err:
        Guardian(env)
    assert words in str(err.value)


def test_the_wrapper_refuses_several_cars_where_the_env_spawns_one():
    multi = {"type": "MultiAgentAction", "action_config": {"type": "DiscreteMetaAction"}}
    with pytest.raises(ConfigError, match="merge-v0 has one controlled car.*guardian/Merge-v0"):
        Guardian(gym.make("merge-v0", config={"controlled_vehicles": 2, "action": multi}))
    env = gym.make("exit-v0", config={"controlled_vehicles": 2, "action": multi})
    wrapped = Guardian(env)
    env.unwrapped.controlled_vehicles.pop()  # an env that spawned fewer cars than asked: refused, not guarded in part
    env.unwrapped.action_type.agents_action_types.pop()
    with pytest.raises(ConfigError, match="'controlled_vehicles' is 2, but the env spawned 1 controlled car"):
        wrapped._attach(env.unwrapped)


def test_the_rollout_keeps_the_cars_from_behind_it_was_given():
    """--traffic 12 --env-config traffic_from_behind=6 once ran with 2 from behind (the default's cap)."""
    from guardian.evaluation.rollouts import Rollout, highway_env_config

    env = "guardian/HighwayOvertake-v0"
    config = highway_env_config(Rollout(env, "", traffic=12, env_config={"traffic_from_behind": 6, "lanes_count": 3}))
    assert config["traffic_from_behind"] == 6 and config["traffic_count"] == 12
    assert highway_env_config(Rollout(env, "", traffic=1))["traffic_from_behind"] == 1


@pytest.mark.parametrize("env_id, extra, key", [
    ("guardian/HighwayOvertake-v0", {"intention": "aggressive"}, "intention"),
    ("guardian/Overtake-v0", {"disturbance": "adversarial"}, "disturbance"),
    ("highway-v0", {"vehicles_count": 5}, "vehicles_count")])
def test_a_key_the_rollout_sets_is_not_also_taken_from_the_config(env_id, extra, key):
    from guardian.evaluation.rollouts import Rollout, highway_env_config

    with pytest.raises(ValueError, match=f"'{key}' is set by"):
        highway_env_config(Rollout(env_id, "", traffic=3 if key == "vehicles_count" else None, env_config=extra))


@pytest.mark.parametrize("env_id, action, config, name", [
    ("highway-v0", None, {}, "meta"), ("guardian/HighwayOvertake-v0", None, {}, "continuous"),
    ("exit-v0", None, {"action": {"type": "DiscreteAction"}}, "discrete"), ("exit-v0", "continuous", {}, "continuous"),
    ("highway-v0", None, {"action": {"type": "MultiAgentAction", "action_config": {"type": "ContinuousAction"}}},
     "continuous")])
def test_the_action_reported_is_the_one_that_ran(env_id, action, config, name):
    from guardian.cli.rollout import action_name

    assert action_name(env_id, action, config) == name


def test_a_library_built_on_first_use_is_announced_with_its_time_and_how_to_build_ahead(library, cache_dir,
                                                                                         tmp_path, monkeypatch):
    """The notice reads only file names: "" where the cache holds the sets, one line naming the time and the
    command that builds them ahead where it does not."""
    from guardian.adapters.highway_env.supervision import first_use_notice
    from intention.params import OvertakeParams

    monkeypatch.setenv("GUARDIAN_CACHE_DIR", str(cache_dir))
    assert first_use_notice(OvertakeParams()) == ""          # the session's library is there
    monkeypatch.setenv("GUARDIAN_CACHE_DIR", str(tmp_path))
    notice = first_use_notice(OvertakeParams.among_traffic())
    assert "about 3.5 minutes" in notice and notice.endswith("guardian rcis build --ego-speed-min 0")
    assert str(tmp_path) in notice
    assert first_use_notice(OvertakeParams()).endswith("To build them ahead: guardian rcis build")
