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
from guardian.model.scene import Car, Scene


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
    cars = [road.memo(("car", s, margin), lambda s=s: car_of(road, s, margin)) for s in moving]  # once per reading
    own = [road.numbering.itha(s.own) for s in moving]
    cars = reversing.lengthen(cars, own)
    cars += [car_of(road, s, margin) for s in sensed if s.fixed]
    return Scene(ego, tuple(cars) + tuple(fixed), road.n_lanes, tuple(sensed))
