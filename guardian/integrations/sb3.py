"""Training under the guardian: what a learner should store for a step the guardian overrode.

A learner trained behind the ``Guardian`` sees the reward of what the vehicle did, but by default it
stores what it proposed: an unsafe proposal is credited with the reward of the guardian's safe action,
and nothing tells the learner it was overridden. The policy then leans on the shield (trained shielded
and run without it, it crashes). Two things fix that, used together:

* ``GuardianConfig(override_penalty=p)``: ``p`` is subtracted from the reward of every step the guardian
  overrode for safety (``info["guardian"]["penalty"]``); a clip to the guardian's modelling bounds is
  not penalised.
* relabelling: ``info["guardian"]["applied_action"]`` is what the vehicle did over the policy step, as an
  action of the env's own space (the executed meta action, the nearest ``DiscreteAction`` index, or the
  normalised mean input of a ``ContinuousAction``). Store that action with the reward it earned (the
  penalty given back) and, when the guardian changed the proposal for safety, the proposal too, with
  the penalised reward (``shielded_transitions``): the learner then learns the value of both actions.

``shielded_transitions`` is the recipe for any learner (no dependency); ``ShieldedReplayBuffer`` applies
it inside a stable-baselines3 off-policy algorithm (DQN, SAC, TD3, ...)::

    from stable_baselines3 import DQN
    from guardian import Guardian, GuardianConfig
    from guardian.integrations.sb3 import ShieldedReplayBuffer

    env = Guardian(gym.make("highway-fast-v0"), config=GuardianConfig(override_penalty=1.0))
    model = DQN("MlpPolicy", env, replay_buffer_class=ShieldedReplayBuffer)

The stable-baselines3 parts are imported on first use; without stable-baselines3 installed they raise
an ``ImportError`` naming ``pip install 'guardian[rl]'``. For on-policy algorithms (PPO, A2C) see
docs/rl.md: the penalty works unchanged; relabelling an on-policy rollout is not offered.
"""
from __future__ import annotations

import numpy as np

__all__ = ["shielded_transitions", "applied_action", "ShieldedReplayBuffer"]

RL_EXTRA = "pip install 'guardian[rl]'"


def applied_action(info: dict):
    """The action the vehicle executed over the step, in the env's own action space.

    Parameters
    ----------
    info : dict
        The ``info`` returned by a ``Guardian``'s ``step``.

    Returns
    -------
    int or list of float or None
        ``info["guardian"]["applied_action"]``; None when the step has no guardian record or no
        supervised simulation step (an inner wrapper reset the env instead of stepping it).
    """
    g = info.get("guardian") if isinstance(info, dict) else None
    if not g or "applied_action" not in g:
        return None
    return g["applied_action"]


def _same(a, b) -> bool:
    return bool(np.allclose(np.asarray(a, dtype=float), np.asarray(b, dtype=float), rtol=0.0, atol=1e-6))


def shielded_transitions(action, reward: float, info: dict, proposals: bool = True) -> list:
    """The ``(action, reward)`` pairs a learner should store for one guarded step (same observation,
    next observation and termination for each).

    Parameters
    ----------
    action
        The action the learner proposed (what it gave ``env.step``).
    reward : float
        The reward ``env.step`` returned (with ``override_penalty`` already subtracted on a step the
        guardian overrode for safety).
    info : dict
        The ``info`` ``env.step`` returned.
    proposals : bool
        Also store the proposal of a step the guardian changed for safety, with the penalised reward
        (so the learner learns that the proposal was worse); otherwise only the executed action.

    Returns
    -------
    list of (action, float)
        ``[(proposed, reward)]`` when the guardian changed nothing; otherwise first the executed action
        with the reward it earned (``reward`` plus any penalty), then, if ``proposals`` and the change
        was for safety, ``(proposed, reward)``. A step without a guardian record is stored as proposed.
    """
    g = info.get("guardian") if isinstance(info, dict) else None
    applied = applied_action(info)
    if not g or applied is None or not g.get("overridden"):
        return [(action, float(reward))]
    penalty = float(g.get("penalty", 0.0))
    if _same(applied, action):  # the same action, done harder (e.g. SLOWER braked further): penalised
        return [(action, float(reward))]
    out = [(applied, float(reward) + penalty)]
    if proposals and g.get("safety_override"):
        out.append((action, float(reward)))
    return out


# ---- stable-baselines3 ------------------------------------------------------------------------------------
def _import_sb3():
    try:
        from stable_baselines3.common.buffers import ReplayBuffer
    except ImportError as exc:
        raise ImportError(f"guardian.integrations.sb3.ShieldedReplayBuffer needs stable-baselines3: {RL_EXTRA} "
                          f"({exc})") from None
    return ReplayBuffer


def _make_replay_buffer_class():
    ReplayBuffer = _import_sb3()
    from gymnasium import spaces

    class ShieldedReplayBuffer(ReplayBuffer):
        """A stable-baselines3 ``ReplayBuffer`` that stores what ``shielded_transitions`` says.

        Pass it to an off-policy algorithm: ``DQN(..., replay_buffer_class=ShieldedReplayBuffer)``,
        ``replay_buffer_kwargs={"proposals": False}`` to store the executed action alone. With several
        envs, a step that adds a second transition for one env keeps it until every env has one
        (buffer rows hold one transition per env), so no transition is stored twice. Rewards are the
        env's (a ``VecNormalize`` that normalises rewards would mix scales with the penalty given
        back); ``optimize_memory_usage`` is refused (it stores the next observation in the next row).

        Parameters
        ----------
        buffer_size, observation_space, action_space, device, n_envs, optimize_memory_usage, \
handle_timeout_termination
            As stable-baselines3's ``ReplayBuffer``.
        proposals : bool
            Also store the proposal of a step overridden for safety, with the penalised reward.
        """

        def __init__(self, buffer_size, observation_space, action_space, device="auto", n_envs: int = 1,
                     optimize_memory_usage: bool = False, handle_timeout_termination: bool = True,
                     proposals: bool = True):
            if optimize_memory_usage:
                raise ValueError("ShieldedReplayBuffer: optimize_memory_usage=True is not supported (an extra "
                                 "transition would overwrite the next observation of the row before it)")
            if not isinstance(action_space, (spaces.Discrete, spaces.Box)):
                raise ValueError(f"ShieldedReplayBuffer: action space {action_space} is not supported "
                                 "(Discrete or Box)")
            super().__init__(buffer_size, observation_space, action_space, device, n_envs=n_envs,
                             optimize_memory_usage=False, handle_timeout_termination=handle_timeout_termination)
            self.proposals = proposals
            self._pending = [[] for _ in range(self.n_envs)]  # per env: extra (obs, next, action, reward, done, info)
            self.relabelled = 0   # transitions stored with the executed action in place of the proposal
            self.proposals_stored = 0

        def _to_buffer(self, action) -> np.ndarray:
            """An action of the env's space as stable-baselines3 stores it (a Box scaled to [-1, 1])."""
            a = np.asarray(action, dtype=float).reshape(self.action_dim)
            if isinstance(self.action_space, spaces.Box):
                lo, hi = self.action_space.low.reshape(-1), self.action_space.high.reshape(-1)
                a = 2.0 * (a - lo) / (hi - lo) - 1.0
            return a

        def _from_buffer(self, action) -> np.ndarray:
            a = np.asarray(action, dtype=float).reshape(self.action_dim)
            if isinstance(self.action_space, spaces.Box):
                lo, hi = self.action_space.low.reshape(-1), self.action_space.high.reshape(-1)
                a = lo + (a + 1.0) * (hi - lo) / 2.0
            return a

        def add(self, obs, next_obs, action, reward, done, infos) -> None:
            """Store the step, each env's transitions as ``shielded_transitions`` gives them."""
            action = np.array(action).reshape((self.n_envs, self.action_dim))
            reward = np.array(reward, dtype=np.float32).reshape(self.n_envs).copy()
            stored = action.astype(float).copy()
            for i in range(self.n_envs):
                proposed = self._from_buffer(action[i])
                proposed = int(round(proposed[0])) if isinstance(self.action_space, spaces.Discrete) else proposed
                pairs = shielded_transitions(proposed, float(reward[i]), infos[i], self.proposals)
                stored[i], reward[i] = self._to_buffer(pairs[0][0]), pairs[0][1]
                self.relabelled += int(len(pairs) > 1 or not _same(pairs[0][0], proposed))
                for extra, r in pairs[1:]:
                    self._pending[i].append((np.array(obs[i]), np.array(next_obs[i]), self._to_buffer(extra), r,
                                             done[i], infos[i]))
            super().add(obs, next_obs, stored.astype(self.actions.dtype), reward, done, infos)
            while all(self._pending):
                rows = [p.pop(0) for p in self._pending]
                o, n, a, r, d, inf = (list(col) for col in zip(*rows))
                super().add(np.stack(o), np.stack(n), np.stack(a).astype(self.actions.dtype),
                            np.array(r, dtype=np.float32), np.array(d), inf)
                self.proposals_stored += self.n_envs

    ShieldedReplayBuffer.__module__, ShieldedReplayBuffer.__qualname__ = __name__, "ShieldedReplayBuffer"
    return ShieldedReplayBuffer


def __getattr__(name: str):
    if name == "ShieldedReplayBuffer":
        cls = _make_replay_buffer_class()
        globals()[name] = cls  # one class: pickled by reference, found again by name
        return cls
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
