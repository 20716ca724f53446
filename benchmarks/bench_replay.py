"""Replay throughput at HighD's size: about 40 million (x, u, d) points in 60 recordings.

Run: python benchmarks/bench_replay.py [--recordings 60] [--minutes 22] [--workdir DIR] [--json]

Generates one recording of ``--minutes`` (cached in the work dir), links it under 60 recording ids
(new ``NN`` names and recordingMeta ids; the tracks files are hard links), then runs
``guardian replay DIR --workers 1`` and ``--workers 2`` in fresh processes and prints wall time,
points per second, the peak resident memory of the largest process, and the speed-up.
Target (issue 5): end to end in under 3 minutes here.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd


def prepare(workdir: Path, recordings: int, minutes: float) -> Path:
    base = workdir / f"base-{minutes:g}min"
    if not (base / "01_tracks.csv").exists():
        subprocess.run(["guardian", "highd", "generate", "--out", str(base), "--recordings", "1",
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


def run(data: Path, workers: int) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    out = subprocess.run(["guardian", "replay", str(data), "--workers", str(workers), "--json"],
                         check=True, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    peak_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    r = json.loads(out.stdout)
    return {"workers": workers, "seconds": round(seconds, 1), "data_points": r["data_points"],
            "points_per_second": round(r["data_points"] / seconds),
            "peak_rss_mb_largest_process": round(max(peak_kb, before) / 1024, 1),
            "override_rates": r["override_rates"], "disturbance_bounds": r["disturbance_bounds"],
            "trajectories": r["trajectories"], "lane_changes": r["lane_changes"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--recordings", type=int, default=60)
    ap.add_argument("--minutes", type=float, default=22.0)
    ap.add_argument("--workdir", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "guardian-bench-highd")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    data = prepare(args.workdir, args.recordings, args.minutes)
    one, two = run(data, 1), run(data, 2)
    res = {"data": str(data), "runs": [one, two], "speedup_workers_2": round(one["seconds"] / two["seconds"], 2),
           "identical_results": one["override_rates"] == two["override_rates"]}
    if args.json:
        print(json.dumps(res, indent=2))
        return
    for r in res["runs"]:
        print(f"--workers {r['workers']}: {r['data_points']:,} points in {r['seconds']} s = "
              f"{r['points_per_second']:,} points/s, peak RSS {r['peak_rss_mb_largest_process']} MB")
    print(f"speed-up with 2 workers: {res['speedup_workers_2']}x; identical results: {res['identical_results']}")


if __name__ == "__main__":
    sys.exit(main())
