"""Projection, redundancy removal and one robust Pre step on random 4-D polytopes of 10-40 facets.

Run: python benchmarks/bench_polyhedra.py [--json] [--cases N] [--no-before]

Fixed seed, so runs are comparable. "before" is ``minimal()`` as one LP per row (the dual-hull
filter switched off), measured in the same run; the sets of both are checked equal (mutual
inclusion to 1e-7). tulip's ``polytope`` is timed beside ours where it has the operation (it is a
test extra).
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

import rcis.polyhedron as polyhedron
from rcis import Polyhedron, PWAPiece, PWASystem


def random_polytope(rng, n: int = 4) -> Polyhedron:
    m = int(rng.integers(10, 41)) - 2 * n
    A = rng.normal(size=(m, n))
    A /= np.linalg.norm(A, axis=1, keepdims=True)
    return Polyhedron(np.vstack([A, np.eye(n), -np.eye(n)]),
                      np.concatenate([1.0 + rng.uniform(0, 0.5, m), np.full(2 * n, 3.0)]))


def linear_system(rng, n: int = 4) -> PWASystem:
    A = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    B = 0.1 * rng.normal(size=(n, 2))
    piece = PWAPiece(Polyhedron.universe(n), A, B, np.zeros(n), 0.05 * np.eye(n)[:, :1],
                     Polyhedron.from_box([-1.0], [1.0]))
    return PWASystem([piece], Polyhedron.from_box([-1.0, -1.0], [1.0, 1.0]), Polyhedron.universe(n))


def timed(f) -> float:
    t = time.perf_counter()
    f()
    return time.perf_counter() - t


def measure(cases) -> tuple[dict, list]:
    figures = {"minimal_s": sum(timed(P.minimal) for P, _ in cases)}
    projections, pres = [], []
    figures["project_to_2d_s"] = sum(timed(lambda P=P: projections.append(P.project([0, 1]))) for P, _ in cases)
    figures["pre_s"] = sum(timed(lambda P=P, S=S: pres.append(S.pre(P))) for P, S in cases)
    return figures, projections + [piece for pre in pres for piece in pre]


def same_sets(xs, ys) -> bool:
    return len(xs) == len(ys) and all(x.contains_polyhedron(y) and y.contains_polyhedron(x) for x, y in zip(xs, ys))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=30)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--no-before", action="store_true", help="skip the one-LP-per-row baseline (~20 s)")
    args = ap.parse_args()
    rng = np.random.default_rng(2026)
    cases = [(random_polytope(rng), linear_system(rng)) for _ in range(args.cases)]
    try:
        import polytope as pc
    except ImportError:
        pc = None
    out = {"cases": args.cases, "ours": {}, "polytope": {}}
    out["ours"], sets = measure(cases)
    if not args.no_before:
        hull_filter = polyhedron._dual_hull_filter
        polyhedron._dual_hull_filter = lambda A, b: None
        try:
            out["before"], before_sets = measure(cases)
        finally:
            polyhedron._dual_hull_filter = hull_filter
        out["same_sets"] = same_sets(sets, before_sets)
        out["speedup"] = {k: round(out["before"][k] / out["ours"][k], 1) for k in out["ours"]}
    if pc is not None:
        peers = [pc.Polytope(P.A, P.b) for P, _ in cases]
        out["polytope"]["reduce_s"] = sum(timed(lambda q=q: pc.reduce(q)) for q in peers)
        out["polytope"]["projection_to_2d_s"] = sum(timed(lambda q=q: pc.projection(q, [1, 2])) for q in peers)
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for who in ("ours", "before", "polytope"):
            for k, v in out.get(who, {}).items():
                print(f"{who:9s} {k:20s} {v:8.3f} s over {args.cases} polytopes")
        if "speedup" in out:
            print("speed-up  " + ", ".join(f"{k} {v}x" for k, v in out["speedup"].items()),
                  f"| same sets: {out['same_sets']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
