"""Finite unions of polyhedra, ``R = P_1 ∪ ... ∪ P_k``, with fast membership.

Pieces may overlap. Membership of many points is vectorised; a single state is
answered by a compiled early-exit loop. Set difference, coverage and inclusion
between unions are exact up to slivers thinner than ``eps`` (Chebyshev radius),
which are reported as covered.
"""
from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from rcis import _kernels
from rcis.polyhedron import Polyhedron
from rcis.tolerances import CERTIFICATE_MARGIN, SLIVER_EPS  # noqa: F401 (re-exported)



class Region:
    """A union of polyhedra of one dimension."""

    def __init__(self, pieces: Iterable[Polyhedron], dim: int | None = None):
        self.pieces: list[Polyhedron] = list(pieces)
        if dim is None:
            if not self.pieces:
                raise ValueError("Region: give dim for an empty union")
            dim = self.pieces[0].dim
        for i, P in enumerate(self.pieces):
            if P.dim != dim:
                raise ValueError(f"Region: piece {i} has dimension {P.dim}, expected {dim}")
        self.dim = dim
        self._stack = None
        self._boxes = None

    def __len__(self) -> int:
        return len(self.pieces)

    def __iter__(self):
        return iter(self.pieces)

    def __repr__(self) -> str:
        return f"Region(dim={self.dim}, pieces={len(self)})"

    @property
    def n_constraints(self) -> int:
        return sum(P.n_constraints for P in self.pieces)

    def stacked(self):
        """All rows stacked: ``(A, b, starts)`` with piece p at rows starts[p]:starts[p+1]."""
        if self._stack is None:
            if self.pieces:
                A = np.vstack([P.A for P in self.pieces])
                b = np.concatenate([P.b for P in self.pieces])
            else:
                A, b = np.zeros((0, self.dim)), np.zeros(0)
            starts = np.cumsum([0] + [P.n_constraints for P in self.pieces]).astype(np.int64)
            self._stack = (np.ascontiguousarray(A), np.ascontiguousarray(b), starts)
        return self._stack

    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """The pieces' bounding boxes stacked: ``(lower, upper)``, each of shape (pieces, dim)."""
        if self._boxes is None:
            boxes = [P.bounding_box() for P in self.pieces]
            self._boxes = (np.array([lo for lo, _ in boxes]).reshape(-1, self.dim),
                           np.array([hi for _, hi in boxes]).reshape(-1, self.dim))
        return self._boxes

    def pieces_whose_box_holds(self, P: Polyhedron, tol: float) -> list[Polyhedron]:
        """Pieces whose bounding box holds P's (to tol): the only ones that can contain P."""
        if not self.pieces:
            return []
        lo, hi = self.boxes()
        plo, phi = P.bounding_box()
        holds = np.all(plo >= lo - tol, axis=1) & np.all(phi <= hi + tol, axis=1)
        return [self.pieces[i] for i in np.flatnonzero(holds)]

    # ---- membership ---------------------------------------------------
    def piece_index(self, X, tol: float = 1e-9):
        """Index of the first piece holding each point (-1 outside)."""
        X = np.asarray(X, dtype=float)
        A, b, starts = self.stacked()
        if X.ndim == 1:
            _check_dim(X.shape[0], self.dim)
            return int(_kernels.first_piece(A, b, starts, np.ascontiguousarray(X), tol))
        _check_dim(X.shape[1], self.dim)
        return _kernels.first_pieces(A, b, starts, np.ascontiguousarray(X), tol)

    def contains(self, X, tol: float = 1e-9):
        idx = self.piece_index(X, tol)
        return idx >= 0 if np.ndim(idx) else bool(idx >= 0)

    # ---- set algebra -------------------------------------------------
    def union(self, other: "Region") -> "Region":
        return Region(self.pieces + other.pieces, self.dim)

    def difference(self, P: Polyhedron, eps: float = SLIVER_EPS) -> list[Polyhedron]:
        """``P \\ R`` as a list of polyhedra (slivers thinner than eps dropped)."""
        remaining = [P] if P.chebyshev_ball().radius > eps else []
        for Q in self.pieces:
            if not remaining:
                break
            remaining = [piece for R in remaining for piece in _subtract(R, Q, eps)]
        return remaining

    def covers(self, P: Polyhedron, eps: float = SLIVER_EPS, budget: int | None = None) -> bool:
        """``P ⊆ R`` up to slivers thinner than eps.

        With a ``budget`` (number of fragments the search may visit) an
        undecided search answers False: callers use this only where a wrong
        "not covered" costs work, never soundness.
        """
        if any(Q.contains_polyhedron(P, eps) for Q in self.pieces_whose_box_holds(P, eps)):
            return True
        if P.chebyshev_ball().radius <= eps:
            return True
        near = [Q for Q in self.pieces if P.may_intersect(Q)]
        rows = Region(near, self.dim).stacked()
        try:
            return not _has_uncovered_part(P, near, 0, eps, [budget if budget is not None else -1], rows)
        except _BudgetExhausted:
            return False

    def line_intervals(self, point, axis: int, tol: float = 1e-9) -> list[tuple[float, float]]:
        """Per piece, the values t with ``point`` (coordinate ``axis`` set to t) inside: non-empty ones."""
        if not self.pieces:
            return []
        A, b, starts = self.stacked()
        x = np.array(point, dtype=float)
        x[axis] = 0.0
        r = b + tol - A @ x
        c = A[:, axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            q = r / c
        upper = np.where(c > 1e-14, q, np.inf)
        lower = np.where(c < -1e-14, q, -np.inf)
        blocked = (np.abs(c) <= 1e-14) & (r < 0)
        idx = starts[:-1]
        hi = np.minimum.reduceat(upper, idx)
        lo = np.maximum.reduceat(lower, idx)
        dead = np.logical_or.reduceat(blocked, idx)
        keep = (~dead) & (lo <= hi)
        return list(zip(lo[keep].tolist(), hi[keep].tolist()))

    def is_subset_of(self, other: "Region", eps: float = SLIVER_EPS) -> bool:
        return all(other.covers(P, eps) for P in self.pieces)

    def witness_outside(self, other: "Region", eps: float = SLIVER_EPS):
        """A point of self outside other, with a ball thicker than eps around it in ``self \\ other``; or None.

        The probes of ``_deepest_probe`` first (the one with the largest such ball, no LP); only when
        none clears eps, the centre of the fattest leftover of the exact difference.
        """
        rows = other.stacked()
        best_point, best_radius = None, -np.inf
        for P in self.pieces:
            if P.chebyshev_ball().radius <= eps:
                continue
            P.bounding_box()
            point, radius = _deepest_probe(P, rows, 0)
            if radius > best_radius:
                best_point, best_radius = point, radius
        if best_radius > eps + CERTIFICATE_MARGIN:
            return best_point
        best = None
        for P in sorted(self.pieces, key=lambda P: -P.chebyshev_ball().radius):
            if best is not None and P.chebyshev_ball().radius <= best.radius:
                break  # a leftover of P lies in P: no fatter one can follow
            for piece in other.difference(P, eps):
                ball = piece.chebyshev_ball()
                if best is None or ball.radius > best.radius:
                    best = ball
        return None if best is None else best.center


def _check_dim(got: int, want: int) -> None:
    if got != want:
        raise ValueError(f"point has dimension {got}, region has {want}")


class _BudgetExhausted(Exception):
    pass


def _has_uncovered_part(R: Polyhedron, pieces, start: int, eps: float, budget: list, rows) -> bool:
    """Depth-first search for a part of R (with interior) outside pieces[start:] (``rows``: theirs, stacked)."""
    budget[0] -= 1
    if budget[0] == 0:
        raise _BudgetExhausted
    if _probe_finds_uncovered_ball(R, rows, start, eps):
        return True
    for q in range(start, len(pieces)):
        Q = pieces[q]
        if not _overlap(R, Q, eps):
            continue
        return any(_has_uncovered_part(F, pieces, q + 1, eps, budget, rows)
                   for F in _subtract(R, Q, eps, tidy=False, overlapping=True))
    return True


_PROBE_STEPS = np.array([0.0, 0.5, 0.8, 0.95, 0.99])


def _probe_finds_uncovered_ball(R: Polyhedron, rows, start: int, eps: float) -> bool:
    """A ball thicker than eps inside R and outside pieces[start:], found without an LP (``_deepest_probe``).

    Sound whatever the search would say: that answer only keeps a candidate (a piece of Pre inside
    the safe set) that the search might have dropped.
    """
    return _deepest_probe(R, rows, start)[1] > eps + CERTIFICATE_MARGIN


def _deepest_probe(R: Polyhedron, rows, start: int):
    """``(point, radius)``: the probe of R with the largest ball inside R and outside pieces[start:].

    Probes lie between R's interior point and its known points (``Polyhedron.known_points``). A probe
    with slack s in R and, for every piece, some row it violates by at least d, is the centre of a
    ball of radius min(s, d) in R and outside the union. ``(None, -inf)`` when R has no known
    interior point or a piece has no rows (the whole space).
    """
    c = R.interior_point()
    A, b, starts = rows
    if c is None or np.any(np.diff(starts[start:]) == 0):
        return None, -np.inf
    X = R.known_points()
    probes = (c + _PROBE_STEPS[:, None, None] * (X[None, :, :] - c)).reshape(-1, R.dim)
    radius = np.min(R.b - probes @ R.A.T, axis=1, initial=np.inf)
    first = starts[start]
    if first < len(b):
        violation = probes @ A[first:].T - b[first:]
        radius = np.minimum(radius, np.maximum.reduceat(violation, starts[start:-1] - first, axis=1).min(axis=1))
    k = int(np.argmax(radius))
    return probes[k], float(radius[k])


def _overlap(R: Polyhedron, Q: Polyhedron, eps: float) -> bool:
    """``R ∩ Q`` holds a ball thicker than eps (the interior points of R and Q are tried before the LP)."""
    return R.may_intersect(Q) and R.intersect(Q).has_ball(eps, (R.interior_point(), Q.interior_point()))


def _subtract(R: Polyhedron, Q: Polyhedron, eps: float, tidy: bool = True,
              overlapping: bool = False) -> list[Polyhedron]:
    """``R \\ Q`` split along the rows of Q that cut R (``overlapping``: the caller checked ``_overlap``)."""
    if not (overlapping or _overlap(R, Q, eps)):
        return [R]
    cutting = np.flatnonzero(R.exceeds(Q.A, Q.b + eps))
    pieces = []
    A, b = R.A, R.b
    hints = (R.interior_point(),)
    for i in cutting:
        outside = Polyhedron._of_unit_rows(np.vstack([A, -Q.A[i]]), np.append(b, -Q.b[i]))
        if outside.has_ball(eps, hints):
            pieces.append(outside.minimal() if tidy else outside)
        A, b = np.vstack([A, Q.A[i]]), np.append(b, Q.b[i])
    return pieces


def region_from_arrays(pieces: Sequence[tuple[np.ndarray, np.ndarray]], dim: int) -> Region:
    return Region([Polyhedron(A, b) for A, b in pieces], dim)


def convex_union(P: Polyhedron, Q: Polyhedron, tol: float = 1e-9) -> Polyhedron | None:
    """``P ∪ Q`` as one polyhedron when the union is convex, else None.

    The envelope ``env(P, Q)`` keeps the rows of each polyhedron that the other
    satisfies (Bemporad, Fukuda and Torrisi); ``P ∪ Q`` is convex iff
    ``env = P ∪ Q``, i.e. iff for every row ``a x <= b`` of P left out of env,
    ``env ∩ {a x >= b} ⊆ Q``.
    """
    if not P.may_intersect(Q) or _segment_leaves(P, Q, tol):
        return None
    if not _share_a_point(P, Q) and P.intersect(Q).chebyshev_ball().radius < -tol:
        return None  # disjoint: a union of two separated sets is not convex
    p_ok = ~Q.exceeds(P.A, P.b + tol)
    q_ok = ~P.exceeds(Q.A, Q.b + tol)
    env = Polyhedron(np.vstack([P.A[p_ok], Q.A[q_ok]]), np.concatenate([P.b[p_ok], Q.b[q_ok]]))
    for a, bi in zip(P.A[~p_ok], P.b[~p_ok]):
        beyond = env.intersect(Polyhedron([-a], [-bi]))
        if not Q.contains_polyhedron(beyond, tol):
            return None
    return env.minimal()


_SEGMENT_STEPS = np.linspace(0.0, 1.0, 9)[1:-1]


def _segment_leaves(P: Polyhedron, Q: Polyhedron, tol: float) -> bool:
    """A segment between known points of P and Q leaves ``P ∪ Q`` (by ``CERTIFICATE_MARGIN``): not convex.

    A necessary condition for convexity, checked without an LP; it never rejects a union that
    ``convex_union``'s own test would accept (see ``rcis.tolerances``).
    """
    p, q = P.known_points(), Q.known_points()
    if not len(p) or not len(q):
        return False
    X = (p[:, None, None, :] + _SEGMENT_STEPS[None, None, :, None] * (q[None, :, None, :] - p[:, None, None, :]))
    X = X.reshape(-1, P.dim)
    margin = tol + CERTIFICATE_MARGIN
    outside_p = np.max(X @ P.A.T - P.b, axis=1, initial=-np.inf) > margin
    outside_q = np.max(X @ Q.A.T - Q.b, axis=1, initial=-np.inf) > margin
    return bool(np.any(outside_p & outside_q))


def _share_a_point(P: Polyhedron, Q: Polyhedron) -> bool:
    """A known point lies in both P and Q with slack ``CERTIFICATE_MARGIN`` (then P ∩ Q is not empty)."""
    X = np.vstack([P.known_points(), Q.known_points()])
    if not len(X):
        return False
    slack = np.minimum(np.min(P.b - X @ P.A.T, axis=1, initial=np.inf),
                       np.min(Q.b - X @ Q.A.T, axis=1, initial=np.inf))
    return bool(np.any(slack >= CERTIFICATE_MARGIN))


def merge_convex(pieces: list[Polyhedron]) -> list[Polyhedron]:
    """Replace pairs whose union is convex by that union (same union, fewer pieces).

    One pass: each piece is merged into the result greedily; a merged piece is
    retried against the rest, pieces already in the result are not re-paired.
    """
    result: list[Polyhedron] = []
    for P in pieces:
        merged = True
        while merged:
            merged = False
            for i, Q in enumerate(result):
                U = convex_union(P, Q)
                if U is not None:
                    result.pop(i)
                    P, merged = U, True
                    break
        result.append(P)
    return result
