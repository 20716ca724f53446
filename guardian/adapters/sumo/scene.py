"""SUMO read as the scene model, and a guarded vehicle driven the way the guardian's model assumes.

The frame: SUMO's straight edge runs along ``+x`` from ``x = 0``; the road model's slot 0 is SUMO's leftmost lane
(index ``n - 1``), its centre at ``y = 0``, ``y`` growing to the right of travel (SUMO's ``-y``). SUMO's angle
(degrees, clockwise from north) is the heading ``radians(angle - 90)`` (positive: turning right). SUMO gives a
vehicle's front bumper; the model takes the body's centre.

Every car's lanes come from its body (``guardian.model.sensing.scene_of``): a car whose body is over the line is in
both lanes whatever SUMO's lane index says (the sublane model drifts cars inside and across lanes).

A guarded vehicle is not driven by SUMO: each step its state is moved by the kinematic bicycle the guardian's sets
assume (``BicycleModel``, highway-env's ``Vehicle.step``) under the applied input, and put there with
``moveToXY`` (SUMO's way for externally driven vehicles: CARLA's co-simulation does the same), so SUMO's traffic
and collision detection see it where the model says it is.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from guardian.model.roads import RoadMap, road_from_dict
from guardian.model.scene import Car, EgoState
from guardian.model.sensing import Sensed, Traffic

KEEP_ROUTE = 2  # map by position (placement exact), on the lane of the centre


class Frame:
    """SUMO's coordinates and lanes against the road model's.

    The corridor is a chain of straight edges along ``+x`` whose lanes are aligned on the left (a lane added on the
    right, as an acceleration lane is): the road model's slots, the main lanes everywhere and the added ones where
    their edge is (a slot whose edge ends before the road does is a dead end). An on-ramp edge (``ramp``) is a
    straight branch leading into the slot its lane joins (``guardian.model.roads``)."""

    def __init__(self, traci, corridor, ramp: str | None = None, exit: str | None = None):
        corridor = (corridor,) if isinstance(corridor, str) else tuple(corridor)
        shapes = {e: [traci.lane.getShape(f"{e}_{k}") for k in range(traci.edge.getLaneNumber(e))] for e in corridor}
        widths = {round(traci.lane.getWidth(f"{e}_{k}"), 6) for e in corridor for k in range(len(shapes[e]))}
        if len(widths) != 1:
            raise ValueError(f"the corridor {corridor} has lanes of different widths {sorted(widths)}")
        for e, lanes in shapes.items():
            (x0, y0), (x1, y1) = lanes[0][0], lanes[0][-1]
            if abs(y1 - y0) > 1e-6 or x1 <= x0:
                raise ValueError(f"edge {e!r} is not straight along +x: {lanes[0]}")
        lefts = {round(lanes[-1][0][1], 3) for lanes in shapes.values()}
        if len(lefts) != 1:
            raise ValueError(f"the corridor's edges {corridor} are not aligned on their left lanes: {sorted(lefts)}")
        self.lane_width, self.edges, self.edge = widths.pop(), corridor, corridor[0]
        self.x0, self.y_left = shapes[corridor[0]][0][0][0], shapes[corridor[0]][-1][0][1]   # slot 0's centre: y = 0
        self.lanes_of = {e: len(lanes) for e, lanes in shapes.items()}
        self.extent = {e: (lanes[0][0][0] - self.x0, lanes[0][-1][0] - self.x0) for e, lanes in shapes.items()}
        self.n_lanes = max(self.lanes_of.values())
        self.length = max(hi for _, hi in self.extent.values())
        self.road = self._road(traci, ramp, exit)

    def _road(self, traci, ramp, exit):
        main = min(self.lanes_of.values())
        if main == self.n_lanes and ramp is None and exit is None:
            return road_from_dict({"lanes": self.n_lanes, "lane_width": self.lane_width})
        spans, ends = [[[None, None]] for _ in range(main)], []
        for slot in range(main, self.n_lanes):
            pieces = sorted(self.extent[e] for e in self.edges if self.lanes_of[e] > slot)
            spans.append([list(piece) for piece in pieces])
            ends += [[slot, hi] for _, hi in pieces if hi < self.length - 1e-6]
        branches = [self._ramp(traci, ramp, spans)] if ramp is not None else []
        if exit is not None:
            branches.append(self._exit(traci, exit))
            ends = [e for e in ends if not (e[0] == branches[-1]["slot"] and abs(e[1] - branches[-1]["s0"]) < 1e-6)]
        spec = {"lanes": self.n_lanes, "lane_width": self.lane_width, "spans": spans, "ends": ends}
        if branches:
            spec["branches"] = branches
        return road_from_dict(spec)

    def _exit(self, traci, exit: str) -> dict:
        """The exit as a straight branch from the end of the lane that leads into it to the exit's end (open: the
        road goes on past it); no dead end there."""
        feeders = [lane for lane in traci.lane.getIDList() if not lane.startswith(":")
                   and any(link[0] == f"{exit}_0" for link in traci.lane.getLinks(lane))]
        edge, index = feeders[0].rsplit("_", 1)
        slot = self.lanes_of[edge] - 1 - int(index)
        start = (self.extent[edge][1], slot * self.lane_width)
        (xe, ye) = traci.lane.getShape(f"{exit}_0")[-1]
        end = (xe - self.x0, self.y_left - ye)
        return {"kind": "straight", "start": list(start), "end": list(end), "width": self.lane_width,
                "length": math.dist(start, end), "slot": slot, "s0": start[0], "open_after": True}

    def _ramp(self, traci, ramp: str, spans) -> dict:
        """The ramp as a straight branch from its start to where its lane's slot begins on the corridor."""
        (xs, ys) = traci.lane.getShape(f"{ramp}_0")[0]
        joins = [lane for lane, *_ in traci.lane.getLinks(f"{ramp}_0")]
        edge, index = joins[0].rsplit("_", 1)
        slot = self.lanes_of[edge] - 1 - int(index)
        start = (xs - self.x0, self.y_left - ys)
        end = (spans[slot][0][0], slot * self.lane_width)
        length = math.dist(start, end)
        return {"kind": "straight", "start": list(start), "end": list(end), "width": self.lane_width,
                "length": length, "slot": slot, "s0": end[0] - length, "open_before": True}

    def leaving(self, x: float, y: float, margin: float = 50.0) -> bool:
        """Is a body centred at ``(x, y)`` within ``margin`` of where SUMO's network ends: the corridor's end, or
        the end of an exit it took (the road model goes on past both)?"""
        if x > self.length - margin:
            return True
        strip = self.road.on_branch(x, y) if isinstance(self.road, RoadMap) else None
        if strip is None or not strip.open_after:
            return False
        s, _ = strip.local(x, y)
        return float(s) > strip.length - margin

    def on_corridor(self, slot: int, x: float) -> bool:
        """Is slot ``slot`` a corridor lane at ``x`` (not only a ramp's or an exit's branch)?"""
        return self.road.slot_at(slot, x) if isinstance(self.road, RoadMap) else 0 <= slot < self.n_lanes

    def centre_y(self, slot: int) -> float:
        """The centre line of lane ``slot`` in the model's frame."""
        return slot * self.lane_width

    def edge_at(self, x: float) -> str:
        """The corridor edge at ``x`` (the model's frame; the nearest one in a junction between two)."""
        return min(self.edges, key=lambda e: max(self.extent[e][0] - x, x - self.extent[e][1], 0.0))

    def lane_at(self, slot: int, x: float) -> tuple[str, int]:
        """SUMO's ``(edge, lane index)`` of slot ``slot`` at ``x``: on the nearest corridor edge that has it."""
        edges = [e for e in self.edges if self.lanes_of[e] > slot] or list(self.edges)
        edge = min(edges, key=lambda e: max(self.extent[e][0] - x, x - self.extent[e][1], 0.0))
        return edge, max(self.lanes_of[edge] - 1 - slot, 0)

    def slot(self, sumo_lane: int, edge: str | None = None) -> int:
        return self.lanes_of[edge or self.edge] - 1 - sumo_lane

    def sumo_lane(self, slot: int, edge: str | None = None) -> int:
        return self.lanes_of[edge or self.edge] - 1 - slot

    def slot_of(self, traci, vid: str) -> int | None:
        """The slot SUMO has vehicle ``vid`` on (on a junction or the ramp: the slot of its position); None when SUMO
        has it on no lane (moved off the road: no driver sees it). Only the lane's id is asked: libsumo crashes on
        ``getRoadID`` of a vehicle on no lane."""
        lane = traci.vehicle.getLaneID(vid)
        if not lane:
            return None
        edge, _, index = lane.rpartition("_")
        if edge in self.lanes_of:
            return self.slot(int(index), edge)
        xs, ys = traci.vehicle.getPosition(vid)
        return self.road.nearest_slot(xs - self.x0, self.y_left - ys)

    def body(self, traci, vid: str) -> Sensed:
        """Vehicle ``vid`` as read from SUMO, in the road model's frame (its own lane: its centre's; its front along
        its lane's chain: ``x + length / 2`` on the corridor, the branch's coordinate on the ramp)."""
        xs, ys = traci.vehicle.getPosition(vid)
        heading = math.radians(traci.vehicle.getAngle(vid) - 90.0)
        length = traci.vehicle.getLength(vid)
        fx, fy = xs - self.x0, self.y_left - ys          # the front bumper, in the model's frame
        x, y = fx - length / 2 * math.cos(heading), fy - length / 2 * math.sin(heading)
        speed = traci.vehicle.getSpeed(vid)
        return Sensed(vid, x, y, heading, speed, length, traci.vehicle.getWidth(vid), self.along(x, y) + length / 2,
                      self.road.nearest_slot(x, y), swings=speed < 0)

    def along(self, x: float, y: float) -> float:
        """The longitudinal coordinate of ``(x, y)`` along its lane's chain."""
        strip = self.road.on_branch(x, y) if isinstance(self.road, RoadMap) else None
        if strip is None:
            return x
        s, _ = strip.local(x, y)
        return float(strip.s0 + s)

    def to_sumo(self, x: float, y: float, heading: float, length: float) -> tuple[float, float, float]:
        """SUMO's front-bumper position and angle of a body centred at ``(x, y)`` with ``heading``."""
        fx, fy = x + length / 2 * math.cos(heading), y + length / 2 * math.sin(heading)
        return fx + self.x0, self.y_left - fy, 90.0 + math.degrees(heading)


def ego_state(b: Sensed) -> EgoState:
    return EgoState(b.front, b.y, b.heading, b.speed, b.own, b.own, b.x)


def traffic_of(frame: Frame, bodies: list, reversing, margin: float) -> Traffic:
    """Every vehicle's body read once this step (``Traffic``), for the scenes of all guarded vehicles among them; on a
    road with a dead end, the end as a standing car."""
    ends = frame.road.end_cars() if isinstance(frame.road, RoadMap) else ()
    return Traffic(frame.road, bodies, reversing, margin, ends)


def sensed_scene(traffic: Traffic, ego: Sensed, patched=()):
    """The scene of guarded vehicle ``ego`` (one of ``traffic``'s bodies) among the other bodies; ``patched``:
    other guarded vehicles' readings with what they announced."""
    return traffic.scene_for(_ego_car(ego), ego.name, patched)


def _ego_car(ego: Sensed) -> Car:
    return Car(ego.front, ego.speed, frozenset(), ego.length, "ego")


@dataclass
class BicycleModel:
    """The kinematic bicycle of the guardian's ego model: highway-env's ``Vehicle.step`` (the position moves at
    the speed and slip angle at the start of the step, then the heading, then the speed)."""

    length: float
    dt: float

    def step(self, x: float, y: float, heading: float, speed: float, a: float, steering: float):
        beta = math.atan(0.5 * math.tan(steering))
        x_next = x + self.dt * speed * math.cos(heading + beta)
        y_next = y + self.dt * speed * math.sin(heading + beta)
        heading_next = heading + self.dt * speed * math.sin(beta) / (self.length / 2)
        heading_next = (heading_next + math.pi) % (2 * math.pi) - math.pi
        return x_next, y_next, heading_next, speed + self.dt * a


def place(traci, frame: Frame, vid: str, x: float, y: float, heading: float, speed: float) -> int:
    """Put guarded vehicle ``vid`` at the model's next state (SUMO moves it in its next step) on the lane of its
    centre, where SUMO maps a vehicle moved by position; that lane's slot. The other lanes its body overlaps get
    shadows (``guardian.adapters.sumo.shadows``)."""
    slot = frame.road.nearest_slot(x, y)
    length = traci.vehicle.getLength(vid)
    xs, ys, angle = frame.to_sumo(x, y, heading, length)
    edge, lane = frame.lane_at(slot, x)
    traci.vehicle.moveToXY(vid, edge, lane, xs, ys, angle, keepRoute=KEEP_ROUTE)
    traci.vehicle.setSpeed(vid, max(speed, 0.0))
    return slot


def corners(b: Sensed) -> np.ndarray:
    c, s = math.cos(b.heading), math.sin(b.heading)
    half = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [b.length / 2, b.width / 2]
    return np.array([b.x, b.y]) + half @ np.array([[c, s], [-s, c]])


def overlap(a: Sensed, b: Sensed) -> bool:
    """Do the two bodies (rotated rectangles) overlap? Separating axes: the rectangles' four edge normals."""
    if math.dist((a.x, a.y), (b.x, b.y)) > (math.hypot(a.length, a.width) + math.hypot(b.length, b.width)) / 2:
        return False
    pa, pb = corners(a), corners(b)
    for h in (a.heading, b.heading):
        for axis in ((math.cos(h), math.sin(h)), (-math.sin(h), math.cos(h))):
            qa, qb = pa @ axis, pb @ axis
            if qa.max() <= qb.min() or qb.max() <= qa.min():
                return False
    return True
