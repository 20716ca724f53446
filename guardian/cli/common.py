"""What every command shares: JSON or text output, the library options, progress, argument types."""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def emit(result: dict, as_json: bool, text: str) -> None:
    print(json.dumps(result, indent=2, ensure_ascii=False) if as_json else text)


def load_library(args):
    from intention.params import OvertakeParams
    from intention.library import LibrarySettings, build_library, replace_settings

    settings = replace_settings(LibrarySettings(), intention_max_iterations=args.iterations)
    params = OvertakeParams()
    if getattr(args, "ego_speed_min", None) is not None:
        params = OvertakeParams(v_ex_bounds=(args.ego_speed_min, params.v_ex_bounds[1]))
    return build_library(params=params, settings=settings, cache_dir=args.cache_dir, use_cache=not args.rebuild,
                         workers=args.workers)


def progress_bar(label: str):
    from guardian.progress import ProgressBar

    return ProgressBar(label)


def positive_error(args, *names) -> str | None:
    for n in names:
        if getattr(args, n) < 1:
            return f"--{n} must be at least 1, got {getattr(args, n)}"
    return None


def combine_runs(runs: list) -> dict:
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


def intention_name(text: str) -> str:
    """``all``, or an intention set by either name (``C_a``/``aggressive``, ``C_c``/``cautious``)."""
    from intention.library import set_name

    try:
        name = "all" if text == "all" else set_name(text)
    except ValueError:
        name = None
    if name not in ("aggressive", "cautious", "all"):
        raise argparse.ArgumentTypeError(f"--intention must be aggressive, cautious, C_a, C_c or all, got {text!r}")
    return name


def ego_speed_min(text: str) -> float:
    value = float(text)
    if not 0.0 <= value < 36.0:
        raise argparse.ArgumentTypeError(f"--ego-speed-min must be in [0, 36) m/s, got {text}")
    return value


def add_library_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--iterations", type=int, default=None,
                   help="inside-out iterations for the aggressive and cautious sets (default 5)")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="where computed sets are cached (default $GUARDIAN_CACHE_DIR or ~/.cache/guardian)")
    p.add_argument("--rebuild", action="store_true", help="ignore the cache and recompute")
    p.add_argument("--workers", type=int, default=2, help="processes for the intention sets (default 2)")
    p.add_argument("--ego-speed-min", type=ego_speed_min, default=None, metavar="V",
                   help="the safe set's lowest ego speed v_ex^min (default: the dissertation's 16 m/s; 0 lets the "
                        "ego wait behind the lead instead of having to overtake)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
