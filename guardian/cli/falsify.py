"""``guardian falsify``: the falsification campaign (``guardian.evaluation.campaign``) and its table."""
from __future__ import annotations

from guardian.cli.common import count, emit, lag_seconds, positive_number, progress_bar, usage_error

DEFAULT_WORKERS = 2

COLUMNS = (("episodes", "episodes"), ("steps", "steps"), ("collisions", "collisions"),
           ("ego_at_fault_collisions", "at fault"), ("starts_outside", "starts outside"),
           ("collisions_after_outside_starts", "collisions after outside"),
           ("ego_at_fault_after_outside_starts", "at fault after outside"),
           ("safety_violations", "exits / no self-safe input"), ("failsafe_steps", "fail-safe steps"),
           ("override_steps", "override steps"), ("conflict_steps", "conflict steps"),
           ("unchecked_entries", "unchecked entries"), ("reversing_steps", "reversing steps"),
           ("unsupervised_steps", "unsupervised"), ("traffic_reversing_uncovered_steps", "uncovered reversals"),
           ("episodes_cut", "cut at the time cap"), ("actuator_clipped_steps", "actuator clips"),
           ("exceptions", "exceptions"))


def table(rows: list, title: str) -> str:
    header = [title] + [name for _, name in COLUMNS]
    body = [[r["group"]] + [str(r[k]) for k, _ in COLUMNS] for r in rows]
    widths = [max(len(line[i]) for line in [header, *body]) for i in range(len(header))]
    fmt = lambda line: "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(line, widths)))
    return "\n".join([fmt(header), *(fmt(line) for line in body)])


def _said(failure: dict) -> str:
    """What a failure's record says beside its kind and command (cell, fault, rule)."""
    return ", ".join(f"{k}={v}" for k, v in failure.items() if k not in ("kind", "command"))


def promise_broken(result: dict) -> bool:
    """Whether a guarded campaign found a failure of the promise: a collision at a guarded car's fault
    after a start inside, an unchecked entry, a reversing or unsupervised step, a command the actuator could not
    follow, an exception, or a
    HighwayOvertake exit from the safe set after a start inside."""
    totals = result["totals"]
    counts = ("ego_at_fault_collisions", "exceptions", "unchecked_entries", "reversing_steps", "unsupervised_steps",
              "actuator_clipped_steps")
    return any(totals.get(k, 0) for k in counts) or any(f["kind"] == "safe-set exit" for f in result["failures"])


def cmd_falsify(args) -> int:
    from guardian.errors import SchedulerError
    from guardian.evaluation.campaign import Campaign, campaign_result, matrix, run_campaign

    if args.scheduler and args.workers is not None:
        return usage_error(args, "--workers does not apply with --scheduler (the Dask cluster has its own workers)")
    workers = None if args.scheduler else DEFAULT_WORKERS if args.workers is None else args.workers
    actuator = [name for name, given in (("--jerk", args.jerk is not None), ("--lag", args.lag is not None)) if given]
    if actuator and args.only not in ("highway", "roads"):
        return usage_error(args, f"{' and '.join(actuator)} {'applies' if len(actuator) == 1 else 'apply'} to "
                                 "highway-env's roads: add --only highway or --only roads")
    cells = matrix(guardian=not args.no_guardian, only=args.only, jerk=args.jerk, lag=args.lag)
    if args.agent:
        cells = [c for c in cells if c.agent in args.agent]
        if not cells:
            return usage_error(args, f"no cell drives agent(s) {', '.join(args.agent)}")
    camp = Campaign()
    try:
        result = run_campaign(cells, args.episodes, args.seed, workers, args.scheduler, args.cache_dir,
                              progress_bar("falsify"), camp=camp)
    except SchedulerError as exc:
        return usage_error(args, f"--scheduler: {exc}")
    except KeyboardInterrupt:  # the table of the episodes that finished, then the one line and 130 / 143
        _report(args, campaign_result(camp, cells, args.episodes, workers, args.scheduler, interrupted=True), workers)
        raise
    return _report(args, result, workers)


def _report(args, result: dict, workers) -> int:
    from guardian.cli.rollout import replay_command

    failures = [dict({k: v for k, v in f.items() if k != "replay"}, command=replay_command(f["replay"]))
                for f in result["failures"]]
    result = dict(result, failures=sorted(failures, key=lambda f: (f["kind"], f["command"])))
    spread = f"on the Dask scheduler {args.scheduler}" if args.scheduler else f"{workers} worker(s)"
    stopped = " (interrupted: the episodes that finished)" if result.get("interrupted") else ""
    lines = [f"{result['episodes']} episodes ({result['cells']} cells x {args.episodes}), "
             f"{'guarded' if not args.no_guardian else 'unguarded'}, {result['seconds']} s, {spread}{stopped}", ""]
    if result["episodes"]:
        lines += [table([dict(result["totals"], group="all")], "campaign"), "",
                  table(result["by_env"], "environment"), "", table(result["by_agent"], "agent"), "",
                  table(result["by_setting"], "setting"), ""]
    if result["failures"]:
        lines.append("failures (each replays alone):")
        lines += [f"  {f['kind']} ({_said(f)}): {f['command']}" for f in result["failures"]]
    else:
        lines.append("no failures")
    emit(result, args.json, "\n".join(lines))
    return 1 if promise_broken(result) and not args.no_guardian else 0


def add_commands(sub) -> None:
    from guardian.evaluation.campaign import MPC_AGENTS, MULTI_AGENTS, ROAD_AGENTS

    p = sub.add_parser("falsify", help="the falsification campaign: adversarial agents, many seeds, one table")
    p.add_argument("--episodes", type=count(1), default=5, help="episodes per cell of the matrix (default 5)")
    p.add_argument("--seed", type=count(0), default=0,
                   help="cell k's episode i is seeded with SEED + 1000 k + i (default %(default)s)")
    p.add_argument("--only", choices=["overtake", "highway", "roads"], default=None,
                   help="only guardian/HighwayOvertake-v0, or only the highway-v0 family (the default matrix is "
                        "both), or the roads beyond one straight segment and several guarded cars (merge-v0, "
                        "merge-generic-v0, exit-v0, guardian/Merge-v0)")
    p.add_argument("--agent", action="append", choices=tuple(dict.fromkeys(ROAD_AGENTS + MPC_AGENTS + MULTI_AGENTS)),
                   default=None,
                   help="only the cells of this agent (repeatable); the choices are the agents the campaign's "
                        "cells drive")
    p.add_argument("--no-guardian", action="store_true", help="the same matrix without the guardian")
    p.add_argument("--jerk", type=positive_number, default=None, metavar="J",
                   help="the controlled cars' actuator changes their acceleration by at most J m/s^3 (with --only "
                        "highway or roads)")
    p.add_argument("--lag", type=lag_seconds, default=None, metavar="TAU",
                   help="the controlled cars' actuator follows a command as a first-order lag of time constant TAU "
                        "seconds (with --only highway or roads)")
    p.add_argument("--workers", type=count(1), default=None, help=f"local processes (default {DEFAULT_WORKERS})")
    p.add_argument("--scheduler", default=None,
                   help="the address of an existing Dask scheduler (tcp://host:8786) to run on instead of local "
                        "processes; takes no --workers")
    p.add_argument("--cache-dir", default=None, help="where the overtake sets are cached")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_falsify)
