"""The guardian on highway-v0 (traffic part alone): refuses irresponsible lane changes, bounds
acceleration, reports in info — for meta and continuous agents."""
import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np
import pytest

from guardian.errors import ConfigError
from guardian.evaluation.rollouts import Rollout, highway_rollouts
from guardian.wrappers.guardian import Guardian

SMALL = {"vehicles_count": 20, "duration": 12}


def _env(action="DiscreteMetaAction"):
    return Guardian(gym.make("highway-v0", config={**SMALL, "action": {"type": action}}))


def test_info_reports_what_the_guardian_did():
    env = _env()
    env.reset(seed=3)
    _, _, _, _, info = env.step(env.unwrapped.action_type.actions_indexes["LANE_LEFT"])
    g = info["guardian"]
    for key in ("proposed", "applied", "overridden", "changed", "reasons", "refused_lane_change", "active_set",
                "valid_intentions", "sim_steps", "clipped_steps", "conflict_steps", "failsafe_steps",
                "model_violations", "admissible_acceleration"):
        assert key in g
    assert g["sim_steps"] == env.unwrapped.config["simulation_frequency"]
    assert g["active_set"] == "itha" and g["valid_intentions"] == []
    assert g["refused_lane_change"] == (g["applied"] != g["proposed"])
    if g["refused_lane_change"]:
        assert g["reasons"]
    env.close()


@pytest.mark.parametrize("action", ["DiscreteMetaAction", "ContinuousAction"])
def test_applied_inputs_stay_in_the_input_bounds(action):
    env = _env(action)
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    steer_max = np.pi / 4 if action == "ContinuousAction" else np.pi / 3
    for _ in range(10):
        a = int(rng.integers(5)) if action == "DiscreteMetaAction" else rng.uniform(-1, 1, 2)
        _, _, term, trunc, info = env.step(a)
        applied = env.unwrapped.vehicle.action
        assert -6.0 - 1e-9 <= applied["acceleration"] <= 6.0 + 1e-9
        assert abs(applied["steering"]) <= steer_max + 1e-9
        if term or trunc:
            break
    env.close()


@pytest.mark.parametrize("action", ["meta", "continuous"])
def test_guardian_prevents_at_fault_collisions_of_a_reckless_agent(action):
    guarded = highway_rollouts(Rollout("highway-v0", "reckless", action=action, env_config=SMALL), 3, 10)
    assert guarded["ego_at_fault_collisions"] == 0 and guarded["collisions"] == 0
    assert guarded["override_steps"] > 0 and guarded["distance_mean"] > 100
    assert guarded["model_violation_steps"] == 0


def test_the_same_agent_crashes_without_the_guardian():
    free = highway_rollouts(Rollout("highway-v0", "reckless", action="meta", guarded=False, env_config=SMALL), 4, 10)
    assert free["collisions"] > 0 and free["override_steps"] == 0


def test_continuous_steering_into_an_occupied_lane_is_refused():
    """A continuous agent steering hard left with a car alongside in the left lane: the body stays out."""
    env = _env("ContinuousAction")
    env.reset(seed=0)
    base = env.unwrapped
    ego = base.vehicle
    lane = ego.lane_index[2]
    if lane == 0:  # need a lane on the left
        pytest.skip("ego starts in the leftmost lane for this seed")
    other = next(v for v in base.road.vehicles if v is not ego)
    other.position = np.array([ego.position[0] + 1.0, (lane - 1) * 4.0])
    other.speed = ego.speed
    other.lane_index = other.target_lane_index = ("0", "1", lane - 1)
    _, _, _, _, info = env.step(np.array([0.0, -1.0]))
    g = info["guardian"]
    assert g["refused_lane_change"] and any("refused" in r for r in g["reasons"])
    half = env.guard.kin.half_extent(float(ego.heading))
    assert ego.position[1] - half >= (lane - 0.5) * 4.0 - 1e-9  # never crossed into the left lane
    env.close()


def test_unknown_agent_is_refused():
    with pytest.raises(ValueError, match="unknown agent"):
        highway_rollouts(Rollout("highway-v0", "nobody"), 1, 0)


@pytest.mark.parametrize("env_id,config,match", [
    ("highway-v0", {"action": {"type": "MultiAgentAction", "action_config": {"type": "DiscreteMetaAction",
                                                                           "lateral": False}}}, "five meta actions"),
    ("highway-v0", {"action": {"type": "DiscreteMetaAction", "lateral": False}}, "five meta actions"),
    ("highway-v0", {"action": {"type": "ContinuousAction", "dynamical": True}}, "'action.dynamical' true"),
    ("roundabout-v0", {}, "cannot reason about this env's road: lane .* runs against the direction of travel"),
    ("two-way-v0", {}, "cannot reason about this env's road"),
    ("parking-v0", {}, "cannot reason about this env's road: no lane runs straight along"),
    ("lane-keeping-v0", {}, "'action.dynamical' true"),
])
def test_configs_it_cannot_supervise_are_refused(env_id, config, match):
    with pytest.raises(ConfigError, match=match):
        Guardian(gym.make(env_id, config=config))


def test_a_non_highway_env_is_refused():
    with pytest.raises(ConfigError, match="not a highway-env environment"):
        Guardian(gym.make("CartPole-v1"))


# ---- supervision is never lost silently -------------------------------------------------------------
def _supervised(info, base):
    g = info["guardian"]
    return g["unsupervised_steps"] == 0 and g["sim_steps"] == base.config["simulation_frequency"] // \
        base.config["policy_frequency"]


def test_an_inner_autoreset_is_followed_and_said():
    env = Guardian(gym.wrappers.Autoreset(gym.make("highway-fast-v0", config={"duration": 2})))
    env.reset(seed=0)
    base = env.unwrapped
    saw_reset = False
    for _ in range(8):
        _, _, term, trunc, info = env.step(1)
        g = info["guardian"]
        if g["sim_steps"] == 0:  # the inner wrapper reset instead of stepping
            assert g["reattached"] and any("reset inside the step" in r for r in g["reasons"])
            saw_reset = True
        else:
            assert _supervised(info, base)
    assert saw_reset
    assert base.vehicle.__dict__["act"].guardian is env  # the new ego is supervised


def test_an_env_reset_before_wrapping_or_behind_the_guardians_back_is_attached():
    inner = gym.make("highway-fast-v0")
    inner.reset(seed=0)
    env = Guardian(inner)
    _, _, _, _, info = env.step(1)
    assert info["guardian"]["reattached"] and _supervised(info, env.unwrapped)
    env.unwrapped.reset(seed=1)  # a new ego, the guardian not told
    _, _, _, _, info = env.step(1)
    g = info["guardian"]
    assert g["reattached"] and any("behind the guardian's back" in r for r in g["reasons"])
    assert _supervised(info, env.unwrapped)


def test_configure_after_wrapping_takes_effect_at_reset():
    env = Guardian(gym.make("highway-fast-v0"))
    env.reset(seed=0)
    env.unwrapped.configure({"lanes_count": 6})
    env.reset(seed=0)
    assert env.guard.kin.n_lanes == 6 and env.road.n_lanes == 6
    _, _, _, _, info = env.step(1)
    assert _supervised(info, env.unwrapped) and not info["guardian"]["reattached"]


def test_a_start_inside_is_reported_and_unsafe_starts_can_be_drawn_again():
    """On three lanes at density 2.5 about one start in three lies inside (on one lane none does: every
    platoon has a tailgater ahead, and the cars behind it are at risk of a pile-up)."""
    dense = {"vehicles_density": 2.5, "policy_frequency": 1}
    env = Guardian(gym.make("highway-fast-v0", config=dense))
    starts = [env.reset(seed=s)[1]["guardian"]["start_inside"] for s in range(15)]
    assert not all(starts)
    for s in range(5):
        _, info = env.reset(seed=s, options={"safe_start": True})
        assert info["guardian"]["start_inside"]


@pytest.mark.parametrize("action", ["meta", "continuous"])
def test_dense_single_lane_traffic_never_makes_the_ego_reverse(action):
    r = highway_rollouts(Rollout("highway-v0", "reckless", action=action,
                                 env_config={"lanes_count": 1, "vehicles_density": 2.5, "duration": 15}), 3, 0)
    assert r["reversing_steps"] == 0 and r["ego_at_fault_collisions"] == 0
