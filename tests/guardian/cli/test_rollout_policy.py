"""``guardian rollout --policy PATH.zip``: a trained stable-baselines3 policy (tiny ones, saved in tmp) runs
under the guardian with the usual JSON; the algorithm is read from the file or named by ``--algo``;
``--env-config`` takes KEY=VALUE or a JSON object, and what the env or the policy cannot take is refused."""
import json

import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np
import pytest

from guardian.cli import main

FAST = "highway-fast-v0"
CONTINUOUS = '{"action": {"type": "ContinuousAction"}}'


@pytest.fixture(scope="module")
def policies(tmp_path_factory):
    """A DQN (meta actions) and a PPO (continuous actions) policy, each trained a few dozen steps."""
    import torch
    from stable_baselines3 import DQN, PPO

    torch.set_num_threads(1)
    tmp = tmp_path_factory.mktemp("policies")
    dqn = DQN("MlpPolicy", gym.make(FAST), learning_starts=20, buffer_size=500, seed=0, device="cpu")
    dqn.learn(total_timesteps=40)
    dqn.save(tmp / "dqn.zip")
    ppo = PPO("MlpPolicy", gym.make(FAST, config={"action": {"type": "ContinuousAction"}}), n_steps=16,
              batch_size=16, n_epochs=1, seed=0, device="cpu")
    ppo.learn(total_timesteps=16)
    ppo.save(tmp / "ppo.zip")
    return {"dqn": tmp / "dqn.zip", "ppo": tmp / "ppo.zip"}


def _rollout(capsys, *argv):
    code = main(["rollout", "--env", FAST, "--episodes", "2", "--seed", "5", "--json", *argv])
    captured = capsys.readouterr()
    return code, (json.loads(captured.out) if code == 0 else captured.err)


def test_a_trained_policy_runs_under_the_guardian_with_the_usual_json(policies, capsys):
    code, guarded = _rollout(capsys, "--policy", str(policies["dqn"]))
    assert code == 0, guarded
    assert guarded["agent"] == f"policy:{policies['dqn']}" and guarded["guardian"] is True
    assert {"episodes", "steps", "collisions", "ego_at_fault_collisions", "override_steps", "distance_mean",
            "crashes"} <= set(guarded)
    assert guarded["episodes"] == 2 and guarded["steps"] > 0 and guarded["ego_at_fault_collisions"] == 0
    assert guarded["unsupervised_steps"] == 0
    code, named = _rollout(capsys, "--policy", str(policies["dqn"]), "--algo", "DQN")
    assert code == 0 and named == guarded  # --algo names what the file says


def test_the_rollout_drives_with_the_policy_itself(policies, capsys):
    """Without the guardian, the CLI's figures are those of the policy's own deterministic actions on the
    same seeds (episode i reset with seed 5 + i)."""
    from stable_baselines3 import DQN

    code, free = _rollout(capsys, "--policy", str(policies["dqn"]), "--no-guardian")
    assert code == 0, free
    model = DQN.load(policies["dqn"], device="cpu")
    env = gym.make(FAST)
    steps, distance = 0, 0.0
    for ep in range(2):
        obs, _ = env.reset(seed=5 + ep)
        x0, done = float(env.unwrapped.vehicle.position[0]), False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, _ = env.step(int(action))
            steps, done = steps + 1, terminated or truncated
        distance += float(env.unwrapped.vehicle.position[0]) - x0
    assert free["steps"] == steps and free["distance_mean"] == pytest.approx(distance / 2)


def test_a_continuous_policy_with_the_algorithm_read_from_the_file(policies, capsys):
    code, out = _rollout(capsys, "--policy", str(policies["ppo"]), "--env-config", CONTINUOUS)
    assert code == 0, out
    assert out["steps"] > 0 and out["unsupervised_steps"] == 0 and out["ego_at_fault_collisions"] == 0


@pytest.mark.parametrize("argv,message", [
    (["--policy", "{dqn}", "--env-config", CONTINUOUS], "acts in"),  # a meta-action policy on continuous actions
    (["--policy", "{dqn}", "--env-config", '{"observation": {"type": "TimeToCollision"}}'], "observes"),
    (["--policy", "{dqn}", "--algo", "NOPE"], "no algorithm 'NOPE'"),
    (["--policy", "{missing}"], "no policy file"),
    (["--policy", "{dqn}", "--agent", "reckless"], "--policy replaces --agent"),
])
def test_what_the_policy_cannot_drive_is_refused_with_the_reason(policies, capsys, tmp_path, argv, message):
    paths = {"{dqn}": str(policies["dqn"]), "{missing}": str(tmp_path / "missing.zip")}
    code, err = _rollout(capsys, *[paths.get(a, a) for a in argv])
    assert code == 2 and message in err, err


def test_env_config_takes_pairs_and_json_objects_and_names_what_the_env_cannot_take(capsys):
    code, out = _rollout(capsys, "--agent", "idle", "--env-config", '{"lanes_count": 3, "duration": 6}',
                         "--env-config", "duration=4")
    assert code == 0 and out["steps"] == 2 * 4  # the later pair overrides the object's duration
    code, err = _rollout(capsys, "--env-config", '{"lanes_count": 3, "nonsense": 1}')
    assert code == 2 and "has no config key 'nonsense'" in err
    code, err = _rollout(capsys, "--env-config", "[1, 2]")
    assert code == 2 and "KEY=VALUE or a JSON object" in err
    code, err = _rollout(capsys, "--env-config", '{"lanes_count": 3,')
    assert code == 2 and "not a JSON object" in err
    # highway-env's own failure (its grayscale observation wants a tuple shape) is named, not a traceback
    grey = {"observation": {"type": "GrayscaleObservation", "observation_shape": [128, 64], "stack_size": 4,
                            "weights": [0.2989, 0.587, 0.114]}}
    code, err = _rollout(capsys, "--env-config", json.dumps(grey))
    assert code == 2 and "cannot be made with the config ['observation']" in err
    half = {"action": {"type": "MultiAgentAction",
                       "action_config": {"type": "DiscreteMetaAction", "longitudinal": False}}}
    code, err = _rollout(capsys, "--env-config", json.dumps(half))
    assert code == 2 and "config 'action' must offer all five meta actions" in err  # the guardian's refusal


def test_a_reckless_agent_on_a_one_lane_road_keeps_its_lane(capsys):
    """A config the guardian supports changes the road it supervises (lanes_count reaches the guardian)."""
    code, out = _rollout(capsys, "--agent", "reckless", "--env-config", "lanes_count=1", "--env-config", "duration=5")
    assert code == 0 and out["lane_changes"] == 0 and out["unchecked_entries"] == 0
    assert np.isfinite(out["distance_mean"])


def test_the_algorithm_is_read_from_the_policy_class_and_ppo_told_from_a2c():
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.dqn.policies import DQNPolicy
    from stable_baselines3.sac.policies import SACPolicy

    from envs.agents import _algorithm_of

    assert _algorithm_of({"policy_class": DQNPolicy}) == "dqn" and _algorithm_of({"policy_class": SACPolicy}) == "sac"
    assert _algorithm_of({"policy_class": ActorCriticPolicy, "clip_range": 0.2}) == "PPO"
    assert _algorithm_of({"policy_class": ActorCriticPolicy}) == "A2C"
    assert _algorithm_of({"policy_class": dict}) is None and _algorithm_of({}) is None



def test_one_episode_of_a_longer_run_replays_alone(capsys):
    """``--first-episode I`` runs episode I of the seeding rule: the longer run less its first I episodes."""
    def run(*extra):
        assert main(["rollout", "--env", "highway-fast-v0", "--agent", "random", "--action", "meta", "--seed", "7",
                     "--env-config", "duration=3", "--json", *extra]) == 0
        return json.loads(capsys.readouterr().out)

    longer, first_two = run("--episodes", "3"), run("--episodes", "2")
    alone = run("--episodes", "1", "--first-episode", "2")
    keys = ("steps", "override_steps", "lane_changes", "collisions", "refused_lane_changes")
    assert alone["episodes"] == 1 and alone["steps"] > 0
    assert {k: longer[k] - first_two[k] for k in keys} == {k: alone[k] for k in keys}
