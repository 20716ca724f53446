"""Supervised rollouts of the overtake scenario (Section 6.5.3)."""
from __future__ import annotations

import sys
import time

import numpy as np

from envs.drivers import make_driver
from envs.overtake import OvertakeEnv
from envs.wrappers import OvertakeGuardianWrapper
from guardian.supervisor import IntentionAwareGuardian
from intention.estimator import IntentionEstimator


def overtake_rollouts(library, intention: str, driver: str, episodes: int, seed: int,
                      guardian: bool = True, use_intention: bool = True, disturbance: str = "random",
                      max_steps: int = 300, horizon: int = 10, rerun_path=None, progress: bool = True) -> dict:
    """Run ``episodes`` seeded episodes; episode i uses seed ``seed + i`` for the env and the driver.

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
                totals["failsafe_steps"] += int(record["unsafe"])
            if recorder:
                recorder.log_step(prev, library.params.dt, record, proposed, applied)
            done = terminated or truncated
        if estimator.identified_at is not None:
            totals["identify_steps"].append(estimator.identified_at)
            totals["wrong_identifications"] += int(estimator.valid != [intention])
        if progress and ((ep + 1) % max(1, episodes // 10) == 0 or ep + 1 == episodes):
            print(f"[rollout {intention}/{driver}] {ep + 1}/{episodes} episodes, "
                  f"{time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    if recorder:
        recorder.close()
    ident = totals.pop("identify_steps")
    return {"episodes": episodes, "intention": intention, "driver": driver, "disturbance": disturbance,
            "guardian": guardian, "intention_aware": guardian and use_intention, **totals,
            "mean_steps_to_identify_intention": float(np.mean(ident)) if ident else None,
            "identified_fraction": len(ident) / episodes if episodes else 0.0,
            "seconds": round(time.perf_counter() - t0, 3)}
