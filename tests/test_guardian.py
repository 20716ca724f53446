"""The intention-aware guardian, the overtake environment and the wrapper."""
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs  # noqa: F401  (registers guardian/Overtake-v0)
from envs.agents import make_agent
from envs.overtake import OvertakeEnv
from envs.wrappers import OvertakeGuardianWrapper
from guardian.rollout import overtake_rollouts
from guardian.supervisor import FAILSAFE_INPUT, IntentionAwareGuardian


def test_environment_passes_the_gymnasium_checker():
    check_env(gym.make("guardian/Overtake-v0").unwrapped, skip_render_check=True)


def test_environment_refuses_actions_outside_the_bounds():
    env = OvertakeEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="outside U_e"):
        env.step([3.5, 0.0])
    with pytest.raises(ValueError, match="finite"):
        env.step([np.nan, 0.0])
    with pytest.raises(ValueError, match="unknown config"):
        OvertakeEnv({"intentoin": "cautious"})


@pytest.mark.parametrize("intention", ["aggressive", "cautious"])
@pytest.mark.parametrize("disturbance", ["random", "adversarial"])
def test_supervised_random_driver_never_leaves_the_invariant_set(library, intention, disturbance):
    """Theorem 4 as a falsifier: random inputs, random or adversarial leads, 8 x 150 steps."""
    env = OvertakeEnv({"intention": intention, "disturbance": disturbance, "max_steps": 150,
                       "initial_region": library.region("bounded_velocity")})
    guard = IntentionAwareGuardian(library)
    env = OvertakeGuardianWrapper(env, guard)
    for ep in range(8):
        obs, _ = env.reset(seed=100 + ep)
        driver = make_agent("random", env, np.random.default_rng(ep))
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(driver(obs))
            g = info["guardian"]
            assert not info["unsafe"], obs
            assert g["in_invariant_set"] and not g["failsafe"]
            assert -3 <= g["applied"][0] <= 3 and -1.8 <= g["applied"][1] <= 1.8
            assert intention in g["valid_intentions"]
            done = terminated or truncated


def test_without_the_guardian_the_bad_driver_crashes(library):
    r = overtake_rollouts(library, "cautious", "bad", 6, seed=0, guardian=False)
    assert r["safety_violations"] >= 4


def test_intention_awareness_overrides_less_on_the_same_seeds(library):
    aware = overtake_rollouts(library, "cautious", "mpc", 5, seed=3)
    pinned = overtake_rollouts(library, "cautious", "mpc", 5, seed=3, use_intention=False)
    assert aware["safety_violations"] == pinned["safety_violations"] == 0
    assert aware["override_steps"] < pinned["override_steps"]
    assert aware["identified_fraction"] == 1.0 and aware["wrong_identifications"] == 0


def test_no_intention_pins_the_bounded_velocity_set(library):
    guard = IntentionAwareGuardian(library, use_intention=False)
    x = np.array([25.0, 0.0, 40.0, 20.0])
    for _ in range(30):
        _, rec = guard.step(x, [0.0, 0.0])
        assert rec.active_set == "bounded_velocity"
        x = library.models["cautious"].system.step(x, rec.applied, np.zeros(4))


def test_outside_every_invariant_set_the_guardian_flags_and_fails_safe(library):
    guard = IntentionAwareGuardian(library)
    x = np.array([30.0, -0.5, 10.5, 5.0])  # 10.5 m behind a slow lead in the right lane
    assert not library.region("bounded_velocity").contains(x)
    applied, rec = guard.step(x, [3.0, 0.0])
    assert not rec.in_invariant_set and rec.overridden and rec.failsafe == (rec.changed == "failsafe")
    if rec.admissible:
        assert library.admissible("bounded_velocity").is_admissible(x, applied)
    else:
        assert rec.changed == "failsafe" and tuple(applied) == FAILSAFE_INPUT


def test_guardian_refuses_malformed_input(library):
    guard = IntentionAwareGuardian(library)
    with pytest.raises(ValueError, match="driver input"):
        guard.step([25, 0, 40, 20], [0.0])
    with pytest.raises(ValueError, match="state"):
        guard.step([25, np.inf, 40, 20], [0.0, 0.0])


def test_rerun_recording_has_the_scene_and_the_overrides(library, tmp_path):
    from guardian.rerun_log import read_entities, read_texts

    path = tmp_path / "run.rrd"
    r = overtake_rollouts(library, "cautious", "bad", 2, seed=0, max_steps=80, rerun_path=path)
    counts = read_entities(path)
    for entity in ("/road/lanes", "/road/ego", "/road/lead", "/inputs/proposed/throttle",
                   "/inputs/applied/steering", "/admissible/throttle/low", "/intention/valid_count"):
        assert entity in counts, entity
    assert counts["/road/ego"] == r["steps"]
    overrides = read_texts(path, "/events/override")
    assert len(overrides) == r["override_steps"] > 0
    assert any("cautious" in t for t in read_texts(path, "/intention/log"))
    from rerun.chunk import RrdReader
    assert len(list(RrdReader(str(path)).blueprints())) == 1  # opens on the road, inputs and events
