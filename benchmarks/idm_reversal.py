"""How far highway-env's IDM traffic backs up behind a standing car: the bound behind
``GuardianConfig.reverse_reach`` (docs/guardian.md "Reversing traffic").

highway-env lets its cars reverse (``Vehicle.MIN_SPEED = -40``); an ``IDMVehicle`` that stands inside its
desired gap brakes into reverse. This drives highway-env's own ``IDMVehicle`` on a one-lane straight road at
15 Hz towards a standing car, from every start in a grid (gap, speed) whose run never touches it, and
prints the longest single reversal (metres covered at negative speed, ``dt |v|`` summed) and where it began.

    python benchmarks/idm_reversal.py [--json]
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

SIM_HZ = 15
SECONDS = 30


def longest_reversal(gap: float, speed: float) -> float | None:
    """The longest reversal of an IDM car starting ``gap`` metres (bumper to bumper) behind a standing car at
    ``speed``; None when it touches the standing car."""
    from highway_env.road.lane import StraightLane
    from highway_env.road.road import Road, RoadNetwork
    from highway_env.vehicle.behavior import IDMVehicle
    from highway_env.vehicle.kinematics import Vehicle

    net = RoadNetwork()
    net.add_lane("a", "b", StraightLane([0.0, 0.0], [10_000.0, 0.0]))
    road = Road(network=net)
    car = IDMVehicle(road, [100.0, 0.0], speed=speed)
    car.target_speed = 30.0
    wall = Vehicle(road, [100.0 + car.LENGTH + gap, 0.0], speed=0.0)
    road.vehicles += [car, wall]
    dt, backed, longest = 1.0 / SIM_HZ, 0.0, 0.0
    for _ in range(SIM_HZ * SECONDS):
        wall.speed = 0.0
        car.act()
        v = float(car.speed)
        car.step(dt)
        if wall.position[0] - car.position[0] < car.LENGTH:
            return None
        backed = backed - v * dt if v < 0 else 0.0
        longest = max(longest, backed)
    return longest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    args = ap.parse_args(argv)
    worst, at, runs, touching = 0.0, None, 0, 0
    for gap in np.linspace(0.0, 75.0, 76):
        for speed in np.linspace(0.0, 25.0, 11):
            r = longest_reversal(float(gap), float(speed))
            runs += 1
            if r is None:
                touching += 1
                continue
            if r > worst:
                worst, at = r, (float(gap), float(speed))
            print(f"\r{runs} starts", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    out = {"starts": runs, "touching": touching, "longest_reversal_m": round(worst, 3),
           "from_gap_m": at[0], "from_speed_mps": at[1]}
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"{runs} starts ({touching} touched the standing car): the longest reversal {worst:.2f} m, "
              f"from a gap of {at[0]:g} m at {at[1]:g} m/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
