"""What the guardian reads from a highway-env simulation: the ego and the other cars.

It turns simulator objects into the plain values the decision objects take (``guardian.model.scene.Scene``,
``guardian.model.scene.EgoState``); the road is read by ``guardian.adapters.highway_env.road``.
"""
from __future__ import annotations

import functools

from highway_env.vehicle.controller import ControlledVehicle

from guardian.adapters.highway_env.blindness import blind_to, ego_probes
from guardian.config import REVERSE_REACH
from guardian.decide.kinematics import BicycleEgo
from guardian.model.body import half_extents, lanes_overlapped
from guardian.model.reversing import lengthen_reversing
from guardian.model.roads import Road, RoadMap
from guardian.model.scene import Car, EgoState, Scene


def road_scene(base, road, ego_lanes=frozenset(), ego=None, guarded=frozenset(), announced=None,
               reverse_reach: float = REVERSE_REACH) -> Scene:
    """The road as ITHA agents: the ego (in ITHA ``ego_lanes``) and every car but the overtake lead.

    A car occupies every lane its body overlaps (widened as the guardian widens its own: a slow car turning out
    of a lane reaches back into it), and its lane and target lane (a car changing lanes occupies both): never
    the lane index alone, since a body may lie over a line while its centre keeps its lane. ``ego`` is the
    guarded car whose scene this is (default: the env's ego); ``guarded`` are the ids of every guarded car
    (they announce, ``Car.announces``); ``announced`` maps a guarded car's id to the ITHA lanes it announced it enters this step. On a
    ``RoadMap`` fronts are along the lanes' chains, obstacles are standing cars and each dead end is a
    standing car of length 0 (``guardian.model.roads``).

    A car driving backwards (outside the traffic model) is taken longer at its rear by how far it may still
    back up (``reverse_reach``, ``GuardianConfig``; more behind a car that reverses too: ``reverse_reaches``)
    and in the lanes beside its own too (its steering swings a reversing body).
    """
    ego = base.vehicle if ego is None else ego
    announced = announced or {}
    if isinstance(road, RoadMap):
        return _map_scene(base, road, ego, ego_lanes, guarded, announced, reverse_reach)
    lead = getattr(base, "lead", None)
    lanes_of = road.numbering
    others, own = [], []
    for k, veh in enumerate(base.road.vehicles):
        if veh is ego or veh is lead:
            continue
        lane = veh.lane_index[2]
        target = veh.target_lane_index[2] if _is_controlled(type(veh)) else lane
        lanes = _itha_pair(lanes_of, lane, target) | lanes_of.itha_set(_straight_body_lanes(veh, road))
        lanes = lanes | announced.get(id(veh), frozenset())
        if veh.speed < 0:
            lanes = lanes | frozenset(j + s for j in lanes for s in (-1, 1) if 1 <= j + s <= road.n_lanes)
        others.append(Car(float(veh.position[0]) + veh.LENGTH / 2, float(veh.speed), lanes, veh.LENGTH, f"car {k}",
                          id(veh) in guarded, bool(veh.crashed), across=_across(veh)))
        own.append(lanes_of.itha(lane))
    others = lengthen_reversing(others, own, reverse_reach)
    me = Car(float(ego.position[0]) + ego.LENGTH / 2, float(ego.speed), frozenset(ego_lanes), ego.LENGTH, "ego",
             id(ego) in guarded)
    return Scene(me, tuple(others), road.n_lanes)


def _across(body) -> tuple:
    """Where ``body`` reaches across the road (world y) now."""
    y, r = float(body.position[1]), half_extents(body.LENGTH, body.WIDTH, float(body.heading))[1]
    return y - r, y + r


def _straight_body_lanes(veh, road: Road) -> frozenset:
    """Lane ids a body overlaps on the straight road (widened as the guardian widens its own)."""
    r = half_extents(veh.LENGTH, veh.WIDTH, float(veh.heading))[1] + BicycleEgo.LATERAL_MARGIN
    y = float(veh.position[1])
    return lanes_overlapped(y - r, y + r, road.n_lanes, road.lane_width)


def _map_scene(base, road: RoadMap, ego, ego_lanes, guarded, announced, reverse_reach: float) -> Scene:
    lanes_of = road.numbering
    others, own = [], []
    ego_front = road.longitudinal(ego.lane_index, float(ego.position[0]), float(ego.position[1])) + ego.LENGTH / 2
    probes = ego_probes(base, ego)
    for k, veh in enumerate(base.road.vehicles):
        if veh is ego:
            continue
        front, slots, lanes = _vehicle_reading(road, veh)
        blind = blind_to(base, veh, probes)
        reversing = veh.speed < 0
        # blind: it may change into a lane beside it in front of the ego unseen; reversing: its body swings
        if (blind and front >= ego_front) or reversing:
            slots = slots | {road.slot_of(side) for side in base.road.network.side_lanes(veh.lane_index)}
            lanes = lanes_of.itha_set(slots)
        lanes = lanes | announced.get(id(veh), frozenset())
        others.append(Car(front, float(veh.speed), lanes, veh.LENGTH, f"car {k}", id(veh) in guarded,
                          bool(veh.crashed), blind=blind, across=_across(veh)))
        own.append(lanes_of.itha(road.slot_of(veh.lane_index)))
    others = lengthen_reversing(others, own, reverse_reach)
    for k, obj in enumerate(base.road.objects):
        if not (getattr(obj, "solid", True) and getattr(obj, "collidable", True)):
            continue
        x, y = float(obj.position[0]), float(obj.position[1])
        slots = road.body_slots(x, y, float(obj.heading), obj.LENGTH, obj.WIDTH, BicycleEgo.LATERAL_MARGIN)
        if slots:
            index = road.memo(("object lane", x, y, float(obj.heading)),
                              lambda: base.road.network.get_closest_lane_index(obj.position, obj.heading))
            others.append(Car(road.longitudinal(index, x, y) + obj.LENGTH / 2, 0.0,
                              lanes_of.itha_set(slots), obj.LENGTH, f"obstacle {k}", fixed=True, across=_across(obj)))
    others.extend(road.end_cars())
    me = Car(ego_front, float(ego.speed), frozenset(ego_lanes), ego.LENGTH, "ego", id(ego) in guarded)
    return Scene(me, tuple(others), road.n_lanes)


def _vehicle_reading(road: RoadMap, veh) -> tuple:
    """A traffic car on the map: its front along its lane's chain, the slots its body (widened as the
    guardian widens its own) overlaps with its lane and target lane, and those slots' ITHA lanes; a function
    of the car's pose and lanes, remembered by the map (every guarded car's scene reads every car)."""
    x, y, heading = float(veh.position[0]), float(veh.position[1]), float(veh.heading)
    target = veh.target_lane_index if _is_controlled(type(veh)) else None

    def read():
        slots = set(road.body_slots(x, y, heading, veh.LENGTH, veh.WIDTH, BicycleEgo.LATERAL_MARGIN))
        slots.add(road.slot_of(veh.lane_index))
        if target is not None:
            slots.add(road.slot_of(target))
        front = road.longitudinal(veh.lane_index, x, y) + veh.LENGTH / 2
        return front, frozenset(slots), road.numbering.itha_set(slots)

    return road.memo(("vehicle", x, y, heading, veh.LENGTH, veh.WIDTH, tuple(veh.lane_index),
                      None if target is None else tuple(target)), read)


def bicycle_state(vehicle, road=None) -> EgoState:
    """The bicycle state of ``vehicle``; on a ``RoadMap`` (``road``) lanes are slots and ``front`` is along
    its lane's chain."""
    if isinstance(road, RoadMap):
        x, y = float(vehicle.position[0]), float(vehicle.position[1])
        lane = road.slot_of(vehicle.lane_index)
        target = road.slot_of(vehicle.target_lane_index) if isinstance(vehicle, ControlledVehicle) else lane
        return EgoState(road.longitudinal(vehicle.lane_index, x, y) + vehicle.LENGTH / 2, y, float(vehicle.heading),
                        float(vehicle.speed), lane, target, x)
    target = vehicle.target_lane_index[2] if isinstance(vehicle, ControlledVehicle) else vehicle.lane_index[2]
    return EgoState(float(vehicle.position[0]) + vehicle.LENGTH / 2, float(vehicle.position[1]),
                    float(vehicle.heading), float(vehicle.speed), vehicle.lane_index[2], target)


@functools.lru_cache(maxsize=None)
def _is_controlled(vehicle_type) -> bool:
    return issubclass(vehicle_type, ControlledVehicle)


@functools.lru_cache(maxsize=None)
def _itha_pair(numbering, lane: int, target: int) -> frozenset:
    return numbering.itha_set({lane, target})
