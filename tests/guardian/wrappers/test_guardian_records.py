"""Honest records: every override has a reason and every reason an override; the meta action reported is
the one executed over the whole policy step; clips to the guardian's modelling bounds are not counted as
safety overrides."""
import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np
import pytest

import envs  # noqa: F401
from envs.agents import make_agent
from guardian import Guardian
from guardian.evaluation.rollouts import OVERTAKE_ENV

SHORT = {"vehicles_count": 20, "duration": 15, "policy_frequency": 5}  # 75 policy steps of 3 simulation steps
MODEL_CLIPS = ("clipped at the model's top speed", "clipped to the model's bound")


def _episodes(env, agents, episodes, seed=0):
    """Yield ``(proposed action, info)`` for every step of ``episodes`` episodes per agent."""
    for agent in agents:
        for ep in range(episodes):
            obs, _ = env.reset(seed=seed + ep)
            act = make_agent(agent, env, np.random.default_rng([seed, ep]))
            done = False
            while not done:
                action = act(obs)
                obs, _, terminated, truncated, info = env.step(action)
                yield action, info
                done = terminated or truncated


@pytest.mark.parametrize("env_id,config,agents,episodes", [
    ("highway-v0", {"action": {"type": "DiscreteMetaAction"}, **SHORT}, ("random", "reckless", "trap"), 1),
    ("highway-v0", {"action": {"type": "ContinuousAction"}, **SHORT}, ("random", "reckless", "trap"), 1),
    ("highway-fast-v0", {"action": {"type": "DiscreteAction"}, "duration": 25}, ("random", "reckless", "trap"), 3),
    (OVERTAKE_ENV, {"duration": 10}, ("random", "reckless"), 2),
    (OVERTAKE_ENV, {"duration": 10, "action": {"type": "DiscreteMetaAction"}}, ("random", "reckless"), 2),
], ids=["highway meta", "highway continuous", "highway-fast discrete", "overtake continuous", "overtake meta"])
def test_every_override_has_a_reason_and_every_reason_an_override(traffic_library, env_id, config, agents, episodes):
    env = Guardian(gym.make(env_id, config=config), traffic_library if env_id == OVERTAKE_ENV else None)
    steps = overridden = 0
    for _, info in _episodes(env, agents, episodes):
        g = info["guardian"]
        assert g["overridden"] == bool(g["reasons"]), g
        assert not g["safety_override"] or g["overridden"]
        steps += 1
        overridden += g["overridden"]
    assert steps >= 200 and 0 < overridden < steps  # the check saw both kinds of step


@pytest.mark.parametrize("env_id,library", [("highway-v0", False), (OVERTAKE_ENV, True)])
def test_the_meta_action_reported_is_the_one_executed_over_the_policy_step(traffic_library, env_id, library):
    """``applied`` is ``applied_action``'s name; a step whose acceleration the guardian lowered (at any of
    its simulation steps) was executed as SLOWER, a refused lane change as IDLE; otherwise the proposal."""
    config = {"action": {"type": "DiscreteMetaAction"}, **(SHORT if env_id == "highway-v0" else {"duration": 15})}
    env = Guardian(gym.make(env_id, config=config), traffic_library if library else None)
    names = env.unwrapped.action_type.actions
    kinds = set()
    for action, info in _episodes(env, ("reckless", "random"), 2):
        g = info["guardian"]
        assert g["applied"] == names[g["applied_action"]] and g["proposed"] == names[int(action)]
        ds = env.cars[0].decisions  # the simulation steps of this policy step
        lowered = any(d.applied[0] < d.proposed[0] - 1e-9 and not d.clipped_to_model for d in ds)
        refused = g["refused_lane_change"]
        expected = "SLOWER" if lowered else "IDLE" if refused else g["proposed"]
        assert g["applied"] == expected, g
        if lowered and not any(d.applied[0] < d.proposed[0] - 1e-9 for d in ds[-1:]):
            kinds.add("lowered before the last simulation step")
        kinds.add("slower" if lowered else "idle" if refused else "as proposed")
    assert {"slower", "as proposed"} <= kinds


def test_clips_to_the_models_top_speed_are_not_safety_overrides():
    """An agent that always asks FASTER with target speeds up to 45 m/s on an empty road: highway-env's
    top speed is the guardian's v_max (40 m/s); every change is a clip to the model, none is for safety."""
    config = {"vehicles_count": 0, "action": {"type": "DiscreteMetaAction", "target_speeds": [20, 30, 40, 45]}}
    env = Guardian(gym.make("highway-fast-v0", config=config))
    faster = env.unwrapped.action_type.actions_indexes["FASTER"]
    env.reset(seed=0)
    clips = 0
    for _ in range(30):
        _, reward, _, _, info = env.step(faster)
        g = info["guardian"]
        assert not g["safety_override"] and "penalty" not in g
        assert all(any(k in r for k in MODEL_CLIPS) for r in g["reasons"]), g["reasons"]
        clips += g["model_clip_steps"]
    assert clips > 100 and env.unwrapped.vehicle.speed == pytest.approx(40.0, abs=1e-6)


def test_with_traffic_every_safety_override_names_a_safety_reason():
    """Target speeds up to 40 m/s among traffic: a step counted as a safety override has a reason other
    than a clip to the model's bounds (the issue: top-speed clips were counted as overrides)."""
    config = {"action": {"type": "DiscreteMetaAction", "target_speeds": [20, 25, 30, 35, 40]}, "duration": 20}
    env = Guardian(gym.make("highway-fast-v0", config=config))
    faster = env.unwrapped.action_type.actions_indexes["FASTER"]
    safety = model = 0
    for ep in range(3):
        env.reset(seed=ep)
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(faster)
            g = info["guardian"]
            if g["safety_override"]:
                assert any(not any(k in r for k in MODEL_CLIPS) for r in g["reasons"]), g["reasons"]
            safety += g["safety_override"]
            model += g["model_clip_steps"]
            done = terminated or truncated
    assert safety > 0 and model > 0


def _watch_inputs(env) -> list:
    """The inputs the ego integrates at each simulation step (after highway-env's own clip), read from the
    vehicle itself, not from the guardian's decisions."""
    ego, seen = env.unwrapped.vehicle, []
    original = ego.step

    def step(dt):
        original(dt)
        seen.append((float(ego.action["acceleration"]), float(ego.action["steering"])))
    ego.step = step
    return seen


@pytest.mark.parametrize("action", ["ContinuousAction", "DiscreteMetaAction", "DiscreteAction"])
def test_applied_mean_and_range_cover_every_simulation_step_of_the_policy_step(action):
    """highway-v0 runs 15 simulation steps per policy step: ``applied_mean`` and ``applied_range`` are the
    mean and range of what the vehicle integrated over all of them (not the last one), and a continuous
    ``applied_action`` is that mean in the action's [-1, 1] coordinates."""
    env = Guardian(gym.make("highway-v0", config={"action": {"type": action}, **SHORT, "policy_frequency": 1}))
    at = env.unwrapped.action_type
    spread = 0
    for ep in range(2):
        obs, _ = env.reset(seed=ep)
        act = make_agent("reckless", env, np.random.default_rng(ep))
        done = False
        while not done:
            seen = _watch_inputs(env)
            obs, _, terminated, truncated, info = env.step(act(obs))
            done = terminated or truncated
            if env.unwrapped.vehicle.crashed:
                continue  # highway-env brakes a crashed car itself
            g, inputs = info["guardian"], np.array(seen)
            assert len(inputs) == g["sim_steps"] == 15
            assert np.allclose(g["applied_mean"], inputs.mean(axis=0), atol=1e-9)
            assert np.allclose(g["applied_range"], np.c_[inputs.min(axis=0), inputs.max(axis=0)], atol=1e-9)
            spread += int(np.ptp(inputs[:, 0]) > 1e-6)
            if action == "ContinuousAction":
                unit = [2 * (m - lo) / (hi - lo) - 1 for m, (lo, hi) in
                        zip(inputs.mean(axis=0), (at.acceleration_range, at.steering_range))]
                assert np.allclose(g["applied_action"], np.clip(unit, -1, 1), atol=1e-6)
    assert spread > 0  # steps whose input changed within the policy step were among those checked


def test_a_lane_reached_between_two_decisions_without_an_entry_is_not_allowed():
    """The record's ``lanes`` (what ``unchecked_entries`` compares with) are the lanes held at the policy
    step's start and the lanes entered during it, not every decision's lanes: a later decision starts where
    the body already is."""
    from guardian.model.decision import Decision
    from guardian.wrappers.record import allowed_lanes

    start = Decision([0.0, 0.0], [0.0, 0.0], "none", lanes=[1])
    drifted = Decision([0.0, 0.0], [0.0, 0.0], "none", lanes=[1, 2])  # the body is over lane 2 now, unjudged
    assert allowed_lanes([start, drifted]) == [1]
    entering = Decision([0.0, 0.0], [0.0, 0.0], "none", entered=[2], lanes=[1, 2])
    assert allowed_lanes([start, entering, drifted]) == [1, 2]
    assert allowed_lanes([]) == []
