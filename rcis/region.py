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
from rcis.tolerances import SLIVER_EPS  # noqa: F401 (re-exported)



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
        if any(_box_inside(P, Q, eps) and Q.contains_polyhedron(P, eps) for Q in self.pieces):
            return True
        if P.chebyshev_ball().radius <= eps:
            return True
        near = [Q for Q in self.pieces if P.may_intersect(Q)]
        try:
            return not _has_uncovered_part(P, near, 0, eps, [budget if budget is not None else -1])
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
        """A point of self outside other (the centre of the fattest leftover), or None."""
        best = None
        for P in self.pieces:
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


def _has_uncovered_part(R: Polyhedron, pieces, start: int, eps: float, budget: list) -> bool:
    """Depth-first search for a part of R (with interior) outside pieces[start:]."""
    budget[0] -= 1
    if budget[0] == 0:
        raise _BudgetExhausted
    for q in range(start, len(pieces)):
        Q = pieces[q]
        if not R.may_intersect(Q) or R.intersect(Q).chebyshev_ball().radius <= eps:
            continue
        return any(_has_uncovered_part(F, pieces, q + 1, eps, budget)
                   for F in _subtract(R, Q, eps, tidy=False))
    return True


def _box_inside(P: Polyhedron, Q: Polyhedron, tol: float) -> bool:
    """Bounding box of P inside that of Q (necessary for P ⊆ Q)."""
    lo1, hi1 = P.bounding_box()
    lo2, hi2 = Q.bounding_box()
    return bool(np.all(lo1 >= lo2 - tol) and np.all(hi1 <= hi2 + tol))


def _subtract(R: Polyhedron, Q: Polyhedron, eps: float, tidy: bool = True) -> list[Polyhedron]:
    """``R \\ Q`` split along the rows of Q that cut R."""
    if not R.may_intersect(Q) or R.intersect(Q).chebyshev_ball().radius <= eps:
        return [R]
    cutting = np.flatnonzero(R.support_many(Q.A) > Q.b + eps)
    pieces = []
    A, b = R.A, R.b
    for i in cutting:
        outside = Polyhedron(np.vstack([A, -Q.A[i]]), np.append(b, -Q.b[i]))
        if outside.chebyshev_ball().radius > eps:
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
    if not P.may_intersect(Q) or P.intersect(Q).chebyshev_ball().radius < -tol:
        return None  # disjoint: a union of two separated sets is not convex
    p_ok = Q.support_many(P.A) <= P.b + tol
    q_ok = P.support_many(Q.A) <= Q.b + tol
    env = Polyhedron(np.vstack([P.A[p_ok], Q.A[q_ok]]), np.concatenate([P.b[p_ok], Q.b[q_ok]]))
    for a, bi in zip(P.A[~p_ok], P.b[~p_ok]):
        beyond = env.intersect(Polyhedron([-a], [-bi]))
        if not Q.contains_polyhedron(beyond, tol):
            return None
    return env.minimal()


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
