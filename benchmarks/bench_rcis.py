"""Speed of the RCIS library: build (cold and cached), membership, admissible set + override.

Run: python benchmarks/bench_rcis.py [--json]
Targets (issue 2, this 2-core machine): library cold < 60 s, cached < 1 s, membership
< 20 µs per state, admissible set + override < 1 ms.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time

import numpy as np

from intention.library import SET_NAMES, build_library


def per_call(fn, n):
    fn()
    t = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t) / n


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        t = time.perf_counter()
        lib = build_library(cache_dir=cache, quiet=True)
        out["library_cold_s"] = time.perf_counter() - t
        out["build_s"] = {n: lib.sets[n].seconds for n in SET_NAMES}
        t = time.perf_counter()
        build_library(cache_dir=cache, quiet=True)
        out["library_cached_s"] = time.perf_counter() - t
    rng = np.random.default_rng(0)
    X = rng.uniform([16, -0.9, -80, 0], [36, 2.7, 80, 33.5], size=(200_000, 4))
    U = rng.uniform([-3, -1.8], [3, 1.8], size=(2000, 2))
    out["membership_us_per_state"] = {}
    out["membership_batched_us_per_state"] = {}
    out["admissible_plus_override_us"] = {}
    for n in SET_NAMES:
        R = lib.region(n)
        out["membership_us_per_state"][n] = per_call(lambda: R.contains(X[7]), 20000) * 1e6
        t = time.perf_counter()
        R.contains(X)
        out["membership_batched_us_per_state"][n] = (time.perf_counter() - t) / len(X) * 1e6
        adm = lib.admissible(n)
        inside = X[:5000][R.contains(X[:5000])][:500]
        times = []
        for i, x in enumerate(inside):
            t = time.perf_counter()
            adm.override(x, U[i % len(U)])
            times.append(time.perf_counter() - t)
        out["admissible_plus_override_us"][n] = {"median": float(np.median(times) * 1e6),
                                                 "p99": float(np.percentile(times, 99) * 1e6),
                                                 "states": len(times)}
    if args.json:
        print(json.dumps(out, indent=2))
        return
    print(f"library cold build        {out['library_cold_s']:.1f} s  (target < 60 s)")
    for n, s in out["build_s"].items():
        print(f"  {n:17s} {s:.1f} s")
    print(f"library from cache        {out['library_cached_s']:.2f} s  (target < 1 s)")
    for n in SET_NAMES:
        a = out["admissible_plus_override_us"][n]
        print(f"{n:17s} membership {out['membership_us_per_state'][n]:.1f} µs/state "
              f"(batched {out['membership_batched_us_per_state'][n]:.2f}), "
              f"S(x)+override median {a['median']:.0f} µs, p99 {a['p99']:.0f} µs")


if __name__ == "__main__":
    main()
