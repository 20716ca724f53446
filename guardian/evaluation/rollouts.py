"""Supervised rollouts of the highway-env environments: the env config, the ``Guardian``, the tally.

``highway_rollouts`` composes the loop (``guardian.evaluation.episodes``) with the one ``Guardian`` and
``HighwayTally`` on any supported environment: ``guardian/Overtake-v0`` (Section 6.5.3's two cars),
``guardian/HighwayOvertake-v0`` and the ``highway-v0`` family.
"""
from __future__ import annotations

import os

from guardian.evaluation.episodes import run_episodes
from guardian.evaluation.tally import HighwayTally

OVERTAKE_ENV = "guardian/HighwayOvertake-v0"
TWO_CARS_ENV = "guardian/Overtake-v0"
OVERTAKE_ENVS = (TWO_CARS_ENV, OVERTAKE_ENV)
ACTIONS = {"meta": {"type": "DiscreteMetaAction"}, "continuous": {"type": "ContinuousAction"}}


def highway_env_config(env_id: str, action: str | None, intention: str | None = None, disturbance: str = "random",
                       traffic: int | None = None, library=None, extra: dict | None = None,
                       controlled: int | None = None) -> dict:
    """The env config of a rollout: the action type, and on HighwayOvertake the scenario's choices.

    On HighwayOvertake initial states are drawn inside ``C_bnd`` (Theorem 4's assumption). ``controlled``:
    that many controlled cars under highway-env's ``MultiAgentAction`` (one agent and one guardian each).
    """
    from guardian.adapters.highway_env.checks import action_types, env_class, merge_limits

    if controlled is not None and env_id in OVERTAKE_ENVS:
        raise ValueError(f"{env_id} has one ego; several controlled cars drive highway-env's roads")
    extra = dict(extra or {})
    chosen = {}   # what this rollout's own arguments set: never also given in ``extra`` (one would be dropped)
    if env_id in OVERTAKE_ENVS:
        from envs.highway_overtake import HighwayOvertakeEnv

        chosen.update({"intention": intention or "cautious", "disturbance": disturbance})
        if traffic is not None and env_id == OVERTAKE_ENV:
            chosen["traffic_count"] = traffic
            if "traffic_from_behind" not in extra:
                chosen["traffic_from_behind"] = min(HighwayOvertakeEnv.default_config()["traffic_from_behind"], traffic)
        if library is not None:
            chosen.update({"initial_region": library.region("bounded_velocity"), "params": library.params})
        if action == "meta":
            chosen["action"] = dict(ACTIONS["meta"])
    else:
        if action is not None:
            chosen["action"] = dict(ACTIONS[action])
        if traffic is not None:
            chosen["vehicles_count"] = traffic
        if controlled is not None:
            chosen["controlled_vehicles"] = controlled
    _refuse_overridden(env_id, extra, chosen)
    config = {**extra, **chosen}
    if env_id in OVERTAKE_ENVS:
        cars = config.get("traffic_count", env_class(env_id).default_config()["traffic_count"])
        if config.get("traffic_from_behind", 0) > cars:
            raise ValueError(f"{env_id}: traffic_from_behind={config['traffic_from_behind']} is more than the "
                             f"{cars} traffic cars (traffic_count)")
    else:
        if controlled is not None:
            inner = config.get("action") or {"type": _default_action(env_id)}
            config["action"] = {"type": "MultiAgentAction", "action_config": dict(inner)}
        kind, inner = action_types(env_id, config)
        merge_limits(env_class(env_id), env_id, inner == "ContinuousAction", kind == "MultiAgentAction")
    return config


SET_BY = {"intention": "--intention", "disturbance": "--disturbance", "traffic_count": "--traffic",
          "traffic_from_behind": "--traffic", "vehicles_count": "--traffic", "action": "--action",
          "controlled_vehicles": "--controlled", "initial_region": "the set library (starts are drawn in its C_bnd)",
          "params": "the set library's parameters (--ego-speed-min)"}


def _refuse_overridden(env_id: str, extra: dict, chosen: dict) -> None:
    """A config key the rollout sets itself cannot also come in ``extra``: one of the two would be dropped
    without a word."""
    clash = [k for k in chosen if k in extra]
    if clash:
        key = clash[0]
        raise ValueError(f"{env_id}: config key {key!r} is set by {SET_BY[key]}; give it there, not in the env config")


def _default_action(env_id: str) -> str:
    """The env's own action type (its class's default config)."""
    from guardian.adapters.highway_env.checks import env_class

    return env_class(env_id).default_config()["action"]["type"]


def highway_rollouts(env_id: str, agent: str, episodes: int, seed: int, *, action: str | None = None,
                     guardian: bool = True, library=None, intention: str | None = None,
                     disturbance: str = "random", traffic: int | None = None, use_intention: bool = True,
                     env_config: dict | None = None, guardian_config=None, safe_start: bool = False,
                     horizon: int = 10, progress=None, rerun_path=None, video_dir=None,
                     policy_algo: str | None = None, controlled: int | None = None, first_episode: int = 0) -> dict:
    """Seeded episodes of one agent on a highway-env environment, with or without the ``Guardian``.

    Parameters
    ----------
    env_id : str
        ``guardian/Overtake-v0``, ``guardian/HighwayOvertake-v0`` or a highway-env id (``highway-v0``, ...).
    agent : str
        A name of ``envs.agents.AGENTS``, or ``policy:PATH`` (a stable-baselines3 policy file).
    episodes, seed, first_episode : int
        Seeded as ``run_episodes`` says; ``first_episode`` skips to episode i of a longer run.
    action : str, optional
        ``continuous`` or ``meta`` (default: the env's own action type).
    guardian, use_intention : bool
        Wrap the env in the ``Guardian``; let it use the estimated intention.
    library : intention.library.OvertakeLibrary, optional
        The sets (HighwayOvertake: initial states are drawn inside ``C_bnd``).
    intention, disturbance, traffic : optional
        HighwayOvertake's lead intention and disturbance mode; the number of other cars.
    env_config, guardian_config : optional
        Extra env config; the ``GuardianConfig``.
    safe_start : bool
        Draw each start again until it lies in the guardian's invariant sets (guarded runs only).
    horizon : int
        The intention estimator's window N (overtake scenarios; the guardian's and the tally's).
    progress : callable, optional
        ``progress(done, total)`` after each episode.
    rerun_path, video_dir : path, optional
        Write a rerun recording; write each episode as MP4 into this folder.
    policy_algo : str, optional
        The algorithm of a ``policy:PATH`` agent (default: read from the file).
    controlled : int, optional
        That many controlled cars (``MultiAgentAction``), each with its own agent and guardian.

    Returns
    -------
    dict
        The counts of ``HighwayTally.result`` (documented there, with the fault judge's rules in
        ``guardian.evaluation.judge``).
    """
    import gymnasium as gym

    import envs  # noqa: F401 - registers guardian/HighwayOvertake-v0
    import highway_env  # noqa: F401 - registers the highway-env environments
    from guardian.errors import ConfigError
    from guardian.wrappers.guardian import Guardian, GuardianConfig

    overtake = env_id in OVERTAKE_ENVS
    config = highway_env_config(env_id, action, intention, disturbance, traffic, library, env_config, controlled)
    if video_dir:  # SDL's offscreen driver: no display is looked for (and no XDG_RUNTIME_DIR error)
        os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    try:
        env = gym.make(env_id, config=config, render_mode="rgb_array" if video_dir else None)
    except ConfigError:
        raise
    except Exception as exc:  # highway-env's own failure on a config it cannot take: name what was given
        given = ([f"the config {sorted(env_config)}"] if env_config else []) + \
            ([f"{controlled} controlled cars"] if controlled is not None else []) + \
            ([f"{traffic} traffic cars"] if traffic is not None else [])
        if not given:
            raise
        raise ConfigError(f"{env_id} cannot be made with {' and '.join(given)} "
                          f"({type(exc).__name__}: {exc})") from exc
    if video_dir:  # highway-env's default ratio (2) makes videos play at double speed
        env.unwrapped.update_metadata(video_real_time_ratio=1)
    if guardian:
        gcfg = guardian_config or GuardianConfig(use_intention=use_intention, horizon=horizon)
        if safe_start:
            import dataclasses

            gcfg = dataclasses.replace(gcfg, resample_unsafe_start=True)
        env = Guardian(env, library, gcfg)
    if video_dir:
        env = gym.wrappers.RecordVideo(env, str(video_dir), episode_trigger=lambda e: True,
                                       name_prefix=env_id.replace("/", "-"), disable_logger=True)
    recorder = None
    if rerun_path is not None:
        from guardian.recording.rerun import GuardianRecorder
        recorder = GuardianRecorder(rerun_path)
    tally = HighwayTally(env, overtake, guardian, recorder, library, horizon)
    run_episodes(env, agent, episodes, seed, [tally], progress, algo=policy_algo, first=first_episode)
    return tally.result(episodes)

