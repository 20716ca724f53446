"""Supervised rollouts of the highway-env environments: the env config, the ``Guardian``, the tally.

A ``Rollout`` names one setting (environment, agent, action type, guardian configuration, scenario
choices); ``highway_rollouts`` runs seeded episodes of it through the loop (``guardian.evaluation.episodes``)
with the one ``Guardian`` and the ``HighwayTally`` on any supported environment: ``guardian/Overtake-v0``
(Section 6.5.3's two cars), ``guardian/HighwayOvertake-v0`` and highway-env's roads.
"""
from __future__ import annotations

import math

import os
from dataclasses import dataclass, field

from guardian.config import GuardianConfig
from guardian.errors import ConfigClash, ConfigError
from guardian.evaluation import MAX_SECONDS
from guardian.evaluation.episodes import run_episodes
from guardian.evaluation.tally import HighwayTally

OVERTAKE_ENV = "guardian/HighwayOvertake-v0"
TWO_CARS_ENV = "guardian/Overtake-v0"
OVERTAKE_ENVS = (TWO_CARS_ENV, OVERTAKE_ENV)
ACTIONS = {"meta": {"type": "DiscreteMetaAction"}, "continuous": {"type": "ContinuousAction"}}
SETS = {"intention": "intention", "disturbance": "disturbance", "traffic_count": "traffic",
        "traffic_from_behind": "traffic", "vehicles_count": "traffic", "action": "action",
        "controlled_vehicles": "controlled", "initial_region": "library", "params": "library"}
"""The env config keys a ``Rollout`` sets itself, and the field that sets each."""


@dataclass(frozen=True)
class Rollout:
    """One setting of seeded episodes.

    Attributes
    ----------
    env_id : str
        ``guardian/Overtake-v0``, ``guardian/HighwayOvertake-v0`` or a highway-env id (``highway-v0``, ...).
    agent : str
        A name of ``envs.agents.AGENTS``, or ``policy:PATH`` (a stable-baselines3 policy file).
    action : str, optional
        ``continuous`` or ``meta`` (default: the env's own action type).
    guarded : bool
        Wrap the env in the ``Guardian``.
    config : GuardianConfig
        The guardian's configuration; the tally counts by the same bounds, guarded or not.
    library : intention.library.OvertakeLibrary, optional
        The overtake sets (HighwayOvertake: initial states are drawn inside ``C_bnd``).
    intention, disturbance : str
        The overtake lead's intention (default cautious) and disturbance mode.
    traffic : int, optional
        The number of other cars.
    controlled : int, optional
        That many controlled cars (``MultiAgentAction``), each with its own agent and guardian.
    env_config : dict
        Further env config; a key that a field above sets is refused (``ConfigClash``).
    policy_algo : str, optional
        The algorithm of a ``policy:PATH`` agent (default: read from the file).
    max_seconds : float, optional
        An episode the env has not ended by this simulated time is stopped and counted as cut
        (``episodes_cut``): ``merge-v0`` never ends an episode itself (its config's ``duration`` is not used).
        None: no cap.
    jerk : float, optional
        The controlled cars' actuator limits the change of their acceleration to this many m/s^3
        (``envs.actuator.Actuated``, guarded or not; highway-env's roads only). None: highway-env's vehicles,
        whose acceleration may jump.
    lag : float, optional
        The controlled cars' actuator moves their acceleration towards the command as a first-order lag of this
        time constant [s] does (sampled each simulation step; with ``jerk``, within its bound too). None: no lag.
    """

    env_id: str
    agent: str
    action: str | None = None
    guarded: bool = True
    config: GuardianConfig = field(default_factory=GuardianConfig)
    library: object = None
    intention: str | None = None
    disturbance: str = "random"
    traffic: int | None = None
    controlled: int | None = None
    env_config: dict = field(default_factory=dict)
    policy_algo: str | None = None
    max_seconds: float | None = MAX_SECONDS
    jerk: float | None = None
    lag: float | None = None

    @property
    def overtake(self) -> bool:
        return self.env_id in OVERTAKE_ENVS


def refuse_set_keys(env_id: str, extra: dict, keys) -> None:
    """A config key the rollout sets itself (``keys``) cannot also come in ``extra``: one of the two would
    be dropped without a word (``ConfigClash`` names the key and the setting)."""
    for key in keys:
        if key in extra:
            raise ConfigClash(env_id, key, SETS[key])


def highway_env_config(r: Rollout) -> dict:
    """The env config of a rollout: its ``env_config``, the action type, and on the overtake envs the
    scenario's choices (initial states drawn inside ``C_bnd``, Theorem 4's assumption). ``controlled``: that
    many controlled cars under highway-env's ``MultiAgentAction`` (one agent and one guardian each)."""
    from guardian.adapters.highway_env.checks import action_types, env_class, merge_limits

    env_id = r.env_id
    if r.controlled is not None and r.overtake:
        raise ValueError(f"{env_id} has one ego; several controlled cars drive highway-env's roads")
    extra = dict(r.env_config)
    chosen = {}   # what this rollout's own fields set: never also given in ``extra``
    if r.overtake:
        from envs.highway_overtake import HighwayOvertakeEnv

        chosen.update({"intention": r.intention or "cautious", "disturbance": r.disturbance})
        if r.traffic is not None and env_id == OVERTAKE_ENV:
            chosen["traffic_count"] = r.traffic
            if "traffic_from_behind" not in extra:
                chosen["traffic_from_behind"] = min(HighwayOvertakeEnv.default_config()["traffic_from_behind"],
                                                    r.traffic)
        if r.library is not None:
            chosen.update({"initial_region": r.library.region("bounded_velocity"), "params": r.library.params})
        if r.action == "meta":
            chosen["action"] = dict(ACTIONS["meta"])
    else:
        if r.action is not None:
            chosen["action"] = dict(ACTIONS[r.action])
        if r.traffic is not None:
            chosen["vehicles_count"] = r.traffic
        if r.controlled is not None:
            chosen["controlled_vehicles"] = r.controlled
    refuse_set_keys(env_id, extra, chosen)
    config = {**extra, **chosen}
    if r.overtake:
        cars = config.get("traffic_count", env_class(env_id).default_config()["traffic_count"])
        if config.get("traffic_from_behind", 0) > cars:
            raise ValueError(f"{env_id}: traffic_from_behind={config['traffic_from_behind']} is more than the "
                             f"{cars} traffic cars (traffic_count)")
    else:
        if r.controlled is not None:
            inner = config.get("action") or {"type": env_class(env_id).default_config()["action"]["type"]}
            config["action"] = {"type": "MultiAgentAction", "action_config": dict(inner)}
        kind, inner = action_types(env_id, config)
        merge_limits(env_class(env_id), env_id, inner == "ContinuousAction", kind == "MultiAgentAction")
    return config


def make_env(r: Rollout, render: bool = False):
    """The rollout's environment, wrapped in the ``Guardian`` when it is guarded (``render``: frames as
    ``rgb_array``, drawn offscreen)."""
    import gymnasium as gym

    import envs  # noqa: F401 - registers guardian/HighwayOvertake-v0
    import highway_env  # noqa: F401 - registers the highway-env environments
    from guardian.wrappers.guardian import Guardian

    config = highway_env_config(r)
    if render:  # SDL's offscreen driver: no display is looked for (and no XDG_RUNTIME_DIR error)
        os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    try:
        env = gym.make(r.env_id, config=config, render_mode="rgb_array" if render else None)
    except ConfigError:
        raise
    except Exception as exc:  # highway-env's own failure on a config it cannot take: name what was given
        given = ([f"the config {sorted(r.env_config)}"] if r.env_config else []) + \
            ([f"{r.controlled} controlled cars"] if r.controlled is not None else []) + \
            ([f"{r.traffic} traffic cars"] if r.traffic is not None else [])
        if not given:
            raise
        raise ConfigError(f"{r.env_id} cannot be made with {' and '.join(given)} "
                          f"({type(exc).__name__}: {exc})") from exc
    if render:  # highway-env's default ratio (2) makes videos play at double speed
        env.unwrapped.update_metadata(video_real_time_ratio=1)
    if r.jerk is not None or r.lag is not None:
        from envs.actuator import Actuated
        from itha.actuator import Actuator

        env = Actuated(env, Actuator(jerk=math.inf if r.jerk is None else float(r.jerk),
                                     lag=0.0 if r.lag is None else float(r.lag), profile="hold"))
    return Guardian(env, r.library, r.config) if r.guarded else env


def highway_rollouts(r: Rollout, episodes: int, seed: int, first_episode: int = 0, progress=None,
                     rerun_path=None, video_dir=None) -> dict:
    """Seeded episodes of one rollout setting.

    Parameters
    ----------
    r : Rollout
        The environment, agent, action type, guardian configuration and scenario choices.
    episodes, seed, first_episode : int
        Seeded as ``run_episodes`` says; ``first_episode`` skips to episode i of a longer run.
    progress : callable, optional
        ``progress(done, total)`` after each episode.
    rerun_path, video_dir : path, optional
        Write a rerun recording; write each episode as MP4 into this folder.

    Returns
    -------
    dict
        The counts of ``HighwayTally.result`` (documented there, with the fault judge's rules in
        ``guardian.evaluation.judge``).
    """
    import gymnasium as gym

    env = make_env(r, render=bool(video_dir))
    if video_dir:
        env = gym.wrappers.RecordVideo(env, str(video_dir), episode_trigger=lambda e: True,
                                       name_prefix=r.env_id.replace("/", "-"), disable_logger=True)
    recorder = None
    if rerun_path is not None:
        from guardian.recording.rerun import GuardianRecorder
        recorder = GuardianRecorder(rerun_path)
    tally = HighwayTally(env, r.guarded, r.config, r.library, recorder)
    run_episodes(env, r.agent, episodes, seed, [tally], progress, algo=r.policy_algo, first=first_episode,
                 max_seconds=r.max_seconds)
    return tally.result(episodes)


def combine_runs(runs: list) -> dict:
    """One record for several runs: counts summed, means weighted by episodes, the runs kept under "runs"."""
    out = {k: sum(r[k] for r in runs) for k, v in runs[0].items()
           if isinstance(v, int) and not isinstance(v, bool) and all(isinstance(r.get(k), int) for r in runs)}
    if all(isinstance(r.get("traffic_model_worst"), dict) for r in runs):
        out["traffic_model_worst"] = {k: max(r["traffic_model_worst"].get(k, 0.0) for r in runs)
                                      for k in runs[0]["traffic_model_worst"]}
    if all("distance_mean" in r for r in runs):
        out["distance_mean"] = sum(r["distance_mean"] * r["episodes"] for r in runs) / out["episodes"]
    if all("identified_fraction" in r for r in runs):
        ident = [(r["mean_steps_to_identify_intention"], r["identified_fraction"] * r["episodes"]) for r in runs
                 if r["mean_steps_to_identify_intention"] is not None]
        n_ident = sum(n for _, n in ident)
        out["mean_steps_to_identify_intention"] = sum(m * n for m, n in ident) / n_ident if n_ident else None
        out["identified_fraction"] = n_ident / out["episodes"]
    out["runs"] = runs
    return out
