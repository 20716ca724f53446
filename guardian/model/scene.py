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
import math
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


class LaneIndex:
    """The cars of a scene per lane, sorted by front once (equal fronts keep the cars' order), so that every lane
    query reads the few cars around a position instead of every car. Built over a scene's ``others``, or once over
    every car on the road and shared by the scenes of several guarded cars (``Traffic``): a query then passes the
    guarded car's own body (``skip``), which its scene does not hold. ``verdicts`` keeps what the traffic rules
    found of each car (``guardian.decide.traffic``) for every scene that shares the index."""

    REACH_SLACK = 1.0   # [m] added to the longest body where a query bounds the fronts it reads (rounding aside)

    def __init__(self, cars: tuple):
        self.cars = cars
        per_lane: dict = {}
        for i, c in enumerate(cars):
            if math.isnan(c.front) or not c.length >= 0:   # sorting and every bound read below need these
                raise ValueError(f"{c.name or 'a car'}: front {c.front!r}, length {c.length!r}: a position must be a "
                                 "number and a length a number >= 0")
            for lane in c.lanes:
                per_lane.setdefault(lane, []).append(i)
        self.lanes = {}
        for lane, order in per_lane.items():
            order.sort(key=lambda i: cars[i].front)
            self.lanes[lane] = ([cars[i].front for i in order], order,
                                max(cars[i].length for i in order) + self.REACH_SLACK)
        self.laneless = [i for i, c in enumerate(cars) if not c.lanes]
        self.longest = max((c.length for c in cars), default=0.0)
        speeds = [abs(c.speed) for c in cars]
        self.fastest = math.inf if any(math.isnan(v) for v in speeds) else max(speeds, default=0.0)   # NaN: read all
        self.any_across = any(c.across for c in cars)
        self.verdicts: dict = {}

    def position(self, car) -> int:
        """Where ``car`` is in ``cars``."""
        if "_position" not in self.__dict__:
            self._position = {id(c): i for i, c in enumerate(self.cars)}
        return self._position[id(car)]

    def flat_position(self, i: int, skip=None) -> int:
        """Where car ``i``'s first lane falls when every car but ``skip`` is listed once per lane it occupies, in
        the cars' order, after one entry for the ego (the lists ``guardian.decide.traffic`` hands to
        ``itha.responsibility``, whose reasons name cars by that position)."""
        if "_offsets" not in self.__dict__:
            offsets, total = [], 0
            for c in self.cars:
                offsets.append(total)
                total += len(c.lanes)
            self._offsets = offsets
        out = 1 + self._offsets[i]
        if skip is not None and self.position(skip) < i:
            out -= len(skip.lanes)
        return out

    def near(self, front: float, reach: float, skip=None) -> list:
        """The positions in ``cars``, in order, of every car (``skip`` aside) whose front is within ``reach`` of
        ``front``."""
        found = {i for i in self.laneless if abs(self.cars[i].front - front) <= reach}
        for fronts, order, _ in self.lanes.values():
            lo, hi = bisect.bisect_left(fronts, front - reach), bisect.bisect_right(fronts, front + reach)
            found.update(order[lo:hi])
        return sorted(i for i in found if self.cars[i] is not skip)

    def nearest(self, lane: int, front: float, skip=None):
        """The nearest car at or ahead of ``front`` and the nearest behind it (None where there is none); among
        equal fronts the first in the cars' order."""
        if lane not in self.lanes:
            return None, None
        fronts, order, _ = self.lanes[lane]
        cars, k = self.cars, bisect.bisect_left(fronts, front)
        ahead = next((cars[i] for i in order[k:] if cars[i] is not skip), None)
        behind = None
        for j in range(k - 1, -1, -1):
            if cars[order[j]] is not skip:
                first = bisect.bisect_left(fronts, fronts[j])   # the first in the cars' order among equal fronts
                behind = next(cars[i] for i in order[first:j + 1] if cars[i] is not skip)
                break
        return ahead, behind

    def ahead_overlapping(self, lane: int, start: int, lead, skip=None) -> list:
        """The cars' positions in ``cars`` of those in ``lane``, from sorted position ``start`` on, whose rear is
        nearer than ``lead``'s front (``lead`` and ``skip`` left out), nearest front first."""
        fronts, order, reach = self.lanes[lane]
        cars, out, bound = self.cars, [], lead.front + reach
        for j in range(start, len(order)):
            if fronts[j] >= bound:
                break
            c = cars[order[j]]
            if c is not lead and c is not skip and c.front - c.length < lead.front:
                out.append(order[j])
        return out

    def leaders(self, lane: int, front: float, skip=None) -> tuple:
        lead = self.nearest(lane, front, skip)[0]
        if lead is None:
            return ()
        start = bisect.bisect_left(self.lanes[lane][0], front)
        return (lead, *(self.cars[i] for i in sorted(self.ahead_overlapping(lane, start, lead, skip))))

    def followers(self, lane: int, front: float, skip=None) -> tuple:
        first = self.nearest(lane, front, skip)[1]
        if first is None:
            return ()
        fronts, order, _ = self.lanes[lane]
        cars, k = self.cars, bisect.bisect_left(fronts, front)
        top = []   # the two foremost rears behind, as (rear, position): the largest rear first, then the first
        for j in range(k - 1, -1, -1):
            if len(top) == 2 and fronts[j] < top[1][0]:
                break   # a rear is never ahead of its front: no car further back has a rear this far forward
            c = cars[order[j]]
            if c is not skip:
                top = sorted(top + [(c.front - c.length, order[j])], key=lambda r: (-r[0], r[1]))[:2]
        rest = []
        for j in range(k - 1, -1, -1):
            if len(top) == 2 and fronts[j] <= top[1][0]:
                break   # hidden behind one of the two foremost rears
            i = order[j]
            c = cars[i]
            if c is skip or c is first:
                continue
            other = [r for r in top if r[1] != i][:1]
            if not (other and other[0][0] >= c.front):
                rest.append(i)
        return (first, *(cars[i] for i in sorted(rest)))

    def leads_of(self, car, lane: int, skip=None) -> tuple:
        if lane not in self.lanes:
            return ()
        fronts, order, _ = self.lanes[lane]
        k = bisect.bisect_right(fronts, car.front)
        while k < len(order) and self.cars[order[k]] is skip:
            k += 1
        if k == len(order):
            return ()
        lead = self.cars[order[k]]
        return (lead, *(self.cars[i] for i in self.ahead_overlapping(lane, k + 1, lead, skip)))


@dataclass(frozen=True)
class Scene:
    """The road at one instant; each lane's nearest car ahead of and behind the ego, computed once.
    ``sensed``: the readings it was built from (``guardian.model.sensing.Sensed``), when a reader built it.
    ``index``: a ``LaneIndex`` shared with other guarded cars' scenes (over every car, this ego's own body
    ``own`` among them); without one the scene indexes its ``others`` when first asked."""

    ego: Car
    others: tuple
    n_lanes: int
    sensed: tuple = field(default=(), compare=False, repr=False)
    index: LaneIndex | None = field(default=None, compare=False, repr=False)
    own: Car | None = field(default=None, compare=False, repr=False)

    def with_ego_lanes(self, lanes) -> "Scene":
        """The same road with the ego occupying ``lanes`` (e.g. where it may be after a step)."""
        e = self.ego
        return Scene(Car(e.front, e.speed, frozenset(lanes), e.length, e.name, e.announces, e.crashed, e.fixed),
                     self.others, self.n_lanes, self.sensed, self.lane_index, self.own)

    @property
    def lane_index(self) -> LaneIndex:
        """The cars per lane (shared, or this scene's own, built once)."""
        if self.index is not None:
            return self.index
        if "_index" not in self.__dict__:
            self.__dict__["_index"] = LaneIndex(self.others)
        return self.__dict__["_index"]

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
            cache[lane] = self.lane_index.leaders(lane, self.ego.front, self.own)
        return cache[lane]

    def followers(self, lane: int) -> tuple:
        """The cars behind in ``lane`` (front behind the ego's) that no other car behind hides: the follower
        first, then every car whose front is beyond the rear of each other car behind (a car with another
        car's rear at or ahead of its front meets that car first)."""
        cache = self.__dict__.setdefault("_followers", {})
        if lane not in cache:
            cache[lane] = self.lane_index.followers(lane, self.ego.front, self.own)
        return cache[lane]

    def _neighbours(self, lane: int):
        cache = self.__dict__.setdefault("_lane_neighbours", {})
        if lane not in cache:
            cache[lane] = self.lane_index.nearest(lane, self.ego.front, self.own)
        return cache[lane]

    def leads_of(self, car: Car, lane: int) -> tuple:
        """The other cars in ``lane`` whose front is strictly ahead of ``car``'s and that no car among them
        hides from it (as ``leaders`` says for the ego): whom ``car`` follows there, the nearest first (the ego
        is never ahead of a car that matters to it)."""
        return self.lane_index.leads_of(car, lane, self.own)


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
