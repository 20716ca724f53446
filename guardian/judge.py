"""Who caused a collision: an independent judge from geometry alone.

The judge knows nothing of the guardian: it watches the vehicles' bodies after every policy step and,
when the ego crashes, applies three rules in order (the first that decides wins):

1. **Lane entry.** A car whose body began to overlap a lane of the other car within
   ``ENTRY_WINDOW`` seconds before the contact entered in front of (or beside) it: the entrant is at
   fault. If both entered such a lane in that window, the ego is at fault.
2. **Side contact.** The bodies overlapped along the road before the step (they were side by side):
   whoever moved sideways towards the other during the step (faster than ``SIDEWAYS`` m/s) is at
   fault; both, the ego.
3. **Rear-end.** The car behind is at fault, unless the car ahead was reversing (negative speed):
   then the car ahead is.

A crash with no other crashed vehicle (an obstacle, the road's edge) is the ego's. When in doubt the
rules count against the ego (ties go to the ego).

The partner is the vehicle whose crash began in the same step and which is nearest to the ego.
Lanes are the road's straight lanes (``guardian.sensing.Road``); a body overlaps a lane when its
lateral extent (heading included) enters the lane's strip.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

ENTRY_WINDOW = 3.0   # [s]
SIDEWAYS = 0.25      # [m/s] lateral speed below this is lane keeping (the overtake ego's noise moves it
                     # by up to 0.18 m/s), not moving sideways


@dataclass
class Crash:
    step: int
    fault: str                  # "ego" | "other"
    rule: str                   # "entry" | "side" | "rear_end" | "alone"
    partner: str | None = None
    detail: dict = field(default_factory=dict)


def body_lanes(vehicle, lane_width: float, n_lanes: int) -> frozenset:
    """highway-env lane ids (0 at ``y = 0``) the vehicle's body overlaps."""
    h = float(vehicle.heading)
    r = vehicle.LENGTH / 2 * abs(math.sin(h)) + vehicle.WIDTH / 2 * abs(math.cos(h))
    y = float(vehicle.position[1])
    return frozenset(k for k in range(n_lanes) if y - r < (k + 0.5) * lane_width and y + r > (k - 0.5) * lane_width)


class FaultJudge:
    """Watches one episode; ``observe`` after every step returns the ego's new ``Crash`` or None.

    Parameters
    ----------
    lane_width : float
        [m] of the road's lanes (lane 0 centred on ``y = 0``).
    n_lanes : int
    dt : float
        [s] per observed step (the policy period).
    """

    def __init__(self, lane_width: float, n_lanes: int, dt: float):
        self.lane_width, self.n_lanes, self.dt = lane_width, n_lanes, dt

    def start(self, base) -> None:
        self.t = 0
        self.entries = {}          # id(vehicle) -> {lane: time of the last entry}
        self.lanes = {}
        self.pos = {}
        self.crashed = set()
        self.ego_entries = []      # (time, lane) of every lane the ego's body began to overlap
        self._see(base, first=True)

    def _see(self, base, first: bool = False) -> None:
        self.prev = dict(self.pos)
        for v in base.road.vehicles:
            k = id(v)
            lanes = body_lanes(v, self.lane_width, self.n_lanes)
            if not first:
                for lane in lanes - self.lanes.get(k, lanes):
                    self.entries.setdefault(k, {})[lane] = self.t
                    if v is base.vehicle:
                        self.ego_entries.append((self.t, lane))
            self.lanes[k] = lanes
            self.pos[k] = (float(v.position[0]), float(v.position[1]))

    def observe(self, base) -> Crash | None:
        """Call after every step; the ego's crash if it began in this step."""
        self.t += 1
        self._see(base)
        ego = base.vehicle
        newly = [v for v in base.road.vehicles if v.crashed and id(v) not in self.crashed]
        self.crashed |= {id(v) for v in newly}
        if not any(v is ego for v in newly):
            return None
        partners = [v for v in newly if v is not ego]
        if not partners:
            return Crash(self.t, "ego", "alone")
        other = min(partners, key=lambda o: math.dist(o.position, ego.position))
        return self._fault(ego, other, base)

    def _entered_lane_of(self, a, b) -> bool:
        """Did ``a``'s body begin to overlap one of ``b``'s lanes within the window?"""
        window = ENTRY_WINDOW / self.dt
        lanes_b = self.lanes[id(b)]
        return any(lane in lanes_b and self.t - t <= window for lane, t in self.entries.get(id(a), {}).items())

    def _fault(self, ego, other, base) -> Crash:
        name = f"car {base.road.vehicles.index(other)}"
        ego_in, other_in = self._entered_lane_of(ego, other), self._entered_lane_of(other, ego)
        if ego_in or other_in:
            return Crash(self.t, "ego" if ego_in else "other", "entry", name,
                         {"ego_entered": ego_in, "other_entered": other_in})
        dx = float(other.position[0] - ego.position[0])
        (ex0, ey0), (ox0, oy0) = self.prev.get(id(ego), self.pos[id(ego)]), self.prev.get(id(other), self.pos[id(other)])
        if abs(ox0 - ex0) < (ego.LENGTH + other.LENGTH) / 2:  # side by side before the step
            towards = math.copysign(1.0, oy0 - ey0)
            fast = SIDEWAYS * self.dt
            ego_moved = (self.pos[id(ego)][1] - ey0) * towards > fast
            other_moved = (self.pos[id(other)][1] - oy0) * -towards > fast
            if ego_moved or other_moved:
                return Crash(self.t, "ego" if ego_moved else "other", "side", name,
                             {"ego_moved": ego_moved, "other_moved": other_moved})
        behind, ahead = (ego, other) if dx > 0 else (other, ego)
        at_fault = ahead if ahead.speed < 0 else behind
        return Crash(self.t, "ego" if at_fault is ego else "other", "rear_end", name, {"dx": dx})
