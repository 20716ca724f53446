"""The two cars of Section 6.5: guardian/Overtake-v0 (HighwayOvertake with only what differs) under the
one Guardian, whose decisions there are IntentionAwareGuardian's."""
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs  # noqa: F401  (registers guardian/Overtake-v0)
from envs.agents import make_agent
from guardian.config import GuardianConfig
from guardian.evaluation.rollouts import TWO_CARS_ENV, Rollout, highway_env_config, highway_rollouts
from guardian.decide.lead import FAILSAFE_INPUT, IntentionAwareGuardian
from guardian.wrappers.guardian import Guardian


def _two_cars(library, intention="cautious", disturbance="random", **extra):
    spec = Rollout(TWO_CARS_ENV, "", intention=intention, disturbance=disturbance, library=library, env_config=extra)
    return gym.make(TWO_CARS_ENV, config=highway_env_config(spec))


def test_the_two_car_env_passes_the_gymnasium_checker_and_observes_the_state():
    env = gym.make(TWO_CARS_ENV)
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert np.array_equal(obs, env.unwrapped.overtake_state())
    assert env.unwrapped.config["traffic_count"] == 0 and env.unwrapped.params.v_ex_bounds == (16.0, 36.0)
    with pytest.raises(ValueError, match="unknown config"):
        gym.make(TWO_CARS_ENV, config={"intentoin": "cautious"})


@pytest.mark.parametrize("intention", ["aggressive", "cautious"])
@pytest.mark.parametrize("disturbance", ["random", "adversarial"])
def test_supervised_random_driver_never_leaves_the_invariant_set(library, intention, disturbance):
    """Theorem 4 as a falsifier: random inputs, random or adversarial leads, 6 x 150 steps."""
    env = Guardian(_two_cars(library, intention, disturbance, duration=15), library)
    for ep in range(6):
        obs, _ = env.reset(seed=100 + ep)
        driver = make_agent("random", env, np.random.default_rng(ep))
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(driver(obs))
            g = info["guardian"]
            assert not info["unsafe"], obs
            assert g["in_invariant_set"] and g["level"] == "composed"
            u = env.unwrapped.last_transition["input"]
            assert -3 <= u[0] <= 3 and -1.8 <= u[1] <= 1.8
            assert intention in g["valid_intentions"]
            assert g["overridden"] == bool(g["reasons"])  # every override says why
            done = terminated or truncated


def test_without_the_guardian_the_bad_driver_leaves_the_safe_set(library):
    r = highway_rollouts(Rollout(TWO_CARS_ENV, "bad", guarded=False, library=library, intention="cautious"), 6, 0)
    assert r["safety_violations"] >= 4


def test_intention_awareness_overrides_less_on_the_same_seeds(library):
    aware = highway_rollouts(Rollout(TWO_CARS_ENV, "mpc", library=library, intention="cautious"), 5, 3)
    pinned = highway_rollouts(Rollout(TWO_CARS_ENV, "mpc", library=library, intention="cautious",
                                      config=GuardianConfig(use_intention=False)), 5, 3)
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
    from guardian.recording.rerun import read_entities, read_texts

    path = tmp_path / "run.rrd"
    r = highway_rollouts(Rollout(TWO_CARS_ENV, "bad", library=library, intention="cautious",
                                 env_config={"duration": 8}), 2, 0, rerun_path=path)
    counts = read_entities(path)
    for entity in ("/road/lanes", "/road/ego", "/road/lead", "/inputs/proposed/throttle",
                   "/inputs/applied/steering", "/admissible/acceleration/low", "/admissible/steering/low",
                   "/intention/valid_count"):
        assert entity in counts, entity
    assert counts["/road/ego"] == r["steps"]
    overrides = read_texts(path, "/events/override")
    assert len(overrides) == r["override_steps"] > 0
    assert any("cautious" in t for t in read_texts(path, "/intention/log"))
    from rerun.chunk import RrdReader
    assert len(list(RrdReader(str(path)).blueprints())) == 1  # opens on the road, inputs and events
