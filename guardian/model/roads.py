"""Roads beyond one straight segment, as plain geometry: on-ramps, exits, lanes that begin and end.

``guardian.adapters.highway_env.road.read_road`` reads highway-env's road network into a ``RoadMap`` (or, for one straight
multi-lane road, the simpler ``guardian.model.roads.Road``); the decision objects and ``guardian.decide.kinematics.RoadMapEgo``
read only this module's plain values, never the simulator.

The road the guardian can reason about is a **corridor** with **branches**:

* the corridor: straight lanes along ``+x`` on ``n_lanes`` lateral **slots** (slot ``k``'s centre line at
  ``y0 + k * lane_width``, slot 0 the leftmost, as highway-env numbers lanes), each slot present on some
  x-intervals (``spans``): the main road's lanes everywhere, an exit lane on ``[400, 500]``, the parallel
  part of an on-ramp on ``[230, 310]``. A span that ends where the road goes on in other slots is a
  **dead end** (an on-ramp's end): a car in that slot has the end as an obstacle (a standing "car" of
  length 0 at the end, ``ends``). A span that ends or begins at the road's own ends is open (the road goes
  on: highway-env's cars drive on past the last node);
* branches: lanes off the corridor (straight, sine or circular), each chained end to start with one
  corridor lane of one slot: an on-ramp's approach leading into its slot, an exit's curve leaving its
  slot. A branch belongs to its slot's ITHA lane: there is no lane beside it, and a car on it is in that
  lane for the ITHA agents (7.3).

ITHA lanes are slots: ITHA lane ``n_lanes - k`` (1 = rightmost) for slot ``k``, as on the straight road.
The longitudinal coordinate of a car (its ``front`` in ``guardian.model.scene``) is ``x`` on the corridor and,
on a branch, the branch's coordinate along its chain, continuous with ``x`` where it joins the corridor
(on highway-env's on-ramps, whose lanes run along x, it is ``x`` itself; on an exit's curve it is the arc
length from the exit, so it differs from ``x`` by less than 1 % over the curve's first 40 m at a 150 m
radius). Fronts are comparable along a lane and across the corridor's slots.

A body is **on the road** when every point of its outline (corners and side midpoints) lies in some
lane's strip (``depth``); it **overlaps** slot ``k`` when its lateral extent (heading included, widened by
a margin and swept by its velocity) meets a strip of slot ``k`` present where the body is (``body_slots``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from guardian.model.body import half_extents, lanes_overlapped
from guardian.model.lanes import LaneNumbering
from guardian.model.scene import Car

SCALAR = (int, float)


def remembered(road, key: tuple, compute):
    """``compute()``, remembered under ``key`` for as long as ``road`` (a ``Road`` or ``RoadMap``: what is remembered
    must be a function of the road and of ``key`` alone, e.g. geometry read from the network the map was read from,
    or a sensed car as the road's lanes see it). At most 50,000 answers: then it starts again."""
    memo = road.__dict__.get("_memo")
    if memo is None or len(memo) > 50_000:
        memo = {}
        object.__setattr__(road, "_memo", memo)
    out = memo.get(key)
    if out is None:
        out = memo[key] = compute()
    return out


@dataclass(frozen=True)
class Road:
    """A straight multi-lane road along x: ``n_lanes`` lanes of ``lane_width``, lane 0 at ``y = 0``."""

    n_lanes: int
    lane_width: float

    @property
    def numbering(self) -> LaneNumbering:
        """Lane ids (0 = leftmost) and ITHA lanes (1 = rightmost)."""
        return LaneNumbering(self.n_lanes)

    def body_slots(self, x, y, heading, length: float, width: float, margin: float = 0.0) -> frozenset:
        """Lanes a body at ``(x, y, heading)`` overlaps, widened by ``margin``."""
        r = half_extents(length, width, float(heading))[1] + margin
        return lanes_overlapped(float(y) - r, float(y) + r, self.n_lanes, self.lane_width)

    def beside(self, slots, x: float) -> frozenset:
        """The lanes next to ``slots`` (the road has them everywhere)."""
        return frozenset(k + s for k in slots for s in (-1, 1) if 0 <= k + s < self.n_lanes)

    def memo(self, key: tuple, compute):
        return remembered(self, key, compute)

    def nearest_slot(self, x: float, y: float) -> int:
        """The lane whose centre line is nearest to ``(x, y)``."""
        return min(max(int(round(float(y) / self.lane_width)), 0), self.n_lanes - 1)



@dataclass(frozen=True)
class Strip:
    """A lane off the corridor as geometry: ``kind`` ``straight`` / ``sine`` (highway-env's ``StraightLane``
    / ``SineLane``: the longitudinal coordinate along the chord ``start -> end``) or ``arc``
    (``CircularLane``: ``start`` is the centre, ``direction`` +1 clockwise). ``s0`` is the longitudinal
    coordinate of the strip's start along its chain; ``open_before`` / ``open_after``: the road goes on
    past that end."""

    kind: str
    start: tuple
    end: tuple
    width: float
    length: float
    slot: int
    s0: float
    amplitude: float = 0.0
    pulsation: float = 0.0
    phase: float = 0.0
    radius: float = 0.0
    start_phase: float = 0.0
    direction: int = 1
    open_before: bool = False
    open_after: bool = False

    def _chord(self):
        chord = self.__dict__.get("_chord_memo")
        if chord is None:
            (x0, y0), (x1, y1) = self.start, self.end
            n = math.hypot(x1 - x0, y1 - y0)
            chord = (x0, y0, (x1 - x0) / n, (y1 - y0) / n)
            object.__setattr__(self, "_chord_memo", chord)
        return chord

    def local(self, x, y):
        """``(s, r)``: longitudinal and lateral coordinates of points (arrays) in the strip's own frame, as
        highway-env's ``local_coordinates`` computes them (for a lane along ``+x``, ``r`` grows with y)."""
        if self.kind == "straight" and type(x) is float and type(y) is float:  # the same arithmetic, in floats
            x0, y0, ux, uy = self._chord()
            return (x - x0) * ux + (y - y0) * uy, -(x - x0) * uy + (y - y0) * ux
        x, y = np.asarray(x, float), np.asarray(y, float)
        if self.kind == "arc":
            cx, cy = self.start
            dx, dy = x - cx, y - cy
            phi = np.arctan2(dy, dx)
            phi = self.start_phase + (phi - self.start_phase + np.pi) % (2 * np.pi) - np.pi
            return (self.direction * (phi - self.start_phase) * self.radius,
                    self.direction * (self.radius - np.hypot(dx, dy)))
        x0, y0, ux, uy = self._chord()
        s = (x - x0) * ux + (y - y0) * uy
        r = -(x - x0) * uy + (y - y0) * ux
        if self.kind == "sine":
            r = r - self.amplitude * np.sin(self.pulsation * s + self.phase)
        return s, r

    def heading_at(self, s):
        """The lane's heading at longitudinal coordinate ``s`` (array)."""
        if self.kind == "straight" and type(s) is float:
            x0, y0, ux, uy = self._chord()
            return math.atan2(uy, ux)
        s = np.asarray(s, float)
        if self.kind == "arc":
            return self.direction * s / self.radius + self.start_phase + self.direction * np.pi / 2
        x0, y0, ux, uy = self._chord()
        theta = math.atan2(uy, ux)
        if self.kind == "sine":
            return theta + np.arctan(self.amplitude * self.pulsation * np.cos(self.pulsation * s + self.phase))
        return np.full_like(s, theta)

    def position(self, s: float, r: float = 0.0) -> tuple:
        """The world point at ``(s, r)`` (for tests and drawings)."""
        if self.kind == "arc":
            phi = self.direction * s / self.radius + self.start_phase
            cx, cy = self.start
            rad = self.radius - r * self.direction
            return cx + rad * math.cos(phi), cy + rad * math.sin(phi)
        x0, y0, ux, uy = self._chord()
        if self.kind == "sine":
            r = r + self.amplitude * math.sin(self.pulsation * s + self.phase)
        return x0 + s * ux - r * uy, y0 + s * uy + r * ux

    def s_limits(self) -> tuple:
        return (-np.inf if self.open_before else 0.0, np.inf if self.open_after else self.length)


@dataclass(frozen=True)
class RoadMap:
    """The road as the guardian reasons about it (see the module docstring).

    Attributes
    ----------
    lane_width : float
    n_lanes : int
        Slots (= ITHA lanes).
    y0 : float
        Slot 0's centre line.
    spans : tuple
        Per slot, the x-intervals ``((lo, hi), ...)`` where it is a corridor lane (``±inf``: open).
    branches : tuple of Strip
    lane_table : tuple
        ``((highway-env lane index, slot, branch number or -1), ...)``.
    ends : tuple
        ``((slot, s), ...)``: dead ends (a standing obstacle of length 0 at ``s``).
    """

    lane_width: float
    n_lanes: int
    y0: float
    spans: tuple
    branches: tuple
    lane_table: tuple
    ends: tuple

    # ---- lanes ----------------------------------------------------------------------------------------
    @property
    def numbering(self) -> LaneNumbering:
        """Slots (0 = leftmost) and ITHA lanes (1 = rightmost)."""
        numbering = self.__dict__.get("_numbering")
        if numbering is None:
            numbering = LaneNumbering(self.n_lanes)
            object.__setattr__(self, "_numbering", numbering)
        return numbering

    def slot_y(self, slot: int) -> float:
        return self.y0 + slot * self.lane_width

    def _lane_table(self) -> dict:
        table = self.__dict__.get("_table")
        if table is None:
            table = {index: (slot, branch) for index, slot, branch in self.lane_table}
            object.__setattr__(self, "_table", table)
        return table

    def slot_of(self, index) -> int:
        """The slot of highway-env lane ``index`` (``(from, to, id)``)."""
        return self._lane_table()[tuple(index)][0]

    def branch_of(self, index):
        """The branch (``Strip``) highway-env lane ``index`` is, or None on the corridor."""
        b = self._lane_table()[tuple(index)][1]
        return None if b < 0 else self.branches[b]

    def longitudinal(self, index, x: float, y: float) -> float:
        """The longitudinal coordinate along the lane's chain of a point on highway-env lane ``index``."""
        strip = self.branch_of(index)
        if strip is None:
            return float(x)
        s, _ = strip.local(x, y)
        return float(strip.s0 + s)

    def slot_at(self, slot: int, x: float) -> bool:
        """Is slot ``slot`` a corridor lane at ``x``?"""
        if not 0 <= slot < self.n_lanes:
            return False
        for lo, hi in self.spans[slot]:
            if lo <= x <= hi:
                return True
        return False

    def beside(self, slots, x: float) -> frozenset:
        """The corridor lanes next to ``slots`` present at ``x``."""
        return frozenset(k + s for k in slots for s in (-1, 1) if self.slot_at(k + s, x))

    def nearest_slot(self, x: float, y: float) -> int:
        """The slot whose strip holds ``(x, y)``: a branch's slot on a branch, else the nearest corridor lane
        present at ``x``."""
        strip = self.on_branch(x, y)
        if strip is not None:
            return strip.slot
        present = [k for k in range(self.n_lanes) if self.slot_at(k, x)] or list(range(self.n_lanes))
        return min(present, key=lambda k: abs(float(y) - self.slot_y(k)))

    def on_branch(self, x: float, y: float):
        """The branch whose strip holds the point ``(x, y)`` while no corridor lane does, else None."""
        k = int(round((y - self.y0) / self.lane_width))
        if 0 <= k < self.n_lanes and abs(y - self.slot_y(k)) <= self.lane_width / 2 and self.slot_at(k, x):
            return None
        for strip in self.branches:
            s, r = strip.local(x, y)
            lo, hi = strip.s_limits()
            if abs(float(r)) <= strip.width / 2 and lo <= float(s) <= hi:
                return strip
        return None

    def lane_heading(self, x: float, y: float) -> float:
        """The heading of the lane at ``(x, y)``: 0 on the corridor, the branch's where only a branch is."""
        strip = self.on_branch(x, y)
        if strip is None:
            return 0.0
        s, _ = strip.local(x, y)
        return float(strip.heading_at(s))

    def end_cars(self) -> tuple:
        """Each dead end as a standing car of length 0 at the end, in its slot's ITHA lane: a car there must
        stop before the end or leave the lane (self-safety (7.4) towards it)."""
        lanes = self.numbering
        return tuple(Car(float(s), 0.0, frozenset({lanes.itha(k)}), 0.0, f"the end of lane {lanes.itha(k)}", fixed=True)
                     for k, s in self.ends)

    # ---- bodies ---------------------------------------------------------------------------------------
    def depth(self, xs, ys) -> np.ndarray:
        """For points (arrays), how far [m] each lies sideways outside every lane's strip present where it
        is (0 on the road; ``inf`` where no lane is present at all)."""
        xs, ys = np.asarray(xs, float), np.asarray(ys, float)
        best = np.full(xs.shape, np.inf)
        half = self.lane_width / 2
        for k, spans in enumerate(self.spans):
            present = np.zeros(xs.shape, bool)
            for lo, hi in spans:
                present |= (xs >= lo) & (xs <= hi)
            lateral = np.maximum(np.abs(ys - self.slot_y(k)) - half, 0.0)
            best = np.where(present, np.minimum(best, lateral), best)
        for strip in self.branches:
            s, r = strip.local(xs, ys)
            lo, hi = strip.s_limits()
            lateral = np.maximum(np.abs(r) - strip.width / 2, 0.0)
            best = np.where((s >= lo) & (s <= hi), np.minimum(best, lateral), best)
        return best

    def body_slots(self, x, y, heading, length: float, width: float, margin: float = 0.0, dx=0.0, dy=0.0) -> frozenset:
        """Slots whose strips the bodies at ``(x, y, heading)`` (arrays allowed: the union over all) overlap:
        each body widened by ``margin`` and swept by ``(dx, dy)`` (its motion over a step); a slot counts
        only where it is present along the body's extent.

        Each body is answered from a memo of the bodies asked before (every guarded car's scene reads every
        car's body once per simulation step)."""
        if isinstance(x, SCALAR) and isinstance(y, SCALAR) and isinstance(heading, SCALAR) and isinstance(dx, SCALAR) \
                and isinstance(dy, SCALAR):
            return self._body(float(x), float(y), float(heading), length, width, margin, float(dx), float(dy))
        x, y, h = (np.atleast_1d(np.asarray(v, float)) for v in (x, y, heading))
        dx, dy = np.broadcast_to(np.asarray(dx, float), x.shape), np.broadcast_to(np.asarray(dy, float), x.shape)
        out = set()
        for xi, yi, hi, dxi, dyi in zip(x.tolist(), y.tolist(), h.tolist(), dx.tolist(), dy.tolist()):
            out |= self._body(xi, yi, hi, length, width, margin, dxi, dyi)
        return frozenset(out)

    def _body(self, x, y, h, length, width, margin, dx, dy) -> frozenset:
        key = ("body", x, y, h, length, width, margin, dx, dy)
        memo = self.__dict__.get("_memo")
        out = None if memo is None else memo.get(key)
        if out is None:
            out = self.memo(key, lambda: self._one_body_slots(x, y, h, length, width, margin, dx, dy))
        return out

    def memo(self, key: tuple, compute):
        return remembered(self, key, compute)

    def _one_body_slots(self, x, y, h, length, width, margin, dx, dy) -> frozenset:
        """The slots one body overlaps (``body_slots``), in floats."""
        rx, ry = half_extents(length, width, h)
        rx, ry = rx + margin, ry + margin
        ylo, yhi = y - ry + (0.0 if 0.0 < dy else dy), y + ry + (0.0 if 0.0 > dy else dy)   # min, max with 0
        xlo, xhi = x - rx + (0.0 if 0.0 < dx else dx), x + rx + (0.0 if 0.0 > dx else dx)
        half, y0, w = self.lane_width / 2, self.y0, self.lane_width
        out = set()
        for k, spans in enumerate(self.spans):
            yk = y0 + k * w
            if ylo < yk + half and yhi > yk - half:
                for lo, hi in spans:
                    if xlo < hi and xhi > lo:
                        out.add(k)
                        break
        sweep = None
        for strip in self.branches:
            if strip.slot in out:
                continue
            if sweep is None:
                sweep = 0.0 if dx == 0.0 and dy == 0.0 else float(np.hypot(dx, dy))
            sl, r = strip.local(x, y)
            sl, r = float(sl), float(r)
            if abs(r) > strip.width / 2 + length / 2 + width / 2 + margin + sweep + 1e-6:
                continue   # beyond any reach across the strip, whatever its heading (saves the turning below)
            rs, rr = half_extents(length, width, h - float(strip.heading_at(sl)))
            rs, rr = rs + margin + sweep, rr + margin + sweep
            lo, hi = strip.s_limits()
            if r - rr < strip.width / 2 and r + rr > -strip.width / 2 and sl + rs > lo and sl - rs < hi:
                out.add(strip.slot)
        return frozenset(out)


def outline(x, y, heading, length: float, width: float):
    """Corners and side midpoints of bodies at ``(x, y, heading)`` (arrays): ``(xs, ys)`` of shape (n, 8)."""
    x, y, h = (np.atleast_1d(np.asarray(v, float)) for v in (x, y, heading))
    c, s = np.cos(h)[:, None], np.sin(h)[:, None]
    a = np.array([1, 1, -1, -1, 1, -1, 0, 0], float) * length / 2
    b = np.array([1, -1, 1, -1, 0, 0, 1, -1], float) * width / 2
    return x[:, None] + a * c - b * s, y[:, None] + a * s + b * c


def road_as_dict(road) -> dict:
    """``road`` (``Road`` or ``RoadMap``) as plain JSON values: what the service's scene sessions take (open
    span ends are ``None``); ``road_from_dict`` reads it back."""
    if isinstance(road, Road):
        return {"lanes": road.n_lanes, "lane_width": road.lane_width}
    open_end = lambda v: None if math.isinf(v) else v  # noqa: E731
    return {"lanes": road.n_lanes, "lane_width": road.lane_width, "y0": road.y0,
            "spans": [[[open_end(lo), open_end(hi)] for lo, hi in spans] for spans in road.spans],
            "branches": [{f.name: (list(v) if isinstance(v := getattr(s, f.name), tuple) else v) for f in fields(s)}
                         for s in road.branches],   # the fields only: a strip also remembers its chord
            "ends": [[k, s] for k, s in road.ends]}


def road_from_dict(spec: dict):
    """The road of a ``road_as_dict`` value: a ``Road`` when only lanes and their width are given (lane 0 at
    ``y = 0``), else a ``RoadMap``."""
    if set(spec) <= {"lanes", "lane_width"}:
        return Road(int(spec["lanes"]), float(spec["lane_width"]))
    n = int(spec["lanes"])
    spans = spec.get("spans") or [[[None, None]]] * n
    spans = tuple(tuple((-math.inf if lo is None else float(lo), math.inf if hi is None else float(hi))
                        for lo, hi in slot) for slot in spans)
    branches = tuple(Strip(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in b.items()})
                     for b in spec.get("branches", ()))
    return RoadMap(float(spec["lane_width"]), n, float(spec.get("y0", 0.0)), spans, branches, (),
                   tuple((int(k), float(s)) for k, s in spec.get("ends", ())))
