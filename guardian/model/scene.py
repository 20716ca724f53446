"""The road at one instant as the guardian's decisions read it: the ego and the other cars as ITHA
agents (7.3).

Positions are front bumpers along the direction of travel (on roads beyond one straight segment: the
longitudinal coordinate along the car's lane, see ``guardian.model.roads``); lanes are ITHA numbers
(1 = rightmost); a car changing lanes occupies both. A car that ``announces`` takes part in the ordered
over-approximation (another guarded car: it announces its lane changes in Example 8's order, or yields);
every other car (highway-env's IDM traffic, an obstacle, a lane's end) announces nothing. Built from a
simulator by ``guardian.adapters.highway_env.scene`` and by hand in the tests: no simulator in here.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Car:
    front: float        # front-bumper position along the direction of travel [m]
    speed: float        # [m/s]
    lanes: frozenset    # ITHA lane numbers the car occupies (1 = rightmost)
    length: float       # [m]
    name: str = ""
    announces: bool = False   # takes part in the ordered over-approximation (a guarded car)
    crashed: bool = False     # has already collided (a wreck: it may stop faster than the model allows)
    fixed: bool = False       # never moves and is never pushed (an obstacle, a lane's end)
    blind: bool = False       # does not see the ego (highway-env's v0 search): neither brakes for it nor
                              # weighs it when changing lanes (guardian.adapters.highway_env.blindness.blind_to)
    across: tuple = ()        # (y_lo, y_hi) its body reaches across the road now, in the ego state's y; () unknown


@dataclass(frozen=True)
class Scene:
    """The road at one instant; each lane's nearest car ahead of and behind the ego, computed once.
    ``sensed``: the readings it was built from (``guardian.model.sensing.Sensed``), when a reader built it."""

    ego: Car
    others: tuple
    n_lanes: int
    sensed: tuple = field(default=(), compare=False, repr=False)

    def with_ego_lanes(self, lanes) -> "Scene":
        """The same road with the ego occupying ``lanes`` (e.g. where it may be after a step)."""
        e = self.ego
        return Scene(Car(e.front, e.speed, frozenset(lanes), e.length, e.name, e.announces, e.crashed, e.fixed),
                     self.others, self.n_lanes, self.sensed)

    def leader(self, lane: int):
        """The nearest car in ``lane`` whose front is at or ahead of the ego's (None if there is none)."""
        return self._neighbours(lane)[0]

    def follower(self, lane: int):
        """The nearest car in ``lane`` whose front is behind the ego's (None if there is none)."""
        return self._neighbours(lane)[1]

    def nearest_rear_ahead(self, lane: int):
        """Of the cars in ``lane`` whose front is at or ahead of the ego's, the one whose rear is nearest (None if
        there is none). It is the leader unless bodies ahead overlap along the road: a car standing with its front
        just past a lane's end (a standing car of length 0), a wreck, a long car straddling into the lane."""
        cache = self.__dict__.setdefault("_rear_ahead", {})
        if lane not in cache:
            ahead = [c for c in self.others if lane in c.lanes and c.front >= self.ego.front]
            cache[lane] = min(ahead, key=lambda c: (c.front - c.length, c.front)) if ahead else None
        return cache[lane]

    def _neighbours(self, lane: int):
        cache = self.__dict__.setdefault("_lane_neighbours", {})
        if lane not in cache:
            ahead = behind = None
            front = self.ego.front
            for c in self.others:  # the first of equals wins, as min/max over the list did
                if lane not in c.lanes:
                    continue
                if c.front >= front:
                    if ahead is None or c.front < ahead.front:
                        ahead = c
                elif behind is None or c.front > behind.front:
                    behind = c
            cache[lane] = (ahead, behind)
        return cache[lane]

    def ahead_of(self, car: Car, lane: int):
        """The nearest other car in ``lane`` whose front is strictly ahead of ``car``'s (None if none):
        whom ``car`` follows there (the ego is never ahead of a car that matters to it)."""
        order = self.__dict__.setdefault("_lane_orders", {})
        if lane not in order:
            cars = sorted((c for c in self.others if lane in c.lanes), key=lambda c: c.front)
            order[lane] = ([c.front for c in cars], cars)
        fronts, cars = order[lane]
        k = bisect.bisect_right(fronts, car.front)
        return cars[k] if k < len(cars) else None


@dataclass(frozen=True)
class EgoState:
    """The bicycle ego at one instant, in highway-env's coordinates (lane ids 0 = leftmost; on a
    ``guardian.model.roads.RoadMap`` lanes are slots and ``front`` is along the lane's chain)."""

    front: float            # front bumper along the road [m]
    y: float                # lateral position of the centre [m]
    heading: float          # [rad]
    speed: float            # [m/s]
    lane: int               # highway-env lane id of the lane it is closest to
    target_lane: int        # the lane its controller steers to (meta agents); ``lane`` otherwise
    x: float = 0.0          # world position of the centre [m] (read on a RoadMap only)
