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


def run_episodes(env, agent: str, episodes: int, seed: int, observers, progress=None, algo: str | None = None,
                 first: int = 0) -> None:
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
            for o in observers:
                o.end_episode(env, ep)
            if progress:
                progress(ep + 1 - first, episodes)
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
                       traffic: int | None = None, library=None, extra: dict | None = None,
                       controlled: int | None = None) -> dict:
    """The env config of a rollout: the action type, and on HighwayOvertake the scenario's choices.

    On HighwayOvertake initial states are drawn inside ``C_bnd`` (Theorem 4's assumption). ``controlled``:
    that many controlled cars under highway-env's ``MultiAgentAction`` (one agent and one guardian each).
    """
    from guardian.env_checks import action_types, env_class, merge_limits

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
    from guardian.env_checks import env_class

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
        ``guardian.judge``).
    """
    import gymnasium as gym

    import envs  # noqa: F401 - registers guardian/HighwayOvertake-v0
    import highway_env  # noqa: F401 - registers the highway-env environments
    from guardian.errors import ConfigError
    from guardian.wrapper import Guardian, GuardianConfig

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
        from guardian.rerun_log import GuardianRecorder
        recorder = GuardianRecorder(rerun_path)
    tally = HighwayTally(env, overtake, guardian, recorder, library, horizon)
    run_episodes(env, agent, episodes, seed, [tally], progress, algo=policy_algo, first=first_episode)
    return tally.result(episodes)


COUNTS = ("episodes", "steps", "collisions", "ego_at_fault_collisions", "starts_outside",
          "collisions_after_outside_starts", "ego_at_fault_after_outside_starts", "safety_violations",
          "override_steps", "model_clip_steps", "refused_lane_changes", "clipped_sim_steps", "lane_changes",
          "model_violation_steps", "traffic_model_violation_steps", "traffic_blind_steps",
          "traffic_reversing_uncovered_steps", "follower_dropped_steps",
          "conflict_steps",
          "failsafe_steps", "unchecked_entries", "reversing_steps", "unsupervised_steps", "reattachments")
MULTI_COUNTS = ("guarded_pair_collisions", "merges", "on_ending_lane")
CAR_COUNTS = ("collisions", "at_fault_collisions", "lane_changes", "override_steps", "refused_lane_changes",
              "merges", "on_ending_lane")


def _multi(base) -> bool:
    return type(getattr(base, "action_type", None)).__name__ == "MultiAgentAction"


def guarded_cars(base) -> list:
    """The cars a rollout counts: highway-env's controlled cars under ``MultiAgentAction``, else the ego."""
    return list(base.controlled_vehicles) if _multi(base) else [base.vehicle]


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
        self.per_car = None          # per controlled car (several): CAR_COUNTS and distance
        self.multi = False

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
        from guardian.roads import RoadMap
        from guardian.sensing import read_road

        base = env.unwrapped
        if self.estimator is not None:
            self.estimator.reset()
        if self.overtake and self.monitor is not None:
            self.monitor.reset()
        if self.recorder is not None:
            self.recorder.start_episode(env, episode)
        self.episode, self.t = episode, 0
        self.road = read_road(base)
        self.on_map = isinstance(self.road, RoadMap)
        self.cars = guarded_cars(base)
        self.last_blind = [None] * len(self.cars)
        self.multi = _multi(base)
        if self.multi and self.per_car is None:
            self.per_car = [dict({k: 0 for k in CAR_COUNTS}, distance=0.0) for _ in self.cars]
        self.x0 = [self._along(v) for v in self.cars]
        self.ending = {slot for slot, _ in self.road.ends} if self.on_map else set()
        self.began_ending = [self._slot(v) in self.ending for v in self.cars]
        self.judge = FaultJudge.for_env(base, 1.0 / base.config["policy_frequency"])
        self.judge.start(base, self.cars)
        self.slots = [self._body_slots(v) for v in self.cars] if self.on_map else None
        self.checkers = None if self.overtake else [_SelfSafetyCheck(base, self.road, v, self.multi) for v in self.cars]
        self.inside = self._start_inside(env, base)
        self.totals["starts_outside"] += int(not self.inside)

    def _along(self, v) -> float:
        """Position along the road (along the lane's chain on a RoadMap)."""
        x = float(v.position[0])
        return self.road.longitudinal(v.lane_index, x, float(v.position[1])) if self.on_map else x

    def _slot(self, v) -> int:
        return self.road.slot_of(v.lane_index) if self.on_map else v.lane_index[2]

    def _body_slots(self, v) -> frozenset:
        return self.road.body_slots(float(v.position[0]), float(v.position[1]), float(v.heading), v.LENGTH, v.WIDTH)

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
        return all(c.inside(base) for c in self.checkers)

    def before_step(self, env, obs, action) -> None:
        self.lanes_before = [self._slot(v) for v in self.cars]

    def after_step(self, env, obs, action, info) -> None:
        base, totals = env.unwrapped, self.totals
        self.t += 1
        g = info.get("guardian")
        records = (g["agents"] if self.multi else [g]) if g else [None] * len(self.cars)
        totals["steps"] += 1
        for i, (v, r) in enumerate(zip(self.cars, records)):
            changed = int(self._slot(v) != self.lanes_before[i])
            totals["lane_changes"] += changed
            _count_step(totals, r)
            if r and r["model_violations"]["traffic_blind"]:
                self.last_blind[i] = self.t
            if self.multi:
                self.per_car[i]["lane_changes"] += changed
                if r:
                    self.per_car[i]["override_steps"] += int(r["safety_override"])
                    self.per_car[i]["refused_lane_changes"] += int(r["refused_lane_change"])
        if g:
            totals["reattachments"] += int(g["reattached"])
        entries_before = [len(e) for e in self.judge.car_entries]
        crashes = self.judge.observe_all(base)
        for i, (v, r) in enumerate(zip(self.cars, records)):
            if self.on_map:  # entries into slots (the judge's lines are not the guardian's lanes)
                now = self._body_slots(v)
                entered = [self.road.itha_lane(k) for k in now - self.slots[i]]
                self.slots[i] = now
            else:
                entered = [self.road.itha_lane(lane) for _, lane in self.judge.car_entries[i][entries_before[i]:]]
            if r is not None:
                held = set(r["lanes"]) | set(r["entered"])
                totals["unchecked_entries"] += sum(lane not in held for lane in entered)
            totals["reversing_steps"] += int(v.speed < -1e-9)
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
            totals["safety_violations"] += sum(not c.inside(base) for c in self.checkers)
        if self.recorder is not None:
            self.recorder.log(env, self.episode, self.t, g)
        for crash in crashes:
            self._count_crash(crash, records[crash.car] or {})

    def _count_crash(self, crash, g: dict) -> None:
        totals = self.totals
        totals["collisions"] += 1
        at_fault = crash.guarded_at_fault
        if self.inside:
            totals["ego_at_fault_collisions"] += int(at_fault)
        else:
            totals["collisions_after_outside_starts"] += 1
            totals["ego_at_fault_after_outside_starts"] += int(at_fault)
        row = {"episode": self.episode, "step": self.t, "fault": crash.fault, "rule": crash.rule,
               "partner": crash.partner, "start_inside": self.inside,
               "level": g.get("level"), "reasons": g.get("reasons", [])}
        if self.guardian:
            blind = self.last_blind[crash.car]
            row["steps_since_traffic_blind"] = None if blind is None else self.t - blind
        if self.multi:
            row.update({"car": crash.car, "partner_car": crash.partner_car})
            totals["guarded_pair_collisions"] = totals.get("guarded_pair_collisions", 0) + int(
                crash.partner_car is not None)
            for i in {crash.car} | ({crash.partner_car} if crash.partner_car is not None else set()):
                self.per_car[i]["collisions"] += 1
            blamed = crash.car if crash.fault == "ego" else crash.partner_car
            if blamed is not None:
                self.per_car[blamed]["at_fault_collisions"] += 1
        totals["crashes"].append(row)

    def end_episode(self, env, episode) -> None:
        base = env.unwrapped
        if self.estimator is not None and self.estimator.identified_at is not None:
            self.identify.append(self.estimator.identified_at)
            self.totals["wrong_identifications"] += int(self.estimator.valid != [base.model.name])
        for i, v in enumerate(self.cars):
            d = self._along(v) - self.x0[i]
            merged = self.began_ending[i] and self._slot(v) not in self.ending
            self.distance += d / len(self.cars)
            if self.on_map:
                self.totals["merges"] = self.totals.get("merges", 0) + int(merged)
                self.totals["on_ending_lane"] = self.totals.get("on_ending_lane", 0) + int(self.began_ending[i])
            if self.multi:
                self.per_car[i]["distance"] += d
                self.per_car[i]["merges"] += int(merged)
                self.per_car[i]["on_ending_lane"] += int(self.began_ending[i])
        if self.guardian:
            for car in _guardian_of(env).cars:
                for k, v in car.monitor.worst.items():
                    self.monitor_worst[k] = max(self.monitor_worst.get(k, 0.0), v)

    def close(self) -> None:
        if self.recorder is not None:
            self.recorder.close()

    def result(self, episodes: int) -> dict:
        """The counts, each by its rule.

        * ``collisions``: crashes of guarded cars (highway-env's crash flag, which also fires on its
          one-step extrapolation of the bodies); with one ego, episodes whose ego crashed; with several
          controlled cars, a crash between two of them counts once. ``ego_at_fault_collisions``: of those in
          episodes starting inside the guardian's invariant sets (every guarded car's start), the ones
          ``guardian.judge.FaultJudge`` gives to a guarded car (the one judged, or a guarded partner); crashes
          after a start outside are counted apart (``collisions_after_outside_starts``,
          ``ego_at_fault_after_outside_starts``). ``starts_outside``: episodes whose start lay outside the
          sets for some guarded car (with the guardian, its own test; without, self-safety towards the cars
          ahead).
        * ``safety_violations``: steps ending outside the safe set (6.8) (HighwayOvertake) or with no
          self-safe input left (highway-env roads; per guarded car), with or without the guardian.
        * ``unchecked_entries``: lanes a guarded car's body began to overlap in a step whose record lists the
          lane neither among the lanes the guardian held the car in at the step's start nor among the
          entries it checked and found responsible during the step (``guardian.wrapper.allowed_lanes``; on
          roads beyond one straight segment: slots of ``guardian.roads``, the body unwidened).
        * ``traffic_blind_steps``: policy steps in which some traffic car did not see a guarded car its
          model has it react to (``guardian.monitor.traffic_blind_to``: highway-env's v0 roads search one
          lane segment; per guarded car); each crash row's ``steps_since_traffic_blind`` counts the policy
          steps since the crashed car's last such step (None: none this episode). Guarded runs only.
        * ``traffic_reversing_uncovered_steps``: policy steps in which some traffic car had backed up further
          than the guardian covers (``GuardianConfig.reverse_reach``; ``guardian.monitor``). Guarded runs only.
        * ``reversing_steps``: steps ending with a negative speed (per guarded car). ``unsupervised_steps``:
          simulation steps the guardian's hook did not see. ``reattachments``: steps at which the
          guardian found the ego reset or replaced behind its back.
        * ``override_steps``: policy steps the guardian changed for safety; ``model_clip_steps``:
          simulation steps whose only change was a clip to the model's bounds (highway-env's top speed);
          ``clipped_sim_steps``, ``refused_lane_changes``, ``follower_dropped_steps``, ``conflict_steps``,
          ``failsafe_steps``: from ``info["guardian"]``; ``lane_changes``: policy
          steps whose lane index (slot) changed; ``distance_mean``: mean distance along the road per episode
          and guarded car. With several guarded cars every per-step count is summed over the cars.
        * On roads beyond one straight segment: ``on_ending_lane``: guarded cars that began an episode on a
          lane that ends (an on-ramp's); ``merges``: those of them on a lane that goes on at the episode's end.
        * With several controlled cars: ``guarded_cars``, ``guarded_pair_collisions`` (crashes between two
          guarded cars) and ``agents``: per car (in highway-env's controlled order) its collisions,
          at-fault collisions, lane changes, overrides, refusals, merges and mean distance.
        """
        totals = self.totals
        totals["episodes"] = episodes
        totals["distance_mean"] = self.distance / episodes
        if not self.guardian:  # measured only by the guardian's monitor (and, on HighwayOvertake, from the env)
            for k in ("traffic_model_violation_steps", "traffic_blind_steps", "traffic_reversing_uncovered_steps"):
                totals[k] = None
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
        if self.multi:
            totals["guarded_cars"] = len(self.per_car)
            totals.setdefault("guarded_pair_collisions", 0)
            totals["agents"] = [dict({k: c[k] for k in CAR_COUNTS}, distance_mean=c["distance"] / episodes)
                                for c in self.per_car]
        return totals


class _SelfSafetyCheck:
    """Whether a guarded car has a self-safe input (7.4) towards the cars ahead in its lanes (and, on a
    ``RoadMap``, its lane's end)."""

    def __init__(self, base, road, car=None, multi: bool = False):
        from guardian.config import GuardianConfig
        from guardian.traffic import TrafficSupervisor
        from itha.car_following import CarFollowingParams

        c = GuardianConfig()
        self.dt = 1.0 / base.config["simulation_frequency"]
        self.road, self.accel, self.reverse_reach = road, c.traffic_accel, c.reverse_reach
        self.car = base.vehicle if car is None else car
        self.guarded = frozenset(id(v) for v in guarded_cars(base)) if multi else frozenset()
        self.traffic = TrafficSupervisor(CarFollowingParams(dt=self.dt, v_max=c.v_max, h_min=c.h_min,
                                                            u_min=-c.traffic_accel, u_max=c.traffic_accel,
                                                            d_min=-c.traffic_accel, d_max=c.traffic_accel),
                                         wreck_margin=c.wreck_margin)

    def inside(self, base) -> bool:
        from guardian.judge import body_lanes
        from guardian.roads import RoadMap
        from guardian.sensing import road_scene

        ego = self.car
        if isinstance(self.road, RoadMap):
            lanes = self.road.body_slots(float(ego.position[0]), float(ego.position[1]), float(ego.heading),
                                         ego.LENGTH, ego.WIDTH) or {self.road.slot_of(ego.lane_index)}
        else:
            lanes = body_lanes(ego, self.road.lane_width, self.road.n_lanes) or {ego.lane_index[2]}
        scene = road_scene(base, self.road, {self.road.itha_lane(i) for i in lanes}, ego=ego, guarded=self.guarded,
                           reverse_reach=self.reverse_reach)
        speeds, _ = self.traffic.self_safe_speeds(scene)
        v, reach = float(ego.speed), self.accel * self.dt
        return any(max(lo, v - reach) <= min(hi, v + reach) for lo, hi in speeds)


def _count_step(totals: dict, g: dict | None) -> None:
    if not g:
        return
    totals["override_steps"] += int(g["safety_override"])
    totals["model_clip_steps"] += g["model_clip_steps"]
    totals["refused_lane_changes"] += int(g["refused_lane_change"])
    totals["clipped_sim_steps"] += g["clipped_steps"]
    mv = g["model_violations"]
    totals["model_violation_steps"] += int(mv["ego"] + mv["lead"] > 0)
    totals["traffic_model_violation_steps"] += int(mv["traffic"] > 0)
    totals["traffic_blind_steps"] += int(mv["traffic_blind"] > 0)
    totals["traffic_reversing_uncovered_steps"] += int(mv["traffic_reversing_uncovered"] > 0)
    for k in ("follower_dropped_steps", "conflict_steps", "failsafe_steps", "unsupervised_steps"):
        totals[k] += g[k]


def _guardian_of(env):
    """The ``Guardian`` inside a stack of wrappers."""
    from guardian.wrapper import Guardian

    while not isinstance(env, Guardian):
        env = env.env
    return env
