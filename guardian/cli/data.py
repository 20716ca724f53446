"""``guardian highd generate``, ``guardian data convert ngsim``, ``guardian replay``: HighD-format data."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from guardian.cli.common import emit, progress_bar, positive_error


def cmd_highd_generate(args) -> int:
    from guardian.highd.generate import TrafficParams, generate

    bad = positive_error(args, "recordings", "frame_rate")
    if bad or args.minutes <= 0:
        print(f"guardian highd generate: {bad or '--minutes must be positive'}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    paths = generate(args.out, args.recordings, args.minutes, args.seed, TrafficParams(lanes=args.lanes, frame_rate=args.frame_rate),
                     progress=progress_bar("highd generate"),
                     first_id=args.first_id)
    result = {"out": str(args.out), "recordings": args.recordings, "files": [str(p) for p in paths],
              "bytes": sum(p.stat().st_size for p in paths), "seconds": round(time.perf_counter() - t0, 3)}
    emit(result, args.json, f"wrote {len(paths)} files ({result['bytes'] / 1e6:.1f} MB) to {args.out}")
    return 0


def cmd_data_convert_ngsim(args) -> int:
    from guardian.highd.ngsim import convert_ngsim
    from guardian.errors import HighDFormatError

    try:
        result = convert_ngsim(args.file, args.out, args.main_lanes, args.recording_id)
    except (HighDFormatError, ValueError) as exc:
        print(f"guardian data convert ngsim: {exc}", file=sys.stderr)
        return 2
    emit(result, args.json, f"wrote {result['vehicles']} vehicles, {result['rows']} rows to {args.out} "
                             f"({result['ramp_rows_dropped']} rows on ramps dropped)")
    return 0


def cmd_replay(args) -> int:
    from guardian.errors import HighDFormatError
    from guardian.highd.replay import ReplayConfig, car_following_params, replay, self_safety_overrides

    if args.workers < 1:
        print("guardian replay: --workers must be at least 1", file=sys.stderr)
        return 2
    cfg = ReplayConfig(seed=args.seed, h_min=args.h_min, u_min=args.u_min, u_max=args.u_max, v_max=args.v_max,
                       input_bounds=args.input_bounds, plausibility=not args.no_plausibility)
    try:
        result = replay(args.path, cfg, contexts=args.contexts, workers=args.workers, scheduler=args.scheduler,
                        progress=progress_bar("replay"), sensitivity=args.sensitivity, cache=not args.no_cache)
    except (HighDFormatError, ValueError) as exc:
        print(f"guardian replay: {exc}", file=sys.stderr)
        return 2
    if args.rerun:
        from guardian.highd.reader import recording_ids
        from guardian.highd.replay import default_sample
        from guardian.rerun_log import log_highd_recording

        folder = Path(args.path) if args.path else default_sample()
        rid = recording_ids(folder)[0]
        p = car_following_params(cfg, result["dt"], result["disturbance_bounds"], result["input_bounds"])
        result["rerun"] = log_highd_recording(args.rerun, folder if folder.is_dir() else folder.parent, rid, p,
                                              lambda d: self_safety_overrides(p, d.v, d.h, d.vL, d.u))
    r = result["override_rates"]
    text = (f"{len(result['recordings'])} recording(s): {result['data_points']} data points, {result['trajectories']} "
            f"trajectories, {result['lane_changes']} lane changes; D = [{result['disturbance_bounds'][0]:.3f}, "
            f"{result['disturbance_bounds'][1]:.3f}] m/s^2\n"
            f"override rates on the held-out 20 %: self-safety {100 * r['self_safety']:.2f} %, "
            f"responsibility trivial {100 * r['responsibility_trivial']:.2f} %, "
            f"ordered {100 * r['responsibility_ordered']:.2f} %")
    if args.contexts:
        text += f"\nself-safety with per-context sets: {100 * result['contexts']['self_safety']:.2f} %"
    cache = result.get("cache")
    if cache:
        text += (f"\n{cache['hits']} of {cache['hits'] + cache['misses']} recording(s) read from the cache "
                 f"{cache['dir']} (--no-cache parses every file)")
    emit(result, args.json, text)
    return 0


def add_commands(sub) -> None:
    hd = sub.add_parser("highd", help="HighD-format data")
    hsub = hd.add_subparsers(dest="highd_command", required=True)
    p = hsub.add_parser("generate", help="write simulated HighD-format recordings (both carriageways, 25 Hz by default)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--recordings", type=int, default=1)
    p.add_argument("--minutes", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lanes", type=int, default=3, help="lanes per carriageway")
    p.add_argument("--frame-rate", type=int, default=25, metavar="HZ", help="frames per second (HighD: 25)")
    p.add_argument("--first-id", type=int, default=1, help="id of the first recording (NN in the file names)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_highd_generate)
    data = sub.add_parser("data", help="convert other trajectory data to HighD format")
    dsub = data.add_subparsers(dest="data_command", required=True)
    conv = dsub.add_parser("convert", help="convert a file")
    csub = conv.add_subparsers(dest="convert_format", required=True)
    p = csub.add_parser("ngsim", help="NGSIM US-101 / I-80 trajectories (txt or CSV export) to a HighD recording")
    p.add_argument("file", type=Path)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--main-lanes", type=int, default=None,
                   help="lanes 1..K are the main line (I-80: 6, US-101: 5) and higher lane ids, ramps, are "
                        "dropped (default: keep every lane)")
    p.add_argument("--recording-id", type=int, default=1)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_data_convert_ngsim)
    p = sub.add_parser("replay", help="override rates of the ITHA guardian on HighD-format data (Table 7.2)")
    p.add_argument("path", nargs="?", type=Path, default=None,
                   help="a folder of recordings or one recording's file (default: the shipped sample)")
    p.add_argument("--seed", type=int, default=0, help="seed of the 80/20 split")
    p.add_argument("--contexts", action="store_true", help="also calibrate per lane and speed band")
    p.add_argument("--workers", type=int, default=1, help="local processes, one recording each")
    p.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler")
    p.add_argument("--sensitivity", action="store_true", help="rates under other open choices")
    p.add_argument("--h-min", type=float, default=2.0, help="safe headway, bumper to bumper (m)")
    p.add_argument("--u-min", type=float, default=-6.0, help="ego input bound U (m/s^2)")
    p.add_argument("--u-max", type=float, default=4.0)
    p.add_argument("--v-max", type=float, default=60.0)
    p.add_argument("--input-bounds", choices=["fixed", "data"], default="fixed",
                   help="U from --u-min/--u-max, or the training inputs' quantiles (per context with --contexts)")
    p.add_argument("--rerun", type=Path, default=None, help="record the first recording with its overrides (.rrd)")
    p.add_argument("--no-cache", action="store_true",
                   help="parse every file afresh; by default each validated recording's ITHA view is kept in "
                        "<GUARDIAN_CACHE_DIR>/highd and read from there when the files are unchanged")
    p.add_argument("--no-plausibility", action="store_true",
                   help="read files that break the plausibility rules (frame rate, speeds, accelerations, markings)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_replay)
