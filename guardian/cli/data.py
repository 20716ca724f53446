"""``guardian highd generate``, ``guardian data convert ngsim|commonroad``, ``guardian replay``: HighD-format data."""
from __future__ import annotations

import time

from guardian.cli.common import (count, emit, existing_path, json_option, number, output_file, output_folder,
                                 positive_number, progress_bar, usage_error)


def cmd_highd_generate(args) -> int:
    from guardian.highd.generate import TrafficParams, generate

    t0 = time.perf_counter()
    paths = generate(args.out, args.recordings, args.minutes, args.seed,
                     TrafficParams(lanes=args.lanes, frame_rate=args.frame_rate),
                     progress=progress_bar("highd generate"), first_id=args.first_id)
    result = {"out": str(args.out), "recordings": args.recordings, "frame_rate": args.frame_rate,
              "files": [str(p) for p in paths], "bytes": sum(p.stat().st_size for p in paths),
              "seconds": round(time.perf_counter() - t0, 3)}
    emit(result, args.json, "\n".join([f"wrote {len(paths)} files ({result['bytes'] / 1e6:.1f} MB, "
                                        f"{args.recordings} recording(s) at {args.frame_rate} Hz) to {args.out} "
                                        f"in {result['seconds']:.1f} s", *result["files"]]))
    return 0


def cmd_data_convert_ngsim(args) -> int:
    from guardian.errors import HighDFormatError
    from guardian.highd.ngsim import convert_ngsim

    try:
        result = convert_ngsim(args.file, args.out, args.main_lanes, args.recording_id)
    except (HighDFormatError, ValueError) as exc:
        return usage_error(args, str(exc))
    emit(result, args.json, "\n".join(f"{k}: {v}" for k, v in result.items()))
    return 0


def cmd_data_convert_commonroad(args) -> int:
    from guardian.errors import HighDFormatError
    from guardian.highd.commonroad import convert_commonroad

    files = sorted(args.path.glob("*.xml")) if args.path.is_dir() else [args.path]
    if not files:
        return usage_error(args, f"{args.path}: no .xml file in the folder")
    done = []
    progress = progress_bar("data convert commonroad")
    try:
        for k, f in enumerate(files):
            done.append(convert_commonroad(f, args.out, args.first_id + k, time_step=args.time_step))
            progress(k + 1, len(files))
    except HighDFormatError as exc:
        return usage_error(args, str(exc))
    result = done[0] if len(done) == 1 else {"out": str(args.out), "recordings": done}
    emit(result, args.json, "\n\n".join("\n".join(f"{k}: {v}" for k, v in r.items()) for r in done))
    return 0


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.2f} %"


def replay_text(result: dict) -> str:
    """Every figure of ``replay``'s JSON, as lines a person reads."""
    r = result["override_rates"]
    lo, hi = result["disturbance_bounds"]
    ulo, uhi = result["input_bounds"]
    cfg = result["config"]
    lines = [f"{len(result['recordings'])} recording(s): {result['data_points']} data points, "
             f"{result['trajectories']} trajectories, {result['lane_changes']} lane changes; dt = {result['dt']:g} s",
             *(f"  recording {rec['id']}: " + ", ".join(str(v) for k, v in rec.items() if k != "id")
               for rec in result["recordings"]),
             f"split (seed {cfg['seed']}): {result['train_disturbance_samples']} training samples; held out "
             f"{100 * cfg['test_fraction']:g} %: {result['test_data_points']} data points, "
             f"{result['test_lane_changes']} lane changes",
             f"calibrated (quantiles {cfg['quantiles'][0]:g}, {cfg['quantiles'][1]:g}): D = [{lo:.3f}, {hi:.3f}] m/s^2, "
             f"U = [{ulo:.3f}, {uhi:.3f}] m/s^2 ({cfg['input_bounds']}); h_min = {cfg['h_min']:g} m, "
             f"v_max = {cfg['v_max']:g} m/s",
             f"override rates on the held-out data: self-safety {_pct(r['self_safety'])}, "
             f"responsibility (the recorded input) trivial {_pct(r['responsibility_trivial'])}, ordered "
             f"{_pct(r['responsibility_ordered'])}; no input responsible: trivial "
             f"{_pct(r.get('responsibility_trivial_no_input'))}, ordered {_pct(r.get('responsibility_ordered_no_input'))}"]
    if "rss_longitudinal" in r:
        lines.append(f"RSS beside them: longitudinal {_pct(r['rss_longitudinal'])} (calibrated "
                     f"{_pct(r.get('rss_longitudinal_calibrated'))}), cut-in {_pct(r.get('rss_cut_in'))} "
                     f"(calibrated {_pct(r.get('rss_cut_in_calibrated'))})")
    if "overrides" in result:
        lines.append("overrides: " + ", ".join(f"{k} {v}" for k, v in result["overrides"].items()))
    for which, prm in result.get("rss_params", {}).items():
        if isinstance(prm, dict):
            lines.append(f"RSS parameters, {which}: " + ", ".join(f"{k} {v:g}" for k, v in prm.items()))
        else:
            lines.append(f"RSS parameters, {which}: {prm}")
    if result.get("plausibility") is False:
        lines.append("the reader's plausibility rules were off (--no-plausibility)")
    ctx = result.get("contexts")
    if ctx:
        lines.append(f"self-safety with per-context sets: {_pct(ctx['self_safety'])} (single sets on the same points "
                     f"{_pct(ctx.get('self_safety_single'))}); held-out lead accelerations outside D: "
                     f"{ctx.get('test_disturbances_outside')} per context, {ctx.get('test_disturbances_outside_single')} "
                     f"single, of {ctx.get('test_disturbances')}" + (f" ({ctx['note']})" if ctx.get("note") else ""))
        for name, c in ctx.get("by_context", {}).items():
            lines.append(f"  {name:14s} train {c['train_samples']:6d}  D = [{c['bounds'][0]:.3f}, {c['bounds'][1]:.3f}]  "
                         f"U = [{c['input_bounds'][0]:.3f}, {c['input_bounds'][1]:.3f}]  test {c['test_points']:6d}  "
                         f"self-safety {_pct(c['self_safety'])} (single {_pct(c.get('self_safety_single'))})  "
                         f"d outside D {c.get('test_disturbances_outside')} of {c.get('test_disturbances')}")
    sens = result.get("sensitivity")
    if sens:
        cols = [k for k in sens[0] if k not in ("variant", "disturbance_bounds", "input_bounds")]
        lines.append("sensitivity (override rates on the held-out data):")
        lines.append(f"  {'variant':24s} {'D':>16s} {'U':>16s} " + " ".join(f"{c:>27s}" for c in cols))
        for row in sens:
            d, u = row["disturbance_bounds"], row["input_bounds"]
            lines.append(f"  {row['variant']:24s} {f'[{d[0]:.2f}, {d[1]:.2f}]':>16s} {f'[{u[0]:.2f}, {u[1]:.2f}]':>16s} "
                         + " ".join(f"{_pct(row[c]):>27s}" for c in cols))
    if result.get("rerun"):
        lines.append("rerun recording: " + ", ".join(f"{k} {v}" for k, v in result["rerun"].items()))
    cache = result.get("cache")
    if cache:
        lines.append(f"{cache['hits']} of {cache['hits'] + cache['misses']} recording(s) read from the cache "
                     f"{cache['dir']} (--no-cache parses every file)")
    t = result.get("timings", {})
    lines.append(f"seconds: {result['seconds']:.2f} (read, convert and split {t.get('read_convert_split', 0):.2f}, "
                 f"evaluate {t.get('evaluate', 0):.2f})")
    return "\n".join(lines)


def cmd_replay(args) -> int:
    from guardian.errors import HighDFormatError, SchedulerError
    from guardian.highd.rates import ReplayConfig, car_following_params, judge_lane_change, self_safety_overrides
    from itha.car_following import MaximalSet
    from guardian.highd.replay import replay

    if args.input_bounds == "data" and (args.u_min is not None or args.u_max is not None):
        return usage_error(args, "--u-min/--u-max do not apply with --input-bounds data (U comes from the data)")
    if args.scheduler and args.workers is not None:
        return usage_error(args, "--workers does not apply with --scheduler (the Dask cluster has its own workers)")
    defaults = ReplayConfig()
    u_min = defaults.u_min if args.u_min is None else args.u_min
    u_max = defaults.u_max if args.u_max is None else args.u_max
    if not u_min < 0 < u_max:
        return usage_error(args, f"--u-min must be below 0 and --u-max above 0 (the ego must be able to brake "
                                 f"and to speed up), got --u-min {u_min:g} --u-max {u_max:g}")
    try:
        cfg = ReplayConfig(seed=args.seed, h_min=args.h_min, v_max=args.v_max, input_bounds=args.input_bounds,
                           u_min=u_min, u_max=u_max, frame_step=args.frame_step,
                           plausibility=not args.no_plausibility)
    except ValueError as exc:
        return usage_error(args, str(exc))
    if args.rerun:
        args.rerun.parent.mkdir(parents=True, exist_ok=True)
    try:
        result = replay(args.path, cfg, contexts=args.contexts, workers=args.workers or 1, scheduler=args.scheduler,
                        progress=progress_bar("replay"), sensitivity=args.sensitivity, cache=not args.no_cache)
    except (HighDFormatError, ValueError) as exc:
        return usage_error(args, str(exc))
    except SchedulerError as exc:
        return usage_error(args, f"--scheduler: {exc}")
    if args.rerun:
        from pathlib import Path

        from guardian.highd.files import recording_ids
        from guardian.highd.replay import default_sample
        from guardian.recording.rerun import log_highd_recording

        folder = Path(args.path) if args.path else default_sample()
        rid = recording_ids(folder)[0]
        p = car_following_params(cfg, result["dt"], result["disturbance_bounds"], result["input_bounds"])
        S = MaximalSet(p)
        result["rerun"] = log_highd_recording(args.rerun, folder if folder.is_dir() else folder.parent, rid, p,
                                              lambda d: self_safety_overrides(p, d.v, d.h, d.vL, d.u),
                                              lambda e, overapprox: judge_lane_change(p, S, e, overapprox),
                                              frame_step=cfg.frame_step)
    emit(result, args.json, replay_text(result))
    return 0


def add_commands(sub) -> None:
    out = json_option()
    hd = sub.add_parser("highd", help="HighD-format data")
    hsub = hd.add_commands("highd_command")
    p = hsub.add_parser("generate", help="write simulated HighD-format recordings (both carriageways, 25 Hz by default)",
                        parents=[out])
    p.add_argument("--out", type=output_folder, required=True, help="the folder the recordings are written to")
    p.add_argument("--recordings", type=count(1), default=1,
                   help="how many recordings, numbered from --first-id (default %(default)s)")
    p.add_argument("--minutes", type=positive_number, default=1.0,
                   help="length of each recording in minutes (default %(default)s)")
    p.add_argument("--seed", type=count(0), default=0,
                   help="recording k is seeded with [SEED, k] (default %(default)s)")
    p.add_argument("--lanes", type=count(1), default=3, help="lanes per carriageway")
    p.add_argument("--frame-rate", type=count(1), default=25, metavar="HZ", help="frames per second (HighD: 25)")
    p.add_argument("--first-id", type=count(1), default=1, help="id of the first recording (NN in the file names)")
    p.set_defaults(func=cmd_highd_generate, on_interrupt="the recordings written so far are complete")
    data = sub.add_parser("data", help="convert other trajectory data to HighD format")
    dsub = data.add_commands("data_command")
    conv = dsub.add_parser("convert", help="convert a file")
    csub = conv.add_commands("convert_format")
    p = csub.add_parser("ngsim", help="NGSIM US-101 / I-80 trajectories (txt or CSV export) to a HighD recording",
                        parents=[out])
    p.add_argument("file", type=existing_path,
                   help="the NGSIM trajectory file (the .txt as published, or the CSV export)")
    p.add_argument("--out", type=output_folder, required=True, help="the folder the recording is written to")
    p.add_argument("--main-lanes", type=count(1), default=None,
                   help="lanes 1..K are the main line (I-80: 6, US-101: 5) and higher lane ids, ramps, are "
                        "dropped (default: keep every lane)")
    p.add_argument("--recording-id", type=count(1), default=1,
                   help="the recording's id, written into the meta files and the file names (NN_tracks.csv; "
                        "default %(default)s)")
    p.set_defaults(func=cmd_data_convert_ngsim)
    p = csub.add_parser("commonroad", help="CommonRoad scenarios (recorded traffic: US-101, highD, ...) to HighD "
                                           "recordings (needs the commonroad extra)", parents=[out])
    p.add_argument("path", type=existing_path,
                   help="a CommonRoad scenario (.xml), or a folder of them (one recording each, sorted by name)")
    p.add_argument("--out", type=output_folder, required=True, help="the folder the recordings are written to")
    p.add_argument("--first-id", type=count(1), default=1,
                   help="the first recording's id (NN in the file names; the next file gets the next id)")
    p.add_argument("--time-step", type=positive_number, default=None, metavar="S",
                   help="convert with this time step instead of the file's timeStepSize (each is checked against "
                        "the vehicles' motion; a file whose motion says another step is refused, naming it)")
    p.set_defaults(func=cmd_data_convert_commonroad, on_interrupt="the recordings written so far are complete")
    p = sub.add_parser("replay", help="override rates of the ITHA guardian on HighD-format data (Table 7.2)",
                       parents=[out])
    p.add_argument("path", nargs="?", type=existing_path, default=None,
                   help="a folder of recordings or one recording's file (default: the shipped sample)")
    p.add_argument("--seed", type=count(0), default=0, help="seed of the 80/20 split")
    p.add_argument("--contexts", action="store_true", help="also calibrate per lane and speed band")
    p.add_argument("--workers", type=count(1), default=None, help="local processes, one recording each (default 1)")
    p.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler (instead of --workers)")
    p.add_argument("--sensitivity", action="store_true", help="rates under other open choices")
    p.add_argument("--h-min", type=positive_number, default=2.0, help="safe headway, bumper to bumper (m)")
    p.add_argument("--u-min", type=number, default=None, help="ego input bound U (m/s^2; default -6, below 0)")
    p.add_argument("--u-max", type=number, default=None, help="(m/s^2; default 4, above 0)")
    p.add_argument("--v-max", type=positive_number, default=60.0,
                   help="the model's top speed (m/s): a recording with a faster vehicle is refused, naming it "
                        "(default %(default)g)")
    p.add_argument("--frame-step", type=count(1), default=1, metavar="K",
                   help="use every K-th frame: the data at frameRate / K (K must divide it; highD's 25 Hz with K = 5 is "
                        "the 5 Hz of highD-derived CommonRoad scenarios) (default 1)")
    p.add_argument("--input-bounds", choices=["fixed", "data"], default="fixed",
                   help="U from --u-min/--u-max, or the training inputs' quantiles (per context with --contexts)")
    p.add_argument("--rerun", type=output_file, default=None,
                   help="record the first recording with its overrides (.rrd)")
    p.add_argument("--no-cache", action="store_true",
                   help="parse every file afresh; by default each validated recording's ITHA view is kept in "
                        "<GUARDIAN_CACHE_DIR>/highd and read from there when the files are unchanged")
    p.add_argument("--no-plausibility", action="store_true",
                   help="read files that break the plausibility rules (frame rate, speeds, accelerations, markings)")
    p.set_defaults(func=cmd_replay, on_interrupt="cached recordings are complete")
