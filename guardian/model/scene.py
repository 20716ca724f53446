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

    def leaders(self, lane: int) -> tuple:
        """The cars ahead in ``lane`` (front at or ahead of the ego's) that no other car ahead hides: the
        leader first, then every car whose rear is nearer than the leader's front. A car whose rear lies at or
        beyond another car's front is behind that car along the road, and the ego meets that car first; where
        bodies overlap along the road (a car straddling into the lane beside one in it, a car standing with
        its front just past a lane's end, a wreck) the ego may meet either first."""
        cache = self.__dict__.setdefault("_leaders", {})
        if lane not in cache:
            lead = self.leader(lane)
            cache[lane] = () if lead is None else (lead, *(
                c for c in self.others if c is not lead and lane in c.lanes and c.front >= self.ego.front
                and c.front - c.length < lead.front))
        return cache[lane]

    def followers(self, lane: int) -> tuple:
        """The cars behind in ``lane`` (front behind the ego's) that no other car behind hides: the follower
        first, then every car whose front is beyond the rear of each other car behind (a car with another
        car's rear at or ahead of its front meets that car first)."""
        cache = self.__dict__.setdefault("_followers", {})
        if lane not in cache:
            behind = [c for c in self.others if lane in c.lanes and c.front < self.ego.front]
            first = self.follower(lane)
            foremost_rears = sorted(behind, key=lambda o: o.front - o.length, reverse=True)[:2]

            def hidden(c) -> bool:
                other = [o for o in foremost_rears if o is not c][:1]
                return bool(other) and other[0].front - other[0].length >= c.front

            cache[lane] = () if first is None else (first, *(c for c in behind if c is not first and not hidden(c)))
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

    def leads_of(self, car: Car, lane: int) -> tuple:
        """The other cars in ``lane`` whose front is strictly ahead of ``car``'s and that no car among them
        hides from it (as ``leaders`` says for the ego): whom ``car`` follows there, the nearest first (the ego
        is never ahead of a car that matters to it)."""
        order = self.__dict__.setdefault("_lane_orders", {})
        if lane not in order:
            cars = sorted((c for c in self.others if lane in c.lanes), key=lambda c: c.front)
            order[lane] = ([c.front for c in cars], cars)
        fronts, cars = order[lane]
        k = bisect.bisect_right(fronts, car.front)
        if k == len(cars):
            return ()
        lead = cars[k]
        return (lead, *(c for c in cars[k + 1:] if c.front - c.length < lead.front))


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
    acceleration: float = 0.0  # [m/s^2] applied over the last step (read where an actuator limits its change)
