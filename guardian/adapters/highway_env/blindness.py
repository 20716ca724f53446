"""Traffic that does not see a guarded car: highway-env's v0 roads search one lane segment.

On highway-env's v0 roads (``neighbour_vehicles_connected_lanes`` false: merge-v0, exit-v0) an IDM car
looks for the cars ahead of and behind it on the lanes of its own segment only. ``blind_to`` says which
traffic cars the scene must take as blind (``guardian.model.scene.Car.blind``); ``traffic_blind_to``
counts the steps in which such a car missed a guarded car (``guardian.adapters.highway_env.monitor``).
"""
from __future__ import annotations

import math

import numpy as np
from highway_env.vehicle.behavior import IDMVehicle

BLIND_MARGIN = 1.0   # [m] highway-env's v0 search finds a car within a lane's width / 2 + 1 m of its centre line
BLIND_ACCEL = 6.0    # [m/s^2] the ego's hardest acceleration over the policy step blindness looks ahead


def ego_probes(base, ego) -> tuple:
    """Where ``ego``'s centre is now and after one policy step of full acceleration (``blind_to``'s
    points); empty when traffic searches across lane segments, where nobody is blind."""
    if getattr(base.road, "neighbour_vehicles_connected_lanes", True):
        return ()
    period = 1.0 / base.config.get("policy_frequency", 1)
    reach = max(float(ego.speed), 0.0) * period + 0.5 * BLIND_ACCEL * period ** 2
    return (ego.position, ego.position + reach * np.array([math.cos(ego.heading), math.sin(ego.heading)]))


def blind_to(base, veh, probes) -> bool:
    """Whether traffic car ``veh`` cannot see the ego at one of its ``probes`` (``ego_probes``).

    On highway-env's v0 roads (``neighbour_vehicles_connected_lanes`` false: merge-v0, exit-v0) an IDM
    car looks for the cars ahead of and behind it, for braking and for MOBIL's lane changes, on the lanes
    of its own segment only (``Road.neighbour_vehicles``: ``on_lane`` with a margin of 1 m). A car whose
    segment holds no lane the ego's centre is on, now or one policy step of full acceleration further,
    neither brakes for the ego nor weighs it when it changes lanes. Guarded cars do not search this way.
    """
    if not probes or not isinstance(veh, IDMVehicle) or veh.lane_index is None:
        return False
    lanes = base.road.network.graph[veh.lane_index[0]][veh.lane_index[1]]
    return not all(any(lane.on_lane(pos, margin=BLIND_MARGIN) for lane in lanes) for pos in probes)



BLIND_RANGE = 100.0  # [m] traffic cars farther than this along x are not asked (a segment's end is nearer)


def traffic_blind_to(road, car) -> bool:
    """Whether some traffic car misses ``car`` ahead or behind it, in its lane or a lane beside it, where
    highway-env's connected-lane search would find it (``guardian.adapters.highway_env.monitor``)."""
    if getattr(road, "neighbour_vehicles_connected_lanes", True) or car.lane_index is None \
            or sum(len(ends) for ends in road.network.graph.values()) < 2:
        return False  # one segment per lane: both searches are the same
    x = float(car.position[0])
    for other in road.vehicles:
        if other is car or not isinstance(other, IDMVehicle) or other.crashed \
                or abs(float(other.position[0]) - x) > BLIND_RANGE or other.lane_index is None:
            continue
        for lane in [other.lane_index, *road.network.side_lanes(other.lane_index)]:
            if lane[:2] == car.lane_index[:2] or car in road.neighbour_vehicles(other, lane):
                continue  # on the car's own segment the v0 search finds it whenever the other would
            road.neighbour_vehicles_connected_lanes = True
            try:
                seen = car in road.neighbour_vehicles(other, lane)
            finally:
                road.neighbour_vehicles_connected_lanes = False
            if seen:
                return True
    return False
