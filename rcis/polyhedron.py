"""Convex polyhedra in H-representation, ``P = {x : A x <= b}``, possibly unbounded.

Every operation that the invariant-set algorithms need lives here, named after
the math: intersection, affine preimage, robust tightening (the Pontryagin
difference ``P ⊖ E W``), projection by Fourier-Motzkin elimination, redundancy
removal, Chebyshev ball and containment.

Floating point policy: whenever rounding could make a computed set larger than
the exact one, we move the error inwards (derived right-hand sides are lowered
by a few ulps of their magnitude). Redundancy removal drops a row only when an
LP shows it is implied to within ``REDUNDANCY_TOL``, far below the margins the
set computations keep (``rcis.pwa.PRE_MARGIN``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rcis.lp import InequalityLP
from rcis.tolerances import (  # noqa: F401 (re-exported)
    CERTIFICATE_MARGIN, CHEBYSHEV_CAP, FM_ROUNDING, GENERATOR_TOL, INCLUSION_TOL, REDUNDANCY_TOL, ROW_NORM_EPS)



def box_support(D: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """``max d^T x`` over the box ``lower <= x <= upper`` for each row d of D (infinite bounds allowed)."""
    with np.errstate(invalid="ignore"):
        return np.where(D > 0, D * upper, np.where(D < 0, D * lower, 0.0)).sum(axis=1)


@dataclass(frozen=True)
class ChebyshevBall:
    center: np.ndarray | None
    radius: float  # < 0 when the polyhedron is empty, 0 when it has no interior


class Polyhedron:
    """``{x in R^n : A x <= b}`` with unit-norm rows.

    Construction normalises rows; a zero row with negative right-hand side
    makes the polyhedron empty (kept as the single row ``0 x <= -1``).

    Parameters
    ----------
    A : array of shape (m, n)
        Finite.
    b : array of shape (m,)
        Finite, or ``+inf`` for a row that constrains nothing (dropped).
    """

    __slots__ = ("A", "b", "_box", "_bbox", "_ball", "_points", "_deep")

    def __init__(self, A, b):
        A = np.atleast_2d(np.asarray(A, dtype=float))
        b = np.asarray(b, dtype=float).reshape(-1)
        if A.shape[0] != b.shape[0]:
            raise ValueError(f"A has {A.shape[0]} rows but b has {b.shape[0]} entries")
        if not (np.isfinite(A).all() and (np.isfinite(b) | (b == np.inf)).all()):
            raise ValueError("Polyhedron: A must be finite and b finite or +inf")
        keep = b < np.inf
        if not keep.all():
            A, b = A[keep], b[keep]
        norms = np.linalg.norm(A, axis=1)
        zero = norms < ROW_NORM_EPS
        if not zero.any():
            A, b = A / norms[:, None], b / norms
        elif np.any(b[zero] < 0):
            A, b = np.zeros((1, A.shape[1])), np.array([-1.0])
        else:
            A, b = A[~zero] / norms[~zero, None], b[~zero] / norms[~zero]
        self.A = A
        self.b = b
        self._box = None
        self._bbox = None
        self._ball = None  # the Chebyshev ball at the default cap, computed once (A and b never change)
        self._points = None  # the bounding box's LP maximisers: points of P, for cheap support bounds
        self._deep = None  # a point with a ball thicker than some eps inside P (found by ``has_ball``)

    # ---- constructors -------------------------------------------------
    @classmethod
    def from_box(cls, lower, upper) -> "Polyhedron":
        """``{x : lower <= x <= upper}``; infinite bounds are left out."""
        lower = np.asarray(lower, dtype=float)
        upper = np.asarray(upper, dtype=float)
        if lower.shape != upper.shape or lower.ndim != 1:
            raise ValueError("from_box: lower and upper must be 1-D of equal length")
        if np.any(np.isnan(lower)) or np.any(np.isnan(upper)):
            raise ValueError("from_box: NaN bound")
        n = lower.size
        eye = np.eye(n)
        A = np.vstack([eye, -eye])
        b = np.concatenate([upper, -lower])
        P = cls(A, b)
        P._box = (lower.copy(), upper.copy())
        return P

    @classmethod
    def _of_unit_rows(cls, A: np.ndarray, b: np.ndarray) -> "Polyhedron":
        """Rows already unit-norm and finite (taken from other polyhedra): no checks, no normalising."""
        P = cls.__new__(cls)
        P.A, P.b = A, b
        P._box = P._bbox = P._ball = P._points = P._deep = None
        return P

    def _is_empty_marker(self) -> bool:
        return self.A.shape[0] == 1 and self.b[0] == -1.0 and not self.A.any()

    @classmethod
    def universe(cls, n: int) -> "Polyhedron":
        return cls(np.zeros((0, n)), np.zeros(0))

    @property
    def dim(self) -> int:
        return self.A.shape[1]

    @property
    def n_constraints(self) -> int:
        return self.A.shape[0]

    def __repr__(self) -> str:
        return f"Polyhedron(dim={self.dim}, constraints={self.n_constraints})"

    # ---- membership ---------------------------------------------------
    def contains(self, X, tol: float = 1e-9):
        """Membership of one point (1-D) or many points (rows of a 2-D array).

        Parameters
        ----------
        X : array of shape (n,) or (k, n)
        tol : float
            ``A x <= b + tol`` counts as inside (``MEMBERSHIP_TOL`` and its policy: ``rcis.tolerances``).

        Returns
        -------
        bool or array of bool
        """
        X = np.asarray(X, dtype=float)
        single = X.ndim == 1
        X2 = np.atleast_2d(X)
        if X2.shape[1] != self.dim:
            raise ValueError(f"points have dimension {X2.shape[1]}, polyhedron has {self.dim}")
        inside = np.all(X2 @ self.A.T <= self.b + tol, axis=1)
        return bool(inside[0]) if single else inside

    # ---- LP-based queries ---------------------------------------------
    def support(self, direction) -> float:
        """``h_P(d) = max_{x in P} d^T x`` (+inf if unbounded, -inf if empty)."""
        d = np.asarray(direction, dtype=float)
        if self._box is not None:
            return float(box_support(d[None, :], *self._box)[0])
        return InequalityLP(self.A, self.b).maximize(d).value

    def support_many(self, directions) -> np.ndarray:
        """Support function for each row of ``directions`` (one model, many costs)."""
        D = np.atleast_2d(np.asarray(directions, dtype=float))
        if self._box is not None:
            return box_support(D, *self._box)
        lp = InequalityLP(self.A, self.b)
        return np.array([lp.maximize(d).value for d in D])

    def chebyshev_ball(self, radius_cap: float = CHEBYSHEV_CAP) -> ChebyshevBall:
        """Largest ball ``{c + r u : |u| <= 1}`` inside P (rows are unit norm)."""
        if radius_cap == CHEBYSHEV_CAP and self._ball is not None:
            c, r = self._ball
            return ChebyshevBall(None if c is None else c.copy(), r)
        ball = self._chebyshev_lp(radius_cap)
        if radius_cap == CHEBYSHEV_CAP:
            self._ball = (None if ball.center is None else ball.center.copy(), ball.radius)
        return ball

    def _chebyshev_lp(self, radius_cap: float) -> ChebyshevBall:
        m, n = self.A.shape
        A = np.hstack([self.A, np.ones((m, 1))])
        upper = np.full(n + 1, np.inf)
        upper[n] = radius_cap
        res = InequalityLP(A, self.b, upper=upper).maximize(np.eye(n + 1)[n])
        if res.status != "optimal":
            return ChebyshevBall(None, -1.0)
        return ChebyshevBall(res.x[:n], float(res.x[n]))

    def is_empty(self) -> bool:
        return self.chebyshev_ball().radius < -1e-9

    def is_fulldim(self, eps: float = 1e-7) -> bool:
        return self.chebyshev_ball().radius > eps

    def contains_polyhedron(self, Q: "Polyhedron", tol: float = INCLUSION_TOL) -> bool:
        """``Q ⊆ self``: every row of self bounds Q (empty Q is contained)."""
        if self.n_constraints == 0:
            return True
        if Q._bbox is not None and np.any(Q._bbox[0] > Q._bbox[1]):
            return True  # Q is empty
        lower, upper = Q.support_bounds(self.A)
        if np.any(lower > self.b + tol + CERTIFICATE_MARGIN):
            return False  # a point of Q lies outside a row (and Q is not empty)
        undecided = ~(upper <= self.b + tol - CERTIFICATE_MARGIN)
        if not np.any(undecided):
            return True
        lp = InequalityLP(Q.A, Q.b)
        for a, bi in zip(self.A[undecided], self.b[undecided]):
            res = lp.maximize(a)
            if res.status == "infeasible":
                return True
            if res.value > bi + tol:
                return False
        return True

    def bounding_box(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` per coordinate (infinite where unbounded); cached."""
        if self._bbox is None:
            eye = np.eye(self.dim)
            D = np.vstack([eye, -eye])
            if self._box is not None:
                values = self.support_many(D)
            else:
                lp = InequalityLP(self.A, self.b)
                results = [lp.maximize(d) for d in D]
                values = np.array([r.value for r in results])
                points = [r.x for r in results if r.x is not None]
                self._points = np.array(points) if points else None
            self._bbox = (-values[self.dim:], values[:self.dim])
        return self._bbox

    # ---- cheap certificates (no LP) ---------------------------------
    def known_points(self) -> np.ndarray:
        """Points known to lie in P (to LP accuracy) without solving anything new: the Chebyshev
        centre, a deep point, the bounding box's maximisers, whichever have been computed."""
        pts = [p for p in (self._ball[0] if self._ball else None, self._deep) if p is not None]
        if self._points is not None:
            pts.extend(self._points)
        return np.array(pts) if pts else np.zeros((0, self.dim))

    def interior_point(self):
        """A point of P with a ball around it inside P, if one is known (else None; no LP)."""
        if self._ball is not None and self._ball[1] > 0:
            return self._ball[0]
        return self._deep

    def support_bounds(self, directions) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` bounds on ``h_P(d)`` for each row d, without an LP.

        Below: the best known point of P (``known_points``; -inf if none). Above: the bounding box
        (+inf until it is computed).
        """
        D = np.atleast_2d(np.asarray(directions, dtype=float))
        pts = self.known_points()
        lower = (D @ pts.T).max(axis=1) if len(pts) else np.full(len(D), -np.inf)
        box = self._box if self._box is not None else self._bbox
        if box is None:
            return lower, np.full(len(D), np.inf)
        return lower, box_support(D, *box)

    def exceeds(self, directions, limits) -> np.ndarray:
        """``h_P(d_i) > limits_i`` for each row ``d_i`` of ``directions``.

        ``support_bounds`` decide the rows they clear by ``CERTIFICATE_MARGIN``; an LP decides the rest,
        so the answer is ``support_many(directions) > limits`` up to the LP's error.
        """
        D = np.atleast_2d(np.asarray(directions, dtype=float))
        limits = np.broadcast_to(np.asarray(limits, dtype=float), (len(D),))
        lower, upper = self.support_bounds(D)
        out = lower > limits + CERTIFICATE_MARGIN
        undecided = ~out & ~(upper <= limits - CERTIFICATE_MARGIN)
        if np.any(undecided):
            out[undecided] = self.support_many(D[undecided]) > limits[undecided]
        return out

    def has_ball(self, eps: float, hints=()) -> bool:
        """The Chebyshev radius exceeds ``eps``.

        A hint point whose slack in every row exceeds ``eps`` by ``CERTIFICATE_MARGIN`` proves it
        without an LP (and is remembered as a deep point); otherwise the Chebyshev LP decides.
        """
        if self._ball is None:
            for p in hints:
                if p is None:
                    continue
                slack = np.min(self.b - self.A @ p) if self.n_constraints else np.inf
                if slack > eps + CERTIFICATE_MARGIN:
                    self._deep = p
                    return True
        return self.chebyshev_ball().radius > eps

    def may_intersect(self, Q: "Polyhedron", tol: float = 1e-7) -> bool:
        """False when the bounding boxes are apart (then P ∩ Q is empty)."""
        lo1, hi1 = self.bounding_box()
        lo2, hi2 = Q.bounding_box()
        return bool(np.all(lo1 <= hi2 + tol) and np.all(lo2 <= hi1 + tol))

    # ---- set operations ----------------------------------------------
    def intersect(self, Q: "Polyhedron") -> "Polyhedron":
        if Q.dim != self.dim:
            raise ValueError(f"intersect: dimensions {self.dim} and {Q.dim}")
        A, b = np.vstack([self.A, Q.A]), np.concatenate([self.b, Q.b])
        if self._is_empty_marker() or Q._is_empty_marker():
            return Polyhedron(A, b)
        return Polyhedron._of_unit_rows(A, b)

    def preimage(self, M, t=None) -> "Polyhedron":
        """``{z : M z + t in P}``: rows ``A M z <= b - A t``."""
        M = np.atleast_2d(np.asarray(M, dtype=float))
        t = np.zeros(self.dim) if t is None else np.asarray(t, dtype=float)
        return Polyhedron(self.A @ M, self.b - self.A @ t)

    def robust_tighten(self, E, W: "Polyhedron") -> "Polyhedron":
        """Pontryagin difference ``P ⊖ E W = {z : z + E w in P for all w in W}``.

        Row i becomes ``a_i z <= b_i - h_W(E^T a_i)``.

        Parameters
        ----------
        E : array of shape (n, p)
        W : Polyhedron
            The disturbance set in ``R^p``; bounded along every row direction, else ``ValueError``.

        Returns
        -------
        Polyhedron
        """
        E = np.atleast_2d(np.asarray(E, dtype=float))
        shift = W.support_many(self.A @ E)
        if np.any(~np.isfinite(shift)):
            raise ValueError("robust_tighten: the disturbance set is unbounded along a constraint")
        return Polyhedron(self.A, self.b - shift)

    def shrink(self, margin: float) -> "Polyhedron":
        """``{x : A x <= b - margin}`` (rows have unit norm: a margin-ball erosion)."""
        return Polyhedron(self.A, self.b - margin)

    def slice(self, dims, values) -> "Polyhedron":
        """Fix coordinates ``dims`` to ``values``; the result lives in the others."""
        dims = np.atleast_1d(dims)
        keep = np.setdiff1d(np.arange(self.dim), dims)
        b = self.b - self.A[:, dims] @ np.asarray(values, dtype=float)
        return Polyhedron(self.A[:, keep], b)

    # ---- redundancy and projection -----------------------------------
    def minimal(self) -> "Polyhedron":
        """Remove redundant rows: duplicates, box-implied rows, a dual-hull pre-filter, then one LP per row.

        The pre-filter (``_dual_hull_filter``) drops rows whose dual points are not hull vertices, each
        one confirmed by an LP over the kept rows only, so the ``REDUNDANCY_TOL`` guarantee stands.
        """
        A, b = _dedupe(self.A, self.b)
        keep = _not_implied_by_axis_bounds(A, b)
        A, b = A[keep], b[keep]
        filtered = _dual_hull_filter(A, b)
        if filtered is not None:
            return Polyhedron(*filtered)
        m = A.shape[0]
        if m <= 1:
            return Polyhedron(A, b)
        lp = InequalityLP(A, b)
        kept = np.ones(m, dtype=bool)
        for i in range(m):
            lp.set_row_bound(i, b[i] + 1.0)
            res = lp.maximize(A[i])
            if res.status == "infeasible":
                return Polyhedron(np.zeros((1, self.dim)), np.array([-1.0]))
            if res.status == "optimal" and res.value <= b[i] + REDUNDANCY_TOL:
                lp.relax_row(i)
                kept[i] = False
            else:
                lp.restore_row(i)
        return Polyhedron(A[kept], b[kept])

    def eliminate(self, dims) -> "Polyhedron":
        """Project out coordinates ``dims`` (Fourier-Motzkin, pruning after each).

        The result lives in the remaining coordinates, in their original order.
        """
        dims = sorted(np.atleast_1d(dims).tolist(), reverse=True)
        P = self.minimal()
        for k in dims:
            P = _fourier_motzkin(P.A, P.b, k).minimal()
        return P

    def project(self, keep) -> "Polyhedron":
        """Orthogonal projection onto coordinates ``keep`` (in increasing order).

        Fourier-Motzkin elimination of the others, redundant rows removed after each step; derived
        right-hand sides are lowered by ``FM_ROUNDING``, so rounding can only shrink the result.

        Parameters
        ----------
        keep : sequence of int

        Returns
        -------
        Polyhedron
            In the coordinates ``keep``.
        """
        drop = np.setdiff1d(np.arange(self.dim), np.atleast_1d(keep))
        return self.eliminate(drop)

    # ---- V-representation --------------------------------------------
    def generators(self):
        """Vertices and rays ``(V, R)`` with ``P = conv(V) + cone(R)``: complete, or an error.

        A box gives its corners exactly. Otherwise cddlib (float) proposes generators and the answer
        is checked against LPs, the referee:

        - bounded P: ``conv(V) ⊆ P`` (each vertex satisfies ``A v <= b`` to ``GENERATOR_TOL``) and
          ``P ⊆ conv(V)``: every facet ``n^T x <= d`` of ``conv(V)`` (and both sides of each equation of
          its affine hull) has ``h_P(n) <= d + GENERATOR_TOL``. A facet that fails adds the LP's
          maximiser, a vertex of P that cddlib missed, and the hull is checked again, so an
          incomplete or inconsistent float answer is repaired (or, after ``max_rounds``, raises);
        - unbounded P: the support of ``conv(V) + cone(R)`` must equal the LP's in every row
          direction, both directions of every axis and 64 fixed random directions; a mismatch raises
          ``ArithmeticError`` (checked, not proved: a cone has no finite facet test here).

        Lines are returned as pairs of opposite rays. Never calls cddlib's canonicalize, which can
        abort the process on float input.
        """
        if self._box is not None and np.all(np.isfinite(self._box[0])) and np.all(np.isfinite(self._box[1])):
            return _box_corners(*self._box), np.zeros((0, self.dim))
        if self.n_constraints == 0:
            eye = np.eye(self.dim)
            return np.zeros((1, self.dim)), np.vstack([eye, -eye])
        if self.is_empty():
            return np.zeros((0, self.dim)), np.zeros((0, self.dim))
        try:
            V, R = self._cdd_generators()
        except (RuntimeError, ValueError):  # "numerical inconsistency": retry without redundant rows,
            try:                            # then start from LP maximisers
                V, R = self.minimal()._cdd_generators()
            except (RuntimeError, ValueError):
                V, R = np.zeros((0, self.dim)), None
        lo, hi = self.bounding_box()
        if np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)):
            return _complete_vertices(self, V), np.zeros((0, self.dim))
        if R is None:
            raise ArithmeticError("cddlib failed on an unbounded polyhedron; no verified fallback for cones")
        if V.shape[0] == 0:  # cddlib lists a cone {A x <= 0} by its rays alone: its apex is the origin
            V = np.zeros((1, self.dim)) if self.contains(np.zeros(self.dim)) else self.chebyshev_ball().center[None]
        _check_unbounded_generators(self, V, R)
        return V, R

    def _cdd_generators(self):
        import cdd

        mat = cdd.matrix_from_array(np.hstack([self.b[:, None], -self.A]).tolist(),
                                    rep_type=cdd.RepType.INEQUALITY)
        gens = cdd.copy_generators(cdd.polyhedron_from_matrix(mat))
        G = np.array(gens.array, dtype=float).reshape(-1, self.dim + 1)
        lines = sorted(gens.lin_set)
        is_vertex = G[:, 0] > 0.5
        vertices = G[is_vertex, 1:] / G[is_vertex, :1]
        rays = G[~is_vertex, 1:]
        if lines:
            rays = np.vstack([rays, -G[lines, 1:]])
        return vertices, rays




def _box_corners(lo, hi) -> np.ndarray:
    n = lo.size
    bits = (np.arange(2 ** n)[:, None] >> np.arange(n)[None, :]) & 1
    return np.where(bits == 1, hi, lo).astype(float)


def _hull_inequalities(V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``N x <= d`` that describe ``conv(V)`` (facets, and both sides of its affine hull)."""
    from scipy.spatial import ConvexHull, QhullError

    n = V.shape[1]
    c = V.mean(axis=0)
    _, sing, Vt = np.linalg.svd(V - c, full_matrices=True)
    scale = max(1.0, float(np.abs(V).max()))
    k = int(np.sum(sing > 1e-9 * scale))
    U, N_eq = Vt[:k].T, Vt[k:]
    rows = [N_eq, -N_eq]
    rhs = [N_eq @ c, -(N_eq @ c)]
    Z = (V - c) @ U
    if k == 1:
        rows += [U.T, -U.T]
        rhs += [np.array([Z.max()]) + U.T @ c, np.array([-Z.min()]) - U.T @ c]
    elif k >= 2:
        try:
            hull = ConvexHull(Z)  # merged facets: coplanar simplices share one equation
        except QhullError:  # nearly degenerate points: joggle; the offsets below are recomputed exactly
            try:
                hull = ConvexHull(Z, qhull_options="QJ")
            except QhullError as exc:
                raise ArithmeticError(f"qhull failed on {len(V)} candidate vertices: {exc}") from exc
        facet_normals = np.unique(np.round(hull.equations[:, :k], 12), axis=0)
        normals = facet_normals @ U.T
        rows.append(normals)
        rhs.append((V @ normals.T).max(axis=0))  # each facet's offset, exact for the points themselves
    return np.vstack(rows).reshape(-1, n), np.concatenate(rhs)


def _merge_close(V: np.ndarray, tol: float) -> np.ndarray:
    """One point per cluster of points closer than ``tol`` in every coordinate (grid snapping)."""
    _, first = np.unique(np.round(V / tol), axis=0, return_index=True)
    return V[np.sort(first)]


def _complete_vertices(P: "Polyhedron", V: np.ndarray, max_rounds: int = 64,
                       max_points: int = 20_000) -> np.ndarray:
    """The vertices of bounded P: ``V`` checked and repaired until ``conv(V) = P`` (see generators)."""
    from rcis.lp import InequalityLP

    lp = InequalityLP(P.A, P.b)
    V = V[P.contains(V, tol=GENERATOR_TOL)] if V.size else V
    if V.shape[0] == 0:  # nothing usable from cddlib: start from the maximisers along the axes
        eye = np.eye(P.dim)
        V = np.array([_polished_vertex(P, lp.maximize(d).x, d) for d in np.vstack([eye, -eye])])
    scale = max(1.0, float(np.abs(V).max()))
    for _ in range(max_rounds):
        V = _merge_close(V, 1e-9 * scale)  # near-duplicates (degenerate vertices) would blow the hull up
        if V.shape[0] > max_points:
            raise ArithmeticError(f"vertex enumeration: more than {max_points} candidate vertices")
        N, d = _hull_inequalities(V)
        missing = []
        for normal, offset in zip(N, d):
            res = lp.maximize(normal)
            if res.value > offset + GENERATOR_TOL * max(1.0, abs(offset)):
                missing.append(_polished_vertex(P, res.x, normal))
        if not missing:
            return _hull_vertices(V)
        V = np.unique(np.vstack([V, missing]), axis=0)
    raise ArithmeticError(f"vertex enumeration did not close after {max_rounds} repair rounds")


def _polished_vertex(P: "Polyhedron", x: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """A point of P (to ``GENERATOR_TOL``) at the LP maximiser ``x`` of ``direction``.

    HiGHS' maximiser may violate a row by its feasibility tolerance, which is relative to the scaled
    model (3.6e-6 on one shipped piece with nearly parallel rows); a vertex must lie in P. In order:
    ``x`` itself; the solution of the n linearly independent rows with the smallest slack at ``x``;
    the maximiser re-solved with 1e-9 feasibility tolerances; else this raises.
    """
    if P.contains(x, tol=GENERATOR_TOL):
        return x
    slack = np.abs(P.b - P.A @ x)
    rows: list[int] = []
    for i in np.argsort(slack, kind="stable"):
        if np.linalg.matrix_rank(P.A[rows + [int(i)]], tol=1e-9) == len(rows) + 1:
            rows.append(int(i))
            if len(rows) == P.dim:
                break
    if len(rows) == P.dim:
        v = np.linalg.solve(P.A[rows], P.b[rows])
        if P.contains(v, tol=GENERATOR_TOL) and np.abs(v - x).max() <= 1e-3 * max(1.0, float(np.abs(x).max())):
            return v
    res = InequalityLP(P.A, P.b, feasibility_tol=1e-9).maximize(direction)
    if res.status == "optimal" and P.contains(res.x, tol=GENERATOR_TOL):
        return res.x
    raise ArithmeticError(f"an LP maximiser lies outside the polyhedron by {float((P.A @ x - P.b).max())!r}, "
                          "and neither its active rows nor a tighter LP give a point inside")


def _hull_vertices(V: np.ndarray) -> np.ndarray:
    """The extreme points among V (drops points cddlib or the LPs gave on edges or faces)."""
    from scipy.spatial import ConvexHull, QhullError

    if V.shape[0] <= V.shape[1]:
        return V
    c = V.mean(axis=0)
    _, sing, Vt = np.linalg.svd(V - c, full_matrices=False)
    k = int(np.sum(sing > 1e-9 * max(1.0, float(np.abs(V).max()))))
    if k < 2:
        if k == 0:
            return V[:1]
        z = (V - c) @ Vt[0]
        return V[[int(np.argmin(z)), int(np.argmax(z))]]
    try:
        return V[ConvexHull((V - c) @ Vt[:k].T, qhull_options="Qt").vertices]
    except QhullError:
        return V


def _check_unbounded_generators(P: "Polyhedron", V: np.ndarray, R: np.ndarray) -> None:
    if V.size and not np.all(P.contains(V, tol=GENERATOR_TOL)):
        raise ArithmeticError("cddlib returned a vertex outside the polyhedron")
    if R.size and np.any(R @ P.A.T > GENERATOR_TOL * np.linalg.norm(R, axis=1)[:, None]):
        raise ArithmeticError("cddlib returned a ray outside the recession cone")
    eye = np.eye(P.dim)
    D = np.vstack([P.A, eye, -eye, np.random.default_rng(0).normal(size=(64, P.dim))])
    lp_support = P.support_many(D)
    ray_reach = (D @ R.T > 1e-9).any(axis=1) if R.size else np.zeros(len(D), dtype=bool)
    gen_support = np.where(ray_reach, np.inf, (D @ V.T).max(axis=1) if V.size else -np.inf)
    both_inf = np.isinf(lp_support) & np.isinf(gen_support) & (np.sign(lp_support) == np.sign(gen_support))
    with np.errstate(invalid="ignore"):
        gap = np.where(both_inf, 0.0, np.abs(lp_support - gen_support))
    bad = ~(gap <= GENERATOR_TOL * np.maximum(1.0, np.abs(np.where(np.isfinite(lp_support), lp_support, 0.0))))
    if np.any(bad):
        i = int(np.argmax(bad))
        raise ArithmeticError(f"incomplete generators: in direction {np.round(D[i], 6).tolist()} the LP support is "
                              f"{lp_support[i]!r}, the generators give {gen_support[i]!r}")


def _dedupe(A: np.ndarray, b: np.ndarray):
    """Keep one row per direction (the tightest)."""
    if A.shape[0] <= 1:
        return A, b
    key = np.round(A, 10)
    order = np.lexsort(np.vstack([b, key.T[::-1]]))
    key, A, b = key[order], A[order], b[order]
    first = np.ones(A.shape[0], dtype=bool)
    first[1:] = np.any(key[1:] != key[:-1], axis=1)
    return A[first], b[first]


_CERTIFICATE_TRIES = 16  # coplanar simplices tried per dropped row before an LP decides


def _dual_hull_filter(A: np.ndarray, b: np.ndarray):
    """The facets of a bounded full-dimensional P, found from one hull; None when it does not apply.

    With c strictly inside a bounded P (its Chebyshev centre), ``P - c = {y : p_i^T y <= 1}`` for the
    dual points ``p_i = a_i / (b_i - a_i^T c)``, and row i is a facet iff ``p_i`` is a vertex of
    ``conv{p_j}``. Every other row is dropped only with a certificate that it is implied to
    ``REDUNDANCY_TOL`` by the kept rows (``_implied_by_hull``, an LP where that fails), so a wrong
    hull can cost speed, never the set. Kept rows are hull vertices: facets, up to rounding, and a
    nearly redundant row kept changes nothing but the row count.
    """
    from scipy.spatial import ConvexHull, QhullError

    m, n = A.shape
    if n < 2 or m < n + 2:
        return None
    ball = Polyhedron(A, b).chebyshev_ball()
    if ball.center is None or not 1e-6 < ball.radius < CHEBYSHEV_CAP / 2:
        return None
    slack = b - A @ ball.center
    try:
        hull = ConvexHull(A / slack[:, None])
    except (QhullError, ValueError):
        return None
    if not np.all(hull.equations[:, -1] < -1e-12):
        return None  # the origin is not inside the dual hull: P is unbounded
    kept = np.zeros(m, dtype=bool)
    kept[hull.vertices] = True
    dropped = np.flatnonzero(~kept)
    if dropped.size == 0:
        return A, b
    proven = _implied_by_hull(A, b, slack, ball.center, hull, dropped, kept)
    lp = InequalityLP(A[kept], b[kept])
    for i in dropped[~proven]:
        res = lp.maximize(A[i])
        if res.status != "optimal" or res.value > b[i] + REDUNDANCY_TOL:
            return None  # the hull missed a facet (rounding): the full LP pass decides
    return A[kept], b[kept]


def _implied_by_hull(A, b, slack, c, hull, dropped, kept) -> np.ndarray:
    """Which dropped rows carry a Farkas certificate from the hull of the dual points.

    The ray from the origin through an interior dual point ``p_i`` leaves the hull through a simplex
    ``S`` at ``t_i p_i`` (``t_i >= 1``), so ``p_i = sum_j lambda_j p_j`` over ``j in S`` with
    ``lambda >= 0`` and ``sum lambda = 1/t_i <= 1``. In the original rows this is
    ``a_i = sum_j nu_j a_j + r`` with ``nu_j = slack_i lambda_j / slack_j >= 0``, hence for every x in
    the kept rows' polyhedron ``a_i^T x <= sum_j nu_j b_j + r^T c + |r|_1 max|x - c|_inf``; the row is
    proven implied when that bound is at most ``b_i + REDUNDANCY_TOL``. Everything is evaluated on
    the data, not on the hull's facet equations, so an inexact hull cannot fake a certificate.
    Coplanar simplices (qhull triangulates non-simplicial facets) tie on ``t``; the nearest few are
    tried in order.
    """
    points = A / slack[:, None]
    t, order = _ray_exits(hull, points[dropped])
    reach_box = None
    proven = np.zeros(len(dropped), dtype=bool)
    for rank in range(order.shape[1]):
        rows = np.flatnonzero(~proven)
        if rows.size == 0:
            break
        facet = order[rows, rank]
        t_exit = t[rows, facet]
        simplex = hull.simplices[facet]
        live = np.isfinite(t_exit) & (t_exit >= 1.0 - 1e-9) & np.all(kept[simplex], axis=1)
        if not np.any(live):
            break
        rows, t_exit, simplex = rows[live], t_exit[live], simplex[live]
        if reach_box is None:
            reach_box = _hull_reach(points, hull, kept)
            if not np.isfinite(reach_box):
                reach_box = _kept_radius(A[kept], b[kept], c)
        proven[rows] = _certified(A, b, points, slack, c, dropped[rows], simplex, t_exit, reach_box)
    return proven


def _ray_exits(hull, X: np.ndarray):
    """Rays from the origin along the rows of X: ``t[k, f]``, where ray k leaves through hull facet f
    (inf where it never does), and each ray's facets nearest first (up to ``_CERTIFICATE_TRIES``)."""
    n = X.shape[1]
    normals, offsets = hull.equations[:, :n], hull.equations[:, n]
    reach = X @ normals.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(reach > 0, -offsets / reach, np.inf)
    return t, np.argsort(t, axis=1)[:, :_CERTIFICATE_TRIES]


def _on_simplices(points, simplex, targets):
    """``mu`` with ``targets[k] = sum_j mu[k, j] points[simplex[k, j]]``, and which simplices were
    solvable (a singular one gets a placeholder solve and ``usable`` False)."""
    M = np.transpose(points[simplex], (0, 2, 1))
    det = np.linalg.det(M)
    usable = np.isfinite(det) & (np.abs(det) > 1e-300)
    M[~usable] = np.eye(M.shape[1])
    return np.linalg.solve(M, targets[..., None])[..., 0], usable


def _certified(A, b, points, slack, c, rows, simplex, t_exit, reach_box) -> np.ndarray:
    """The certificate test of ``_implied_by_hull`` for rows ``rows`` against their simplices."""
    mu, usable = _on_simplices(points, simplex, t_exit[:, None] * points[rows])
    usable &= np.all(mu >= -1e-9, axis=1)
    lam = np.maximum(mu, 0.0) / t_exit[:, None]
    nu = slack[rows][:, None] * lam / slack[simplex]
    residual = A[rows] - np.einsum("kj,kjn->kn", nu, A[simplex])
    with np.errstate(invalid="ignore"):
        bound = np.einsum("kj,kj->k", nu, b[simplex]) + residual @ c + np.abs(residual).sum(axis=1) * reach_box
    return usable & (lam.sum(axis=1) <= 1.0 + 1e-9) & (bound <= b[rows] + REDUNDANCY_TOL)


def _hull_reach(points, hull, kept) -> float:
    """An upper bound on ``max |y|_inf`` over ``{y : p_j^T y <= 1, j kept}`` from the hull (no LP).

    Along each axis direction d the ray from the origin leaves the hull through a simplex S at
    ``t d = sum_j mu_j p_j + r`` (``mu >= 0``, r the residual evaluated on the data); for y in the set,
    ``t d^T y <= sum mu + |r|_1 R`` with ``R = max |y|_inf``, hence ``R <= alpha / (1 - beta)`` with
    ``alpha = max (sum mu) / t`` and ``beta = max |r|_1 / t``. inf when a direction finds no usable
    simplex (the caller then solves the LPs).
    """
    n = points.shape[1]
    D = np.vstack([np.eye(n), -np.eye(n)])
    t, order = _ray_exits(hull, D)
    alpha = np.full(len(D), np.inf)
    beta = np.full(len(D), np.inf)
    for rank in range(order.shape[1]):
        rows = np.flatnonzero(~np.isfinite(alpha))
        if rows.size == 0:
            break
        facet = order[rows, rank]
        t_exit = t[rows, facet]
        simplex = hull.simplices[facet]
        live = np.isfinite(t_exit) & (t_exit > 0) & np.all(kept[simplex], axis=1)
        rows, t_exit, simplex = rows[live], t_exit[live], simplex[live]
        if rows.size == 0:
            continue
        mu, usable = _on_simplices(points, simplex, t_exit[:, None] * D[rows])
        mu = np.maximum(mu, 0.0)
        residual = t_exit[:, None] * D[rows] - np.einsum("kj,kjn->kn", mu, points[simplex])
        ok = usable & np.isfinite(mu).all(axis=1)
        alpha[rows[ok]] = mu[ok].sum(axis=1) / t_exit[ok]
        beta[rows[ok]] = np.abs(residual[ok]).sum(axis=1) / t_exit[ok]
    a, bt = alpha.max(), beta.max()
    return float(a / (1.0 - bt)) if np.isfinite(a) and bt < 0.5 else np.inf


def _kept_radius(A: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """``max |x - c|_inf`` over ``A x <= b`` (2n LPs; inf when unbounded)."""
    lp = InequalityLP(A, b)
    reach = 0.0
    for direction in np.vstack([np.eye(len(c)), -np.eye(len(c))]):
        res = lp.maximize(direction)
        if res.status != "optimal":
            return np.inf
        reach = max(reach, res.value - direction @ c)
    return reach


def _not_implied_by_axis_bounds(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mask of rows that the axis-aligned rows alone do not imply."""
    m, n = A.shape
    nonzero = np.abs(A) > ROW_NORM_EPS
    axis = nonzero.sum(axis=1) == 1
    rows = np.flatnonzero(axis)
    j = np.argmax(nonzero[rows], axis=1)
    coef = A[rows, j]
    bound = b[rows] / coef
    upper = np.full(n, np.inf)
    lower = np.full(n, -np.inf)
    np.minimum.at(upper, j[coef > 0], bound[coef > 0])
    np.maximum.at(lower, j[coef < 0], bound[coef < 0])
    box_max = box_support(A, lower, upper)
    implied = (~axis) & (box_max <= b + REDUNDANCY_TOL)
    return ~implied


def _fourier_motzkin(A: np.ndarray, b: np.ndarray, k: int) -> Polyhedron:
    """Eliminate coordinate k from ``A x <= b`` (no pruning)."""
    col = A[:, k]
    pos, neg = col > ROW_NORM_EPS, col < -ROW_NORM_EPS
    zero = ~(pos | neg)
    Ap, bp = A[pos] / col[pos, None], b[pos] / col[pos]
    An, bn = A[neg] / -col[neg, None], b[neg] / -col[neg]
    comb_A = (Ap[:, None, :] + An[None, :, :]).reshape(-1, A.shape[1])
    comb_b = (bp[:, None] + bn[None, :]).reshape(-1)
    scale = (np.abs(bp)[:, None] + np.abs(bn)[None, :]).reshape(-1) + 1.0
    comb_b = comb_b - FM_ROUNDING * scale
    newA = np.vstack([A[zero], comb_A])
    newb = np.concatenate([b[zero], comb_b])
    return Polyhedron(np.delete(newA, k, axis=1), newb)
