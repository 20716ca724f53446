"""What the guardian reads from a highway-env simulation: the road's lanes, the ego, the other cars.

The only module besides the wrapper that touches simulator objects; it turns them into the plain
values the decision objects take (``guardian.scene.Scene``, ``guardian.bicycle.EgoState``, the
overtake state).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

from highway_env.road.lane import StraightLane
from highway_env.vehicle.controller import ControlledVehicle

from guardian.bicycle import EgoState
from guardian.errors import ConfigError
from guardian.scene import Car, Scene


@dataclass(frozen=True)
class Road:
    """A straight multi-lane road along x: ``n_lanes`` lanes of ``lane_width``, lane 0 at ``y = 0``."""

    n_lanes: int
    lane_width: float

    def itha_lane(self, lane_id: int) -> int:
        """ITHA lane number (1 = rightmost) of highway-env lane id ``lane_id`` (0 = leftmost)."""
        return self.n_lanes - lane_id


def read_road(base) -> Road:
    """The env's road as parallel straight lanes along x, equally spaced; else a ConfigError."""
    graph = base.road.network.graph
    lanes = [lane for _from in graph.values() for group in _from.values() for lane in group]
    ok = bool(lanes) and all(isinstance(lane, StraightLane) and abs(lane.heading) < 1e-9 for lane in lanes)
    if ok:
        ys = sorted(float(lane.start[1]) for lane in lanes)
        widths = {round(lane.width, 9) for lane in lanes}
        gaps = {round(b - a, 9) for a, b in zip(ys, ys[1:])}
        ok = len(graph) == 1 and len(widths) == 1 and (len(ys) == 1 or gaps == widths) and abs(ys[0]) < 1e-9
    if not ok:
        raise ConfigError("Guardian: the road must be one straight multi-lane road along x with equal lanes "
                          "(highway-env's 'highway-v0' family, config 'lanes_count'); this env's road is not")
    return Road(len(lanes), float(lanes[0].width))


def road_scene(base, road: Road, ego_lanes=frozenset()) -> Scene:
    """The road as ITHA agents: the ego (in ITHA ``ego_lanes``) and every car but the overtake lead.

    A car changing lanes (``lane_index != target_lane_index``) occupies both.
    """
    ego, lead = base.vehicle, getattr(base, "lead", None)
    others = []
    for k, veh in enumerate(base.road.vehicles):
        if veh is ego or veh is lead:
            continue
        lane = veh.lane_index[2]
        target = veh.target_lane_index[2] if _is_controlled(type(veh)) else lane
        others.append(Car(float(veh.position[0]) + veh.LENGTH / 2, float(veh.speed),
                          _itha_lanes(road.n_lanes, lane, target), veh.LENGTH, f"car {k}"))
    me = Car(float(ego.position[0]) + ego.LENGTH / 2, float(ego.speed), frozenset(ego_lanes), ego.LENGTH, "ego")
    return Scene(me, tuple(others), road.n_lanes)


def bicycle_state(vehicle) -> EgoState:
    target = vehicle.target_lane_index[2] if isinstance(vehicle, ControlledVehicle) else vehicle.lane_index[2]
    return EgoState(float(vehicle.position[0]) + vehicle.LENGTH / 2, float(vehicle.position[1]),
                    float(vehicle.heading), float(vehicle.speed), vehicle.lane_index[2], target)


@functools.lru_cache(maxsize=None)
def _is_controlled(vehicle_type) -> bool:
    return issubclass(vehicle_type, ControlledVehicle)


@functools.lru_cache(maxsize=None)
def _itha_lanes(n_lanes: int, lane: int, target: int) -> frozenset:
    return frozenset({n_lanes - lane, n_lanes - target})
