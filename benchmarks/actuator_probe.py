"""An ego that cannot brake at once behind a lead that brakes at once: which guardian keeps the bumpers apart.

The ego's actuator (``itha.actuator.Actuator``) moves its acceleration at most ``jerk`` m/s^3 (ramping over each
0.1 s step, as in CommonRoad's ACC falsification suite) and acts on a command ``delay`` steps after it is given;
both cars move exactly. The lead cruises, then at a random step brakes at -8 m/s^2 at once until it stands.
The driver proposes +1.5 m/s^2 every step. Two guardians decide the command:

* ``unaware``: the car-following set with exact integration but no actuator (``MaximalSet``,
  ``admissible_inputs``), as if the acceleration could jump; the actuator then does what it can;
* ``actuated``: ``ActuatedSet`` with the actuator declared (``admissible_commands``).

Starts are drawn inside the actuated set (and so inside both). Counted per episode from the gap's least value in
every step: contacts (below 0; the episode ends at the step where the bumpers meet) and floor deficits (below
``h_min`` = 1 mm). What the actuator costs: the share of
random states (speeds 0-30 m/s, gap 0-60 m, acceleration now -8..3) each set accepts.

    python benchmarks/actuator_probe.py [--episodes 300] [--seed 0] [--json]
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from itha.actuator import Actuator, ActuatedSet, least_gap, motion
from itha.car_following import CarFollowingParams, MaximalSet, admissible_inputs

VEHICLE = dict(dt=0.1, v_max=30.0, h_min=0.001, u_min=-8.0, u_max=3.0, d_min=-8.0, d_max=3.0, integration="exact")
ACTUATORS = {"jerk 10": Actuator(jerk=10.0), "jerk 5": Actuator(jerk=5.0),
             "jerk 10, delay 0.2 s": Actuator(jerk=10.0, delay=2)}
PROPOSED = 1.5
STEPS = 80


def start(A: ActuatedSet, rng) -> tuple:
    """A state inside ``A``: speeds in [5, 30], acceleration now in [-2, 2] (queued commands the same), the gap
    0-3 m above the least the set allows."""
    p = A.params
    v, vL = rng.uniform(5.0, 30.0, 2)
    a = rng.uniform(-2.0, 2.0)
    x = (v, 0.0, vL, a, *([a] * A.actuator.delay))
    h = p.h_min - A.floor(x) + rng.uniform(0, 3)
    return (v, h, vL, a, *([a] * A.actuator.delay))


def command(guardian: str, A: ActuatedSet, S: MaximalSet, x) -> float:
    if guardian == "actuated":
        allowed = A.admissible_commands(x)
    else:
        allowed = admissible_inputs(S, x[:3])
    if not allowed:
        return A.params.u_min
    return min(max(PROPOSED, allowed[0][0]), allowed[-1][1])


def episode(guardian: str, A: ActuatedSet, rng) -> dict:
    p, S = A.params, MaximalSet(A.params)
    x = start(A, rng)
    brake_at = int(rng.integers(0, 40))
    least, empty = x[1], 0
    for k in range(STEPS):
        v, h, vL, a, *queue = x
        wanted = command(guardian, A, S, x)
        empty += guardian == "actuated" and not A.admissible_commands(x)
        lo, hi = A.command_bounds(x)
        c = min(max(wanted, lo), hi)                    # the actuator reaches what it can
        aL = p.d_min if k >= brake_at else 0.0
        first = (queue + [c])[0]
        ego = motion(v, a, [A._step(a, first)])
        lead = motion(vL, aL, [(p.dt, 0.0, None)])
        least = min(least, least_gap(h, ego, lead, p.dt))
        x = A.next_state(x, c, aL)
        if least < 0.0 or (x[0] == 0.0 and x[2] == 0.0):   # the bumpers met (the episode ends), or both stand
            break
    return {"least_gap": least, "contact": least < 0.0, "deficit": least < p.h_min, "empty_steps": empty}


def probe(guardian: str, name: str, episodes: int, seed: int = 0) -> dict:
    A, rng = ActuatedSet(CarFollowingParams(**VEHICLE), ACTUATORS[name]), np.random.default_rng(seed)
    runs = [episode(guardian, A, rng) for _ in range(episodes)]
    least = min(r["least_gap"] for r in runs)
    return {"actuator": name, "guardian": guardian, "episodes": episodes,
            "contacts": sum(r["contact"] for r in runs), "floor_deficits": sum(r["deficit"] for r in runs),
            "least_gap_m": least, "deepest_overlap_m": max(0.0, -least),
            "steps_without_admissible_command": sum(r["empty_steps"] for r in runs)}


def accepted_share(samples: int, seed: int = 0) -> dict:
    """The share of random states each set accepts (the queue holds the acceleration now)."""
    p, rng = CarFollowingParams(**VEHICLE), np.random.default_rng(seed)
    states = np.column_stack([rng.uniform(0, 30, samples), rng.uniform(0, 60, samples), rng.uniform(0, 30, samples),
                              rng.uniform(-8, 3, samples)])
    out = {"no actuator dynamics": float(MaximalSet(p).contains(states[:, :3]).mean())}
    for name, act in ACTUATORS.items():
        A = ActuatedSet(p, act)
        out[name] = float(np.mean([A.contains((*s, *([s[3]] * act.delay))) for s in states]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for name in ACTUATORS:
        for guardian in ("unaware", "actuated"):
            t0 = time.perf_counter()
            rows.append(dict(probe(guardian, name, args.episodes, args.seed), seconds=round(time.perf_counter() - t0, 1)))
            print(f"{name}, {guardian}: done", file=sys.stderr)
    share = accepted_share(20_000, args.seed)
    if args.json:
        print(json.dumps({"vehicle": VEHICLE, "proposed": PROPOSED, "rows": rows, "accepted_share": share}, indent=1))
        return 0
    print(f"{'actuator':22} {'guardian':9} {'episodes':>8} {'contacts':>8} {'deficits':>8} {'least gap [m]':>14}")
    for r in rows:
        print(f"{r['actuator']:22} {r['guardian']:9} {r['episodes']:>8} {r['contacts']:>8} {r['floor_deficits']:>8} "
              f"{r['least_gap_m']:>14.6f}")
    print("share of random states accepted: " + ", ".join(f"{k} {v:.1%}" for k, v in share.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
