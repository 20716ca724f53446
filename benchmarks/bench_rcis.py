"""Speed of the RCIS library: build (cold and cached), membership, admissible set + override.

Run: python benchmarks/bench_rcis.py [--before REV] [--json]
Targets (this 2-core machine): library cold < 60 s, cached < 1 s, membership
< 20 µs per state, admissible set + override < 1 ms, library cold <= 15 s.

The cold build runs in a fresh process (as ``guardian rcis build --rebuild`` does); ``--before REV``
also runs an older commit's cold build (a temporary git worktree) in the same run and says whether
its sets are bitwise the same (a hash of every piece's A and b).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from intention.library import SET_NAMES, build_library
from worktree import ROOT, checkout

COLD = """
import hashlib, json, time
from intention.library import SET_NAMES, build_library
t = time.perf_counter()
lib = build_library(cache_dir={cache!r}, use_cache=False, quiet=True)
seconds = time.perf_counter() - t
digest = {{n: hashlib.sha256(b"".join(P.A.tobytes() + P.b.tobytes() for P in lib.region(n).pieces)).hexdigest()[:16]
          for n in SET_NAMES}}
print(json.dumps({{"seconds": seconds, "sets": {{n: {{"seconds": lib.sets[n].seconds, "pieces": len(lib.region(n))}}
                                               for n in SET_NAMES}}, "digest": digest}}))
"""


def cold_build(tree: Path, cache: str) -> dict:
    """One cold library build in a fresh process of the code in ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run([sys.executable, "-c", COLD.format(cache=cache)], cwd=tree, env=env, check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def per_call(fn, n):
    fn()
    t = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t) / n


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--before", default=None, help="an older commit whose cold build runs beside this one")
    args = ap.parse_args()
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        if args.before:
            with checkout(args.before) as tree:
                out["before"] = {"rev": args.before, **cold_build(tree, os.path.join(cache, "before"))}
        now = cold_build(ROOT, cache)
        out["library_cold_s"] = now["seconds"]
        out["build_s"] = {n: now["sets"][n]["seconds"] for n in SET_NAMES}
        out["digest"] = now["digest"]
        if args.before:
            out["same_sets_as_before"] = now["digest"] == out["before"]["digest"]
        lib = build_library(cache_dir=cache, quiet=True)
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
    print(f"library cold build        {out['library_cold_s']:.1f} s  (target <= 15 s)")
    for n, s in out["build_s"].items():
        print(f"  {n:17s} {s:.1f} s")
    if "before" in out:
        b = out["before"]
        print(f"  before ({b['rev']}): {b['seconds']:.1f} s ("
              + ", ".join(f"{n} {v['seconds']:.1f} s" for n, v in b["sets"].items())
              + f"); the same sets: {out['same_sets_as_before']}")
    print(f"library from cache        {out['library_cached_s']:.2f} s  (target < 1 s)")
    for n in SET_NAMES:
        a = out["admissible_plus_override_us"][n]
        print(f"{n:17s} membership {out['membership_us_per_state'][n]:.1f} µs/state "
              f"(batched {out['membership_batched_us_per_state'][n]:.2f}), "
              f"S(x)+override median {a['median']:.0f} µs, p99 {a['p99']:.0f} µs")


if __name__ == "__main__":
    main()
