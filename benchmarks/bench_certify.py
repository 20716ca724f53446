"""Wall time of ``guardian rcis certify --samples N`` for the three sets, before and after.

Run: python benchmarks/bench_certify.py [--samples 100000] [--before REV] [--json]

"now, 1 worker" and "now, 2 workers" run this checkout; ``--before REV`` also runs the command of an
older commit (checked out into a temporary git worktree, with its own warm cache) in the same run.
This checkout's runs must give identical JSON (the same samples, counterexamples and split counts),
else this exits 1; an older commit may draw its samples differently (each set is drawn as two seeded
halves, `CERTIFY_PARTS`), so against it only the counterexample counts are compared.
Target: at most 30 s on this 2-core machine. The library is built once first, so no figure
includes a cold build.
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

from worktree import ROOT, checkout


def certify(cwd: Path, samples: int, workers: int, cache: Path) -> tuple[float, dict]:
    env = {**os.environ, "GUARDIAN_CACHE_DIR": str(cache)}
    cmd = [sys.executable, "-m", "guardian.cli", "rcis", "certify", "--samples", str(samples), "--json"]
    if workers:
        cmd += ["--workers", str(workers)]
    subprocess.run([sys.executable, "-m", "guardian.cli", "rcis", "build", "--json"], cwd=cwd, env=env,
                   check=True, capture_output=True)
    t = time.perf_counter()
    out = subprocess.run(cmd, cwd=cwd, env=env, check=True, capture_output=True, text=True)
    return time.perf_counter() - t, json.loads(out.stdout)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--before", default=None, help="an older commit to time beside this checkout")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    runs, results = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "cache"
        for workers in (1, 2):
            runs[f"now, {workers} worker{'s' if workers > 1 else ''}"], results[workers] = \
                certify(ROOT, args.samples, workers, cache)
        if args.before:
            with checkout(args.before) as tree:
                runs[f"before ({args.before}, as it ran)"], results["before"] = \
                    certify(tree, args.samples, 0, Path(tmp) / "cache-before")
    same = results[2] == results[1]
    def counts(r):
        return {n: s["counterexamples"] for n, s in r["sets"].items()}
    out = {"samples_per_set": args.samples, "seconds": {k: round(v, 1) for k, v in runs.items()},
           "same_reports": same,
           "same_counterexample_counts_as_before": (counts(results["before"]) == counts(results[1])
                                                    if "before" in results else None),
           "counterexamples": {n: r["counterexamples"] for n, r in results[2]["sets"].items()}}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for k, v in out["seconds"].items():
            print(f"{k:32s} {v:6.1f} s")
        print(f"same reports with 1 and 2 workers: {same}; counterexamples: {out['counterexamples']}"
              + ("" if out["same_counterexample_counts_as_before"] is None else
                 f"; the same counts as before: {out['same_counterexample_counts_as_before']}"))
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
