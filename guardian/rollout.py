"""Supervised rollouts of the overtake scenario (Section 6.5.3)."""
from __future__ import annotations

import time

import numpy as np

from envs.drivers import make_driver
from envs.overtake import OvertakeEnv
from envs.wrappers import OvertakeGuardianWrapper
from guardian.supervisor import IntentionAwareGuardian
from intention.estimator import IntentionEstimator


def overtake_rollouts(library, intention: str, driver: str, episodes: int, seed: int,
                      guardian: bool = True, use_intention: bool = True, disturbance: str = "random",
                      max_steps: int = 300, horizon: int = 10, rerun_path=None, progress=None) -> dict:
    """Run ``episodes`` seeded episodes; episode i uses seed ``seed + i`` for the env and the driver.

    ``progress(done, total)`` is called after each episode (as ``highway_rollouts`` does).

    Initial states are drawn inside ``C_bnd`` (Theorem 4's assumption). The estimator
    statistics come from the guardian's estimator, or from a passive one when the guardian
    does not estimate (so the numbers are comparable across modes).
    """
    env = OvertakeEnv({"intention": intention, "disturbance": disturbance, "max_steps": max_steps,
                       "initial_region": library.region("bounded_velocity"), "params": library.params})
    guard = IntentionAwareGuardian(library, use_intention=use_intention, horizon=horizon) if guardian else None
    if guard is not None:
        env = OvertakeGuardianWrapper(env, guard)
    passive = not (guard is not None and use_intention)  # estimate alongside, for the statistics
    estimator = IntentionEstimator({n: library.models[n] for n in ("aggressive", "cautious")},
                                   horizon=horizon) if passive else guard.estimator
    drv = make_driver(driver, library.params)
    recorder = None
    if rerun_path is not None:
        from guardian.rerun_log import OvertakeRecorder
        recorder = OvertakeRecorder(rerun_path)
    totals = {"steps": 0, "safety_violations": 0, "override_steps": 0, "failsafe_steps": 0,
              "identify_steps": [], "wrong_identifications": 0}
    try:
        t0 = time.perf_counter()
        for ep in range(episodes):
            obs, _ = env.reset(seed=seed + ep)
            drv.reset(np.random.default_rng(seed + ep + 1_000_003))
            if passive:
                estimator.reset()
            if recorder:
                recorder.start_episode(ep, obs)
            done = False
            while not done:
                proposed = drv.act(obs)
                prev = obs
                obs, _, terminated, truncated, info = env.step(proposed)
                record = info.get("guardian")
                applied = np.array(record["applied"]) if record else proposed
                if passive:
                    estimator.update(prev, applied, obs)
                totals["steps"] += 1
                totals["safety_violations"] += int(info["unsafe"])
                if record:
                    totals["override_steps"] += int(record["overridden"])
                    totals["failsafe_steps"] += int(record["failsafe"])
                if recorder:
                    recorder.log_step(prev, library.params.dt, record, proposed, applied)
                done = terminated or truncated
            if estimator.identified_at is not None:
                totals["identify_steps"].append(estimator.identified_at)
                totals["wrong_identifications"] += int(estimator.valid != [intention])
            if progress:
                progress(ep + 1, episodes)
    finally:  # the .rrd is closed on every exit
        if recorder:
            recorder.close()
    ident = totals.pop("identify_steps")
    return {"episodes": episodes, "intention": intention, "driver": driver, "disturbance": disturbance,
            "guardian": guardian, "intention_aware": guardian and use_intention, **totals,
            "mean_steps_to_identify_intention": float(np.mean(ident)) if ident else None,
            "identified_fraction": len(ident) / episodes if episodes else 0.0,
            "seconds": round(time.perf_counter() - t0, 3)}


# ---- highway-env environments (guardian/HighwayOvertake-v0, the highway-v0 family) ------------------
OVERTAKE_ENV = "guardian/HighwayOvertake-v0"
ACTIONS = {"meta": {"type": "DiscreteMetaAction"}, "continuous": {"type": "ContinuousAction"}}


def highway_env_config(env_id: str, action: str | None, intention: str | None = None, disturbance: str = "random",
                       traffic: int | None = None, library=None, extra: dict | None = None) -> dict:
    """The env config of a rollout: the action type, and on HighwayOvertake the scenario's choices.

    On HighwayOvertake initial states are drawn inside ``C_bnd`` (Theorem 4's assumption).
    """
    config = dict(extra or {})
    if env_id == OVERTAKE_ENV:
        from envs.highway_overtake import HighwayOvertakeEnv

        config.update({"intention": intention or "cautious", "disturbance": disturbance})
        if traffic is not None:
            config["traffic_count"] = traffic
            config["traffic_from_behind"] = min(HighwayOvertakeEnv.default_config()["traffic_from_behind"], traffic)
        if library is not None:
            config["initial_region"] = library.region("bounded_velocity")
        if action == "meta":
            config["action"] = dict(ACTIONS["meta"])
    elif action is not None:
        config["action"] = dict(ACTIONS[action])
        if traffic is not None:
            config["vehicles_count"] = traffic
    return config


def highway_rollouts(env_id: str, agent: str, episodes: int, seed: int, *, action: str | None = None,
                     guardian: bool = True, library=None, intention: str | None = None,
                     disturbance: str = "random", traffic: int | None = None, use_intention: bool = True,
                     env_config: dict | None = None, guardian_config=None, progress=None, recorder=None,
                     video_dir=None) -> dict:
    """Seeded episodes of one agent on a highway-env environment, with or without the ``Guardian``.

    Episode i resets the env with seed ``seed + i`` and seeds the agent with ``[seed, i]``.

    Returns
    -------
    dict
        ``episodes, steps, collisions, ego_at_fault_collisions, override_steps, refused_lane_changes,
        clipped_sim_steps, lane_changes, distance_mean, model_violation_steps`` (steps where the ego's or
        the lead's observed transition left the model), ``traffic_model_violation_steps``,
        ``conflict_steps, failsafe_steps, crashes``; on HighwayOvertake also ``safety_violations``
        (exits from the safe set (6.8)), ``wrong_identifications``, ``mean_steps_to_identify_intention``,
        ``identified_fraction``.
    """
    import gymnasium as gym

    import envs  # noqa: F401 - registers guardian/HighwayOvertake-v0
    import highway_env  # noqa: F401 - registers the highway-env environments
    from envs.agents import collision_fault, make_agent
    from guardian.wrapper import EntryLedger, Guardian, GuardianConfig

    overtake = env_id == OVERTAKE_ENV
    config = highway_env_config(env_id, action, intention, disturbance, traffic, library, env_config)
    env = gym.make(env_id, config=config, render_mode="rgb_array" if video_dir else None)
    if guardian:
        gcfg = guardian_config or GuardianConfig(use_intention=use_intention)
        env = Guardian(env, library, gcfg)
    if video_dir:
        env = gym.wrappers.RecordVideo(env, str(video_dir), episode_trigger=lambda e: True,
                                       name_prefix=env_id.replace("/", "-"), disable_logger=True)
    estimator = monitor = None
    if overtake:
        from guardian.monitor import ModelMonitor
        from intention.estimator import IntentionEstimator
        from intention.models import intention_models

        models = intention_models(env.unwrapped.params)
        candidates = {n: models[n] for n in ("aggressive", "cautious")}
        estimator = IntentionEstimator(candidates, horizon=10)
        if not guardian:  # the guardian's own monitor counts when it is there
            g = GuardianConfig()
            monitor = ModelMonitor(env.unwrapped.params.dt, (-g.traffic_accel, g.traffic_accel), g.v_max,
                                   env.unwrapped.params, candidates)
    totals = {"episodes": episodes, "steps": 0, "collisions": 0, "ego_at_fault_collisions": 0, "override_steps": 0,
              "refused_lane_changes": 0, "clipped_sim_steps": 0, "lane_changes": 0, "distance_mean": 0.0,
              "model_violation_steps": 0, "traffic_model_violation_steps": 0, "conflict_steps": 0,
              "failsafe_steps": 0, "crashes": []}
    if overtake:
        totals.update({"safety_violations": 0, "wrong_identifications": 0})
    identify = []
    distance = 0.0
    monitor_worst = {}
    try:
        for ep in range(episodes):
            obs, info = env.reset(seed=seed + ep)
            base = env.unwrapped
            pol = make_agent(agent, env, np.random.default_rng([seed, ep]))
            if estimator is not None:
                estimator.reset()
            if recorder is not None:
                recorder.start_episode(env, ep)
            x0 = float(base.vehicle.position[0])
            ledger = EntryLedger(base) if overtake else None
            done, t = False, 0
            while not done:
                lane_before = base.vehicle.lane_index[2]
                y_before = float(base.vehicle.position[1])
                if ledger is not None:
                    ledger.before_step(base)
                obs, _, term, trunc, info = env.step(pol(obs))
                t += 1
                if ledger is not None:
                    ledger.after_step(base)
                _count_step(totals, info.get("guardian"), base, lane_before)
                if estimator is not None:
                    tr = base.last_transition
                    estimator.update(tr["state"], tr["input"], tr["next_state"])
                if monitor is not None:
                    totals["model_violation_steps"] += int(sum(monitor.overtake_transition(
                        tr["state"], tr["input"], tr["next_state"])) > 0)
                    totals["safety_violations"] += int(info["unsafe"])
                if recorder is not None:
                    recorder.log(env, ep, t, info.get("guardian"))
                fault = collision_fault(env, y_before if overtake else None,
                                        ledger.entered_responsibly if ledger is not None else None)
                if fault:
                    g = info.get("guardian") or {}
                    totals["collisions"] += 1
                    totals["ego_at_fault_collisions"] += int(fault == "ego")
                    totals["crashes"].append({"episode": ep, "step": t, "fault": fault,
                                              "conflict": bool(g.get("conflict_steps")),
                                              "reasons": g.get("reasons", [])})
                done = term or trunc
            if estimator is not None and estimator.identified_at is not None:
                identify.append(estimator.identified_at)
                totals["wrong_identifications"] += int(estimator.valid != [base.model.name])
            distance += float(base.vehicle.position[0]) - x0
            if guardian:
                for k, v in _guardian_of(env).monitor.worst.items():
                    monitor_worst[k] = max(monitor_worst.get(k, 0.0), v)
            if progress:
                progress(ep + 1, episodes)
    finally:
        env.close()
    totals["distance_mean"] = distance / episodes
    if not guardian:  # measured only by the guardian's monitor (and, on HighwayOvertake, from the env's transitions)
        totals["traffic_model_violation_steps"] = None
        if not overtake:
            totals["model_violation_steps"] = None
    if guardian:
        totals["traffic_model_worst"] = {k: round(v, 6) for k, v in monitor_worst.items()}
    if overtake:
        totals["mean_steps_to_identify_intention"] = float(np.mean(identify)) if identify else None
        totals["identified_fraction"] = len(identify) / episodes
    return totals


def _count_step(totals: dict, g: dict | None, base, lane_before) -> None:
    totals["steps"] += 1
    totals["lane_changes"] += int(base.vehicle.lane_index[2] != lane_before)
    if not g:
        return
    totals["override_steps"] += int(g["overridden"])
    totals["refused_lane_changes"] += int(g["refused_lane_change"])
    totals["clipped_sim_steps"] += g["clipped_steps"]
    mv = g["model_violations"]
    totals["model_violation_steps"] += int(mv["ego"] + mv["lead"] > 0)
    totals["traffic_model_violation_steps"] += int(mv["traffic"] > 0)
    totals["conflict_steps"] += g["conflict_steps"]
    totals["failsafe_steps"] += g["failsafe_steps"]


def _guardian_of(env):
    """The ``Guardian`` inside a stack of wrappers."""
    from guardian.wrapper import Guardian

    while not isinstance(env, Guardian):
        env = env.env
    return env
