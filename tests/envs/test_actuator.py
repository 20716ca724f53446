"""The jerk-limited world (``envs.actuator.JerkLimit``) and the guardian in it: the actuator follows the rate
limit, stops the car at 0 and counts what it could not follow; the guardian asks only for what it reaches and
keeps its promise with the brake-checking and seeking drivers; what does not apply is refused."""
import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np
import pytest

import envs  # noqa: F401
from envs.actuator import Actuated, JerkLimit
from guardian.errors import ConfigError
from guardian.evaluation.rollouts import Rollout, highway_rollouts
from guardian.wrappers.guardian import Guardian
from itha.actuator import Actuator

FAST = {"action": {"type": "ContinuousAction"}}


def test_the_actuator_follows_the_rate_limit_counts_its_clips_and_never_reverses():
    env = JerkLimit(gym.make("highway-fast-v0", config=dict(FAST, vehicles_count=0)), jerk=5.0)
    obs, info = env.reset(seed=0)
    ego = env.unwrapped.vehicle
    dt = 1 / env.unwrapped.config["simulation_frequency"]
    per_policy = env.unwrapped.config["simulation_frequency"] // env.unwrapped.config["policy_frequency"]
    assert info["actuator"] == {"jerk": 5.0, "lag": 0.0, "clipped_steps": 0}
    speeds, accels, clips = [ego.speed], [ego.applied_acceleration], []
    for k in range(40):
        _, _, term, trunc, info = env.step(np.array([-1.0, 0.0]))   # full braking, asked at once
        speeds.append(ego.speed)
        accels.append(ego.applied_acceleration)
        clips.append(info["actuator"]["clipped_steps"])
        if term or trunc:
            break
    # 1 m/s^2 a simulation step from 0 to -5: the first four steps could not follow the command, then none
    assert 5.0 * dt == 1.0 and clips[:3] == [4, 0, 0] and sum(clips) == 4
    steps = np.diff(accels)
    assert np.all(np.abs(steps) <= 5.0 * dt * per_policy + 1e-9)
    assert min(speeds) >= 0.0 and speeds[-1] == 0.0
    assert accels[1] == pytest.approx(-5.0 * dt * per_policy)   # a ramp, not a jump


def test_under_a_lag_the_acceleration_goes_part_of_the_way_each_step_and_no_lag_is_a_clip():
    tau = 0.5
    env = Actuated(gym.make("highway-fast-v0", config=dict(FAST, vehicles_count=0)), Actuator(lag=tau, profile="hold"))
    _, info = env.reset(seed=0)
    ego = env.unwrapped.vehicle
    config = env.unwrapped.config
    dt, per_policy = 1 / config["simulation_frequency"], config["simulation_frequency"] // config["policy_frequency"]
    assert info["actuator"] == {"jerk": None, "lag": tau, "clipped_steps": 0}
    _, _, _, _, info = env.step(np.array([-1.0, 0.0]))   # full braking asked: -5 m/s^2 on highway-env's scale
    assert ego.applied_acceleration == pytest.approx(-5.0 * (1 - np.exp(-per_policy * dt / tau)), abs=1e-12)
    assert info["actuator"]["clipped_steps"] == 0


@pytest.mark.parametrize("make,why", [
    (lambda: JerkLimit(gym.make("guardian/Overtake-v0"), 5.0), "overtake"),
    (lambda: JerkLimit(Guardian(gym.make("highway-fast-v0")), 5.0), "before the guardian"),
    (lambda: JerkLimit(gym.make("highway-fast-v0"), 0.0), "positive finite"),
    (lambda: JerkLimit(gym.make("highway-fast-v0"), float("inf")), "positive finite"),
    (lambda: Actuated(gym.make("highway-fast-v0"), Actuator(profile="hold")), "limits nothing"),
    (lambda: Actuated(gym.make("highway-fast-v0"), Actuator(jerk=5.0)), "hold"),
    (lambda: Actuated(gym.make("highway-fast-v0"), Actuator(jerk=5.0, delay=1, profile="hold")), "without a delay"),
    (lambda: Actuated(gym.make("highway-fast-v0"), 0.5), "itha.actuator.Actuator"),
])
def test_what_does_not_apply_is_refused(make, why):
    with pytest.raises(ConfigError, match=why):
        make()


@pytest.mark.parametrize("agent,action,jerk,lag", [("brake_check", "continuous", 5.0, None),
                                                   ("seek", "meta", 5.0, None),
                                                   ("brake_check", "continuous", None, 0.5),
                                                   ("seek", "continuous", 10.0, 0.3)])
def test_the_guarded_car_asks_only_for_what_the_actuator_reaches_and_causes_no_crash(agent, action, jerk, lag):
    r = highway_rollouts(Rollout("highway-fast-v0", agent, action=action, jerk=jerk, lag=lag), 4, seed=3)
    assert r["actuator_clipped_steps"] == 0
    assert r["ego_at_fault_collisions"] == 0 and r["unchecked_entries"] == 0 and r["reversing_steps"] == 0
    assert r["model_violation_steps"] == 0


def test_unguarded_the_actuator_clips_and_counts():
    r = highway_rollouts(Rollout("highway-fast-v0", "reckless", action="continuous", guarded=False, jerk=5.0), 1,
                         seed=0)
    assert r["actuator_clipped_steps"] > 0
