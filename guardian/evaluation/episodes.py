"""The rollout loop: one seeding rule, one progress callback, observers closed on every exit."""
from __future__ import annotations

import numpy as np

from envs.agents import make_agent


class Observer:
    """What a rollout counts or records; ``run_episodes`` calls these hooks (all optional)."""

    def start_episode(self, env, episode: int, obs) -> None: ...

    def before_step(self, env, obs, action) -> None: ...

    def after_step(self, env, obs, action, info: dict) -> None: ...

    def cut_episode(self, env, episode: int) -> None:
        """The episode reached the rollout's time cap before the env ended it, and was stopped there."""

    def end_episode(self, env, episode: int) -> None: ...

    def close(self) -> None: ...


def run_episodes(env, agent: str, episodes: int, seed: int, observers, progress=None, algo: str | None = None,
                 first: int = 0, max_seconds: float | None = None) -> None:
    """The rollout loop: ``episodes`` seeded episodes of ``agent`` on ``env``.

    Parameters
    ----------
    env : gymnasium.Env
        The environment, wrapped as the caller wants (guardian, video, ...). It is closed at the end.
    agent : str
        A name of ``envs.agents.AGENTS``, or ``policy:PATH`` (a stable-baselines3 policy file; ``algo``
        names its algorithm when the file should not be asked).
    episodes, seed : int
        Episode i resets the env with seed ``seed + i`` and builds the agent with
        ``numpy.random.default_rng([seed, i])``: the one seeding rule of every rollout.
    observers : list of Observer
        Told of every episode and step; closed on every exit, an exception too.
    progress : callable, optional
        ``progress(done, total)`` after each episode.
    first : int
        Run episodes ``first .. first + episodes - 1`` of the rule: episode i of a longer run, alone.
    max_seconds : float, optional
        Stop an episode the env has not ended once its simulated time (``env.unwrapped.time``) reaches this;
        observers hear ``cut_episode`` first. Some envs never end an episode themselves (``merge-v0``): a
        guardian that holds its car forever would hang the run.
    """
    try:
        for ep in range(first, first + episodes):
            obs, _ = env.reset(seed=seed + ep)
            act = make_agent(agent, env, np.random.default_rng([seed, ep]), algo=algo)
            for o in observers:
                o.start_episode(env, ep, obs)
            done = False
            while not done:
                action = act(obs)
                for o in observers:
                    o.before_step(env, obs, action)
                obs, _, terminated, truncated, info = env.step(action)
                for o in observers:
                    o.after_step(env, obs, action, info)
                done = terminated or truncated
                if not done and max_seconds is not None and env.unwrapped.time >= max_seconds - 1e-9:
                    for o in observers:
                        o.cut_episode(env, ep)
                    done = True
            for o in observers:
                o.end_episode(env, ep)
            if progress:
                progress(ep + 1 - first, episodes)
    finally:
        env.close()
        for o in observers:
            o.close()

