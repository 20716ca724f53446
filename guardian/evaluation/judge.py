"""Who caused a collision: an independent judge from geometry alone.

The judge knows nothing of the guardian: it watches the vehicles' bodies after every policy step and,
when the ego crashes, applies three rules in order (the first that decides wins) to the bodies *at
contact*: a vehicle whose crash began during a policy step is taken as it was at the end of the
simulation step in which it began (the judge hooks the road's ``step``), not where the crash pushed or
slid it by the end of the policy step (at 1 Hz, up to a second later). Roads without a ``step`` (and
simulators whose crash is flagged after it) are judged on the bodies after the policy step.

1. **Lane entry.** A car whose body began to overlap a lane of the other car within
   ``ENTRY_WINDOW`` seconds before the contact entered in front of (or beside) it: the entrant is at
   fault. If both entered such a lane in that window, the ego is at fault.
2. **Side contact.** The bodies overlapped along the road before the step (they were side by side):
   whoever moved sideways towards the other from the last observation to contact (faster than
   ``SIDEWAYS`` m/s) is at fault; both, the ego.
3. **Rear-end.** The car behind is at fault, unless the car ahead was reversing (negative speed):
   then the car ahead is.

A crash with no other crashed vehicle (an obstacle, the road's edge) is the ego's. When in doubt the
rules count against the ego (ties go to the ego).

The partner is the vehicle whose crash began in the same step and which is nearest to the ego; when
there is none, the nearest vehicle that had crashed before and whose body overlapped the ego's when the
ego's crash began, or was about to by highway-env's own test (a wreck that backs or slides into the ego,
or that the ego drives into).
Lanes are the road's straight lanes (``guardian.model.roads.Road``); a body overlaps a lane when its
lateral extent (heading included) enters the lane's strip.

**Other roads** (``FaultJudge.for_env``): lanes are highway-env's own lane objects, grouped into
*lines*: a lane whose end is another lane's start continues it (an on-ramp's approach, its sine part and
its parallel part are one line; an exit lane and the curve after it are one; a main lane is one line
across its segments). A body overlaps a lane when, in the lane's own coordinates (highway-env's
``local_coordinates`` and ``heading_at``), its lateral extent meets the lane's strip and its longitudinal
extent meets the lane's length; it overlaps the line of every lane it overlaps. "Sideways" and "along"
are measured against the heading of the lane each body is on. Nothing of the guardian's road reading
(``guardian.model.roads``) is used.

**Many guarded cars** (``start(base, guarded=[...])``, ``observe_all``): every guarded car's crash is
judged with that car in the ego's place; a crash between two guarded cars is judged once (the car first
in highway-env's controlled order takes the ego's place) and says which guarded car the partner is.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

ENTRY_WINDOW = 3.0   # [s]
SIDEWAYS = 0.25      # [m/s] lateral speed below this is lane keeping (the overtake ego's noise moves it
                     # by up to 0.18 m/s), not moving sideways


@dataclass
class Crash:
    step: int
    fault: str                  # "ego" | "other" (the guarded car judged, or its partner)
    rule: str                   # "entry" | "side" | "rear_end" | "alone"
    partner: str | None = None
    detail: dict = field(default_factory=dict)
    car: int = 0                # the guarded car judged (its place in highway-env's controlled order)
    partner_car: int | None = None   # the partner's place when it is a guarded car too

    @property
    def guarded_at_fault(self) -> bool:
        """Was a guarded car at fault (the one judged, or a guarded partner)?"""
        return self.fault == "ego" or self.partner_car is not None


def body_lanes(vehicle, lane_width: float, n_lanes: int) -> frozenset:
    """highway-env lane ids (0 at ``y = 0``) the vehicle's body overlaps."""
    h = float(vehicle.heading)
    r = vehicle.LENGTH / 2 * abs(math.sin(h)) + vehicle.WIDTH / 2 * abs(math.cos(h))
    y = float(vehicle.position[1])
    return frozenset(k for k in range(n_lanes) if y - r < (k + 0.5) * lane_width and y + r > (k - 0.5) * lane_width)


class Lines:
    """highway-env's lanes grouped into lines (a lane continues the lane whose end is its start), and which
    lines a body overlaps, from highway-env's own lane geometry."""

    JOIN = 1e-6   # [m]

    def __init__(self, network):
        self.lanes = [((f, t, i), lane) for f, tos in network.graph.items() for t, group in tos.items()
                      for i, lane in enumerate(group)]
        parent = {index: index for index, _ in self.lanes}

        def root(a):
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            return a

        ends = {index: lane.position(lane.length, 0.0) for index, lane in self.lanes}
        for a, _ in self.lanes:
            for b, lane in self.lanes:
                if a != b and math.dist(ends[a], lane.position(0.0, 0.0)) < self.JOIN:
                    parent[root(b)] = root(a)
        roots = sorted({root(index) for index, _ in self.lanes})
        self.line = {index: roots.index(root(index)) for index, _ in self.lanes}   # lane index -> line number

    def of(self, vehicle) -> frozenset:
        """Lines whose lanes the vehicle's body overlaps."""
        out = set()
        pos, h = vehicle.position, float(vehicle.heading)
        for index, lane in self.lanes:
            if self.line[index] in out:
                continue
            s, r = lane.local_coordinates(pos)
            rel = h - float(lane.heading_at(s))
            across = vehicle.LENGTH / 2 * abs(math.sin(rel)) + vehicle.WIDTH / 2 * abs(math.cos(rel))
            along = vehicle.LENGTH / 2 * abs(math.cos(rel)) + vehicle.WIDTH / 2 * abs(math.sin(rel))
            if abs(r) < float(lane.width_at(s)) / 2 + across and -along < s < lane.length + along:
                out.add(self.line[index])
        return frozenset(out)

    def heading(self, vehicle) -> float:
        """The heading of the lane the vehicle is on (highway-env's ``lane_index``)."""
        lane = next(lane for index, lane in self.lanes if index == tuple(vehicle.lane_index))
        s, _ = lane.local_coordinates(vehicle.position)
        return float(lane.heading_at(s))


def _touch(a, b, dt: float) -> bool:
    """Do the bodies of ``a`` and ``b`` overlap, now or over one more simulation step of ``dt`` at their
    velocities? (highway-env's own test for a crash: a body about to overlap is pushed back and flagged.)"""
    from highway_env import utils

    reach = (abs(float(a.speed)) + abs(float(b.speed))) * dt
    if math.dist(a.position, b.position) > (a.diagonal + b.diagonal) / 2 + reach:
        return False
    now, soon, _ = utils.are_polygons_intersecting(a.polygon(), b.polygon(), a.velocity * dt, b.velocity * dt)
    return bool(now or soon)


class FaultJudge:
    """Watches one episode; ``observe`` after every step returns the ego's new ``Crash`` or None
    (``observe_all``: every guarded car's).

    Parameters
    ----------
    lane_width : float
        [m] of the road's lanes (lane 0 centred on ``y = 0``).
    n_lanes : int
    dt : float
        [s] per observed step (the policy period).
    lines : Lines, optional
        A road beyond one straight segment (``for_env``): lanes and directions from highway-env's lanes.
    """

    def __init__(self, lane_width: float, n_lanes: int, dt: float, lines: Lines | None = None):
        self.lane_width, self.n_lanes, self.dt = lane_width, n_lanes, dt
        self.lines = lines

    @classmethod
    def for_env(cls, base, dt: float) -> "FaultJudge":
        """The judge of ``base``'s road: straight lanes along x from y when the road is one straight segment
        of equal lanes with lane 0 at ``y = 0``, else highway-env's lanes grouped into lines."""
        network = base.road.network
        lanes = [lane for tos in network.graph.values() for group in tos.values() for lane in group]
        straight = len(network.graph) == 1 and all(
            type(lane).__name__ == "StraightLane" and abs(float(lane.heading)) < 1e-9 for lane in lanes)
        ys = sorted(float(lane.start[1]) for lane in lanes) if straight else []
        if straight and abs(ys[0]) < 1e-9 and all(abs(b - a - lanes[0].width) < 1e-9 for a, b in zip(ys, ys[1:])):
            return cls(float(lanes[0].width), len(lanes), dt)
        return cls(float(lanes[0].width), len(lanes), dt, Lines(network))

    def start(self, base, guarded=None) -> None:
        """A new episode; ``guarded``: the vehicles judged (default: the env's ego)."""
        self.t = 0
        self.contact = {}          # id(vehicle) -> its body when its crash began (``_after_sim_step``)
        self.since_seen = 0.0      # [s] simulated since the last observation
        self._hook(base.road)
        self.guarded = list(guarded) if guarded is not None else [base.vehicle]
        self.entries = {}          # id(vehicle) -> {lane: time of the last entry}
        self.lanes = {}
        self.pos = {}
        self.crashed = set()
        self.ego_entries = []      # (time, lane) of every lane the ego's body began to overlap
        self.car_entries = [[] for _ in self.guarded]   # the same, per guarded car
        self._see(base, first=True)

    def _hook(self, road) -> None:
        """Have ``road.step`` report every simulation step to the judge of the current episode."""
        road._fault_judge = self
        step = getattr(road, "step", None)
        if step is None or getattr(step, "reports_to_judge", False):
            return

        def step_and_report(dt, *args, **kwargs):
            out = step(dt, *args, **kwargs)
            road._fault_judge._after_sim_step(road, dt)
            return out

        step_and_report.reports_to_judge = True
        road.step = step_and_report

    def _after_sim_step(self, road, dt: float) -> None:
        self.since_seen += dt
        for v in road.vehicles:
            if v.crashed and id(v) not in self.crashed and id(v) not in self.contact:
                wrecks = [o for o in road.vehicles if o is not v and id(o) in self.crashed and _touch(v, o, dt)]
                self.contact[id(v)] = {"lanes": self.body_lanes_of(v), "speed": float(v.speed),
                                       "position": (float(v.position[0]), float(v.position[1])),
                                       "seconds": self.since_seen, "wrecks": wrecks}

    def _at_contact(self, v) -> dict | None:
        """``v``'s body when its crash began, if that was in the step being observed."""
        return self.contact.get(id(v)) if id(v) not in self.crashed else None

    def body_lanes_of(self, vehicle) -> frozenset:
        """The lanes (straight road) or lines (other roads) the vehicle's body overlaps."""
        if self.lines is not None:
            return self.lines.of(vehicle)
        return body_lanes(vehicle, self.lane_width, self.n_lanes)

    def _see(self, base, first: bool = False) -> None:
        self.prev = dict(self.pos)
        cars = {id(v): i for i, v in enumerate(self.guarded)}
        for v in base.road.vehicles:
            k = id(v)
            contact = self._at_contact(v)
            lanes = contact["lanes"] if contact else self.body_lanes_of(v)
            if not first:
                for lane in lanes - self.lanes.get(k, lanes):
                    self.entries.setdefault(k, {})[lane] = self.t
                    if v is base.vehicle:
                        self.ego_entries.append((self.t, lane))
                    if k in cars:
                        self.car_entries[cars[k]].append((self.t, lane))
            self.lanes[k] = lanes
            self.pos[k] = contact["position"] if contact else (float(v.position[0]), float(v.position[1]))

    def observe(self, base) -> Crash | None:
        """Call after every step; the ego's crash if it began in this step."""
        crashes = self.observe_all(base)
        return next((c for c in crashes if self.guarded[c.car] is base.vehicle), None)

    def observe_all(self, base) -> list:
        """Call after every step; every guarded car's crash that began in this step."""
        self.t += 1
        self._see(base)
        newly = [v for v in base.road.vehicles if v.crashed and id(v) not in self.crashed]
        contact = {id(v): self._at_contact(v) for v in newly}
        # [s] from the last observation to each contact (the policy period when it is not known)
        span = {k: c["seconds"] if c and c["seconds"] > 0 else self.dt for k, c in contact.items()}
        speed = {id(v): contact[id(v)]["speed"] if contact[id(v)] else float(v.speed) for v in newly}
        self.crashed |= {id(v) for v in newly}
        self.since_seen = 0.0
        judged, out = set(), []
        for i, car in enumerate(self.guarded):
            if not any(v is car for v in newly) or id(car) in judged:
                continue
            partners = [v for v in newly if v is not car] or (contact[id(car)] or {}).get("wrecks", [])
            if not partners:
                out.append(Crash(self.t, "ego", "alone", car=i))
                continue
            for v in partners:
                speed.setdefault(id(v), float(v.speed))
            other = min(partners, key=lambda o: math.dist(self.pos[id(o)], self.pos[id(car)]))
            crash = self._fault(car, other, base, span[id(car)], speed)
            crash.car = i
            j = next((j for j, g in enumerate(self.guarded) if g is other), None)
            if j is not None:
                crash.partner_car = j
                judged.add(id(other))
            out.append(crash)
        return out

    def _entered_lane_of(self, a, b) -> bool:
        """Did ``a``'s body begin to overlap one of ``b``'s lanes within the window?"""
        window = ENTRY_WINDOW / self.dt
        lanes_b = self.lanes[id(b)]
        return any(lane in lanes_b and self.t - t <= window for lane, t in self.entries.get(id(a), {}).items())

    def _fault(self, ego, other, base, span: float, speed: dict) -> Crash:
        name = f"car {base.road.vehicles.index(other)}"
        ego_in, other_in = self._entered_lane_of(ego, other), self._entered_lane_of(other, ego)
        if ego_in or other_in:
            return Crash(self.t, "ego" if ego_in else "other", "entry", name,
                         {"ego_entered": ego_in, "other_entered": other_in})
        if self.lines is not None:
            return self._fault_along_lanes(ego, other, name, span, speed)
        dx = float(other.position[0] - ego.position[0])
        (ex0, ey0), (ox0, oy0) = self.prev.get(id(ego), self.pos[id(ego)]), self.prev.get(id(other), self.pos[id(other)])
        if abs(ox0 - ex0) < (ego.LENGTH + other.LENGTH) / 2:  # side by side before the step
            towards = math.copysign(1.0, oy0 - ey0)
            fast = SIDEWAYS * span
            ego_moved = (self.pos[id(ego)][1] - ey0) * towards > fast
            other_moved = (self.pos[id(other)][1] - oy0) * -towards > fast
            if ego_moved or other_moved:
                return Crash(self.t, "ego" if ego_moved else "other", "side", name,
                             {"ego_moved": ego_moved, "other_moved": other_moved})
        behind, ahead = (ego, other) if dx > 0 else (other, ego)
        at_fault = ahead if speed[id(ahead)] < 0 else behind
        return Crash(self.t, "ego" if at_fault is ego else "other", "rear_end", name, {"dx": dx})

    def _fault_along_lanes(self, ego, other, name: str, span: float, speed: dict) -> Crash:
        """The side and rear-end rules with "along" and "sideways" taken against the ego's lane heading."""
        h = self.lines.heading(ego)
        t, n = np.array([math.cos(h), math.sin(h)]), np.array([-math.sin(h), math.cos(h)])
        e0, o0 = np.array(self.prev.get(id(ego), self.pos[id(ego)])), np.array(self.prev.get(id(other), self.pos[id(other)]))
        e1, o1 = np.array(self.pos[id(ego)]), np.array(self.pos[id(other)])
        if abs(float((o0 - e0) @ t)) < (ego.LENGTH + other.LENGTH) / 2:  # side by side before the step
            towards = math.copysign(1.0, float((o0 - e0) @ n))
            fast = SIDEWAYS * span
            ego_moved = float((e1 - e0) @ n) * towards > fast
            other_moved = float((o1 - o0) @ n) * -towards > fast
            if ego_moved or other_moved:
                return Crash(self.t, "ego" if ego_moved else "other", "side", name,
                             {"ego_moved": ego_moved, "other_moved": other_moved})
        dx = float((o1 - e1) @ t)
        behind, ahead = (ego, other) if dx > 0 else (other, ego)
        at_fault = ahead if speed[id(ahead)] < 0 else behind
        return Crash(self.t, "ego" if at_fault is ego else "other", "rear_end", name, {"dx": dx})
