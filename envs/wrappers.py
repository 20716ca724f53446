"""Gymnasium wrappers that put a supervisor between an agent and an environment."""
from __future__ import annotations

import gymnasium as gym
import numpy as np


class OvertakeGuardianWrapper(gym.Wrapper):
    """Every action passes through an ``IntentionAwareGuardian``; ``info["guardian"]`` says what it did.

    Parameters
    ----------
    env : gymnasium.Env
        ``guardian/Overtake-v0`` (possibly wrapped).
    guardian : Supervisor
        Usually an ``IntentionAwareGuardian``.
    keep_polygons : bool
        Put the admissible polygons ``S_I(x)`` into the record too (for plots and recordings).
    """

    def __init__(self, env: gym.Env, guardian, keep_polygons: bool = False):
        super().__init__(env)
        self.guardian = guardian
        self.keep_polygons = keep_polygons
        self._obs = None

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.guardian.reset()
        self._obs = obs
        return obs, info

    def step(self, action):
        applied, record = self.guardian.step(self._obs, np.asarray(action, dtype=float))
        obs, reward, terminated, truncated, info = self.env.step(applied)
        self._obs = obs
        info = dict(info, guardian=record.as_dict(polygons=self.keep_polygons))
        return obs, reward, terminated, truncated, info
