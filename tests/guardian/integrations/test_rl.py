"""Training under the guardian: the override penalty, relabelling with the applied action, and the
stable-baselines3 replay buffer that does it (checked inside stock DQN and SAC)."""
import subprocess
import sys

import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np
import pytest

from guardian import Guardian, GuardianConfig
from guardian.integrations.sb3 import applied_action, shielded_transitions
from project import ROOT

FAST = "highway-fast-v0"


class Log(gym.Wrapper):
    """Keeps every step's action, reward and info, as the learner gets them."""

    def __init__(self, env):
        super().__init__(env)
        self.steps = []

    def step(self, action):
        out = self.env.step(action)
        self.steps.append((action, out[1], out[4]))
        return out


def _faster_steps(config=None, n=12, seed=0):
    env = Guardian(gym.make(FAST), config=config or GuardianConfig(override_penalty=0.7))
    faster = env.unwrapped.action_type.actions_indexes["FASTER"]
    env.reset(seed=seed)
    return [env.step(faster) for _ in range(n)], faster


def test_the_penalty_is_subtracted_on_safety_overrides_only():
    plain, faster = _faster_steps(GuardianConfig())
    penalised, _ = _faster_steps(GuardianConfig(override_penalty=0.7))
    assert any(s[4]["guardian"]["safety_override"] for s in plain)
    for (_, r0, *_, i0), (_, r1, *_, i1) in zip(plain, penalised):
        g = i1["guardian"]
        assert g["safety_override"] == i0["guardian"]["safety_override"]
        assert r1 == pytest.approx(r0 - (0.7 if g["safety_override"] else 0.0))
        assert g.get("penalty", 0.0) == (0.7 if g["safety_override"] else 0.0)


def test_shielded_transitions_store_the_executed_action_and_the_penalised_proposal():
    steps, faster = _faster_steps()
    kinds = set()
    for _, reward, _, _, info in steps:
        g = info["guardian"]
        pairs = shielded_transitions(faster, reward, info)
        assert applied_action(info) == g["applied_action"]
        if not g["overridden"]:
            assert pairs == [(faster, reward)]
            kinds.add("kept")
        elif g["applied_action"] != faster:
            assert pairs[0] == (g["applied_action"], pytest.approx(reward + g.get("penalty", 0.0)))
            assert pairs[1:] == ([(faster, reward)] if g["safety_override"] else [])
            assert shielded_transitions(faster, reward, info, proposals=False) == pairs[:1]
            kinds.add("relabelled")
    assert kinds == {"kept", "relabelled"}
    assert shielded_transitions(3, 1.0, {}) == [(3, 1.0)]  # no guardian record: stored as proposed
    assert applied_action({"guardian": {"enabled": True}}) is None


def _train(env, algo, steps, **kwargs):
    import torch
    from stable_baselines3 import DQN, SAC

    from guardian.integrations.sb3 import ShieldedReplayBuffer

    torch.set_num_threads(1)
    cls = {"DQN": DQN, "SAC": SAC}[algo]
    model = cls("MlpPolicy", env, learning_starts=10_000, buffer_size=2_000, seed=0, device="cpu",
                replay_buffer_class=ShieldedReplayBuffer, **kwargs)  # learning_starts: only collect
    model.learn(total_timesteps=steps)
    return model


def _rows(buf):
    n = buf.pos
    return buf.actions[:n, 0], buf.rewards[:n, 0], buf.observations[:n, 0], buf.next_observations[:n, 0]


def test_dqn_stores_what_the_recipe_says(tmp_path):
    """Stock DQN with ``ShieldedReplayBuffer``: the buffer holds, in order, each step's transitions as
    ``shielded_transitions`` gives them (the same observations for the extra one); save and load work."""
    from stable_baselines3 import DQN

    env = Log(Guardian(gym.make(FAST, config={"duration": 10}), config=GuardianConfig(override_penalty=1.0)))
    model = _train(env, "DQN", 120)
    actions, rewards, obs, nxt = _rows(model.replay_buffer)
    expected = [p for a, r, info in env.steps for p in shielded_transitions(int(a), r, info)]
    assert [int(a) for a in actions[:, 0]] == [int(a) for a, _ in expected]
    assert np.allclose(rewards, [r for _, r in expected], atol=1e-6)
    k = 0
    for a, r, info in env.steps:  # an extra transition repeats the step's observations
        n = len(shielded_transitions(int(a), r, info))
        assert all(np.array_equal(obs[k], obs[k + j]) and np.array_equal(nxt[k], nxt[k + j]) for j in range(n))
        k += n
    buf = model.replay_buffer
    assert buf.relabelled > 0 and buf.proposals_stored > 0 and len(expected) > len(env.steps)
    model.save(tmp_path / "dqn.zip")
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    again = DQN.load(tmp_path / "dqn.zip", env=env, device="cpu")
    again.load_replay_buffer(tmp_path / "buffer.pkl")
    assert type(again.replay_buffer).__name__ == "ShieldedReplayBuffer" and again.replay_buffer.pos == buf.pos


def test_with_several_envs_no_transition_is_stored_twice():
    from stable_baselines3.common.env_util import make_vec_env

    logs = []

    def logged(env):
        logs.append(Log(Guardian(env, config=GuardianConfig(override_penalty=1.0))))
        return logs[-1]

    vec = make_vec_env(FAST, n_envs=2, seed=0, env_kwargs={"config": {"duration": 8}}, wrapper_class=logged)
    model = _train(vec, "DQN", 60)
    buf = model.replay_buffer
    for i, log in enumerate(logs):
        expected = [(int(a), round(r, 5)) for a, r, info in log.steps for a, r in shielded_transitions(int(a), r, info)]
        stored = [(int(a), round(float(r), 5)) for a, r in zip(buf.actions[:buf.pos, i, 0], buf.rewards[:buf.pos, i])]
        pending = [(int(p[2][0]), round(float(p[3]), 5)) for p in buf._pending[i]]
        assert sorted(stored + pending) == sorted(expected)  # extra transitions wait for a row of their own
        assert not pending or all(not p for j, p in enumerate(buf._pending) if j != i)
    assert buf.proposals_stored > 0
    vec.close()


def test_sac_stores_the_executed_continuous_action_in_its_own_scale():
    """A continuous agent: the stored action is the mean applied input in the action space's [-1, 1]."""
    env = Log(Guardian(gym.make(FAST, config={"action": {"type": "ContinuousAction"}, "duration": 6}),
                       config=GuardianConfig(override_penalty=0.5)))
    model = _train(env, "SAC", 40)
    actions, rewards, _, _ = _rows(model.replay_buffer)
    expected = [p for a, r, info in env.steps for p in shielded_transitions(np.asarray(a), r, info)]
    assert np.allclose(actions, np.array([np.asarray(a, float) for a, _ in expected]), atol=1e-6)
    assert np.allclose(rewards, [r for _, r in expected], atol=1e-6)
    assert any(info["guardian"]["safety_override"] for _, _, info in env.steps)


def test_refusals():
    from gymnasium import spaces

    from guardian.integrations.sb3 import ShieldedReplayBuffer

    box = spaces.Box(-1, 1, (3,))
    with pytest.raises(ValueError, match="optimize_memory_usage"):
        ShieldedReplayBuffer(10, box, spaces.Discrete(5), optimize_memory_usage=True, handle_timeout_termination=False)
    with pytest.raises(ValueError, match="not supported"):
        ShieldedReplayBuffer(10, box, spaces.MultiDiscrete([2, 2]))


def test_guardian_rl_imports_without_stable_baselines3_and_says_what_to_install():
    code = ("import sys; sys.modules['stable_baselines3'] = None\n"
            "import guardian.integrations.sb3 as rl\n"
            "assert rl.shielded_transitions(1, 0.5, {}) == [(1, 0.5)]\n"
            "try:\n    rl.ShieldedReplayBuffer\nexcept ImportError as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "pip install 'guardian[rl]'" in out


def test_the_recipe_in_docs_rl_runs_as_written(tmp_path, monkeypatch, capsys):
    """docs/rl.md's stable-baselines3 block, run as written (in a temporary folder: it saves the model)."""
    import re

    import torch

    text = (ROOT / "docs" / "rl.md").read_text()
    (block,) = re.findall(r"```python\n(.*?)```", text, re.S)
    expected = [line[2:] for line in block.splitlines() if line.startswith("# ")]
    monkeypatch.chdir(tmp_path)
    torch.set_num_threads(1)
    exec(compile(block, "docs/rl.md", "exec"), {})
    assert capsys.readouterr().out.split("\n")[:-1] == expected
    assert (tmp_path / "dqn_shielded.zip").is_file()
