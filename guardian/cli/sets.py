"""``guardian rcis build|certify|export|plot``: the overtake RCIS library (Section 6.4.1)."""
from __future__ import annotations

import json
import sys
import time

from guardian.cli.common import (_writable_folder_error, count, emit, json_option, library_options, load_library,
                                 output_file, output_folder, progress_bar, usage_error)

KEPT = "finished sets are kept in the cache"


def cache_folder_error(args) -> str | None:
    """Why ``rcis build`` cannot fill its cache folder (``--cache-dir`` or the default), or None.

    The other commands that load the library go on without a cache (one warning); filling the cache is
    ``rcis build``'s only job, so there an unwritable folder is refused before any set is computed.
    """
    import os

    from rcis.cache import default_cache_dir

    folder = args.cache_dir if args.cache_dir is not None else default_cache_dir()
    bad = _writable_folder_error(folder)
    if bad is None:
        return None
    if args.cache_dir is not None:
        return f"--cache-dir: cannot write into {folder}: {bad}"
    source = "$GUARDIAN_CACHE_DIR" if "GUARDIAN_CACHE_DIR" in os.environ else "the default"
    return f"cannot write into the cache folder {folder} ({source}; choose one with --cache-dir): {bad}"


def cmd_rcis_build(args) -> int:
    bad = cache_folder_error(args)
    if bad:
        return usage_error(args, bad)
    t0 = time.perf_counter()
    lib = load_library(args)
    result = {"sets": {n: s.summary() for n, s in lib.sets.items()},
              "containment": lib.containment(), "seconds": round(time.perf_counter() - t0, 3)}
    lines = [f"{n:17s} iterations={s['iterations']:3d} converged={s['converged']!s:5s} "
             f"pieces={s['pieces']:4d} seconds={s['seconds']:.1f}{' (cache)' if s['from_cache'] else ''}"
             for n, s in result["sets"].items()]
    lines += [f"{k}: {v}" for k, v in result["containment"].items()]
    lines.append(f"seconds: {result['seconds']:.1f}")
    emit(result, args.json, "\n".join(lines))
    failed = [k for k, v in result["containment"].items() if not k.startswith("witness") and not v]
    if failed:
        print(f"{args._prog}: Proposition 22 does not hold for these sets: {'; '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


CERTIFY_PARTS = 2  # each set drawn as two seeded halves: the largest set keeps both workers busy


def cmd_rcis_certify(args) -> int:
    from rcis.certify import falsify_all
    from intention.library import SET_NAMES
    from rcis.polyhedron import Polyhedron

    lib = load_library(args)
    p = lib.params
    window = Polyhedron.from_box([-1e3, -1e3, -(p.h_r + 100), -1e3], [1e3, 1e3, p.h_r + 100, 1e3])
    largest_first = sorted(SET_NAMES, key=lambda n: -len(lib.region(n).pieces))
    jobs = {name: {"system": lib.models[name].system, "invariant": lib.region(name), "samples": args.samples,
                   "seed": args.seed, "window": window, "admissible": lib.admissible(name)} for name in largest_first}
    reports = falsify_all(jobs, workers=args.workers, progress=progress_bar("certify"), parts=CERTIFY_PARTS)
    result = {"sets": {name: reports[name].as_dict() for name in SET_NAMES}}
    lines = [f"{n:17s} " + " ".join(f"{k}={v}" for k, v in r.items() if not isinstance(v, (list, dict)))
             for n, r in result["sets"].items()]
    lines += [f"counterexample in {n}: {c}" for n, r in result["sets"].items() for c in r["first_counterexamples"]]
    emit(result, args.json, "\n".join(lines))
    bad = [n for n, r in result["sets"].items() if r["counterexamples"]]
    if bad:
        print(f"{args._prog}: counterexamples to invariance in {', '.join(bad)}", file=sys.stderr)
    return 1 if bad else 0


def cmd_rcis_export(args) -> int:
    from intention.library import export_set, set_name

    try:
        name = set_name(args.name)
    except ValueError as exc:
        print(f"guardian rcis export: {exc}", file=sys.stderr)
        return 2
    data = export_set(load_library(args), name)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(data))
    emit({"name": name, "pieces": len(data["pieces"]), "out": str(args.out)}, args.json,
          f"wrote {name} ({len(data['pieces'])} pieces) to {args.out}")
    return 0


def cmd_rcis_plot(args) -> int:
    from intention.plots import plot_admissible, plot_slices

    lib = load_library(args)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    paths = [str(plot_slices(lib, out)), str(plot_admissible(lib, out))]
    emit({"files": paths}, args.json, "\n".join(paths))
    return 0


def add_commands(sub) -> None:
    rcis = sub.add_parser("rcis", help="robust controlled invariant sets of the overtake scenario")
    rsub = rcis.add_commands("rcis_command")
    library, out = library_options(), json_option()

    p = rsub.add_parser("build", help="build or load the RCIS library", parents=[library_options(1), out])
    p.set_defaults(func=cmd_rcis_build, on_interrupt=KEPT)

    p = rsub.add_parser("certify", help="falsify invariance by sampling states and disturbances",
                        parents=[library, out])
    p.add_argument("--samples", type=count(1), default=100_000, help="states per set (default 100000)")
    p.add_argument("--seed", type=count(0), default=0, help="seed of the samples (default %(default)s)")
    for action in p._actions:  # certify's --workers: the sets are certified in parallel
        if "--workers" in action.option_strings:
            action.help = ("processes certifying the sets in parallel, each set in two seeded halves; a library "
                           "not in the cache is built with them too (default 2)")
    p.set_defaults(func=cmd_rcis_certify, on_interrupt=KEPT)

    p = rsub.add_parser("export", help="write one set as JSON pieces A x <= b", parents=[library, out])
    p.add_argument("name", help="C_bnd | C_a | C_c (or bounded_velocity | aggressive | cautious)")
    p.add_argument("--out", type=output_file, required=True, help="the JSON file to write")
    p.set_defaults(func=cmd_rcis_export, on_interrupt=KEPT)

    p = rsub.add_parser("plot", help="PNG slices (Fig. 6.3) and admissible inputs (Fig. 6.4)", parents=[library, out])
    p.add_argument("--out", type=output_folder, required=True, help="the folder the PNG files are written to")
    p.set_defaults(func=cmd_rcis_plot, on_interrupt=KEPT)
