"""The scene from what is sensed: bodies on the road, and what a simulator also knows of each car.

Every reader of a simulator or a client (``guardian.adapters.highway_env.scene``, the service's scene
sessions) turns each other car into a ``Sensed`` record and asks ``scene_of`` for the ``Scene``: one place
where bodies become lanes, so every reader gives the decisions the same scene from the same bodies.

A car occupies every lane its body overlaps (widened by ``margin``, as the guardian widens its own), the
lanes its reader says it is in or moving to (``lanes``: a lane index, a target lane), the lanes beside those
when it may swing sideways (``swings``: a car driving backwards, whose steering swings its body), the
lanes its reader adds beside it (``beside``), and, for another guarded car, the lanes it announced.
A car that may be driving backwards before the next look is taken longer at its rear by how far it may still back
up (``reversing``, a ``guardian.model.reversing.ReversingCover``).
"""
from __future__ import annotations

from dataclasses import dataclass

from guardian.model.body import half_extents
from guardian.model.scene import Car, LaneIndex, Scene


@dataclass(frozen=True)
class Sensed:
    """One other car as a reader reports it, in the road's coordinates (``x`` along the corridor, ``y``
    across it, as ``guardian.model.roads`` has them; lanes are slots, 0 the leftmost).

    ``front`` is its front bumper along the road (``x + length / 2`` on the corridor; along a branch's chain
    on a ``RoadMap``); ``own`` the slot of its own lane (cars queue on it when they reverse)."""

    name: str
    x: float
    y: float
    heading: float
    speed: float
    length: float
    width: float
    front: float
    own: int
    lanes: frozenset = frozenset()       # slots its reader says it is in or moving to
    beside: frozenset = frozenset()      # slots beside it its reader says it may move into
    swings: bool = False                 # it may swing into the lanes next to all of its own
    announced: frozenset = frozenset()   # ITHA lanes it announced (another guarded car)
    announces: bool = False
    crashed: bool = False
    blind: bool = False
    fixed: bool = False                  # never moves and is never pushed (an obstacle)

    def across(self) -> tuple:
        """Where its body reaches across the road now."""
        r = half_extents(self.length, self.width, self.heading)[1]
        return self.y - r, self.y + r


def car_of(road, s: Sensed, margin: float) -> Car:
    """``s`` as an ITHA agent of ``road``'s scene (its lanes from its body and what its reader knows)."""
    slots = road.body_slots(s.x, s.y, s.heading, s.length, s.width, margin) | s.lanes | s.beside
    numbering = road.numbering
    if s.swings:
        slots = slots | road.beside(slots | numbering.slot_set(s.announced), s.x)
    lanes = numbering.itha_set(slots) | s.announced
    return Car(s.front, s.speed, lanes, s.length, s.name, s.announces, s.crashed, s.fixed, s.blind, s.across())


def scene_of(road, ego: Car, sensed, reversing, margin: float, fixed=()) -> Scene:
    """The ``Scene`` of ``ego`` among ``sensed`` cars on ``road`` (``Road`` or ``RoadMap``); ``fixed`` are cars
    added as they are (a lane's end as a standing car of length 0)."""
    moving = [s for s in sensed if not s.fixed]
    cars = _cars_of(road, moving, margin)
    own = [road.numbering.itha(s.own) for s in moving]
    cars = reversing.lengthen(cars, own)
    cars += [car_of(road, s, margin) for s in sensed if s.fixed]
    return Scene(ego, tuple(cars) + tuple(fixed), road.n_lanes, tuple(sensed))


def _cars_of(road, readings, margin: float) -> list:
    """Each reading as a ``Car`` of ``road``, made once per reading (remembered on the road by its value)."""
    return [road.memo(("car", s, margin), lambda s=s: car_of(road, s, margin)) for s in readings]


class Traffic:
    """Every car on the road at one instant, read once for all the guarded cars among them: each guarded car's
    scene (``scene_for``) is this road without its own body, and every such scene shares one ``LaneIndex`` (the
    cars per lane sorted once, the traffic rules' verdicts kept once). The scenes are those ``scene_of`` builds
    from the same readings car by car; where they could differ (a car that may reverse is lengthened by the cars
    around it; another guarded car's announcement changes its lanes) ``scene_for`` builds that one by
    ``scene_of``."""

    def __init__(self, road, sensed, reversing, margin: float, fixed=()):
        self.road, self.reversing, self.margin, self.fixed = road, reversing, margin, tuple(fixed)
        self.sensed = tuple(sensed)
        moving, standing = [s for s in self.sensed if not s.fixed], [s for s in self.sensed if s.fixed]
        cars = _cars_of(road, moving, margin)
        self.shared = not any(reversing.may_reverse(c.speed) for c in cars)   # then lengthening changes no car
        cars += [car_of(road, s, margin) for s in standing]
        self.cars = tuple(cars) + self.fixed
        self.index = LaneIndex(self.cars)
        self._car_at = {s.name: k for k, s in enumerate(moving + standing)}
        self._sensed_at = {s.name: k for k, s in enumerate(self.sensed)}
        if len(self._sensed_at) != len(self.sensed):
            raise ValueError("Traffic: two readings share a name; a guarded car is found by its name")
        self._patches: dict = {}

    def scene_for(self, ego: Car, name: str, patched=()) -> Scene:
        """The scene of the guarded car ``name`` (its reading is one of ``sensed``) as the ITHA agent ``ego``;
        ``patched``: readings that replace those of the same names for this car (other guarded cars'
        announcements)."""
        k = self._sensed_at.get(name)
        if k is None:
            raise ValueError(f"Traffic: no reading named {name!r}")
        sensed = self.sensed[:k] + self.sensed[k + 1:]
        changed = [s for s in patched if s.name != name]
        if changed:
            out = list(sensed)
            for s in changed:
                j = self._sensed_at[s.name]
                out[j - (j > k)] = s
            sensed = tuple(out)
        if not self.shared or any(self._differs(s) for s in changed):
            return scene_of(self.road, ego, sensed, self.reversing, self.margin, self.fixed)
        i = self._car_at[name]
        return Scene(ego, self.cars[:i] + self.cars[i + 1:], self.road.n_lanes, sensed, self.index, self.cars[i])

    def _differs(self, s: Sensed) -> bool:
        """Does reading ``s`` make another car than the one the index holds under its name (by value)?"""
        known = self._patches.get(s)
        if known is None:
            base = self.cars[self._car_at[s.name]]
            known = self._patches[s] = car_of(self.road, s, self.margin) != base
        return known
