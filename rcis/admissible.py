"""Admissible inputs ``S(x) = {u in U : f(x, u, W) ⊆ C}`` and the nearest admissible input.

For a PWA system and an invariant union ``C = ∪_i C_i``, at state x with piece j,

    S(x) = ∪_i {u in U : G_i (A_j x + B_j u + c_j) <= g_i - h_W(E_j^T G_i^T) - margin},

a union of convex polygons when u is 2-D (possibly non-convex, Fig. 6.4).
The rows ``G_i A_j``, ``G_i B_j`` and the constant part are stacked once per
PWA piece, so a query is one matrix-vector product and one compiled clipping
pass. The same rows, with a larger margin, are what ``PWASystem.pre`` used,
so every state of C has an admissible input.

The override keeps the driver's input when admissible; otherwise it changes
the inputs in a user-set priority (default: throttle, then steering, then
both), as Section 6.5.2 proposes for non-convex admissible sets.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rcis import _kernels
from rcis.pwa import RUNTIME_MARGIN, PWASystem
from rcis.region import Region
from rcis.tolerances import BOUNDS_ROUNDING  # noqa: F401 (re-exported)
from rcis.intervals import nearest_in_intervals



@dataclass(frozen=True)
class OverrideResult:
    applied: np.ndarray      # the input to apply (always inside U when feasible)
    overridden: bool         # applied differs from the proposed input
    feasible: bool           # S(x) was non-empty
    changed: str             # "none" | the name of the one input changed | "both" | "infeasible"


class AdmissibleInputs:
    """``S(x)`` for one PWA system and one invariant region (inputs must be 2-D).

    Parameters
    ----------
    system : PWASystem
        With two inputs and a box input set.
    invariant : Region
        The robust controlled invariant set (a union of polyhedra).
    margin : float
        Erosion of the set at run time (``RUNTIME_MARGIN``, below the margin the set was built with, so
        every state of the set has an admissible input).
    input_names : pair of str
        Names used in ``OverrideResult.changed``.
    """

    def __init__(self, system: PWASystem, invariant: Region, margin: float = RUNTIME_MARGIN,
                 input_names=("throttle", "steering")):
        if system.n_u != 2:
            raise ValueError("AdmissibleInputs handles 2-D inputs (polygons)")
        box = system.input_set._box
        if box is None:
            raise ValueError("AdmissibleInputs needs a box input set")
        self.system = system
        self.invariant = invariant
        self.u_lower, self.u_upper = (np.asarray(v, float) for v in box)
        self.input_names = tuple(input_names)
        self._rows = [self._stack_rows(j, margin) for j in range(len(system.pieces))]

    def _stack_rows(self, j: int, margin: float):
        p = self.system.pieces[j]
        GA, GB, r0, starts = [], [], [], [0]
        for T in self.invariant.pieces:
            G, g = self.system._robust_target_rows(p, T, margin)
            GA.append(G @ p.A)
            GB.append(G @ p.B)
            r0.append(g - G @ p.c)
            starts.append(starts[-1] + G.shape[0])
        return (np.vstack(GA), np.ascontiguousarray(np.vstack(GB)), np.concatenate(r0),
                np.asarray(starts, dtype=np.int64))

    def at(self, x) -> "AdmissibleQuery":
        """``S(x)`` at one state: its half-planes, answered lazily (polygons, ranges, membership)."""
        x = np.asarray(x, dtype=float)
        if x.shape != (self.system.n_x,) or not np.all(np.isfinite(x)):
            raise ValueError(f"state must be {self.system.n_x} finite numbers, got {x.tolist()}")
        j = self.system.piece_index(x)
        GA, GB, r0, starts = self._rows[j]
        return AdmissibleQuery(self, GB, r0 - GA @ x, starts, piece=j)

    def polygons(self, x) -> list[np.ndarray]:
        """``S(x)`` as convex polygons (vertex arrays, counter-clockwise); [] if empty."""
        return self.at(x).polygons

    def is_admissible(self, x, u, polygons=None) -> bool:
        if polygons is None:
            return self.at(x).contains(np.asarray(u, float))
        return any(_in_polygon(P, np.asarray(u, float)) for P in polygons)

    def intervals(self, polygons, axis: int, value: float) -> list[tuple[float, float]]:
        """Admissible ranges of input ``axis`` with the other input fixed to ``value`` (Fig. 6.5)."""
        out = []
        for P in polygons:
            iv = _line_interval(P, 1 - axis, value)
            if iv is not None:
                out.append(iv)
        return sorted(out)

    def override(self, x, u, priority=(0, 1), polygons=None, query=None) -> OverrideResult:
        """The driver's input if admissible, else the nearest admissible one by priority.

        ``priority`` lists input indices: first change only ``priority[0]``
        (nearest value on the line through u), then only ``priority[1]``, then
        both (nearest point, distances scaled by the input ranges).

        Parameters
        ----------
        x : array
            The state.
        u : array of 2 floats
            The proposed input (finite, else ``ValueError``).
        priority : pair of int
        polygons, query : optional
            ``S(x)`` already computed for this x.

        Returns
        -------
        OverrideResult
            ``applied`` (inside U, and inside ``S(x)`` when ``feasible``), ``overridden``, ``feasible``
            and which input ``changed``.
        """
        u = np.asarray(u, dtype=float)
        if u.shape != (2,) or not np.all(np.isfinite(u)):
            raise ValueError(f"input must be 2 finite numbers, got {u.tolist()}")
        if sorted(priority) != [0, 1]:
            raise ValueError(f"priority must order the inputs 0 and 1, got {priority}")
        q = query if query is not None else self.at(x)
        polys = q.polygons if polygons is None else polygons
        if not polys:
            return OverrideResult(u.copy(), False, False, "infeasible")
        if self._in_bounds(u) and q.contains(u):
            return OverrideResult(u.copy(), False, True, "none")
        for axis in priority:
            ranges = q.ranges(axis, u[1 - axis])
            if ranges:
                v = u.copy()
                v[axis] = nearest_in_intervals(ranges, u[axis])
                return OverrideResult(self._inside_bounds(v), True, True, self.input_names[axis])
        scale = self.u_upper - self.u_lower
        best = min((_nearest_on_polygon(P / scale, u / scale) for P in polys),
                   key=lambda pt: np.sum((pt - u / scale) ** 2))
        return OverrideResult(self._inside_bounds(best * scale), True, True, "both")

    def _in_bounds(self, u) -> bool:
        return bool(np.all(u >= self.u_lower) and np.all(u <= self.u_upper))

    def _inside_bounds(self, u: np.ndarray) -> np.ndarray:
        """Remove float rounding at the bounds of U; anything larger is an error."""
        clipped = np.clip(u, self.u_lower, self.u_upper)
        if np.max(np.abs(clipped - u)) > BOUNDS_ROUNDING:
            raise ArithmeticError(f"override produced {u.tolist()} outside the input bounds")
        return clipped


class AdmissibleQuery:
    """``S(x) = ∪_p {u in U : G_p u <= r_p}`` at one state x."""

    def __init__(self, owner: AdmissibleInputs, G: np.ndarray, r: np.ndarray, starts: np.ndarray,
                 piece: int | None = None):
        self.owner, self.G, self.r, self.starts = owner, G, r, starts
        self.piece = piece  # the PWA piece of the state, when the query came from ``at``
        self._polygons = None
        self._clipped = None

    def clipped(self) -> tuple[np.ndarray, np.ndarray]:
        """``(verts, counts)``: polygon p of the set's piece p is ``verts[p, :counts[p]]`` (empty when 0)."""
        if self._clipped is None:
            self._clipped = _kernels.clip_box_by_halfplanes(self.G, self.r, self.starts,
                                                            self.owner.u_lower, self.owner.u_upper)
        return self._clipped

    @property
    def polygons(self) -> list[np.ndarray]:
        if self._polygons is None:
            verts, counts = self.clipped()
            self._polygons = [verts[p, :counts[p]].copy() for p in np.flatnonzero(counts)]
        return self._polygons

    def contains(self, u: np.ndarray, tol: float = 1e-12) -> bool:
        if np.any(u < self.owner.u_lower - tol) or np.any(u > self.owner.u_upper + tol):
            return False
        return _kernels.first_piece(self.G, self.r, self.starts, u, tol) >= 0

    def restricted(self, boxes) -> "AdmissibleQuery":
        """``S(x) ∩ ∪_k B_k`` for boxes ``B_k = ((lo_0, hi_0), (lo_1, hi_1))`` of the input plane.

        Each polygon of S(x) is intersected with each box (sides outside ``U`` add no row), so
        the result is again a union of convex polygons with the same queries.
        """
        lo_u, hi_u = self.owner.u_lower, self.owner.u_upper
        if len(boxes) == 1:
            (lo0, hi0), (lo1, hi1) = boxes[0]
            if lo0 <= lo_u[0] and hi0 >= hi_u[0] and lo1 <= lo_u[1] and hi1 >= hi_u[1]:
                return self  # the box is all of U: nothing to intersect (the common case, every step)
        n = len(self.starts) - 1
        counts = np.diff(self.starts)
        piece_of_row = np.repeat(np.arange(n), counts)
        G, r, starts, offset = [], [], [np.zeros(1, dtype=np.int64)], 0
        for (lo0, hi0), (lo1, hi1) in boxes:
            rows = [(np.array([1.0, 0.0]), hi0, hi0 < hi_u[0]), (np.array([-1.0, 0.0]), -lo0, lo0 > lo_u[0]),
                    (np.array([0.0, 1.0]), hi1, hi1 < hi_u[1]), (np.array([0.0, -1.0]), -lo1, lo1 > lo_u[1])]
            rows = [(a, b) for a, b, binding in rows if binding]
            k = len(rows)
            total = len(self.G) + k * n
            Gb, rb = np.empty((total, 2)), np.empty(total)
            Gb[np.arange(len(self.G)) + k * piece_of_row] = self.G
            rb[np.arange(len(self.G)) + k * piece_of_row] = self.r
            for j, (a, b) in enumerate(rows):
                at = self.starts[1:] + k * np.arange(n) + j
                Gb[at] = a
                rb[at] = b
            G.append(Gb)
            r.append(rb)
            starts.append(offset + self.starts[1:] + k * np.arange(1, n + 1))
            offset += total
        if not G:
            return AdmissibleQuery(self.owner, np.zeros((0, 2)), np.zeros(0), np.zeros(1, dtype=np.int64))
        return AdmissibleQuery(self.owner, np.ascontiguousarray(np.vstack(G)), np.concatenate(r),
                               np.concatenate(starts).astype(np.int64))

    @classmethod
    def of_boxes(cls, owner: AdmissibleInputs, boxes) -> "AdmissibleQuery":
        """``∪_k B_k ∩ U`` as a query: boxes ``((lo_0, hi_0), (lo_1, hi_1))`` of the input plane."""
        G, r, starts = [], [], [0]
        for (lo0, hi0), (lo1, hi1) in boxes:
            G.extend([(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)])
            r.extend([hi0, -lo0, hi1, -lo1])
            starts.append(starts[-1] + 4)
        return cls(owner, np.array(G, dtype=float).reshape(-1, 2), np.array(r, dtype=float),
                   np.asarray(starts, dtype=np.int64))

    def union(self, *others: "AdmissibleQuery") -> "AdmissibleQuery":
        """The union of this query's polygons and the others' (same owner, so the same ``U``)."""
        parts = [self, *others]
        if any(q.owner is not self.owner for q in others):
            raise ValueError("AdmissibleQuery.union: the queries belong to different input sets")
        G = np.vstack([q.G for q in parts]) if parts else np.zeros((0, 2))
        r = np.concatenate([q.r for q in parts])
        starts, offset = [np.zeros(1, dtype=np.int64)], 0
        for q in parts:
            starts.append(q.starts[1:] + offset)
            offset += len(q.G)
        return AdmissibleQuery(self.owner, np.ascontiguousarray(G), r, np.concatenate(starts).astype(np.int64))

    def ranges(self, axis: int, value: float) -> list[tuple[float, float]]:
        """Admissible ranges of input ``axis`` with the other fixed to ``value`` (Fig. 6.5)."""
        iv = _kernels.line_intervals(self.G, self.r, self.starts, axis, float(value),
                                     self.owner.u_lower, self.owner.u_upper)
        keep = iv[:, 0] <= iv[:, 1]
        return sorted(map(tuple, iv[keep].tolist()))  # the same float pairs, 5x faster than a generator


def _in_polygon(P: np.ndarray, u: np.ndarray, tol: float = 1e-12) -> bool:
    if len(P) == 1:
        return bool(np.all(np.abs(P[0] - u) <= tol))
    if len(P) == 2:
        return _dist_to_segment(P[0], P[1], u) <= tol
    edges = np.roll(P, -1, axis=0) - P
    rel = u - P
    cross = edges[:, 0] * rel[:, 1] - edges[:, 1] * rel[:, 0]
    return bool(np.all(cross >= -tol * np.linalg.norm(edges, axis=1)))


def _dist_to_segment(a, b, u) -> float:
    d = b - a
    t = 0.0 if not np.any(d) else np.clip(np.dot(u - a, d) / np.dot(d, d), 0.0, 1.0)
    return float(np.linalg.norm(a + t * d - u))


def _line_interval(P: np.ndarray, fixed_axis: int, value: float):
    """Range of the free coordinate on ``P ∩ {u[fixed_axis] = value}``, or None."""
    free = 1 - fixed_axis
    c = P[:, fixed_axis]
    if value < c.min() or value > c.max():
        return None
    pts = list(P[c == value, free])
    Q = np.roll(P, -1, axis=0)
    cq = Q[:, fixed_axis]
    cross = (c - value) * (cq - value) < 0
    t = (value - c[cross]) / (cq[cross] - c[cross])
    pts.extend(P[cross, free] + t * (Q[cross, free] - P[cross, free]))
    if not pts:
        return None
    return (float(min(pts)), float(max(pts)))


def _nearest_on_polygon(P: np.ndarray, u: np.ndarray) -> np.ndarray:
    if _in_polygon(P, u):
        return u.copy()
    Q = np.roll(P, -1, axis=0)
    d = Q - P
    dd = np.einsum("ij,ij->i", d, d)
    t = np.where(dd > 0, np.einsum("ij,ij->i", u - P, d) / np.where(dd > 0, dd, 1.0), 0.0)
    pts = P + np.clip(t, 0.0, 1.0)[:, None] * d
    return pts[np.argmin(np.sum((pts - u) ** 2, axis=1))]
