"""A lead that brakes at once, cars that move continuously: the car-following set under exact integration.

The world moves both cars exactly (each holds its acceleration over the 0.1 s step; a braking car stays at
standstill, ``itha.exact``). The lead cruises, then at a random step brakes at its hardest bound until it
stands. The ego's driver proposes +1.5 m/s^2 every step; the guardian applies the nearest self-safe input of
the closed-form car-following set (``itha.car_following.admissible_inputs``), or its hardest braking when there
is none. ``h_min`` is 1 mm, so nothing but the model stands between the bumpers. Two guardians: the set of
(7.3) with its Euler step (the dissertation's model) and the set with exact integration.

Counted per episode, from the gap's least value inside every step (``exact.gap_min``, the world's own
kinematics): a contact (the gap below 0 at some instant) and a floor deficit (below ``h_min``).

    python benchmarks/exact_integration.py [--episodes 10000] [--seed 0] [--json]
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from itha import exact
from itha.car_following import CarFollowingParams, MaximalSet, admissible_inputs, headway_floor

VEHICLE = dict(dt=0.1, v_max=30.0, h_min=0.001, u_min=-8.0, u_max=3.0, d_min=-8.0, d_max=3.0)
PROPOSED = 1.5
STEPS = 80


def params(integration: str) -> CarFollowingParams:
    return CarFollowingParams(**VEHICLE, integration=integration)


def start(rng, p: CarFollowingParams) -> tuple[float, float, float]:
    """A state inside the guardian's set: speeds drawn in [5, 30], the gap 0-3 m above the least it may be."""
    v, vL = rng.uniform(5.0, 30.0, 2)
    h = p.h_min - float(headway_floor(p, np.array([v]), np.array([0.0]), np.array([vL]))[0]) + rng.uniform(0, 3)
    return float(v), float(h), float(vL)


def episode(p: CarFollowingParams, rng) -> dict:
    """One episode; the least gap over every instant, and the steps the guardian found no self-safe input."""
    S = MaximalSet(p)
    v, h, vL = start(rng, p)
    brake_at = int(rng.integers(0, 40))
    least, empty = h, 0
    for k in range(STEPS):
        inputs = admissible_inputs(S, (v, h, vL))
        if inputs:
            u = min(max(PROPOSED, inputs[0][0]), inputs[-1][1])
        else:
            u, empty = p.u_min, empty + 1
        aL = p.d_min if k >= brake_at else 0.0
        least = min(least, exact.gap_min(h, v, u, vL, aL, p.dt))
        v, h, vL = exact.next_state(p.dt, v, h, vL, u, aL)
        if v == 0.0 and vL == 0.0:
            break
    return {"least_gap": least, "contact": least < 0.0, "deficit": least < p.h_min, "empty_steps": empty}


def probe(integration: str, episodes: int, seed: int = 0) -> dict:
    """``episodes`` seeded episodes against the guardian of ``integration``; counts and the worst gap."""
    p, rng = params(integration), np.random.default_rng(seed)
    runs = [episode(p, rng) for _ in range(episodes)]
    least = min(r["least_gap"] for r in runs)
    return {"guardian": integration, "episodes": episodes, "contacts": sum(r["contact"] for r in runs),
            "floor_deficits": sum(r["deficit"] for r in runs), "least_gap_m": least,
            "deepest_overlap_m": max(0.0, -least), "steps_without_self_safe_input": sum(r["empty_steps"] for r in runs)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for integration in ("euler", "exact"):
        t0 = time.perf_counter()
        rows.append(dict(probe(integration, args.episodes, args.seed), seconds=round(time.perf_counter() - t0, 1)))
        print(f"{integration}: done", file=sys.stderr)
    if args.json:
        print(json.dumps({"vehicle": VEHICLE, "proposed": PROPOSED, "rows": rows}, indent=1))
        return 0
    print(f"{'guardian':8} {'episodes':>8} {'contacts':>8} {'deficits':>8} {'least gap [m]':>14} {'no input':>8}")
    for r in rows:
        print(f"{r['guardian']:8} {r['episodes']:>8} {r['contacts']:>8} {r['floor_deficits']:>8} "
              f"{r['least_gap_m']:>14.6f} {r['steps_without_self_safe_input']:>8}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
