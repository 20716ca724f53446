"""What the guardian reads from a highway-env simulation: the ego and the other cars.

Each other car becomes a ``guardian.model.sensing.Sensed`` record (its body, and the lane and target lane
highway-env gives it), and ``guardian.model.sensing.scene_of`` makes the ``Scene`` the decision objects take,
as it does for every reader (the service's scene sessions among them); the ego becomes an ``EgoState``. The
road is read by ``guardian.adapters.highway_env.road``.
"""
from __future__ import annotations

import functools

from highway_env.vehicle.controller import ControlledVehicle

from guardian.adapters.highway_env.blindness import blind_to, ego_probes
from guardian.config import GuardianConfig
from guardian.decide.kinematics import BicycleEgo
from guardian.model.roads import RoadMap
from guardian.model.scene import Car, EgoState, Scene
from guardian.model.sensing import Sensed, scene_of


def road_scene(base, road, ego_lanes=frozenset(), ego=None, guarded=frozenset(), announced=None,
               reversing=GuardianConfig().reversing) -> Scene:
    """The road as ITHA agents: the ego (in ITHA ``ego_lanes``) and every car but the overtake lead.

    A car occupies every lane its body overlaps (widened as the guardian widens its own: a slow car turning out
    of a lane reaches back into it), and its lane and target lane (a car changing lanes occupies both): never
    the lane index alone, since a body may lie over a line while its centre keeps its lane. ``ego`` is the
    guarded car whose scene this is (default: the env's ego); ``guarded`` are the ids of every guarded car
    (they announce, ``Car.announces``); ``announced`` maps a guarded car's id to the ITHA lanes it announced it
    enters this step. On a ``RoadMap`` fronts are along the lanes' chains, obstacles are standing cars and each
    dead end is a standing car of length 0 (``guardian.model.roads``).

    A car that may be driving backwards before the next look (outside the traffic model) is taken longer at its
    rear by how far it may still back up (``reversing``, ``GuardianConfig.reversing``; more behind a car that
    reverses); one seen driving backwards is in the lanes beside its own too (its steering swings it).
    """
    ego = base.vehicle if ego is None else ego
    sensed = sensed_traffic(base, road, ego, guarded, announced or {})
    return scene_of(road, ego_car(road, ego, ego_lanes, guarded), sensed, reversing, BicycleEgo.LATERAL_MARGIN,
                    road.end_cars() if isinstance(road, RoadMap) else ())


def ego_car(road, ego, ego_lanes=frozenset(), guarded=frozenset()) -> Car:
    """The guarded car ``ego`` as the ITHA agent whose scene it is, in ITHA ``ego_lanes``."""
    return Car(_front(road, ego), float(ego.speed), frozenset(ego_lanes), ego.LENGTH, "ego", id(ego) in guarded)


def sensed_traffic(base, road, ego, guarded=frozenset(), announced=None) -> list:
    """Every other car (and, on a ``RoadMap``, every solid obstacle on the road) as ``Sensed`` records."""
    announced = announced or {}
    if isinstance(road, RoadMap):
        return _map_traffic(base, road, ego, guarded, announced)
    lead = getattr(base, "lead", None)
    out = []
    for k, veh in enumerate(base.road.vehicles):
        if veh is ego or veh is lead:
            continue
        lane = veh.lane_index[2]
        target = veh.target_lane_index[2] if _is_controlled(type(veh)) else lane
        out.append(_sensed(veh, f"car {k}", float(veh.position[0]) + veh.LENGTH / 2, lane, frozenset({lane, target}),
                           guarded, announced, swings=veh.speed < 0))
    return out


def _sensed(veh, name: str, front: float, own: int, lanes: frozenset, guarded, announced, **kw) -> Sensed:
    return Sensed(name, float(veh.position[0]), float(veh.position[1]), float(veh.heading), float(veh.speed),
                  veh.LENGTH, veh.WIDTH, front, own, lanes, announced=announced.get(id(veh), frozenset()),
                  announces=id(veh) in guarded, crashed=bool(veh.crashed), **kw)


def _map_traffic(base, road: RoadMap, ego, guarded, announced) -> list:
    ego_front = _front(road, ego)
    probes = ego_probes(base, ego)
    out = []
    for k, veh in enumerate(base.road.vehicles):
        if veh is ego:
            continue
        front, own, lanes = _vehicle_reading(road, veh)
        blind = blind_to(base, veh, probes)
        beside = frozenset()
        # blind: it may change into a lane beside it in front of the ego unseen; reversing: its body swings
        if (blind and front >= ego_front) or veh.speed < 0:
            beside = frozenset(road.slot_of(side) for side in base.road.network.side_lanes(veh.lane_index))
        out.append(_sensed(veh, f"car {k}", front, own, lanes, guarded, announced, beside=beside, blind=blind))
    for k, obj in enumerate(base.road.objects):
        if not (getattr(obj, "solid", True) and getattr(obj, "collidable", True)):
            continue
        x, y = float(obj.position[0]), float(obj.position[1])
        if not road.body_slots(x, y, float(obj.heading), obj.LENGTH, obj.WIDTH, BicycleEgo.LATERAL_MARGIN):
            continue
        index = road.memo(("object lane", x, y, float(obj.heading)),
                          lambda: base.road.network.get_closest_lane_index(obj.position, obj.heading))
        out.append(Sensed(f"obstacle {k}", x, y, float(obj.heading), 0.0, obj.LENGTH, obj.WIDTH,
                          road.longitudinal(index, x, y) + obj.LENGTH / 2, road.slot_of(index), fixed=True))
    return out


def _front(road, veh) -> float:
    x, y = float(veh.position[0]), float(veh.position[1])
    along = road.longitudinal(veh.lane_index, x, y) if isinstance(road, RoadMap) else x
    return along + veh.LENGTH / 2


def _vehicle_reading(road: RoadMap, veh) -> tuple:
    """A traffic car on the map: its front along its lane's chain, its lane's slot, and the slots of its lane
    and target lane; remembered by the map for its pose (every guarded car's scene reads every car)."""
    x, y, heading = float(veh.position[0]), float(veh.position[1]), float(veh.heading)
    target = veh.target_lane_index if _is_controlled(type(veh)) else None

    def read():
        own = road.slot_of(veh.lane_index)
        lanes = {own} | ({road.slot_of(target)} if target is not None else set())
        return road.longitudinal(veh.lane_index, x, y) + veh.LENGTH / 2, own, frozenset(lanes)

    return road.memo(("vehicle", x, y, heading, veh.LENGTH, tuple(veh.lane_index),
                      None if target is None else tuple(target)), read)


def bicycle_state(vehicle, road=None) -> EgoState:
    """The bicycle state of ``vehicle``; on a ``RoadMap`` (``road``) lanes are slots and ``front`` is along
    its lane's chain. The acceleration is the one its actuator applied over the last step, where the world fits
    one (``envs.actuator.JerkLimit``); 0 elsewhere (unread)."""
    accel = float(vehicle.__dict__.get("applied_acceleration", 0.0))
    if isinstance(road, RoadMap):
        x, y = float(vehicle.position[0]), float(vehicle.position[1])
        lane = road.slot_of(vehicle.lane_index)
        target = road.slot_of(vehicle.target_lane_index) if isinstance(vehicle, ControlledVehicle) else lane
        return EgoState(road.longitudinal(vehicle.lane_index, x, y) + vehicle.LENGTH / 2, y, float(vehicle.heading),
                        float(vehicle.speed), lane, target, x, accel)
    target = vehicle.target_lane_index[2] if isinstance(vehicle, ControlledVehicle) else vehicle.lane_index[2]
    return EgoState(float(vehicle.position[0]) + vehicle.LENGTH / 2, float(vehicle.position[1]),
                    float(vehicle.heading), float(vehicle.speed), vehicle.lane_index[2], target, 0.0, accel)


@functools.lru_cache(maxsize=None)
def _is_controlled(vehicle_type) -> bool:
    return issubclass(vehicle_type, ControlledVehicle)
