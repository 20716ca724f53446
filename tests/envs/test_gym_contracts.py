"""gymnasium's contracts on every guarded env, checked with gymnasium's and stable-baselines3's own tools:
``check_env``, ``env.spec`` through ``gym.make``, ``pickle`` and ``copy.deepcopy``, sync and async vector
envs (every start method), ``make_vec_env(..., wrapper_class=Guardian)``. After each, the steps are
still supervised: the record says every simulation step was seen by the guardian."""
import copy
import multiprocessing
import pickle
import warnings

import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs  # noqa: F401
from guardian import Guardian, GuardianConfig

OVERTAKE, TWO_CARS = "guardian/HighwayOvertake-v0", "guardian/Overtake-v0"
HIGHWAY_CASES = [
    ("highway-v0", {"action": {"type": "DiscreteMetaAction"}}),
    ("highway-v0", {"action": {"type": "ContinuousAction"}}),
    ("highway-fast-v0", {"action": {"type": "DiscreteMetaAction"}}),
    ("highway-fast-v0", {"action": {"type": "ContinuousAction"}}),
    ("highway-fast-v0", {"action": {"type": "DiscreteAction"}}),
    ("highway-fast-v0", {"action": {"type": "ContinuousAction", "lateral": False}}),
    ("highway-fast-v0", {"action": {"type": "ContinuousAction", "longitudinal": False}}),
]
OVERTAKE_CASES = [(OVERTAKE, {}), (OVERTAKE, {"action": {"type": "DiscreteMetaAction"}}), (TWO_CARS, {}),
                  (OVERTAKE, {"action": {"type": "DiscreteAction"}}),
                  (OVERTAKE, {"action": {"type": "ContinuousAction", "lateral": False}})]
# what highway-env's own envs warn about under check_env too (and any wrapper draws the first)
KNOWN_WARNINGS = ("is different from the unwrapped version", "observation space minimum value is -infinity",
                  "observation space maximum value is infinity")


def _case_id(case):
    env_id, config = case
    action = config.get("action", {})
    axes = "".join(f" {k}=False" for k in ("longitudinal", "lateral") if action.get(k) is False)
    return f"{env_id} {action.get('type', 'default')}{axes}"


def _guarded(env_id, env_config, libraries, **kw):
    library = libraries.get(env_id)
    return Guardian(gym.make(env_id, config=env_config), library, **kw)


@pytest.fixture(scope="module")
def libraries(library, traffic_library):
    return {OVERTAKE: traffic_library, TWO_CARS: library}


def _per_policy_step(env) -> int:
    c = env.unwrapped.config
    return c["simulation_frequency"] // c["policy_frequency"]


def _assert_supervised(info, env):
    g = info["guardian"]
    assert g["sim_steps"] == _per_policy_step(env) and g["unsupervised_steps"] == 0 and not g["reattached"], g


@pytest.mark.parametrize("case", HIGHWAY_CASES + OVERTAKE_CASES, ids=_case_id)
def test_check_env_passes_on_every_guarded_env(case, libraries):
    env = _guarded(*case, libraries)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env, skip_render_check=True)
    unexpected = [str(w.message) for w in caught if not any(k in str(w.message) for k in KNOWN_WARNINGS)]
    assert not unexpected  # the passive checker's findings (an obs outside its space, ...) are warnings
    env.close()


@pytest.mark.parametrize("case", HIGHWAY_CASES[2:3] + HIGHWAY_CASES[3:4] + OVERTAKE_CASES[:1], ids=_case_id)
def test_the_spec_round_trips_through_gym_make_and_keeps_supervising(case, libraries):
    env = _guarded(*case, libraries, config=GuardianConfig(override_penalty=0.5, h_min=3.0))
    wrapper = env.spec.additional_wrappers[-1]
    assert wrapper.name == "Guardian" and wrapper.entry_point == "guardian.wrappers.guardian:Guardian"
    made = gym.make(env.spec)
    assert isinstance(made, Guardian) and made.spec == env.spec
    assert made.config == env.config and made.library is env.library
    assert made.unwrapped.config == env.unwrapped.config
    made.reset(seed=0)
    _, _, _, _, info = made.step(made.action_space.sample())
    _assert_supervised(info, made)
    assert made.unwrapped.vehicle.__dict__["act"].guardian is made


@pytest.mark.parametrize("case", HIGHWAY_CASES[2:5] + OVERTAKE_CASES, ids=_case_id)
def test_pickle_and_deepcopy_round_trip_and_the_copy_supervises_itself(case, libraries):
    """A copy taken mid-episode continues exactly as the original (same observations, rewards and
    decisions for the same actions), its ego hooked to the copy, the original's to the original."""
    env = _guarded(*case, libraries)
    env.reset(seed=3)
    for _ in range(2):
        env.step(env.action_space.sample())
    twins = {"pickle": pickle.loads(pickle.dumps(env)), "deepcopy": copy.deepcopy(env)}
    for how, twin in twins.items():
        assert twin.unwrapped.vehicle.__dict__["act"].guardian is twin, how
        assert twin.unwrapped.vehicle is not env.unwrapped.vehicle, how
    assert env.unwrapped.vehicle.__dict__["act"].guardian is env
    for _ in range(6):
        a = env.action_space.sample()
        o1, r1, t1, u1, i1 = env.step(a)
        _assert_supervised(i1, env)
        for how, twin in twins.items():
            o2, r2, t2, u2, i2 = twin.step(a)
            _assert_supervised(i2, twin)
            assert np.array_equal(o1, o2) and r1 == r2 and (t1, u1) == (t2, u2), how
            for key in ("applied_action", "applied_mean", "overridden", "reasons", "level", "active_set",
                        "valid_intentions"):
                assert i1["guardian"][key] == i2["guardian"][key], (how, key)
        if t1 or u1:
            break


def _make(env_id, config, library=None, guardian_config=None):
    def make():
        import highway_env  # noqa: F401, F811 - a spawned process registers the envs itself

        return Guardian(gym.make(env_id, config=config), library, guardian_config)
    return make


def _check_vector_infos(infos, expected_sim_steps, n_envs):
    """Each sub-env's record: a supervised step, or the reset record of an autoreset."""
    g = infos["guardian"]
    seen = 0
    for i in range(n_envs):
        if g.get("_sim_steps", np.ones(n_envs, bool))[i] and "sim_steps" in g:
            assert g["sim_steps"][i] == expected_sim_steps and g["unsupervised_steps"][i] == 0
            assert g["reattached"][i] == False  # noqa: E712 - numpy bool
            seen += 1
        else:
            assert g["enabled"][i]  # the step reset this sub-env (next-step autoreset)
    return seen


@pytest.mark.parametrize("method", [None, "fork", "spawn", "forkserver"])
def test_vector_envs_keep_supervising_each_sub_env(method, libraries, cache_dir, monkeypatch):
    """Sync, and async with every start method; episodes short enough that sub-envs autoreset."""
    if method is not None and method not in multiprocessing.get_all_start_methods():
        pytest.skip(f"no {method} start method here")
    monkeypatch.setenv("GUARDIAN_CACHE_DIR", str(cache_dir))
    fns = [_make("highway-fast-v0", {"duration": 3}), _make("highway-fast-v0", {"duration": 4}),
           _make(OVERTAKE, {"duration": 1, "action": {"type": "DiscreteMetaAction"}}, libraries[OVERTAKE])]
    for group, sim_steps in ((fns[:2], 5), (fns[2:] * 2, 1)):
        vec = gym.vector.SyncVectorEnv(group) if method is None else gym.vector.AsyncVectorEnv(group, context=method)
        try:
            vec.reset(seed=0)
            seen = 0
            for _ in range(12):
                _, _, _, _, infos = vec.step(vec.action_space.sample())
                seen += _check_vector_infos(infos, sim_steps, len(group))
            assert seen >= len(group) * 8
        finally:
            vec.close()


@pytest.mark.parametrize("vec_env", ["DummyVecEnv", "SubprocVecEnv"])
def test_stable_baselines3_make_vec_env_with_the_guardian_as_wrapper_class(vec_env):
    from stable_baselines3.common import vec_env as sb3_vec
    from stable_baselines3.common.env_util import make_vec_env

    vec = make_vec_env("highway-fast-v0", n_envs=2, seed=0, env_kwargs={"config": {"duration": 3}},
                       wrapper_class=Guardian, wrapper_kwargs={"config": GuardianConfig(override_penalty=1.0)},
                       vec_env_cls=getattr(sb3_vec, vec_env))
    try:
        vec.reset()
        ends = 0
        for _ in range(8):
            _, _, dones, infos = vec.step(np.array([3, 3]))  # FASTER
            for info in infos:
                g = info["guardian"]
                assert g["sim_steps"] == 5 and g["unsupervised_steps"] == 0 and not g["reattached"]
                assert ("penalty" in g) == g["safety_override"]
            ends += int(dones.sum())
        assert ends >= 2  # episodes ended and the next ones are supervised too
    finally:
        vec.close()
