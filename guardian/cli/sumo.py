"""``guardian sumo``: guarded episodes among Eclipse SUMO's traffic, one setting or a campaign (docs/sumo.md)."""
from __future__ import annotations

import contextlib
import itertools

from guardian.cli.common import (count, emit, lag_seconds, number, output_file, output_folder, positive_number,
                                  usage_error)
from guardian.cli.progress import ProgressBar
from guardian.evaluation.sumo_agents import AGENTS

TRAFFIC = ("Krauss", "IDM", "EIDM")
DECEL = 4.5          # [m/s^2] the traffic's decel (guardian.adapters.sumo.network.Traffic)
MIN_LENGTH = 500.0    # [m]
MAX_FLOW = 36_000.0  # [vehicles per hour] one per SUMO step of 0.1 s: SUMO refuses a denser flow


def cmd_sumo(args) -> int:
    import time

    from guardian.errors import ConfigError, SchedulerError

    refusal = _refusal(args)
    if refusal:
        return usage_error(args, refusal)
    try:
        cells = _cells(args)
    except ConfigError as exc:
        return usage_error(args, str(exc))
    if args.write_scenario:
        return _write_scenario(args, cells[0][0])
    work = [(cell, seed) for cell in cells for seed in range(args.seed, args.seed + args.episodes)]
    progress, done, start = ProgressBar("sumo"), {}, time.perf_counter()
    try:
        with _service(args) as ask, _recorder(args) as recorder:
            for (cell, seed), result in _run(work, args, ask, progress, recorder):
                done.setdefault(cell, []).append((seed, result))
    except ConfigError as exc:
        return usage_error(args, str(exc))
    except SchedulerError as exc:
        return usage_error(args, f"--scheduler: {exc}")
    except KeyboardInterrupt:
        _emit(args, done, time.perf_counter() - start, interrupted=True)  # the episodes that finished
        raise
    finally:
        from guardian.adapters.sumo.connection import close_servers

        close_servers()
    _emit(args, done, time.perf_counter() - start)
    return 0


def _write_scenario(args, setting) -> int:
    """``--write-scenario DIR``: the scenario's files and a SUMO configuration naming them, and the server's command."""
    from pathlib import Path

    from guardian.adapters.sumo.network import sumo_home
    from guardian.evaluation.sumo_setting import write_scenario

    cfg = write_scenario(setting, Path(args.write_scenario), args.seed)
    command = [str(sumo_home() / "bin" / "sumo"), "-c", str(cfg), "--remote-port", "8813"]
    emit({"config": str(cfg), "server_command": command}, args.json,
         f"wrote {cfg}\nstart a SUMO server on it: {' '.join(command)}\nthen: guardian sumo --connection HOST:8813 "
         f"--scenario-dir {cfg.parent} (the same options)")
    return 0


def _refusal(args) -> str | None:
    """Why the command line's options do not fit together, or None."""
    if args.through_service and args.no_guardian:
        return "--through-service does not apply with --no-guardian (nothing is asked)"
    if args.through_service and (args.workers > 1 or args.scheduler):
        return "--through-service runs in this process: use --workers 1 and no --scheduler"
    remote = args.connection not in ("libsumo", "traci")
    if remote and (args.workers > 1 or args.scheduler):
        return "--connection HOST:PORT drives one SUMO server from this process: use --workers 1 and no --scheduler"
    if args.write_scenario and (args.campaign or args.connection != "libsumo" or args.scenario_dir):
        return "--write-scenario writes one setting's files and starts nothing: not with --campaign, --connection or --scenario-dir"
    if args.rerun and (args.workers > 1 or args.scheduler or args.campaign):
        return "--rerun records in this process, one setting: use --workers 1, no --scheduler and no --campaign"
    if args.scheduler and args.workers > 1:
        return "--workers does not apply with --scheduler (the Dask cluster has its own workers)"
    if args.campaign:
        given = [f"--{name.replace('_', '-')}" for name in ("agent", "traffic", "sublane", "no_guardian",
                                                             "through_service") if getattr(args, name)]
        if given:
            return (f"{', '.join(given)} do(es) not apply with --campaign (it runs every traffic model, lane-change "
                    "model and agent, guarded and unguarded)")
    if args.start == "ramp" and (args.road != "merge" or args.guarded != 1):
        return "--start ramp needs --road merge (a road with an on-ramp) and one guarded vehicle"
    if args.overapprox == "ordered" and args.guarded == 1:
        return "--overapprox ordered does not apply to one guarded vehicle (nothing to announce): use --guarded N"
    if args.length < MIN_LENGTH:
        return f"--length must be at least {MIN_LENGTH:g} m (the run needs room to insert and to drive), got {args.length:g}"
    if not 0 <= args.sigma <= 1:
        return f"--sigma must be in [0, 1], got {args.sigma:g}"
    if args.emergency_decel < DECEL:
        return f"--emergency-decel must be at least the traffic's decel {DECEL:g} m/s^2, got {args.emergency_decel:g}"
    if args.flow > MAX_FLOW:
        return f"--flow must be at most {MAX_FLOW:g} vehicles per hour (one per SUMO step of 0.1 s), got {args.flow:g}"
    return None


def _emit(args, done: dict, wall: float, interrupted: bool = False) -> None:
    rows = [_row(cell, sorted(results)) for cell, results in done.items()]
    result = {"rows": rows, "episodes_per_cell": args.episodes, "seconds_per_episode": args.seconds, "seed": args.seed,
              "wall_seconds": round(wall, 1), **({"interrupted": True} if interrupted else {})}
    emit(result, args.json, _text(result))


def _cells(args) -> list:
    from guardian.adapters.sumo.network import HighwayNet, Traffic
    from guardian.evaluation.sumo_setting import SumoSetting

    def setting(traffic: str, sublane: bool):
        return SumoSetting(net=HighwayNet.of_road(args.road, lanes=args.lanes, length=args.length), seconds=args.seconds,
                           warmup=args.warmup, guarded=args.guarded, connection=args.connection, start=args.start,
                           jerk=args.jerk, lag=args.lag,
                           traffic=Traffic(car_following=traffic, sublane=sublane, vehicles_per_hour=args.flow,
                                           sigma=args.sigma, emergency_decel=args.emergency_decel))

    if args.campaign:
        return [(setting(t, s), a, g) for t, s, a, g in itertools.product(TRAFFIC, (False, True), AGENTS, (False, True))]
    return [(setting(args.traffic or "Krauss", args.sublane), args.agent or "reckless", not args.no_guardian)]


def _run(work: list, args, ask, progress, recorder=None):
    """``(work item, its result)`` as each episode finishes."""
    from pathlib import Path

    from guardian.config import GuardianConfig
    from guardian.evaluation.sumo import run_episode
    from rcis.parallel import Jobs

    with Jobs(workers=args.workers, scheduler=args.scheduler) as jobs:
        config = GuardianConfig(overapprox=args.overapprox)
        folder = Path(args.scenario_dir) if args.scenario_dir else None
        running = {k: jobs.submit(run_episode, cell[0], cell[1], seed, cell[2], config, folder, ask, recorder)
                   for k, (cell, seed) in enumerate(work)}
        for n, (k, value) in enumerate(jobs.as_completed(running), 1):
            progress(n, len(work))
            yield work[k], value


def _row(cell, results: list) -> dict:
    from guardian.evaluation.sumo import summary

    setting, agent, guarded = cell
    total = summary([r for _, r in results])
    steps = total["traffic_car_steps"]
    crashes = [{"seed": seed, **crash} for seed, r in results for crash in r["crashes"]]
    road = "merge" if setting.net.ramp else ("exit" if setting.net.exit else "straight")
    return {"road": road, "start": setting.start, "guarded": setting.guarded,
            "traffic": setting.traffic.car_following, "lane_change": setting.traffic.lane_change, "agent": agent,
            "guardian": guarded, **total, "per_hour": total["collisions"] / total["hours"] if total["hours"] else 0.0,
            "traffic_uncovered_share": total["traffic_uncovered"] / steps if steps else 0.0, "crashes": crashes}


def _text(result: dict) -> str:
    """Every figure of the JSON: a block per setting, its crashes below it."""
    head = (f"{result['episodes_per_cell']} episode(s) per setting of {result['seconds_per_episode']:g} s, seeds from "
            f"{result['seed']}; {result['wall_seconds']:g} s" + (" (interrupted)" if result.get("interrupted") else ""))
    lines = [head]
    for r in result["rows"]:
        lines.append(f"{r['road']} road, {r['guarded']} guarded (start: {r['start']}): {r['traffic']} {r['lane_change']} {r['agent']} "
                     f"guardian={'on' if r['guardian'] else 'off'}")
        figures = [(k, v) for k, v in r.items() if k not in ("road", "start", "guarded", "traffic", "lane_change",
                                                              "agent", "guardian", "crashes")]
        lines.append("  " + " ".join(f"{k}={_number(v)}" for k, v in figures))
        lines += [f"  crash: seed {c['seed']} step {c['step']} {c['vehicle']} and {c['partner']} rule={c['rule']} "
                  f"at_fault={c['culprit'] or False} start_inside={c['start_inside']}" for c in r["crashes"]]
    return "\n".join(lines)


def _number(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


@contextlib.contextmanager
def _recorder(args):
    """With ``--rerun FILE``: every episode logged to FILE (``guardian.recording.sumo``); else nothing."""
    if not args.rerun:
        yield None
        return
    from guardian.recording.sumo import SumoRecorder

    with SumoRecorder(args.rerun) as recorder:
        yield recorder


@contextlib.contextmanager
def _service(args):
    """With ``--through-service``: a ``guardian serve`` in this process and, per episode, a scene session asked every
    step beside the in-process decision (``guardian.client.shadow.Shadow``); else nothing."""
    if not args.through_service:
        yield None
        return
    from guardian.client import GuardianClient
    from guardian.client.bodies import guardian_body, vehicle_body
    from guardian.client.shadow import Shadow
    from guardian.service import ServiceConfig, ServiceThread
    from intention.library import build_library

    with ServiceThread(build_library(quiet=True), ServiceConfig(port=0)) as service, \
            GuardianClient(service.url) as client:
        def ask(guard, road):
            session = client.create_scene_session(road, vehicle_body(guard.kin, guard.meta, guard.actuator),
                                                  guardian_body(guard.config))
            return Shadow(guard, session, road)

        yield ask


def add_commands(sub) -> None:
    p = sub.add_parser("sumo", help="guarded episodes among Eclipse SUMO's traffic (needs guardian[sumo])")
    p.add_argument("--episodes", type=count(1), default=4, help="episodes per setting (4)")
    p.add_argument("--agent", choices=AGENTS, default=None,
                   help="the driver the guardian supervises: random, reckless, seek (the nearest body ahead) or sumo "
                        "(SUMO's own car-following and lane-change models with its lane-change checks off) (reckless)")
    p.add_argument("--traffic", choices=TRAFFIC, default=None, help="SUMO's car-following model (Krauss)")
    p.add_argument("--sublane", action="store_true",
                   help="SL2015 with 0.8 m sublanes: traffic drifts inside and across lanes (default LC2013)")
    p.add_argument("--campaign", action="store_true",
                   help="every traffic model x lane-change model x agent, guarded and unguarded, in one table")
    p.add_argument("--lanes", type=count(1), default=3, help="lanes of the straight highway (3)")
    p.add_argument("--road", choices=("straight", "merge", "exit"), default="straight",
                   help="a straight highway; one an on-ramp joins at a third of its length through a 250 m "
                        "acceleration lane that ends (merge); one an exit leaves at a third of its length after a "
                        "250 m deceleration lane (exit) (straight)")
    p.add_argument("--start", choices=("main", "ramp"), default="main",
                   help="where the guarded vehicle starts: on a main lane, or on the on-ramp (--road merge, one "
                        "guarded vehicle; the result counts ramp_starts and merged) (main)")
    p.add_argument("--length", type=positive_number, default=3000.0, help="the highway's length [m] (3000)")
    p.add_argument("--guarded", type=count(1), default=1,
                   help="guarded vehicles, each with its own guardian and driver, all others traffic to it (1)")
    p.add_argument("--overapprox", choices=("trivial", "ordered"), default="trivial",
                   help="with several guarded vehicles: ordered, they decide in Example 8's order and announce "
                        "their lanes to the ones after (trivial)")
    p.add_argument("--flow", type=positive_number, default=3000.0, help="traffic vehicles per hour (3000)")
    p.add_argument("--sigma", type=number, default=0.5, help="the traffic drivers' imperfection, 0..1 (0.5)")
    p.add_argument("--emergency-decel", type=positive_number, default=6.0,
                   help="the traffic's hardest braking [m/s^2] (6); the guardian's traffic model reads it")
    p.add_argument("--seconds", type=positive_number, default=60.0, help="simulated seconds per episode (60)")
    p.add_argument("--warmup", type=positive_number, default=40.0,
                   help="simulated seconds of traffic before the guarded vehicle enters (40)")
    p.add_argument("--seed", type=count(0), default=0, help="the first episode's seed (0)")
    p.add_argument("--jerk", type=positive_number, default=None, metavar="J",
                   help="the guarded vehicles' actuator changes their acceleration by at most J m/s^3 (the guardian's "
                        "sets then carry the acceleration)")
    p.add_argument("--lag", type=lag_seconds, default=None, metavar="TAU",
                   help="the guarded vehicles' actuator follows a command as a first-order lag of time constant TAU "
                        "seconds (sampled each step; with --jerk, within its bound too)")
    p.add_argument("--no-guardian", action="store_true", help="the agent drives unsupervised (for comparison)")
    p.add_argument("--through-service", action="store_true",
                   help="also ask every decision of a guardian serve scene session (started here) and count the "
                        "answers that differ from the in-process ones to the bit")
    p.add_argument("--connection", default="libsumo", metavar="libsumo|traci|HOST:PORT",
                   help="libsumo in this process (default); traci: SUMO in its own process over TraCI's socket; "
                        "HOST:PORT: a SUMO server started on --write-scenario's files")
    p.add_argument("--scenario-dir", type=output_folder, default=None, metavar="DIR",
                   help="write each episode's scenario files here (a folder a remote server reads at the same path)")
    p.add_argument("--write-scenario", type=output_folder, default=None, metavar="DIR",
                   help="write the setting's scenario files and a SUMO configuration into DIR, print the server's "
                        "command, and exit")
    p.add_argument("--rerun", type=output_file, default=None, metavar="FILE.rrd",
                   help="record every episode for the rerun viewer (road, cars, shadows, overrides, crashes)")
    p.add_argument("--workers", type=count(1), default=1, help="local processes running episodes (1)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="a Dask scheduler's address (tcp://host:8786) to run the episodes on")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_sumo)
