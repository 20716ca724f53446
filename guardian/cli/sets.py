"""``guardian rcis build|certify|export|plot``: the overtake RCIS library (Section 6.4.1)."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from guardian.cli.common import emit, load_library, progress_bar, add_library_options


def cmd_rcis_build(args) -> int:
    t0 = time.perf_counter()
    lib = load_library(args)
    result = {"sets": {n: s.summary() for n, s in lib.sets.items()},
              "containment": lib.containment(), "seconds": round(time.perf_counter() - t0, 3)}
    lines = [f"{n:17s} iterations={s['iterations']:3d} converged={s['converged']!s:5s} "
             f"pieces={s['pieces']:4d} seconds={s['seconds']:.1f}{' (cache)' if s['from_cache'] else ''}"
             for n, s in result["sets"].items()]
    lines += [f"{k}: {v}" for k, v in result["containment"].items()]
    emit(result, args.json, "\n".join(lines))
    checks = [v for k, v in result["containment"].items() if not k.startswith("witness")]
    return 0 if all(checks) else 1


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
    lines = [f"{n:17s} samples={r['samples']} inputs={r['inputs_checked']} "
             f"counterexamples={r['counterexamples']} split={r['split_successor_sets']}"
             for n, r in result["sets"].items()]
    emit(result, args.json, "\n".join(lines))
    return 0 if all(r["counterexamples"] == 0 for r in result["sets"].values()) else 1


def cmd_rcis_export(args) -> int:
    from intention.library import export_set, set_name

    try:
        name = set_name(args.name)
    except ValueError as exc:
        print(f"guardian rcis export: {exc}", file=sys.stderr)
        return 2
    data = export_set(load_library(args), name)
    Path(args.out).write_text(json.dumps(data))
    emit({"name": name, "pieces": len(data["pieces"]), "out": str(args.out)}, args.json,
          f"wrote {args.out} ({len(data['pieces'])} pieces)")
    return 0


def cmd_rcis_plot(args) -> int:
    from intention.plots import plot_admissible, plot_slices

    lib = load_library(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [str(plot_slices(lib, out)), str(plot_admissible(lib, out))]
    emit({"files": paths}, args.json, "\n".join(paths))
    return 0


def add_commands(sub) -> None:
    rcis = sub.add_parser("rcis", help="robust controlled invariant sets of the overtake scenario")
    rsub = rcis.add_subparsers(dest="rcis_command", required=True)

    p = rsub.add_parser("build", help="build or load the RCIS library")
    add_library_options(p)
    p.set_defaults(func=cmd_rcis_build)

    p = rsub.add_parser("certify", help="falsify invariance by sampling states and disturbances")
    add_library_options(p)
    p.add_argument("--samples", type=int, default=100_000, help="states per set (default 100000)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_rcis_certify)

    p = rsub.add_parser("export", help="write one set as JSON pieces A x <= b")
    p.add_argument("name", help="C_bnd | C_a | C_c (or bounded_velocity | aggressive | cautious)")
    p.add_argument("--out", type=Path, required=True)
    add_library_options(p)
    p.set_defaults(func=cmd_rcis_export)

    p = rsub.add_parser("plot", help="PNG slices (Fig. 6.3) and admissible inputs (Fig. 6.4)")
    p.add_argument("--out", type=Path, required=True)
    add_library_options(p)
    p.set_defaults(func=cmd_rcis_plot)
