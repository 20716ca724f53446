"""The intention sets C_a and C_c, iterated further than the library does: is a fixed point near?

Run: python benchmarks/bench_intention_sets.py [--iterations 10] [--budget 300] [--samples 200000] [--json]

Inside-out from C_bnd (the library's seed) for each intention, in two processes, until nothing new
appears, ``--iterations`` or ``--budget`` seconds per set. After every iteration it prints the new
pieces, all pieces, the seconds so far, and the volume of the set inside a fixed bounded window as a
fraction of the window (``--samples`` fixed uniform points, with its standard error): a fixed point
shows as new pieces falling to 0 and the volume levelling off. Every iterate contains C_bnd and is an
RCIS by construction; the last one is falsified with 20,000 samples as ``guardian rcis certify`` does.
"""
from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

WINDOW = ([16.0, -0.9, -40.0, 0.0], [36.0, 2.7, 40.0, 33.5])  # v_ex, y_e, h, v_Lx: the lead within 40 m


class _Budget(Exception):
    pass


def grow(name: str, iterations: int, budget: float, samples: int) -> dict:
    from intention.library import LibrarySettings, build_library
    from intention.models import intention_models, safe_set
    from intention.params import OvertakeParams
    from rcis.certify import falsify
    from rcis.invariant import inside_out
    from rcis.polyhedron import Polyhedron

    params, settings = OvertakeParams(), LibrarySettings()
    seed = build_library(quiet=True).region("bounded_velocity")
    X = np.random.default_rng(0).uniform(*WINDOW, size=(samples, 4))
    rows, last, t0 = [], {}, time.perf_counter()

    def observe(k, region):
        inside = region.contains(X)
        frac = float(inside.mean())
        rows.append({"iteration": k, "pieces": len(region.pieces), "seconds": round(time.perf_counter() - t0, 1),
                     "volume_fraction": round(frac, 5), "volume_se": round(float(np.sqrt(frac * (1 - frac) / samples)), 5)})
        last["region"] = region
        print(f"[{name}] {rows[-1]}", flush=True)
        if time.perf_counter() - t0 > budget:
            raise _Budget

    model = intention_models(params)[name]
    converged = False
    try:
        res = inside_out(model.system, seed, safe_set(params), iterations, merge=settings.merge,
                         cover_budget=settings.cover_budget, observe=observe)
        converged = res.converged
    except _Budget:
        pass
    p = params
    window = Polyhedron.from_box([-1e3, -1e3, -(p.h_r + 100), -1e3], [1e3, 1e3, p.h_r + 100, 1e3])
    rep = falsify(model.system, last["region"], 20_000, seed=0, window=window)
    seed_frac = float(seed.contains(X).mean())
    return {"set": name, "converged": converged, "iterations": rows, "seed_volume_fraction": round(seed_frac, 5),
            "falsifier_20000": {"counterexamples": len(rep.counterexamples), "split": rep.split}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=10)
    ap.add_argument("--budget", type=float, default=300.0, help="seconds per set")
    ap.add_argument("--samples", type=int, default=200_000)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    with ProcessPoolExecutor(max_workers=2) as pool:
        futures = [pool.submit(grow, n, args.iterations, args.budget, args.samples) for n in ("aggressive", "cautious")]
        results = [f.result() for f in futures]
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    for r in results:
        print(f"\n{r['set']}: converged={r['converged']}, C_bnd fills {r['seed_volume_fraction']:.3%} of the window; "
              f"falsifier on the last iterate: {r['falsifier_20000']}")
        print("| iteration | pieces | seconds | volume in the window |")
        for row in r["iterations"]:
            print(f"| {row['iteration']} | {row['pieces']} | {row['seconds']} | "
                  f"{row['volume_fraction']:.3%} ± {row['volume_se']:.3%} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
