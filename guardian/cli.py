"""The ``guardian`` command line: one entry point, one sub-command per job."""
from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from pathlib import Path


def _emit(result: dict, as_json: bool, text: str) -> None:
    print(json.dumps(result, indent=2, ensure_ascii=False) if as_json else text)


def _library(args):
    from intention.params import OvertakeParams
    from intention.library import LibrarySettings, build_library, replace_settings

    settings = replace_settings(LibrarySettings(), intention_max_iterations=args.iterations)
    params = OvertakeParams()
    if getattr(args, "ego_speed_min", None) is not None:
        params = OvertakeParams(v_ex_bounds=(args.ego_speed_min, params.v_ex_bounds[1]))
    return build_library(params=params, settings=settings, cache_dir=args.cache_dir, use_cache=not args.rebuild,
                         workers=args.workers)


def cmd_rcis_build(args) -> int:
    t0 = time.perf_counter()
    lib = _library(args)
    result = {"sets": {n: s.summary() for n, s in lib.sets.items()},
              "containment": lib.containment(), "seconds": round(time.perf_counter() - t0, 3)}
    lines = [f"{n:17s} iterations={s['iterations']:3d} converged={s['converged']!s:5s} "
             f"pieces={s['pieces']:4d} seconds={s['seconds']:.1f}{' (cache)' if s['from_cache'] else ''}"
             for n, s in result["sets"].items()]
    lines += [f"{k}: {v}" for k, v in result["containment"].items()]
    _emit(result, args.json, "\n".join(lines))
    checks = [v for k, v in result["containment"].items() if not k.startswith("witness")]
    return 0 if all(checks) else 1


def cmd_rcis_certify(args) -> int:
    from rcis.certify import falsify
    from intention.library import SET_NAMES
    from rcis.polyhedron import Polyhedron

    lib = _library(args)
    p = lib.params
    window = Polyhedron.from_box([-1e3, -1e3, -(p.h_r + 100), -1e3], [1e3, 1e3, p.h_r + 100, 1e3])
    result = {"sets": {}}
    for name in SET_NAMES:
        def progress(done, total, name=name):
            print(f"[certify {name}] {done}/{total} states", file=sys.stderr, flush=True)
        rep = falsify(lib.models[name].system, lib.region(name), args.samples, seed=args.seed,
                      window=window, admissible=lib.admissible(name), progress=progress)
        result["sets"][name] = rep.as_dict()
    lines = [f"{n:17s} samples={r['samples']} inputs={r['inputs_checked']} "
             f"counterexamples={r['counterexamples']} split={r['split_successor_sets']}"
             for n, r in result["sets"].items()]
    _emit(result, args.json, "\n".join(lines))
    return 0 if all(r["counterexamples"] == 0 for r in result["sets"].values()) else 1


def cmd_rcis_export(args) -> int:
    from intention.library import SET_NAMES, export_set

    if args.name not in SET_NAMES:
        print(f"guardian rcis export: unknown set {args.name!r}; choose from {', '.join(SET_NAMES)}",
              file=sys.stderr)
        return 2
    data = export_set(_library(args), args.name)
    Path(args.out).write_text(json.dumps(data))
    _emit({"name": args.name, "pieces": len(data["pieces"]), "out": str(args.out)}, args.json,
          f"wrote {args.out} ({len(data['pieces'])} pieces)")
    return 0


def cmd_rcis_plot(args) -> int:
    from intention.plots import plot_admissible, plot_slices

    lib = _library(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [str(plot_slices(lib, out)), str(plot_admissible(lib, out))]
    _emit({"files": paths}, args.json, "\n".join(paths))
    return 0


def _stderr_counter(label: str):
    def report(*a):
        *what, done, total = a
        print(f"[{label}{' ' + str(what[0]) if what else ''}] {done}/{total}", file=sys.stderr, flush=True)
    return report


def _positive(args, *names) -> str | None:
    for n in names:
        if getattr(args, n) < 1:
            return f"--{n} must be at least 1, got {getattr(args, n)}"
    return None


def cmd_itha_highway(args) -> int:
    from itha.car_following import CarFollowingParams, make_set
    from itha.highway import OVERAPPROXIMATIONS, HighwayParams, highway_experiment, run_highway_episode

    bad = _positive(args, "runs", "steps")
    if bad:
        print(f"guardian itha highway: {bad}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    prm = HighwayParams()
    S = make_set(prm.car_following, args.set, cache_dir=args.cache_dir, rebuild=args.rebuild,
                 log=lambda m: print(m, file=sys.stderr))
    which = OVERAPPROXIMATIONS if args.overapprox == "both" else (args.overapprox,)
    result = highway_experiment(args.runs, args.steps, args.seed, S, prm, which,
                                progress=_stderr_counter("itha highway"))
    if args.rerun:
        import numpy as np
        from guardian.rerun_log import HighwayRecorder

        rec = HighwayRecorder(args.rerun, prm.n_lanes)
        for oa in which:
            ep = run_highway_episode(prm, S, oa, args.steps, np.random.default_rng([args.seed, 0]), record=True)
            rec.log_itha_frames(ep.frames)
        rec.close()
    out = dict(result)
    out["set"] = {"kind": S.kind, **getattr(S, "info", {})}
    out["seconds"] = round(time.perf_counter() - t0, 3)
    text = "\n".join(f"{oa:8s} distance_mean={r['distance_mean']:.1f} m unsafe_steps={r['unsafe_steps']} "
                     f"lane_changes={r['lane_changes']} collisions={r['collisions']}"
                     for oa, r in result.items() if oa in which)
    _emit(out, args.json, text)
    return 0 if all(result[oa]["unsafe_steps"] == 0 for oa in which) else 1


def cmd_itha_processors(args) -> int:
    from itha.processors import ProcessorParams, processors_experiment

    bad = _positive(args, "runs", "steps")
    if bad:
        print(f"guardian itha processors: {bad}", file=sys.stderr)
        return 2
    result = processors_experiment(args.runs, args.steps, args.seed, ProcessorParams(keep_jobs=args.keep_jobs),
                                   progress=_stderr_counter("itha processors"))
    text = "\n".join(f"{k:8s} accepted_jobs_mean={r['accepted_jobs_mean']:.2f} "
                     f"violations_mean={r['violations_mean']:.2f}" for k, r in result.items())
    _emit(result, args.json, text)
    return 0


def cmd_rollout_highway_env(args) -> int:
    import gymnasium as gym

    import envs  # noqa: F401 - registers guardian/HighwayOvertake-v0
    import highway_env  # noqa: F401 - registers the environments
    from envs.agents import AGENTS
    from envs.highway_overtake import ConfigError
    from guardian.rollout import OVERTAKE_ENV, highway_rollouts

    if args.env not in gym.registry:
        known = sorted(k for k in gym.registry if k.startswith(("highway", "merge", "roundabout", "guardian/")))
        print(f"guardian rollout: unknown environment {args.env!r}; ids: {', '.join(known)}", file=sys.stderr)
        return 2
    if args.agent not in AGENTS:
        print(f"guardian rollout: unknown agent {args.agent!r}; choose from {', '.join(AGENTS)}", file=sys.stderr)
        return 2
    overtake = args.env == OVERTAKE_ENV
    if args.agent in ("mpc", "bad", "careful") and not (overtake and args.action in (None, "continuous")):
        print(f"guardian rollout: the {args.agent} driver drives {OVERTAKE_ENV} with --action continuous",
              file=sys.stderr)
        return 2
    if args.traffic is not None and args.traffic < 0:
        print(f"guardian rollout: --traffic must be >= 0, got {args.traffic}", file=sys.stderr)
        return 2
    library = _library(args) if overtake else None  # initial states are drawn inside C_bnd, guarded or not
    intentions = (("aggressive", "cautious") if args.intention == "all" else (args.intention,)) if overtake else (None,)
    from guardian.wrapper import GuardianConfig

    gcfg = GuardianConfig(use_intention=not args.no_intention, conflict=args.conflict)
    runs = []
    for k, intention in enumerate(intentions):
        recorder = None
        if args.rerun and k == 0:
            from guardian.rerun_log import GuardianRecorder
            recorder = GuardianRecorder(args.rerun)
        label = f"rollout {args.env}" + (f" {intention}" if intention else "")
        try:
            r = highway_rollouts(args.env, args.agent, args.episodes, args.seed, action=args.action,
                                 guardian=not args.no_guardian, library=library, intention=intention,
                                 disturbance=args.disturbance, traffic=args.traffic, guardian_config=gcfg,
                                 env_config={"params": library.params} if library is not None else None,
                                 progress=_stderr_counter(label), recorder=recorder,
                                 video_dir=(args.video / (intention or "all")) if args.video else None)
        except ConfigError as exc:
            print(f"guardian rollout: {exc}", file=sys.stderr)
            return 2
        finally:
            if recorder:
                recorder.close()
        r.update({"env": args.env, "agent": args.agent, "action": args.action or "default",
                  "guardian": not args.no_guardian, "intention_aware": not args.no_guardian and not args.no_intention,
                  "disturbance": args.disturbance})
        if intention:
            r["intention"] = intention
        runs.append(r)
    result = runs[0] if len(runs) == 1 else _combine(runs)
    text = "\n".join(
        f"{args.env} {r.get('intention', '')} {args.agent} guardian={'on' if r['guardian'] else 'off'} "
        f"episodes={r['episodes']} steps={r['steps']} collisions={r['collisions']} "
        f"ego_at_fault={r['ego_at_fault_collisions']} override_steps={r['override_steps']} "
        f"safety_violations={r.get('safety_violations', '-')} model_violation_steps={r['model_violation_steps']} "
        f"conflict_steps={r['conflict_steps']} distance_mean={r['distance_mean']:.1f} m" for r in runs)
    _emit(result, args.json, text)
    return 0


def cmd_highd_generate(args) -> int:
    from guardian.highd.generate import TrafficParams, generate

    bad = _positive(args, "recordings")
    if bad or args.minutes <= 0:
        print(f"guardian highd generate: {bad or '--minutes must be positive'}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    paths = generate(args.out, args.recordings, args.minutes, args.seed, TrafficParams(lanes=args.lanes),
                     progress=lambda rid, d, tot: print(f"[highd generate {rid:02d}] frame {d}/{tot}",
                                                        file=sys.stderr, flush=True),
                     first_id=args.first_id)
    result = {"out": str(args.out), "recordings": args.recordings, "files": [str(p) for p in paths],
              "bytes": sum(p.stat().st_size for p in paths), "seconds": round(time.perf_counter() - t0, 3)}
    _emit(result, args.json, f"wrote {len(paths)} files ({result['bytes'] / 1e6:.1f} MB) to {args.out}")
    return 0


def cmd_data_convert_ngsim(args) -> int:
    from guardian.highd.ngsim import convert_ngsim
    from guardian.highd.reader import HighDFormatError

    try:
        result = convert_ngsim(args.file, args.out, args.main_lanes, args.recording_id)
    except (HighDFormatError, ValueError) as exc:
        print(f"guardian data convert ngsim: {exc}", file=sys.stderr)
        return 2
    _emit(result, args.json, f"wrote {result['vehicles']} vehicles, {result['rows']} rows to {args.out} "
                             f"({result['ramp_rows_dropped']} rows on ramps dropped)")
    return 0


def cmd_replay(args) -> int:
    from guardian.highd.reader import HighDFormatError
    from guardian.highd.replay import ReplayConfig, car_following_params, replay, self_safety_overrides

    if args.workers < 1:
        print("guardian replay: --workers must be at least 1", file=sys.stderr)
        return 2
    cfg = ReplayConfig(seed=args.seed, h_min=args.h_min, u_min=args.u_min, u_max=args.u_max, v_max=args.v_max,
                       input_bounds=args.input_bounds, plausibility=not args.no_plausibility)
    try:
        result = replay(args.path, cfg, contexts=args.contexts, workers=args.workers, scheduler=args.scheduler,
                        progress=_stderr_counter("replay"), sensitivity=args.sensitivity)
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
    _emit(result, args.json, text)
    return 0


def cmd_rollout(args) -> int:
    from envs.drivers import DRIVERS
    from guardian.rollout import overtake_rollouts

    if args.episodes < 1:
        print("guardian rollout: --episodes must be at least 1", file=sys.stderr)
        return 2
    if args.env is not None:
        if args.scenario is not None:
            print("guardian rollout: --env and --scenario exclude each other", file=sys.stderr)
            return 2
        return cmd_rollout_highway_env(args)
    lib = _library(args)
    intentions = ("aggressive", "cautious") if args.intention == "all" else (args.intention,)
    drivers = DRIVERS if args.driver == "all" else (args.driver,)
    runs = [overtake_rollouts(lib, i, d, args.episodes, args.seed, guardian=not args.no_guardian,
                              use_intention=not args.no_intention, disturbance=args.disturbance,
                              max_steps=args.max_steps, horizon=args.horizon,
                              rerun_path=args.rerun if len(intentions) * len(drivers) == 1 else None)
            for i in intentions for d in drivers]
    result = runs[0] if len(runs) == 1 else _combine(runs)
    text = "\n".join(f"{r['intention']:10s} {r['driver']:8s} episodes={r['episodes']} steps={r['steps']} "
                     f"violations={r['safety_violations']} overrides={r['override_steps']} "
                     f"identified={r['identified_fraction']:.2f} "
                     f"mean_steps_to_identify={r['mean_steps_to_identify_intention']}" for r in runs)
    _emit(result, args.json, text)
    return 0


def cmd_serve(args) -> int:
    from guardian.service import Limits, ServiceConfig, make_server, token_from_env

    limits = Limits(max_body=args.max_body, read_timeout=args.read_timeout, keepalive_timeout=args.keepalive_timeout)
    config = ServiceConfig(host=args.host, port=args.port, token=token_from_env(args.token),
                           session_ttl=args.session_ttl, max_sessions=args.max_sessions, limits=limits)
    try:
        config.check()
    except ValueError as exc:
        print(f"guardian serve: {exc}", file=sys.stderr)
        return 2
    lib = _library(args)
    server, sock = make_server(lib, config)
    host, port = sock.getsockname()[:2]
    url = f"http://{host}:{port}"
    info = {"url": url, "token_required": config.token is not None, "session_ttl_s": config.session_ttl,
            "max_sessions": config.max_sessions}
    _emit(info, args.json, f"guardian service on {url} (SIGINT or SIGTERM stops it; sessions idle "
                           f"{config.session_ttl:g} s expire; token {'required' if config.token else 'off'})")
    sys.stdout.flush()
    # uvicorn answers the requests in flight, restores these handlers and re-raises the signal
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        server.run(sockets=[sock])
    except KeyboardInterrupt:
        pass
    finally:
        sock.close()
    return 0


def _combine(runs: list) -> dict:
    """One record for several runs: counts summed, means weighted by episodes, the runs kept under "runs"."""
    out = {k: sum(r[k] for r in runs) for k, v in runs[0].items()
           if isinstance(v, int) and not isinstance(v, bool) and all(isinstance(r.get(k), int) for r in runs)}
    if all(isinstance(r.get("traffic_model_worst"), dict) for r in runs):
        out["traffic_model_worst"] = {k: max(r["traffic_model_worst"].get(k, 0.0) for r in runs)
                                      for k in runs[0]["traffic_model_worst"]}
    if all("distance_mean" in r for r in runs):
        out["distance_mean"] = sum(r["distance_mean"] * r["episodes"] for r in runs) / out["episodes"]
    if all("identified_fraction" in r for r in runs):
        ident = [(r["mean_steps_to_identify_intention"], r["identified_fraction"] * r["episodes"]) for r in runs
                 if r["mean_steps_to_identify_intention"] is not None]
        n_ident = sum(n for _, n in ident)
        out["mean_steps_to_identify_intention"] = sum(m * n for m, n in ident) / n_ident if n_ident else None
        out["identified_fraction"] = n_ident / out["episodes"]
    out["runs"] = runs
    return out


def _ego_speed_min(text: str) -> float:
    value = float(text)
    if not 0.0 <= value < 36.0:
        raise argparse.ArgumentTypeError(f"--ego-speed-min must be in [0, 36) m/s, got {text}")
    return value


def _library_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--iterations", type=int, default=None,
                   help="inside-out iterations for the aggressive and cautious sets (default 5)")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="where computed sets are cached (default $GUARDIAN_CACHE_DIR or ~/.cache/guardian)")
    p.add_argument("--rebuild", action="store_true", help="ignore the cache and recompute")
    p.add_argument("--workers", type=int, default=2, help="processes for the intention sets (default 2)")
    p.add_argument("--ego-speed-min", type=_ego_speed_min, default=None, metavar="V",
                   help="the safe set's lowest ego speed v_ex^min (default: the dissertation's 16 m/s; 0 lets the "
                        "ego wait behind the lead instead of having to overtake)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="guardian", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    rcis = sub.add_parser("rcis", help="robust controlled invariant sets of the overtake scenario")
    rsub = rcis.add_subparsers(dest="rcis_command", required=True)

    p = rsub.add_parser("build", help="build or load the RCIS library")
    _library_options(p)
    p.set_defaults(func=cmd_rcis_build)

    p = rsub.add_parser("certify", help="falsify invariance by sampling states and disturbances")
    _library_options(p)
    p.add_argument("--samples", type=int, default=100_000, help="states per set (default 100000)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_rcis_certify)

    p = rsub.add_parser("export", help="write one set as JSON pieces A x <= b")
    p.add_argument("name", help="bounded_velocity | aggressive | cautious")
    p.add_argument("--out", type=Path, required=True)
    _library_options(p)
    p.set_defaults(func=cmd_rcis_export)

    p = rsub.add_parser("plot", help="PNG slices (Fig. 6.3) and admissible inputs (Fig. 6.4)")
    p.add_argument("--out", type=Path, required=True)
    _library_options(p)
    p.set_defaults(func=cmd_rcis_plot)
    p = sub.add_parser("rollout", help="supervised rollouts of the overtake scenario")
    p.add_argument("--scenario", choices=["overtake"], default=None,
                   help="the overtake scenario (the default when --env is not given)")
    p.add_argument("--env", default=None,
                   help="a highway-env id: guardian/HighwayOvertake-v0 (lead part + ITHA), highway-v0, "
                        "highway-fast-v0, ... (ITHA)")
    p.add_argument("--agent", default="random",
                   help="with --env: random | reckless | idle | mpc | bad | careful (the MPC drivers: "
                        "HighwayOvertake, continuous)")
    p.add_argument("--action", choices=["continuous", "meta"], default=None,
                   help="with --env: the agent's action type (default: the env's own)")
    p.add_argument("--traffic", type=int, default=None, help="with --env: number of other cars")
    p.add_argument("--video", type=Path, default=None, help="with --env: write each episode as MP4 into this folder")
    p.add_argument("--conflict", choices=["lead", "traffic"], default="traffic",
                   help="with --env: who wins when self-safety against the car ahead and the lead's set do not intersect")
    p.add_argument("--intention", choices=["aggressive", "cautious", "all"], default="cautious")
    p.add_argument("--driver", choices=["mpc", "bad", "careful", "random", "all"], default="mpc")
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--disturbance", choices=["random", "adversarial"], default="random")
    p.add_argument("--max-steps", type=int, default=300, help="steps per episode (dt = 0.1 s)")
    p.add_argument("--horizon", type=int, default=10, help="intention estimator horizon N")
    p.add_argument("--no-guardian", action="store_true", help="drive without supervision")
    p.add_argument("--no-intention", action="store_true",
                   help="keep the guardian but pin it to the bounded-velocity set")
    p.add_argument("--rerun", type=Path, default=None, help="write a rerun recording (.rrd)")
    _library_options(p)
    p.set_defaults(func=cmd_rollout)
    itha = sub.add_parser("itha", help="inter-triggering hybrid automata experiments (Chapter 7)")
    isub = itha.add_subparsers(dest="itha_command", required=True)
    p = isub.add_parser("highway", help="Section 7.4.1: the responsible ego on a 5-lane highway with IDM traffic")
    p.add_argument("--runs", type=int, default=25)
    p.add_argument("--steps", type=int, default=500)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--overapprox", choices=["trivial", "ordered", "both"], default="both")
    p.add_argument("--set", choices=["polyhedral", "closed-form"], default="polyhedral",
                   help="the car-following RCIS: computed by rcis (cached) or its closed form")
    p.add_argument("--cache-dir", type=Path, default=None)
    p.add_argument("--rebuild", action="store_true")
    p.add_argument("--rerun", type=Path, default=None, help="record run 0 of each over-approximation (.rrd)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_itha_highway)
    p = isub.add_parser("processors", help="Section 7.4.2: parallel processors, Table 7.1")
    p.add_argument("--runs", type=int, default=25)
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--keep-jobs", type=int, default=1,
                   help="jobs a recruiter keeps for itself (0 = (7.9) literally; see README)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_itha_processors)
    hd = sub.add_parser("highd", help="HighD-format data")
    hsub = hd.add_subparsers(dest="highd_command", required=True)
    p = hsub.add_parser("generate", help="write simulated HighD-format recordings (both carriageways, 25 Hz)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--recordings", type=int, default=1)
    p.add_argument("--minutes", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lanes", type=int, default=3, help="lanes per carriageway")
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
    p.add_argument("--no-plausibility", action="store_true",
                   help="read files that break the plausibility rules (frame rate, speeds, accelerations, markings)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_replay)
    p = sub.add_parser("serve", help="the guardian as an HTTP JSON service (one estimator per session)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default loopback; any other address needs a token)")
    p.add_argument("--port", type=int, default=8765, help="0 picks a free port (printed)")
    p.add_argument("--token", default=None,
                   help="bearer token checked on every request and stream (default: $GUARDIAN_TOKEN)")
    p.add_argument("--session-ttl", type=float, default=300.0, help="seconds an idle session lives (300)")
    p.add_argument("--max-sessions", type=int, default=1000, help="live sessions at most (1000)")
    p.add_argument("--max-body", type=int, default=64 * 1024, help="bytes of a body or stream message (65536)")
    p.add_argument("--read-timeout", type=float, default=10.0,
                   help="seconds to receive a whole request once it began (10)")
    p.add_argument("--keepalive-timeout", type=float, default=5.0, help="seconds an idle connection stays open (5)")
    _library_options(p)
    p.set_defaults(func=cmd_serve)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "samples", 1) < 1:
        print("guardian: --samples must be at least 1", file=sys.stderr)
        return 2
    if getattr(args, "iterations", None) is not None and args.iterations < 0:
        print("guardian: --iterations must be >= 0", file=sys.stderr)
        return 2
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
