"""Speed of the ITHA experiment of Section 7.4.1.

Run: python benchmarks/bench_itha.py [--json]
Target: 25 runs x 500 steps, both over-approximations, under 2 minutes.
The guardian's cost on highway-env is in ``bench_highway_guardian.py``.
"""
from __future__ import annotations

import argparse
import json
import time

from itha.car_following import CarFollowingParams, load_or_build
from itha.highway_experiment import highway_experiment
from itha.road import HighwayParams


def bench_7_4_1() -> dict:
    t0 = time.perf_counter()
    S = load_or_build(CarFollowingParams())
    t_set = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = highway_experiment(25, 500, 0, S, HighwayParams())
    return {"set_seconds": round(t_set, 3), "experiment_seconds": round(time.perf_counter() - t0, 3),
            "steps": 2 * 25 * 500, "distance_mean": {k: round(v["distance_mean"], 1) for k, v in r.items()}}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    res = {"section_7_4_1": bench_7_4_1()}
    if args.json:
        print(json.dumps(res, indent=2))
        return
    a = res["section_7_4_1"]
    print(f"7.4.1: 25 x 500 steps x 2 over-approximations in {a['experiment_seconds']:.1f} s "
          f"(set {a['set_seconds']:.2f} s); distances {a['distance_mean']}")


if __name__ == "__main__":
    main()
