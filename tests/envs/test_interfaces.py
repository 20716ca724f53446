"""The declared interfaces: every implementation answers its Protocol."""
import gymnasium as gym
import pytest
import numpy as np

import envs  # noqa: F401 - registers the environments
from envs.agents import AGENTS, Agent, make_agent
from guardian.decide.lead import IntentionAwareGuardian, Supervisor
from itha.car_following import CarFollowingParams, CarFollowingSet, MaximalSet, load_or_build


def test_car_following_sets_agents_and_the_supervisor_answer_their_protocols(library, tmp_path):
    p = CarFollowingParams()
    assert isinstance(MaximalSet(p), CarFollowingSet)
    assert isinstance(load_or_build(p, cache_dir=tmp_path), CarFollowingSet)
    env = gym.make("guardian/HighwayOvertake-v0")
    env.reset(seed=0)
    assert all(isinstance(make_agent(name, env, np.random.default_rng(0)), Agent) for name in AGENTS)
    assert isinstance(IntentionAwareGuardian(library), Supervisor)
    assert not isinstance(object(), Supervisor)


def test_the_decision_objects_and_the_scenario_supervisions_answer_their_protocols(traffic_library):
    """Both decision objects answer ``DecisionObject``; both scenario families ``Supervision``; the wrapper
    holds one of each, whatever the environment."""
    import highway_env  # noqa: F401

    from guardian.adapters.highway_env.supervision import Supervision
    from guardian.decide.interface import DecisionObject
    from guardian.wrappers.guardian import Guardian

    for env_id, config in (("highway-fast-v0", {}), ("merge-v0", {}),
                           ("guardian/HighwayOvertake-v0", {"params": traffic_library.params})):
        env = Guardian(gym.make(env_id, config=config), traffic_library if "Overtake" in env_id else None)
        env.reset(seed=0)
        assert isinstance(env.supervision, Supervision) and isinstance(env.guard, DecisionObject), env_id
    assert not isinstance(object(), DecisionObject) and not isinstance(object(), Supervision)


def test_every_agent_acts_inside_the_action_space_of_every_env_it_drives():
    """One registry, one calling convention: each agent on the overtake envs and on highway-env (meta and
    continuous) returns actions of that space; the MPC drivers refuse highway-v0 and meta actions."""
    import highway_env  # noqa: F401

    from envs.mpc import STYLES

    envs_ = {"overtake": gym.make("guardian/Overtake-v0"),
             "highway_overtake": gym.make("guardian/HighwayOvertake-v0"),
             "overtake_meta": gym.make("guardian/HighwayOvertake-v0",
                                               config={"action": {"type": "DiscreteMetaAction"}}),
             "meta": gym.make("highway-fast-v0", config={"action": {"type": "DiscreteMetaAction"}}),
             "continuous": gym.make("highway-fast-v0", config={"action": {"type": "ContinuousAction"}})}
    for kind, env in envs_.items():
        for name in AGENTS:
            obs, _ = env.reset(seed=1)
            if name in STYLES and kind not in ("overtake", "highway_overtake"):
                with pytest.raises(ValueError, match="MPC drivers drive"):
                    make_agent(name, env, np.random.default_rng(0))
                continue
            agent = make_agent(name, env, np.random.default_rng(0))
            for _ in range(25):
                action = agent(obs)
                assert env.action_space.contains(action), (kind, name, action)
                obs, _, term, trunc, _ = env.step(action)
                if term or trunc:
                    obs, _ = env.reset(seed=2)


def test_the_line_agent_rides_a_lane_line():
    """``line`` puts the body's edge on the line beside its lane (the side drawn per episode) and keeps it
    there, at either policy frequency: the adversary for lanes that begin or close in under a body."""
    import highway_env  # noqa: F401

    for frequency in (1, 5):
        env = gym.make("highway-v0", config={"action": {"type": "ContinuousAction"}, "vehicles_count": 0,
                                             "policy_frequency": frequency})
        for seed in (0, 2):
            obs, _ = env.reset(seed=3)
            agent = make_agent("line", env, np.random.default_rng(seed))
            for _ in range(8 * frequency):
                obs, *_ = env.step(agent(obs))
            ego = env.unwrapped.vehicle
            centre = ego.lane.position(ego.lane.local_coordinates(ego.position)[0], 0)[1]
            edge = ego.position[1] + agent.side * ego.WIDTH / 2
            assert abs(edge - (centre + agent.side * ego.lane.width_at(0) / 2)) < 0.05
