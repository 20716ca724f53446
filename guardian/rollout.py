"""Supervised rollouts: one loop, one tally, for every environment and agent.

``run_episodes`` is the loop (one seeding rule, one progress callback, observers closed on every
exit); ``highway_rollouts`` composes it with the one ``Guardian`` and ``HighwayTally`` on any supported
environment: ``guardian/Overtake-v0`` (Section 6.5.3's two cars), ``guardian/HighwayOvertake-v0`` and
the ``highway-v0`` family.
"""
from __future__ import annotations

import os
import time

import numpy as np

from envs.agents import make_agent


class Observer:
    """What a rollout counts or records; ``run_episodes`` calls these hooks (all optional)."""

    def start_episode(self, env, episode: int, obs) -> None: ...

    def before_step(self, env, obs, action) -> None: ...

    def after_step(self, env, obs, action, info: dict) -> None: ...

    def end_episode(self, env, episode: int) -> None: ...

    def close(self) -> None: ...


def run_episodes(env, agent: str, episodes: int, seed: int, observers, progress=None, algo: str | None = None) -> None:
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
    """
    try:
        for ep in range(episodes):
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
            for o in observers:
                o.end_episode(env, ep)
            if progress:
                progress(ep + 1, episodes)
    finally:
        env.close()
        for o in observers:
            o.close()


# ---- highway-env environments (guardian/Overtake-v0, guardian/HighwayOvertake-v0, the highway-v0 family) ----
OVERTAKE_ENV = "guardian/HighwayOvertake-v0"
TWO_CARS_ENV = "guardian/Overtake-v0"
OVERTAKE_ENVS = (TWO_CARS_ENV, OVERTAKE_ENV)
ACTIONS = {"meta": {"type": "DiscreteMetaAction"}, "continuous": {"type": "ContinuousAction"}}


def highway_env_config(env_id: str, action: str | None, intention: str | None = None, disturbance: str = "random",
                       traffic: int | None = None, library=None, extra: dict | None = None) -> dict:
    """The env config of a rollout: the action type, and on HighwayOvertake the scenario's choices.

    On HighwayOvertake initial states are drawn inside ``C_bnd`` (Theorem 4's assumption).
    """
    config = dict(extra or {})
    if env_id in OVERTAKE_ENVS:
        from envs.highway_overtake import HighwayOvertakeEnv

        config.update({"intention": intention or "cautious", "disturbance": disturbance})
        if traffic is not None and env_id == OVERTAKE_ENV:
            config["traffic_count"] = traffic
            config["traffic_from_behind"] = min(HighwayOvertakeEnv.default_config()["traffic_from_behind"], traffic)
        if library is not None:
            config["initial_region"] = library.region("bounded_velocity")
            config["params"] = library.params
        if action == "meta":
            config["action"] = dict(ACTIONS["meta"])
    else:
        if action is not None:
            config["action"] = dict(ACTIONS[action])
        if traffic is not None:
            config["vehicles_count"] = traffic
    return config


def highway_rollouts(env_id: str, agent: str, episodes: int, seed: int, *, action: str | None = None,
                     guardian: bool = True, library=None, intention: str | None = None,
                     disturbance: str = "random", traffic: int | None = None, use_intention: bool = True,
                     env_config: dict | None = None, guardian_config=None, safe_start: bool = False,
                     horizon: int = 10, progress=None, rerun_path=None, video_dir=None,
                     policy_algo: str | None = None) -> dict:
    """Seeded episodes of one agent on a highway-env environment, with or without the ``Guardian``.

    Parameters
    ----------
    env_id : str
        ``guardian/Overtake-v0``, ``guardian/HighwayOvertake-v0`` or a highway-env id (``highway-v0``, ...).
    agent : str
        A name of ``envs.agents.AGENTS``, or ``policy:PATH`` (a stable-baselines3 policy file).
    episodes, seed : int
        Seeded as ``run_episodes`` says.
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

    Returns
    -------
    dict
        The counts of ``HighwayTally.result`` (documented there, with the fault judge's rules in
        ``guardian.judge``).
    """
    import gymnasium as gym

    import envs  # noqa: F401 - registers guardian/HighwayOvertake-v0
    import highway_env  # noqa: F401 - registers the highway-env environments
    from guardian.errors import ConfigError
    from guardian.wrapper import Guardian, GuardianConfig

    overtake = env_id in OVERTAKE_ENVS
    config = highway_env_config(env_id, action, intention, disturbance, traffic, library, env_config)
    if video_dir:  # SDL's offscreen driver: no display is looked for (and no XDG_RUNTIME_DIR error)
        os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    try:
        env = gym.make(env_id, config=config, render_mode="rgb_array" if video_dir else None)
    except ConfigError:
        raise
    except Exception as exc:  # highway-env's own failure on a config it cannot take: name the keys given
        if not env_config:
            raise
        raise ConfigError(f"{env_id} cannot be made with the config {sorted(env_config)} given "
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
        from guardian.rerun_log import GuardianRecorder
        recorder = GuardianRecorder(rerun_path)
    tally = HighwayTally(env, overtake, guardian, recorder, library, horizon)
    run_episodes(env, agent, episodes, seed, [tally], progress, algo=policy_algo)
    return tally.result(episodes)


COUNTS = ("episodes", "steps", "collisions", "ego_at_fault_collisions", "starts_outside",
          "collisions_after_outside_starts", "ego_at_fault_after_outside_starts", "safety_violations",
          "override_steps", "model_clip_steps", "refused_lane_changes", "clipped_sim_steps", "lane_changes",
          "model_violation_steps", "traffic_model_violation_steps", "follower_dropped_steps", "conflict_steps",
          "failsafe_steps", "unchecked_entries", "reversing_steps", "unsupervised_steps", "reattachments")


class HighwayTally(Observer):
    """Counts of a highway-env rollout, each by a written rule (see ``result``)."""

    def __init__(self, env, overtake: bool, guardian: bool, recorder=None, library=None, horizon: int = 10):
        self.overtake, self.guardian, self.recorder = overtake, guardian, recorder
        self.library, self._aside, self.horizon = library, None, horizon
        self.estimator = None
        if overtake:
            self._watch_the_lead(env)
        self.totals = {k: 0 for k in COUNTS}
        self.totals["crashes"] = []
        if overtake:
            self.totals["wrong_identifications"] = 0
        self.identify, self.distance, self.monitor_worst = [], 0.0, {}

    def _watch_the_lead(self, env) -> None:
        from guardian.monitor import ModelMonitor
        from intention.estimator import IntentionEstimator
        from intention.models import intention_models

        models = intention_models(env.unwrapped.params)
        candidates = {n: models[n] for n in ("aggressive", "cautious")}
        self.estimator = IntentionEstimator(candidates, horizon=self.horizon)
        self.monitor = None
        if not self.guardian:  # the guardian's own monitor counts when it is there
            from guardian.config import GuardianConfig

            g = GuardianConfig()
            self.monitor = ModelMonitor(env.unwrapped.params.dt, (-g.traffic_accel, g.traffic_accel), g.v_max,
                                        env.unwrapped.params, candidates, ego_stops_at_zero=True)

    def start_episode(self, env, episode, obs) -> None:
        from guardian.judge import FaultJudge
        from guardian.sensing import read_road

        base = env.unwrapped
        if self.estimator is not None:
            self.estimator.reset()
        if self.overtake and self.monitor is not None:
            self.monitor.reset()
        if self.recorder is not None:
            self.recorder.start_episode(env, episode)
        self.episode, self.t = episode, 0
        self.x0 = float(base.vehicle.position[0])
        self.road = read_road(base)
        self.judge = FaultJudge(self.road.lane_width, self.road.n_lanes, 1.0 / base.config["policy_frequency"])
        self.judge.start(base)
        self.inside = self._start_inside(env, base)
        self.totals["starts_outside"] += int(not self.inside)
        self.checker = None if self.overtake else _SelfSafetyCheck(base, self.road)

    def _start_inside(self, env, base) -> bool:
        """The guardian's own test; without it, the same sets' test on a guardian built aside."""
        if self.guardian:
            return bool(_guardian_of(env).start_inside())
        if self.overtake:
            if self._aside is None:
                from guardian.pointmass import PointMassGuardian
                from guardian.config import GuardianConfig

                self._aside = PointMassGuardian(self.library, self.road.n_lanes,
                                                base.vehicle.WIDTH / 2 / base.config["lateral_scale"],
                                                int(base.config["traffic_count"]) > 0, GuardianConfig())
            from guardian.sensing import road_scene

            return bool(self._aside.inside(base.overtake_state(), road_scene(base, self.road)))
        return _SelfSafetyCheck(base, self.road).inside(base)

    def before_step(self, env, obs, action) -> None:
        base = env.unwrapped
        self.lane_before = base.vehicle.lane_index[2]

    def after_step(self, env, obs, action, info) -> None:
        base, totals = env.unwrapped, self.totals
        self.t += 1
        g = info.get("guardian")
        _count_step(totals, g, base, self.lane_before)
        entries_before = len(self.judge.ego_entries)
        crash = self.judge.observe(base)
        if g is not None:
            held = set(g["lanes"]) | set(g["entered"])
            for _, lane in self.judge.ego_entries[entries_before:]:
                totals["unchecked_entries"] += int(self.road.itha_lane(lane) not in held)
        totals["reversing_steps"] += int(base.vehicle.speed < -1e-9)
        if self.overtake:
            from intention.models import unclip_standstill

            tr = base.last_transition
            self.estimator.update(tr["state"], tr["input"], unclip_standstill(base.params, tr["state"], tr["input"],
                                                                              tr["next_state"]))
            if self.monitor is not None:
                totals["model_violation_steps"] += int(sum(self.monitor.overtake_transition(
                    tr["state"], tr["input"], tr["next_state"])) > 0)
            totals["safety_violations"] += int(info["unsafe"])
        else:
            totals["safety_violations"] += int(not self.checker.inside(base))
        if self.recorder is not None:
            self.recorder.log(env, self.episode, self.t, g)
        if crash is not None:
            self._count_crash(crash, g or {})

    def _count_crash(self, crash, g: dict) -> None:
        totals = self.totals
        totals["collisions"] += 1
        at_fault = crash.fault == "ego"
        if self.inside:
            totals["ego_at_fault_collisions"] += int(at_fault)
        else:
            totals["collisions_after_outside_starts"] += 1
            totals["ego_at_fault_after_outside_starts"] += int(at_fault)
        totals["crashes"].append({"episode": self.episode, "step": self.t, "fault": crash.fault, "rule": crash.rule,
                                  "partner": crash.partner, "start_inside": self.inside,
                                  "level": g.get("level"), "reasons": g.get("reasons", [])})

    def end_episode(self, env, episode) -> None:
        base = env.unwrapped
        if self.estimator is not None and self.estimator.identified_at is not None:
            self.identify.append(self.estimator.identified_at)
            self.totals["wrong_identifications"] += int(self.estimator.valid != [base.model.name])
        self.distance += float(base.vehicle.position[0]) - self.x0
        if self.guardian:
            for k, v in _guardian_of(env).monitor.worst.items():
                self.monitor_worst[k] = max(self.monitor_worst.get(k, 0.0), v)

    def close(self) -> None:
        if self.recorder is not None:
            self.recorder.close()

    def result(self, episodes: int) -> dict:
        """The counts, each by its rule.

        * ``collisions``: episodes whose ego crashed (highway-env's crash flag, which also fires on
          its one-step extrapolation of the bodies). ``ego_at_fault_collisions``: of those starting
          inside the guardian's invariant sets, the ones ``guardian.judge.FaultJudge`` gives to the
          ego; crashes after a start outside are counted apart (``collisions_after_outside_starts``,
          ``ego_at_fault_after_outside_starts``). ``starts_outside``: episodes whose start lay
          outside the sets (with the guardian, its own test; without, self-safety towards the cars
          ahead on highway-v0).
        * ``safety_violations``: steps ending outside the safe set (6.8) (HighwayOvertake) or with no
          self-safe input left (highway-v0), with or without the guardian.
        * ``unchecked_entries``: lanes the ego's body began to overlap in a step whose record lists the
          lane neither among the lanes the guardian held the ego in nor among the entries it checked and
          found responsible.
        * ``reversing_steps``: steps ending with a negative ego speed. ``unsupervised_steps``:
          simulation steps the guardian's hook did not see. ``reattachments``: steps at which the
          guardian found the ego reset or replaced behind its back.
        * ``override_steps``: policy steps the guardian changed for safety; ``model_clip_steps``:
          simulation steps whose only change was a clip to the model's bounds (highway-env's top speed);
          ``clipped_sim_steps``, ``refused_lane_changes``, ``follower_dropped_steps``, ``conflict_steps``,
          ``failsafe_steps``: from ``info["guardian"]``; ``lane_changes``: policy
          steps whose lane index changed; ``distance_mean``: mean distance along the road per episode.
        """
        totals = self.totals
        totals["episodes"] = episodes
        totals["distance_mean"] = self.distance / episodes
        if not self.guardian:  # measured only by the guardian's monitor (and, on HighwayOvertake, from the env)
            totals["traffic_model_violation_steps"] = None
            if not self.overtake:
                totals["model_violation_steps"] = None
            for k in ("unchecked_entries", "unsupervised_steps", "reattachments"):
                totals[k] = None
        if self.guardian:
            totals["traffic_model_worst"] = {k: round(v, 6) for k, v in self.monitor_worst.items()}
        if self.overtake:
            ident = self.identify
            totals["mean_steps_to_identify_intention"] = float(np.mean(ident)) if ident else None
            totals["identified_fraction"] = len(ident) / episodes
        return totals


class _SelfSafetyCheck:
    """Whether the highway-v0 ego has a self-safe input (7.4) towards the cars ahead in its lanes."""

    def __init__(self, base, road):
        from guardian.config import GuardianConfig
        from guardian.traffic import TrafficSupervisor
        from itha.car_following import CarFollowingParams

        c = GuardianConfig()
        self.dt = 1.0 / base.config["simulation_frequency"]
        self.road, self.accel = road, c.traffic_accel
        self.traffic = TrafficSupervisor(CarFollowingParams(dt=self.dt, v_max=c.v_max, h_min=c.h_min,
                                                            u_min=-c.traffic_accel, u_max=c.traffic_accel,
                                                            d_min=-c.traffic_accel, d_max=c.traffic_accel))

    def inside(self, base) -> bool:
        from guardian.judge import body_lanes
        from guardian.sensing import road_scene

        ego = base.vehicle
        lanes = body_lanes(ego, self.road.lane_width, self.road.n_lanes) or {ego.lane_index[2]}
        speeds, _ = self.traffic.self_safe_speeds(road_scene(base, self.road, {self.road.itha_lane(i) for i in lanes}))
        v, reach = float(ego.speed), self.accel * self.dt
        return any(max(lo, v - reach) <= min(hi, v + reach) for lo, hi in speeds)


def _count_step(totals: dict, g: dict | None, base, lane_before) -> None:
    totals["steps"] += 1
    totals["lane_changes"] += int(base.vehicle.lane_index[2] != lane_before)
    if not g:
        return
    totals["override_steps"] += int(g["safety_override"])
    totals["model_clip_steps"] += g["model_clip_steps"]
    totals["refused_lane_changes"] += int(g["refused_lane_change"])
    totals["clipped_sim_steps"] += g["clipped_steps"]
    mv = g["model_violations"]
    totals["model_violation_steps"] += int(mv["ego"] + mv["lead"] > 0)
    totals["traffic_model_violation_steps"] += int(mv["traffic"] > 0)
    for k in ("follower_dropped_steps", "conflict_steps", "failsafe_steps", "unsupervised_steps"):
        totals[k] += g[k]
    totals["reattachments"] += int(g["reattached"])


def _guardian_of(env):
    """The ``Guardian`` inside a stack of wrappers."""
    from guardian.wrapper import Guardian

    while not isinstance(env, Guardian):
        env = env.env
    return env
