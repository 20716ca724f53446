"""What the guardian reads from a highway-env simulation: the road's lanes, the ego, the other cars.

The only module besides the wrapper that touches simulator objects; it turns them into the plain
values the decision objects take (``guardian.scene.Scene``, ``guardian.bicycle.EgoState``, the
overtake state, ``guardian.roads.RoadMap``).

Roads: one straight multi-lane road along x is a ``Road`` (the ``highway-v0`` family); any other road
highway-env builds from straight, sine and circular lanes of one width, one-way along ``+x``, is read as a
``guardian.roads.RoadMap`` (``merge-v0``, ``merge-generic-v0``, ``exit-v0``) when it is a corridor of
straight lanes with on-ramps and exits chained to it (see ``guardian.roads``); every other road is refused
with the reason (``read_road``).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import numpy as np

from highway_env.road.lane import CircularLane, SineLane, StraightLane
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle

from guardian.bicycle import EgoState
from guardian.config import REVERSE_REACH
from guardian.errors import ConfigError
from guardian.roads import RoadMap, Strip
from guardian.scene import Car, Scene

JOIN = 1e-6  # [m] lane ends closer than this are joined


@dataclass(frozen=True)
class Road:
    """A straight multi-lane road along x: ``n_lanes`` lanes of ``lane_width``, lane 0 at ``y = 0``."""

    n_lanes: int
    lane_width: float

    def itha_lane(self, lane_id: int) -> int:
        """ITHA lane number (1 = rightmost) of highway-env lane id ``lane_id`` (0 = leftmost)."""
        return self.n_lanes - lane_id


def read_road(base):
    """The env's road: a ``Road`` when it is one straight multi-lane road along x with equal lanes, lane 0
    at ``y = 0`` (the ``highway-v0`` family); else a ``guardian.roads.RoadMap`` (``read_road_map``); a
    road the guardian cannot reason about raises a ConfigError with the reason."""
    graph = base.road.network.graph
    lanes = [lane for _from in graph.values() for group in _from.values() for lane in group]
    ok = bool(lanes) and all(isinstance(lane, StraightLane) and abs(lane.heading) < 1e-9 for lane in lanes)
    if ok:
        ys = sorted(float(lane.start[1]) for lane in lanes)
        widths = {round(lane.width, 9) for lane in lanes}
        gaps = {round(b - a, 9) for a, b in zip(ys, ys[1:])}
        ok = len(graph) == 1 and len(widths) == 1 and (len(ys) == 1 or gaps == widths) and abs(ys[0]) < 1e-9
    if ok:
        return Road(len(lanes), float(lanes[0].width))
    return read_road_map(base.road.network)


def _refuse(why: str):
    raise ConfigError(f"Guardian: cannot reason about this env's road: {why}. It reads one-way roads along +x "
                      "of equal lanes: straight lanes on parallel slots, with on-ramps and exits (straight, sine or "
                      "circular lanes) chained to one slot (highway-v0, merge-v0, merge-generic-v0, exit-v0)")


def _close(a, b) -> bool:
    return math.hypot(float(a[0]) - float(b[0]), float(a[1]) - float(b[1])) < JOIN


def read_road_map(network) -> RoadMap:
    """highway-env's ``RoadNetwork`` as a corridor with branches (``guardian.roads``), or a ConfigError
    saying why the guardian cannot reason about it."""
    graph = network.graph
    lanes = [((f, t, i), lane) for f, tos in graph.items() for t, group in tos.items() for i, lane in enumerate(group)]
    if not lanes:
        _refuse("it has no lanes")
    for index, lane in lanes:
        if type(lane) not in (StraightLane, SineLane, CircularLane):
            _refuse(f"lane {index} is a {type(lane).__name__}")
    widths = {round(float(lane.width), 9) for _, lane in lanes}
    if len(widths) != 1:
        _refuse(f"its lanes have different widths {sorted(widths)} m")
    w = widths.pop()
    starts = {index: lane.position(0.0, 0.0) for index, lane in lanes}
    ends = {index: lane.position(lane.length, 0.0) for index, lane in lanes}
    for index, lane in lanes:
        if math.cos(float(lane.heading_at(0.0))) < 0 or math.cos(float(lane.heading_at(lane.length))) < 0:
            _refuse(f"lane {index} runs against the direction of travel (towards -x)")
    along = [(index, lane) for index, lane in lanes if type(lane) is StraightLane
             and abs(float(lane.direction[1])) < 1e-9 and float(lane.direction[0]) > 0]
    if not along:
        _refuse("no lane runs straight along +x")

    def on_grid(y, y_ref):
        q = (y - y_ref) / w
        return abs(q - round(q)) < 1e-6

    # the grid of slots: the one holding most straight lanes along x (ties: the leftmost)
    ys = sorted({round(float(lane.start[1]), 9) for _, lane in along})
    y_ref = max(ys, key=lambda y: (sum(on_grid(float(lane.start[1]), y) for _, lane in along), -y))
    corridor = {index: lane for index, lane in along if on_grid(float(lane.start[1]), y_ref)}
    y0 = min(float(lane.start[1]) for lane in corridor.values())
    slot = {index: int(round((float(lane.start[1]) - y0) / w)) for index, lane in corridor.items()}
    n_lanes = max(slot.values()) + 1
    incoming = {t for tos in graph.values() for t in tos}
    sources = {f for f in graph if f not in incoming}
    sinks = {t for t in incoming if not graph.get(t)}

    def successors(index):
        return [j for j, _ in lanes if j != index and _close(ends[index], starts[j])]

    def predecessors(index):
        return [j for j, _ in lanes if j != index and _close(ends[j], starts[index])]

    # branches: chains of the other lanes, each joined to one corridor lane at one end
    branches, table, done = [], {index: (slot[index], -1) for index in corridor}, set()
    continued_after, continued_before = set(), set()   # corridor lanes a branch continues / leads into
    for index, _ in lanes:
        if index in corridor or index in done:
            continue
        chain = [index]
        while True:  # walk back to the chain's first lane
            back = [j for j in predecessors(chain[0]) if j not in corridor]
            if len(back) > 1:
                _refuse(f"lanes {back} both lead into lane {chain[0]}")
            if not back or back[0] in chain:
                break
            chain.insert(0, back[0])
        while True:  # and on to its last
            fwd = [j for j in successors(chain[-1]) if j not in corridor]
            if len(fwd) > 1:
                _refuse(f"lane {chain[-1]} forks into {fwd}")
            if not fwd or fwd[0] in chain:
                break
            chain.append(fwd[0])
        done.update(chain)
        into = [j for j in successors(chain[-1]) if j in corridor]
        out_of = [j for j in predecessors(chain[0]) if j in corridor]
        if into and out_of:
            _refuse(f"lanes {chain} leave the straight lanes and join them again")
        if not into and not out_of:
            _refuse(f"lanes {chain} are not chained to the straight lanes along x")
        if len(into) > 1 or len(out_of) > 1:
            _refuse(f"lanes {chain} join more than one straight lane")
        joint = (into or out_of)[0]
        k = slot[joint]
        if into:  # an on-ramp: its chain ends where the slot's lane begins
            continued_before.add(joint)
            s = float(starts[joint][0])
            coords = []
            for j in reversed(chain):
                s -= float(_lane(lanes, j).length)
                coords.insert(0, s)
        else:  # an exit: its chain begins where the slot's lane ends
            continued_after.add(joint)
            s, coords = float(ends[joint][0]), []
            for j in chain:
                coords.append(s)
                s += float(_lane(lanes, j).length)
        for n, (j, s0) in enumerate(zip(chain, coords)):
            lane = _lane(lanes, j)
            first, last = n == 0, n == len(chain) - 1
            branches.append(_strip(lane, w, k, s0, open_before=first and not out_of and j[0] in sources,
                                   open_after=last and not into and j[1] in sinks))
            table[j] = (k, len(branches) - 1)
    # the corridor's spans per slot, open at the road's own ends; dead ends where a slot stops
    spans, dead = [], []
    for k in range(n_lanes):
        pieces = sorted((float(lane.start[0]), float(lane.end[0]), index) for index, lane in corridor.items()
                        if slot[index] == k)
        merged = []
        for lo, hi, index in pieces:
            if merged and lo <= merged[-1][1] + JOIN:
                if lo < merged[-1][1] - JOIN:
                    _refuse(f"straight lanes overlap on slot {k} around x = {lo:g}")
                merged[-1] = [merged[-1][0], max(hi, merged[-1][1]), merged[-1][2], index]
            else:
                merged.append([lo, hi, index, index])
        out = []
        for lo, hi, first, last in merged:
            if first[0] in sources and first not in continued_before:
                lo = -math.inf
            if last[1] in sinks and last not in continued_after:
                hi = math.inf
            elif last not in continued_after:
                dead.append((k, hi))
            out.append((lo, hi))
        spans.append(tuple(out))
    if set(table) != {index for index, _ in lanes}:
        _refuse("some lanes could not be placed")
    return RoadMap(float(w), n_lanes, y0, tuple(spans), tuple(branches),
                   tuple((index, k, b) for index, (k, b) in sorted(table.items())), tuple(dead))


def _lane(lanes, index):
    return next(lane for j, lane in lanes if j == index)


def _strip(lane, w: float, slot: int, s0: float, open_before: bool, open_after: bool) -> Strip:
    if isinstance(lane, CircularLane):
        return Strip("arc", (float(lane.center[0]), float(lane.center[1])), (0.0, 0.0), w, float(lane.length), slot,
                     s0, radius=float(lane.radius), start_phase=float(lane.start_phase), direction=int(lane.direction),
                     open_before=open_before, open_after=open_after)
    start, end = (float(lane.start[0]), float(lane.start[1])), (float(lane.end[0]), float(lane.end[1]))
    if isinstance(lane, SineLane):
        return Strip("sine", start, end, w, float(lane.length), slot, s0, amplitude=float(lane.amplitude),
                     pulsation=float(lane.pulsation), phase=float(lane.phase), open_before=open_before,
                     open_after=open_after)
    return Strip("straight", start, end, w, float(lane.length), slot, s0, open_before=open_before, open_after=open_after)


def road_scene(base, road, ego_lanes=frozenset(), ego=None, guarded=frozenset(), announced=None,
               reverse_reach: float = REVERSE_REACH) -> Scene:
    """The road as ITHA agents: the ego (in ITHA ``ego_lanes``) and every car but the overtake lead.

    A car changing lanes (``lane_index != target_lane_index``) occupies both. ``ego`` is the guarded car
    whose scene this is (default: the env's ego); ``guarded`` are the ids of every guarded car (they
    announce, ``Car.announces``). On a ``RoadMap``, and with several guarded cars, every car also occupies
    the lanes its body overlaps (widened as the guardian widens its own: a slow car turning out of a lane
    reaches back into it); with one guarded car on the straight road the scene is what it always was;
    ``announced`` maps a guarded car's id to the ITHA lanes it announced it enters this step. On a
    ``RoadMap`` fronts are along the lanes' chains, obstacles are standing cars and each dead end is a
    standing car of length 0 (``guardian.roads``).

    A car driving backwards (outside the traffic model) is taken longer at its rear by how far it may still
    back up (``reverse_reach``, ``GuardianConfig``; more behind a car that reverses too: ``reverse_reaches``)
    and in the lanes beside its own too (its steering swings a reversing body).
    """
    ego = base.vehicle if ego is None else ego
    announced = announced or {}
    if isinstance(road, RoadMap):
        return _map_scene(base, road, ego, ego_lanes, guarded, announced, reverse_reach)
    lead = getattr(base, "lead", None)
    others, own = [], []
    for k, veh in enumerate(base.road.vehicles):
        if veh is ego or veh is lead:
            continue
        lane = veh.lane_index[2]
        target = veh.target_lane_index[2] if _is_controlled(type(veh)) else lane
        lanes = _itha_lanes(road.n_lanes, lane, target)
        if guarded:
            lanes = lanes | frozenset(road.n_lanes - j for j in _straight_body_lanes(veh, road))
            lanes = lanes | announced.get(id(veh), frozenset())
        if veh.speed < 0:
            lanes = lanes | frozenset(j + s for j in lanes for s in (-1, 1) if 1 <= j + s <= road.n_lanes)
        others.append(Car(float(veh.position[0]) + veh.LENGTH / 2, float(veh.speed), lanes, veh.LENGTH, f"car {k}",
                          id(veh) in guarded, bool(veh.crashed)))
        own.append(road.n_lanes - lane)
    others = _lengthen_reversing(others, own, reverse_reach)
    me = Car(float(ego.position[0]) + ego.LENGTH / 2, float(ego.speed), frozenset(ego_lanes), ego.LENGTH, "ego",
             id(ego) in guarded)
    return Scene(me, tuple(others), road.n_lanes)


def _straight_body_lanes(veh, road: Road) -> frozenset:
    """Lane ids a body overlaps on the straight road (widened as the guardian widens its own)."""
    from guardian.ego import BicycleEgo, _lanes_overlapped

    h = float(veh.heading)
    r = veh.LENGTH / 2 * abs(math.sin(h)) + veh.WIDTH / 2 * abs(math.cos(h)) + BicycleEgo.LATERAL_MARGIN
    y = float(veh.position[1])
    return _lanes_overlapped(y - r, y + r, road.n_lanes, road.lane_width)


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


def _map_scene(base, road: RoadMap, ego, ego_lanes, guarded, announced, reverse_reach: float) -> Scene:
    from guardian.ego import BicycleEgo

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
            lanes = frozenset(road.itha_lane(j) for j in slots)
        lanes = lanes | announced.get(id(veh), frozenset())
        others.append(Car(front, float(veh.speed), lanes, veh.LENGTH, f"car {k}", id(veh) in guarded,
                          bool(veh.crashed), blind=blind))
        own.append(road.itha_lane(road.slot_of(veh.lane_index)))
    others = _lengthen_reversing(others, own, reverse_reach)
    for k, obj in enumerate(base.road.objects):
        if not (getattr(obj, "solid", True) and getattr(obj, "collidable", True)):
            continue
        x, y = float(obj.position[0]), float(obj.position[1])
        slots = road.body_slots(x, y, float(obj.heading), obj.LENGTH, obj.WIDTH, BicycleEgo.LATERAL_MARGIN)
        if slots:
            index = road.memo(("object lane", x, y, float(obj.heading)),
                              lambda: base.road.network.get_closest_lane_index(obj.position, obj.heading))
            others.append(Car(road.longitudinal(index, x, y) + obj.LENGTH / 2, 0.0,
                              frozenset(road.itha_lane(j) for j in slots), obj.LENGTH, f"obstacle {k}", fixed=True))
    others.extend(road.end_cars())
    me = Car(ego_front, float(ego.speed), frozenset(ego_lanes), ego.LENGTH, "ego", id(ego) in guarded)
    return Scene(me, tuple(others), road.n_lanes)


def reverse_reaches(fronts, speeds, lanes, reach: float) -> list:
    """How far each car may still back up: 0 for a car that does not drive backwards; ``reach`` for one that
    does, plus the reach of the car it follows in its own lane (``lanes[i]``, ``fronts`` along it) when that
    car drives backwards too: a queue that reverses backs up link by link (an IDM car reverses to open its
    gap to the car ahead, and that car is moving back)."""
    out = [0.0] * len(fronts)
    order = sorted(range(len(fronts)), key=lambda i: -fronts[i])
    ahead = {}   # lane -> the index of the last car seen (the nearest ahead of the next one)
    for i in order:
        j = ahead.get(lanes[i])
        if speeds[i] < 0:
            out[i] = reach + (out[j] if j is not None and speeds[j] < 0 else 0.0)
        ahead[lanes[i]] = i
    return out


def _lengthen_reversing(cars: list, own: list, reach: float) -> list:
    if not any(c.speed < 0 for c in cars):
        return cars
    extra = reverse_reaches([c.front for c in cars], [c.speed for c in cars], own, reach)
    return [replace(c, length=c.length + e) if e else c for c, e in zip(cars, extra)]


def _vehicle_reading(road: RoadMap, veh) -> tuple:
    """A traffic car on the map: its front along its lane's chain, the slots its body (widened as the
    guardian widens its own) overlaps with its lane and target lane, and those slots' ITHA lanes; a function
    of the car's pose and lanes, remembered by the map (every guarded car's scene reads every car)."""
    from guardian.ego import BicycleEgo

    x, y, heading = float(veh.position[0]), float(veh.position[1]), float(veh.heading)
    target = veh.target_lane_index if _is_controlled(type(veh)) else None

    def read():
        slots = set(road.body_slots(x, y, heading, veh.LENGTH, veh.WIDTH, BicycleEgo.LATERAL_MARGIN))
        slots.add(road.slot_of(veh.lane_index))
        if target is not None:
            slots.add(road.slot_of(target))
        front = road.longitudinal(veh.lane_index, x, y) + veh.LENGTH / 2
        return front, frozenset(slots), frozenset(road.itha_lane(j) for j in slots)

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
def _itha_lanes(n_lanes: int, lane: int, target: int) -> frozenset:
    return frozenset({n_lanes - lane, n_lanes - target})
