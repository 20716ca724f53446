"""An ego whose actuator lags behind a lead that brakes at once: does the lagged set keep h_min, and does a set that
ignores the lag?

The world is (7.3)'s Euler step at highway-env's 15 Hz with ``GuardianConfig``'s bounds (U = D = [-6, 6] m/s^2,
v_max 40 m/s, h_min 2 m); the ego's acceleration follows ``itha.actuator.Actuator.follows`` (a first-order lag
sampled each step, within a jerk bound when one is given), the speed stopping at 0. The lead cruises (a random
acceleration in [-1, 1] each step), then at a random step brakes at -6 m/s^2 until it stands. The driver asks for
full throttle (+6) every step. Two guardians decide the command, as ``BicycleGuardian`` does on one lane (the next
speeds turned into accelerations by ``BicycleEgo.accel_for_speeds``, the nearest to the proposal taken):

* ``lagged``: ``RateLimitedSet`` with the actuator declared, bound to the ego's speed and acceleration; the
  proposal judged by what the lag makes of it, the answer the command that applies the acceleration chosen
  (``Actuator.asks``);
* ``unaware``: (7.3)'s closed-form set (``MaximalSet``), as if the acceleration could jump; the lag then does what
  it can with the command.

Starts are drawn inside the lagged set (speeds 5-30 m/s, acceleration now -3..3 m/s^2, the gap 0-3 m above the
least the set allows), so inside both. Counted: contacts (gap below 0 at a step's end; the episode ends there),
floor deficits (gap below h_min), the least gap.

    python benchmarks/lag_probe.py [--episodes 10000] [--unaware-episodes 1000] [--seed 0] [--json]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from guardian.config import GuardianConfig
from guardian.decide.kinematics import BicycleEgo
from itha.actuator import Actuator, RateLimitedSet
from itha.car_following import INNER, CarFollowingParams, MaximalSet
from rcis.intervals import nearest_in_intervals

DT, STEPS = 1 / 15, 200
ACTUATORS = {"lag 0.2 s": Actuator(lag=0.2, profile="hold"), "lag 0.5 s": Actuator(lag=0.5, profile="hold"),
             "jerk 10 m/s^3, lag 0.3 s": Actuator(jerk=10.0, lag=0.3, profile="hold")}


def params() -> CarFollowingParams:
    c = GuardianConfig()
    return CarFollowingParams(dt=DT, v_max=c.v_max, h_min=c.h_min, u_min=-c.traffic_accel, u_max=c.traffic_accel,
                              d_min=-c.traffic_accel, d_max=c.traffic_accel)


def start(S: RateLimitedSet, rng) -> tuple:
    v, vL = rng.uniform(5.0, 30.0, 2)
    a = rng.uniform(-3.0, 3.0)
    lo, hi = 0.0, 500.0   # the least gap inside, by bisection (membership grows with the gap)
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if S.contains((v, mid, vL, a)) else (mid, hi)
    return v, hi + rng.uniform(0.0, 3.0), vL, a


def command(guardian: str, S: RateLimitedSet, M: MaximalSet, kin: BicycleEgo, x) -> float:
    v, h, vL, a = x
    p, act = S.params, S.actuator
    h_next, vL_next = h + p.dt * (vL - v), max(vL + p.dt * p.d_min, 0.0)
    if guardian == "lagged":
        bound = S.bound(v, a)
        accel = kin.accel_for_speeds(v, bound.speed_intervals(h_next, vL_next), bound.commands)
        if not accel:
            return p.u_min
        return act.asks(a, nearest_in_intervals(accel, act.lagged(a, p.u_max, p.dt)), p.u_min, p.u_max, p.dt)
    accel = kin.accel_for_speeds(v, M.speed_intervals(h_next, vL_next))
    return nearest_in_intervals(accel, p.u_max) if accel else max(p.u_min, -v / p.dt)


def episode(guardian: str, S: RateLimitedSet, M: MaximalSet, kin: BicycleEgo, rng) -> dict:
    p, act = S.params, S.actuator
    x = start(S, rng)
    brake_at = int(rng.integers(0, STEPS // 2))
    least, deficit = x[1], False
    for t in range(STEPS):
        v, h, vL, a = x
        u = command(guardian, S, M, kin, x)
        assert p.u_min <= u <= p.u_max, u
        applied = act.follows(a, u, p.dt)
        d = p.d_min if t >= brake_at else rng.uniform(-1.0, 1.0)
        x = (max(v + p.dt * applied, 0.0), h + p.dt * (vL - v), min(max(vL + p.dt * d, 0.0), p.v_max), applied)
        least = min(least, x[1])
        deficit |= x[1] < p.h_min - INNER
        if x[1] < 0:
            break
    return {"least": least, "contact": least < 0, "deficit": deficit}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=10_000)
    ap.add_argument("--unaware-episodes", type=int, default=1_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    p = params()
    kin = BicycleEgo(DT, -p.u_min, 5.0, 2.0, 4.0, 1, math.pi / 4)
    M = MaximalSet(p)
    rows = []
    for name, act in ACTUATORS.items():
        S = RateLimitedSet(p, act)
        for guardian, n in (("lagged", args.episodes), ("unaware", args.unaware_episodes)):
            rng, t0 = np.random.default_rng([args.seed, len(rows)]), time.perf_counter()
            runs = [episode(guardian, S, M, kin, rng) for _ in range(n)]
            rows.append({"actuator": name, "guardian": guardian, "episodes": n,
                         "contacts": sum(r["contact"] for r in runs), "deficits": sum(r["deficit"] for r in runs),
                         "least_gap_m": round(min(r["least"] for r in runs), 6),
                         "seconds": round(time.perf_counter() - t0, 1)})
            print(f"{name} {guardian}: done", file=sys.stderr, flush=True)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"{'actuator':26} {'guardian':8} {'episodes':>8} {'contacts':>8} {'deficits':>8} {'least gap':>10}")
    for r in rows:
        print(f"{r['actuator']:26} {r['guardian']:8} {r['episodes']:8} {r['contacts']:8} {r['deficits']:8} "
              f"{r['least_gap_m']:9.3f}m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
