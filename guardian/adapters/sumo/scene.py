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

from guardian.model.roads import road_from_dict
from guardian.model.scene import Car, EgoState
from guardian.model.sensing import Sensed, scene_of

KEEP_ROUTE = 2  # map by position (placement exact), on the lane of the centre


class Frame:
    """SUMO's coordinates and lane indices against the road model's (one straight edge)."""

    def __init__(self, traci, edge: str):
        n = traci.edge.getLaneNumber(edge)
        shapes = [traci.lane.getShape(f"{edge}_{k}") for k in range(n)]
        (x0, y0), (x1, y1) = shapes[0][0], shapes[0][-1]
        if abs(y1 - y0) > 1e-6 or x1 <= x0:
            raise ValueError(f"edge {edge!r} is not straight along +x: {shapes[0]}")
        widths = {round(traci.lane.getWidth(f"{edge}_{k}"), 6) for k in range(n)}
        if len(widths) != 1:
            raise ValueError(f"edge {edge!r} has lanes of different widths {sorted(widths)}")
        self.n_lanes, self.lane_width = n, widths.pop()
        self.x0, self.y_left = x0, shapes[n - 1][0][1]     # the leftmost lane's centre line: y = 0
        self.length = x1 - x0
        self.edge = edge
        self.road = road_from_dict({"lanes": n, "lane_width": self.lane_width})

    def centre_y(self, slot: int) -> float:
        """The centre line of lane ``slot`` in the model's frame."""
        return slot * self.lane_width

    def slot(self, sumo_lane: int) -> int:
        return self.n_lanes - 1 - sumo_lane

    def sumo_lane(self, slot: int) -> int:
        return self.n_lanes - 1 - slot

    def body(self, traci, vid: str) -> Sensed:
        """Vehicle ``vid`` as read from SUMO, in the road model's frame (its own lane: its centre's)."""
        xs, ys = traci.vehicle.getPosition(vid)
        heading = math.radians(traci.vehicle.getAngle(vid) - 90.0)
        length = traci.vehicle.getLength(vid)
        fx, fy = xs - self.x0, self.y_left - ys          # the front bumper, in the model's frame
        x, y = fx - length / 2 * math.cos(heading), fy - length / 2 * math.sin(heading)
        speed = traci.vehicle.getSpeed(vid)
        return Sensed(vid, x, y, heading, speed, length, traci.vehicle.getWidth(vid), x + length / 2,
                      self.road.nearest_slot(x, y), swings=speed < 0)

    def to_sumo(self, x: float, y: float, heading: float, length: float) -> tuple[float, float, float]:
        """SUMO's front-bumper position and angle of a body centred at ``(x, y)`` with ``heading``."""
        fx, fy = x + length / 2 * math.cos(heading), y + length / 2 * math.sin(heading)
        return fx + self.x0, self.y_left - fy, 90.0 + math.degrees(heading)


def ego_state(b: Sensed) -> EgoState:
    return EgoState(b.front, b.y, b.heading, b.speed, b.own, b.own, b.x)


def scene(frame: Frame, ego: Sensed, others: list, reverse_reach: float, margin: float):
    me = Car(ego.front, ego.speed, frozenset(), ego.length, "ego")
    return scene_of(frame.road, me, others, reverse_reach, margin)


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
    traci.vehicle.moveToXY(vid, frame.edge, frame.sumo_lane(slot), xs, ys, angle, keepRoute=KEEP_ROUTE)
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
