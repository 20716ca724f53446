"""The ITHA guardian on highway-env: refuses irresponsible lane changes, bounds acceleration, reports in info."""
import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np
import pytest

from envs.highway_guard import HighwayGuardianWrapper, collision_fault, highway_rollouts

SMALL = {"vehicles_count": 20, "duration": 12}


def _env():
    return HighwayGuardianWrapper(gym.make("highway-v0", config=SMALL))


def test_info_reports_what_the_guardian_did():
    env = _env()
    env.reset(seed=3)
    _, _, _, _, info = env.step(env.unwrapped.action_type.actions_indexes["LANE_LEFT"])
    g = info["guardian"]
    for key in ("proposed", "applied", "refused", "reason", "clipped_steps", "sim_steps", "overridden"):
        assert key in g
    assert g["sim_steps"] == env.unwrapped.config["simulation_frequency"]
    assert g["refused"] == (g["applied"] != g["proposed"])
    if g["refused"]:
        assert g["reason"]
    env.close()


def test_applied_acceleration_stays_in_the_input_bounds():
    env = _env()
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(10):
        _, _, term, trunc, info = env.step(int(rng.integers(5)))
        a = env.unwrapped.vehicle.action["acceleration"]
        assert -6.0 - 1e-9 <= a <= 6.0 + 1e-9
        if term or trunc:
            break
    env.close()


def test_guardian_prevents_at_fault_collisions_of_a_reckless_agent():
    guarded = highway_rollouts("highway-v0", "reckless", 4, seed=10, env_config=SMALL)
    assert guarded["ego_at_fault_collisions"] == 0
    assert guarded["override_steps"] > 0 and guarded["distance_mean"] > 100


def test_the_same_agent_crashes_without_the_guardian():
    free = highway_rollouts("highway-v0", "reckless", 4, seed=10, guardian=False, env_config=SMALL)
    assert free["collisions"] > 0 and free["override_steps"] == 0


def test_wrapper_needs_meta_actions():
    env = gym.make("highway-v0", config={"action": {"type": "ContinuousAction"}})
    with pytest.raises(ValueError, match="DiscreteMetaAction"):
        HighwayGuardianWrapper(env)


def test_unknown_agent_is_refused():
    with pytest.raises(ValueError, match="unknown agent"):
        highway_rollouts("highway-v0", "nobody", 1, 0)
