"""The guardian's cost per SUMO step beside SUMO's own: reading the scene, deciding, and SUMO's step.

Run: python benchmarks/bench_sumo.py [--episodes 4] [--seconds 60] [--agent reckless] [--traffic Krauss]
          [--guarded 1] [--length 3000] [--road straight|merge|exit] [--json]

Runs guarded episodes of ``guardian.evaluation.sumo`` (libsumo in process, ``--guarded`` vehicles) with timers around
SUMO's ``simulationStep``, the scene read (every vehicle's body from SUMO, once per step), the road indexed once per
step (``guardian.model.sensing.Traffic``), each guarded vehicle's scene taken from it and its decision
(``BicycleGuardian.step``); prints each one's median and p99 in milliseconds, the
traffic's size, the wall time one simulated hour would take at those medians, and the wall time measured (warm-up,
insertion, shadows and counting included), and the process's CPU time per episode (SUMO runs in the process: its
warm-up, the guardian and the counts; a figure other jobs on the machine inflate less than wall times, for comparing
two versions of the code). Run it on a quiet machine.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

import guardian.evaluation.sumo as sumo_run
from guardian.adapters.sumo.network import HighwayNet, Traffic
from guardian.evaluation.sumo_agents import AGENTS


def timed(store: list, fn):
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        store.append(time.perf_counter() - t0)
        return out
    return wrapper


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--episodes", type=int, default=4)
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--agent", default="reckless", choices=AGENTS)
    p.add_argument("--guarded", type=int, default=1, help="guarded vehicles (1)")
    p.add_argument("--length", type=float, default=3000.0, help="the highway's length [m] (3000)")
    p.add_argument("--traffic", default="Krauss", choices=("Krauss", "IDM", "EIDM"))
    p.add_argument("--road", default="straight", choices=("straight", "merge", "exit"),
                   help="the straight highway, or one with an on-ramp or an exit a third of the way along")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    import contextlib
    import sys

    with contextlib.redirect_stdout(sys.stderr):  # libsumo warns about pyarrow's version on stdout
        import libsumo

    times = {"sumo_step": [], "scene": [], "decision": []}
    vehicles = []
    real_step, real_decide = libsumo.simulationStep, sumo_run.BicycleGuardian.step
    real_traffic, real_scene = sumo_run.traffic_of, sumo_run.sensed_scene
    libsumo.simulationStep = timed(times["sumo_step"], real_step)
    sumo_run.BicycleGuardian.step = timed(times["decision"], real_decide)

    def traffic_of(frame, bodies, *rest):
        vehicles.append(len(bodies))
        return real_traffic(frame, bodies, *rest)

    sumo_run.traffic_of = timed(times.setdefault("index", []), traffic_of)
    sumo_run.sensed_scene = timed(times["scene"], real_scene)
    real_body = sumo_run.Frame.body
    sumo_run.Frame.body = timed(times.setdefault("body_reads", []), real_body)
    setting = sumo_run.SumoSetting(seconds=args.seconds, traffic=Traffic(car_following=args.traffic),
                                   guarded=args.guarded, net=HighwayNet.of_road(args.road, length=args.length))
    t0, cpu0 = time.perf_counter(), time.process_time()
    try:
        results = [sumo_run.run_episode(setting, args.agent, seed) for seed in range(args.episodes)]
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    finally:
        libsumo.simulationStep, sumo_run.BicycleGuardian.step = real_step, real_decide
        sumo_run.traffic_of, sumo_run.sensed_scene = real_traffic, real_scene
        sumo_run.Frame.body = real_body
    if not times["decision"]:
        raise SystemExit(f"no guarded vehicle was inserted in {args.episodes} episodes (inserted: "
                         f"{[r['inserted'] for r in results]}): give the road room for them (--length)")
    steps = sum(r["steps"] for r in results)
    vehicle_steps = sum(r["vehicle_steps"] for r in results)
    reads_per_step = len(times["body_reads"]) / max(steps, 1)
    out = {"episodes": args.episodes, "guarded": args.guarded, "sumo_steps": steps, "guarded_steps": vehicle_steps,
           "guarded_mean": vehicle_steps / max(steps, 1), "vehicles_mean": float(np.mean(vehicles)),
           "reads_ms_per_step": 1e3 * sum(times["body_reads"]) / max(steps, 1), "reads_per_step": reads_per_step,
           "index_ms_per_step": 1e3 * sum(times["index"]) / max(steps, 1),
           "wall_s": round(wall, 1), "simulated_s": steps * setting.step_length, "road": args.road,
           "cpu_s_per_episode": round(cpu / args.episodes, 3)}
    for name in ("sumo_step", "scene", "decision"):
        ms = 1e3 * np.array(times[name])  # SUMO's steps: the warm-ups' too (the same traffic)
        out[name] = {"median_ms": round(float(np.median(ms)), 4), "p99_ms": round(float(np.percentile(ms, 99)), 4)}
    per_step = out["sumo_step"]["median_ms"] + out["reads_ms_per_step"] + out["index_ms_per_step"] + out["guarded_mean"] * (
        out["scene"]["median_ms"] + out["decision"]["median_ms"])
    out["wall_s_per_simulated_hour"] = round(per_step / 1e3 * 3600 / setting.step_length, 1)
    out["measured_wall_s_per_simulated_hour"] = round(wall / max(out["simulated_s"], 1e-9) * 3600, 1)
    if args.json:
        print(json.dumps(out, indent=2))
        return
    print(f"{steps} SUMO steps, {out['guarded_mean']:.1f} guarded vehicles and {out['vehicles_mean']:.1f} vehicles in "
          f"the scene on average")
    for name in ("sumo_step", "scene", "decision"):
        print(f"  {name:10s} median {out[name]['median_ms']:.3f} ms  p99 {out[name]['p99_ms']:.3f} ms")
    print(f"  reading every body from SUMO: {out['reads_ms_per_step']:.3f} ms per step ({reads_per_step:.0f} reads)")
    print(f"  indexing the road once for every guarded vehicle: {out['index_ms_per_step']:.3f} ms per step")
    print(f"  CPU per episode (SUMO with its warm-up, the guardian, the counts): {out['cpu_s_per_episode']:.2f} s")
    print(f"  one simulated hour at these medians: {out['wall_s_per_simulated_hour']:g} s; measured (warm-up and "
          f"insertion included): {out['measured_wall_s_per_simulated_hour']:g} s")


if __name__ == "__main__":
    main()
