"""Replay throughput at HighD's size: about 40 million (x, u, d) points in 60 recordings.

Run: python benchmarks/bench_replay.py [--recordings 60] [--minutes 22] [--workdir DIR] [--before REV] [--json]

Generates one recording of ``--minutes`` (cached in the work dir), links it under 60 recording ids
(new ``NN`` names and recordingMeta ids; the tracks files are hard links), then runs ``guardian replay
DIR`` in fresh processes, each with wall time, points per second, the peak resident memory of the
largest process (the command or one of its workers), and the override rates:

* ``--before REV``: the code of an older commit (a temporary git worktree first on ``PYTHONPATH``);
* first run: 2 workers, an empty cache (the compiled reader parses, the checks validate, the ITHA
  view is stored);
* repeated run: 2 workers, then 1 worker, the cache warm (no CSV is parsed).

Targets: first run <= 20 s with 2 workers, repeated <= 5 s, >= 3 M points/s per core once
cached, peak memory <= 1.5 GB; the rates identical in every run.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd


def prepare(workdir: Path, recordings: int, minutes: float) -> Path:
    base = workdir / f"base-{minutes:g}min"
    if not (base / "01_tracks.csv").exists():
        subprocess.run([sys.executable, "-m", "guardian.cli", "highd", "generate", "--out", str(base), "--recordings", "1",
                        "--minutes", str(minutes), "--seed", "11"], check=True)
    data = workdir / f"highd-{recordings}x{minutes:g}min"
    data.mkdir(parents=True, exist_ok=True)
    meta = pd.read_csv(base / "01_recordingMeta.csv")
    for rid in range(1, recordings + 1):
        for kind in ("tracks", "tracksMeta"):
            dst = data / f"{rid:02d}_{kind}.csv"
            if not dst.exists():
                os.link(base / f"01_{kind}.csv", dst)
        meta.assign(id=rid).to_csv(data / f"{rid:02d}_recordingMeta.csv", index=False)
    return data


ROOT = Path(__file__).resolve().parents[1]
PEAK = ("import resource, subprocess, sys; subprocess.run(sys.argv[1:], check=True); "
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr)")


def run(label: str, data: Path, workers: int, cache: Path, pythonpath: Path | None = None) -> dict:
    """One ``guardian replay`` in a fresh process; the peak RSS is the largest of it and its workers."""
    env = {**os.environ, "GUARDIAN_CACHE_DIR": str(cache)}
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    cmd = [sys.executable, "-c", PEAK, sys.executable, "-m", "guardian.cli", "replay", str(data),
           "--workers", str(workers), "--json"]
    t0 = time.perf_counter()
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env,
                         cwd=pythonpath if pythonpath is not None else ROOT)  # -m puts the cwd first on sys.path
    seconds = time.perf_counter() - t0
    peak_kb = int(out.stderr.strip().splitlines()[-1])
    r = json.loads(out.stdout)
    return {"run": label, "workers": workers, "seconds": round(seconds, 1), "data_points": r["data_points"],
            "points_per_second": round(r["data_points"] / seconds),
            "points_per_second_per_worker": round(r["data_points"] / seconds / workers),
            "peak_rss_mb_largest_process": round(peak_kb / 1024, 1),
            "cache": r.get("cache"), "timings": r.get("timings"),
            "override_rates": r["override_rates"], "disturbance_bounds": r["disturbance_bounds"],
            "trajectories": r["trajectories"], "lane_changes": r["lane_changes"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--recordings", type=int, default=60)
    ap.add_argument("--minutes", type=float, default=22.0)
    ap.add_argument("--workdir", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "guardian-bench-highd")
    ap.add_argument("--before", default=None, help="an older commit to run beside this checkout")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    data = prepare(args.workdir, args.recordings, args.minutes)
    cache, cache_before = args.workdir / "cache", args.workdir / "cache-before"
    for folder in (cache, cache_before):  # both first runs start from an empty cache
        shutil.rmtree(folder, ignore_errors=True)
    runs = []
    if args.before:
        from worktree import checkout

        with checkout(args.before) as tree:
            runs.append(run(f"before ({args.before})", data, 2, cache_before, tree))
    runs += [run("first run (empty cache)", data, 2, cache), run("repeated (cache warm)", data, 2, cache),
             run("repeated (cache warm)", data, 1, cache)]
    res = {"data": str(data), "runs": runs,
           "identical_results": all(r["override_rates"] == runs[0]["override_rates"] for r in runs)}
    if args.json:
        print(json.dumps(res, indent=2))
        return
    for r in res["runs"]:
        print(f"{r['run']:26s} --workers {r['workers']}: {r['data_points']:,} points in {r['seconds']} s = "
              f"{r['points_per_second']:,} points/s ({r['points_per_second_per_worker']:,} per worker), "
              f"peak RSS {r['peak_rss_mb_largest_process']} MB, timings {r['timings']}")
    print(f"identical results: {res['identical_results']}")


if __name__ == "__main__":
    sys.exit(main())
