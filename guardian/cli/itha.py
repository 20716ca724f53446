"""``guardian itha highway|processors``: the Chapter 7 experiments."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from guardian.cli.common import count, emit, json_option, output_file, progress_bar, usage_error


def cmd_itha_highway(args) -> int:
    from itha.car_following import make_set
    from itha.highway_experiment import highway_experiment, run_highway_episode
    from itha.responsibility import OVERAPPROXIMATIONS
    from itha.road import HighwayParams

    if args.set == "closed-form" and (args.cache_dir is not None or args.rebuild):
        return usage_error(args, "--cache-dir and --rebuild do not apply to --set closed-form (nothing is computed)")
    if args.rerun:
        args.rerun.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    prm = HighwayParams()
    S = make_set(prm.car_following, args.set, cache_dir=args.cache_dir, rebuild=args.rebuild,
                 log=lambda m: print(m, file=sys.stderr))
    which = OVERAPPROXIMATIONS if args.overapprox == "both" else (args.overapprox,)
    result = highway_experiment(args.runs, args.steps, args.seed, S, prm, which,
                                progress=progress_bar("itha highway"))
    if args.rerun:
        import numpy as np
        from guardian.recording.rerun import HighwayRecorder

        with HighwayRecorder(args.rerun, prm.n_lanes) as rec:
            for oa in which:
                ep = run_highway_episode(prm, S, oa, args.steps, np.random.default_rng([args.seed, 0]), record=True)
                rec.log_itha_frames(ep.frames)
    out = dict(result)
    out["set"] = {"kind": S.kind, **getattr(S, "info", {})}
    out["seconds"] = round(time.perf_counter() - t0, 3)
    text = "\n".join(f"{oa:8s} distance_mean={r['distance_mean']:.1f} m unsafe_steps={r['unsafe_steps']} "
                     f"lane_changes={r['lane_changes']} collisions={r['collisions']} "
                     f"infeasible_steps={r['infeasible_steps']}\n{'':8s} distances (m): "
                     + " ".join(f"{d:g}" for d in r["distances"])
                     for oa, r in result.items() if oa in which)
    text += "\nset: " + " ".join(f"{k}={v:.2f}" if isinstance(v, float) else f"{k}={v}" for k, v in out["set"].items())
    text += f"\nseconds: {out['seconds']:.1f}"
    emit(out, args.json, text)
    return 0 if all(result[oa]["unsafe_steps"] == 0 for oa in which) else 1


def cmd_itha_processors(args) -> int:
    from itha.processors import ProcessorParams, processors_experiment

    result = processors_experiment(args.runs, args.steps, args.seed, ProcessorParams(keep_jobs=args.keep_jobs),
                                   progress=progress_bar("itha processors"))
    text = "\n".join(f"{k:8s} " + " ".join(f"{f}={v:.2f}" if isinstance(v, float) else f"{f}={v}"
                                          for f, v in r.items()) for k, r in result.items())
    emit(result, args.json, text)
    return 0


def add_commands(sub) -> None:
    out = json_option()
    itha = sub.add_parser("itha", help="inter-triggering hybrid automata experiments (Chapter 7)")
    isub = itha.add_commands("itha_command")
    p = isub.add_parser("highway", help="Section 7.4.1: the responsible ego on a 5-lane highway with IDM traffic",
                        parents=[out])
    p.add_argument("--runs", type=count(1), default=25,
                   help="episodes per over-approximation, the same traffic for each (default %(default)s)")
    p.add_argument("--steps", type=count(1), default=500, help="steps per episode (default %(default)s)")
    p.add_argument("--seed", type=count(0), default=0, help="run r is seeded with [SEED, r] (default %(default)s)")
    p.add_argument("--overapprox", choices=["trivial", "ordered", "both"], default="both",
                   help="how the ego over-approximates the other cars' lane changes: trivial (7.6), ordered "
                        "(Algorithm 1, Example 8's order) or both, compared (default %(default)s)")
    p.add_argument("--set", choices=["polyhedral", "closed-form"], default="polyhedral",
                   help="the car-following RCIS: computed by rcis (cached) or its closed form")
    p.add_argument("--cache-dir", type=Path, default=None, help="where the polyhedral set is cached")
    p.add_argument("--rebuild", action="store_true", help="recompute the polyhedral set")
    p.add_argument("--rerun", type=output_file, default=None, help="record run 0 of each over-approximation (.rrd)")
    p.set_defaults(func=cmd_itha_highway, on_interrupt="a computed set is kept in the cache")
    p = isub.add_parser("processors", help="Section 7.4.2: parallel processors, Table 7.1", parents=[out])
    p.add_argument("--runs", type=count(1), default=25,
                   help="episodes per estimate, the same graphs, queues and arrivals for each (default %(default)s)")
    p.add_argument("--steps", type=count(1), default=50, help="steps per episode (default %(default)s)")
    p.add_argument("--seed", type=count(0), default=0, help="run r is seeded with [SEED, r] (default %(default)s)")
    p.add_argument("--keep-jobs", type=count(0), default=1,
                   help="jobs a recruiter keeps for itself (0 = (7.9) literally; see the docs)")
    p.set_defaults(func=cmd_itha_processors)
