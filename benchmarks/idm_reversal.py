"""How far highway-env's IDM traffic backs up behind a standing car: the bound behind
``GuardianConfig.reverse_reach`` (docs/guardian.md "Reversing traffic").

highway-env lets its cars reverse (``Vehicle.MIN_SPEED = -40``); an ``IDMVehicle`` that stands inside its
desired gap brakes into reverse. This drives highway-env's own ``IDMVehicle`` on a one-lane straight road at
15 Hz towards a standing car, from every start in a grid (gap, speed) whose run never touches it, and
prints the longest single reversal (metres covered at negative speed, ``dt |v|`` summed) and where it began.

A second family ("beside") puts the standing car in the next lane's half, its centre 2.9 m to the side and
0.2-5 m ahead: highway-env's neighbour search counts a car as in a lane when its centre is within half
the lane's width plus 1 m (``Road.neighbour_vehicles``, ``on_lane(..., margin=1)``), so the IDM car takes it
as the car ahead at a gap below zero. This is what a guarded car standing half-merged at the on-ramp's
end is to the IDM car beside it; the bodies never touch.

    python benchmarks/idm_reversal.py [--json]
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

SIM_HZ = 15
SECONDS = 30


BESIDE = 2.9   # lateral offset of the standing car's centre in the "beside" family [m]


def longest_reversal(gap: float, speed: float, beside: bool = False) -> float | None:
    """The longest reversal of an IDM car starting ``gap`` metres (bumper to bumper; ``beside``: centre to
    centre, the standing car ``BESIDE`` to the side) behind a standing car at ``speed``; None when it
    touches the standing car."""
    from highway_env.road.lane import StraightLane
    from highway_env.road.road import Road, RoadNetwork
    from highway_env.vehicle.behavior import IDMVehicle
    from highway_env.vehicle.kinematics import Vehicle

    net = RoadNetwork()
    net.add_lane("a", "b", StraightLane([0.0, 0.0], [10_000.0, 0.0]))
    road = Road(network=net)
    car = IDMVehicle(road, [100.0, 0.0], speed=speed)
    car.target_speed = 30.0
    wall = Vehicle(road, [100.0 + gap, BESIDE] if beside else [100.0 + car.LENGTH + gap, 0.0], speed=0.0)
    road.vehicles += [car, wall]
    dt, backed, longest = 1.0 / SIM_HZ, 0.0, 0.0
    for _ in range(SIM_HZ * SECONDS):
        wall.speed = 0.0
        car.act()
        v = float(car.speed)
        car.step(dt)
        if not beside and wall.position[0] - car.position[0] < car.LENGTH:
            return None
        backed = backed - v * dt if v < 0 else 0.0
        longest = max(longest, backed)
    return longest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    args = ap.parse_args(argv)
    out = _family(np.linspace(0.0, 75.0, 76), np.linspace(0.0, 25.0, 11), beside=False)
    out["beside"] = _family(np.linspace(0.2, 5.0, 25), np.linspace(0.0, 5.0, 6), beside=True)
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    for name, r in (("behind it in its lane", out), ("beside it (half in the lane ahead)", out["beside"])):
        print(f"{name}: {r['starts']} starts ({r['touching']} touched the standing car): the longest reversal "
              f"{r['longest_reversal_m']:.2f} m, from a gap of {r['from_gap_m']:g} m at {r['from_speed_mps']:g} m/s")
    return 0


def _family(gaps, speeds, beside: bool) -> dict:
    worst, at, runs, touching = 0.0, None, 0, 0
    for gap in gaps:
        for speed in speeds:
            r = longest_reversal(float(gap), float(speed), beside)
            runs += 1
            if r is None:
                touching += 1
                continue
            if r > worst:
                worst, at = r, (float(gap), float(speed))
            print(f"\r{runs} starts", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return {"starts": runs, "touching": touching, "longest_reversal_m": round(worst, 3),
            "from_gap_m": at[0], "from_speed_mps": at[1]}


if __name__ == "__main__":
    sys.exit(main())
