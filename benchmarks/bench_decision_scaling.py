"""A decision's cost per guarded car against the number of guarded cars, on synthetic straight-road scenes.

N guarded cars and as many traffic cars on a straight 4-lane road, 40 m apart on average in each lane (the road
grows with N, so each car has the same neighbours whatever N is), speeds 20-30 m/s. Every guarded car reads its
scene from every other body and decides, as the service's scene sessions, SUMO's adapter and highway-env's wrapper
do today: ``guardian.model.sensing.scene_of`` then ``BicycleGuardian.step`` with the driver's proposal (+1 m/s²,
straight on). Timed per guarded car and simulation step: reading the scene, deciding, and both, median and p99
in µs. A flat row in N is the aim (the decision depends on a car's neighbours only).

Two ways of reading the scene, both giving the same scenes (hence the same decisions, checked here):

* ``shared`` (default): every body is read once per simulation step (``Sensed``) and the road is indexed once
  (``guardian.model.sensing.Traffic``: the cars per lane sorted once); each guarded car's scene is that road
  without its own body (``Traffic.scene_for``). A guarded car's share of the step's reading and indexing is
  counted in its scene time (the step's cost divided by N).
* ``per-car`` (``--per-car``): each guarded car reads every other body and builds its scene alone
  (``scene_of``), as the adapters did before ``Traffic``.

    python benchmarks/bench_decision_scaling.py [--n 1 10 100 1000] [--steps 20] [--seed 0] [--per-car] [--json]

Time it on an idle machine: other jobs on the cores inflate every figure.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time

import numpy as np

from guardian.config import GuardianConfig
from guardian.decide.bicycle import BicycleGuardian
from guardian.decide.kinematics import BicycleEgo
from guardian.model.roads import Road
from guardian.model.scene import Car, EgoState
from guardian.model.sensing import Sensed, Traffic, scene_of

LANES, LANE_WIDTH, SPACING, LENGTH, WIDTH, DT = 4, 4.0, 40.0, 5.0, 2.0, 1 / 15


def fleet(n_guarded: int, rng) -> list[dict]:
    """``2 n`` cars (the first ``n`` guarded) spread over the lanes, about ``SPACING`` apart in each lane."""
    total = 2 * n_guarded
    per_lane = -(-total // LANES)
    cars = []
    for i in range(total):
        lane, k = i % LANES, i // LANES
        x = k * SPACING + rng.uniform(-8, 8)
        cars.append({"name": f"car {i}", "x": x, "y": lane * LANE_WIDTH, "speed": rng.uniform(20, 30), "lane": lane})
    assert len(cars) <= per_lane * LANES
    return cars


def sensed(road: Road, c: dict) -> Sensed:
    lanes = road.body_slots(c["x"], c["y"], 0.0, LENGTH, WIDTH)
    return Sensed(c["name"], c["x"], c["y"], 0.0, c["speed"], LENGTH, WIDTH, c["x"] + LENGTH / 2, c["lane"], lanes,
                  road.beside(lanes, c["x"]))


def run(n_guarded: int, steps: int, seed: int, per_car: bool = False) -> dict:
    rng, road, config = np.random.default_rng(seed), Road(LANES, LANE_WIDTH), GuardianConfig()
    kin = BicycleEgo(DT, config.traffic_accel, LENGTH, WIDTH, LANE_WIDTH, LANES, np.pi / 4)
    cars = fleet(n_guarded, rng)
    guards = [BicycleGuardian(kin, config, meta=False) for _ in range(n_guarded)]
    read, decide, digest = [], [], []
    for _ in range(steps):
        shared_seconds = 0.0
        if not per_car:
            t0 = time.perf_counter()
            traffic = Traffic(road, [sensed(road, o) for o in cars], config.reversing, BicycleEgo.LATERAL_MARGIN)
            shared_seconds = (time.perf_counter() - t0) / n_guarded
        for i, guard in enumerate(guards):
            c = cars[i]
            t0 = time.perf_counter()
            me = Car(c["x"] + LENGTH / 2, c["speed"], frozenset(), LENGTH, "ego")
            if per_car:
                scene = scene_of(road, me, [sensed(road, o) for j, o in enumerate(cars) if j != i], config.reversing,
                                 BicycleEgo.LATERAL_MARGIN)
            else:
                scene = traffic.scene_for(me, c["name"])
            t1 = time.perf_counter()
            state = EgoState(c["x"] + LENGTH / 2, c["y"], 0.0, c["speed"], c["lane"], c["lane"], c["x"])
            applied, d = guard.step(state, scene, np.array([1.0, 0.0]))
            t2 = time.perf_counter()
            read.append(t1 - t0 + shared_seconds)
            decide.append(t2 - t1)
            digest.append((float(applied[0]), float(applied[1]), d.changed, d.level, repr(d)))
            c["next_speed"] = max(c["speed"] + DT * float(applied[0]), 0.0)
        for c in cars:   # everyone moves by the Euler step; traffic holds its speed
            c["x"] += DT * c["speed"]
            c["speed"] = c.pop("next_speed", c["speed"])
    read, decide = np.array(read) * 1e6, np.array(decide) * 1e6
    both = read + decide
    return {"guarded": n_guarded, "cars": len(cars), "decisions": len(both), "way": "per-car" if per_car else "shared",
            "digest": hashlib.sha256(repr(digest).encode()).hexdigest()[:16],
            **{f"{name}_us": {"median": round(float(np.median(a)), 1), "p99": round(float(np.percentile(a, 99)), 1)}
               for name, a in (("scene", read), ("decision", decide), ("total", both))}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 10, 100, 1000])
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--per-car", action="store_true", help="each guarded car reads every body alone (the old way)")
    ap.add_argument("--both", action="store_true", help="run both ways, one after the other, and compare decisions")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    ways = (True, False) if args.both else (args.per_car,)
    for n in args.n:
        for per_car in ways:
            rows.append(run(n, max(1, args.steps if n <= 100 else args.steps // 10), args.seed, per_car))
            print(f"N = {n} ({rows[-1]['way']}): done", file=sys.stderr)
        if args.both and rows[-1]["digest"] != rows[-2]["digest"]:
            print(f"N = {n}: the two ways decided differently", file=sys.stderr)
            return 1
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"{'guarded':>7} {'cars':>5} {'way':>8} {'decisions':>9}  {'scene µs':>17}  {'decision µs':>17}  "
          f"{'total µs':>17}")
    print(f"{'':>7} {'':>5} {'':>8} {'':>9}  {'median':>8} {'p99':>8}  {'median':>8} {'p99':>8}  {'median':>8} {'p99':>8}")
    for r in rows:
        cells = "  ".join(f"{r[k]['median']:>8.1f} {r[k]['p99']:>8.1f}" for k in ("scene_us", "decision_us", "total_us"))
        print(f"{r['guarded']:>7} {r['cars']:>5} {r['way']:>8} {r['decisions']:>9}  {cells}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
