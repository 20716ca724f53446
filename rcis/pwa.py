"""Piecewise-affine systems with additive disturbances and their robust Pre.

A piece ``j`` is ``x+ = A_j x + B_j u + c_j + E_j w`` for ``x`` in the domain
``D_j`` and ``w`` in ``W_j``; inputs live in the box ``U``. Domains are closed
polyhedra; rows flagged *strict* are open (``<``), which is how discontinuous
switching surfaces are given one owner (e.g. the reaction zone ``|h| <= h_r``).

``pre`` implements the robust one-step backward reachable set (2.10),

    Pre(T) = {x in X : exists u in U, f(x, u, W) ⊆ T},

for a convex target ``T`` piece by piece: for each PWA piece it is the
projection onto x of ``{(x, u) : x in D_j, u in U, A_j x + B_j u + c_j in T ⊖ E_j W_j}``.
For a union target, the union of the per-piece results is an
under-approximation of Pre, which keeps inside-out iterations sound.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rcis.polyhedron import Polyhedron, box_support
from rcis.tolerances import CERTIFICATE_MARGIN, PIECE_TOL, PRE_MARGIN, RUNTIME_MARGIN  # noqa: F401 (re-exported)



@dataclass(frozen=True)
class PWAPiece:
    """``x+ = A x + B u + c + E w`` on ``domain``, ``w in W``."""

    domain: Polyhedron
    A: np.ndarray
    B: np.ndarray
    c: np.ndarray
    E: np.ndarray
    W: Polyhedron
    strict: np.ndarray = field(default=None)  # bool per domain row: open inequality
    label: str = ""

    def __post_init__(self):
        n = self.domain.dim
        for name, M, shape in (("A", self.A, (n, n)), ("c", self.c, (n,))):
            if np.shape(M) != shape:
                raise ValueError(f"PWAPiece {self.label!r}: {name} has shape {np.shape(M)}, expected {shape}")
        if np.shape(self.B)[0] != n or np.shape(self.E)[0] != n:
            raise ValueError(f"PWAPiece {self.label!r}: B and E need {n} rows")
        if np.shape(self.E)[1] != self.W.dim:
            raise ValueError(f"PWAPiece {self.label!r}: E has {np.shape(self.E)[1]} columns, W has dim {self.W.dim}")
        if self.strict is None:
            object.__setattr__(self, "strict", np.zeros(self.domain.n_constraints, dtype=bool))

    def holds(self, x) -> bool:
        """Is x in this piece's domain (strict rows strict)?"""
        s = self.domain.A @ x - self.domain.b
        return bool(np.all(np.where(self.strict, s < -PIECE_TOL, s <= PIECE_TOL)))

    def closed_domain_shrunk(self, margin: float) -> Polyhedron:
        """The domain with its open rows moved inwards by margin (a closed subset)."""
        return Polyhedron(self.domain.A, self.domain.b - margin * self.strict)

    def image(self, x, u) -> np.ndarray:
        """The nominal successor ``A x + B u + c``."""
        return self.A @ x + self.B @ u + self.c


class PWASystem:
    """A PWA system ``f`` with input box ``U`` on state domain ``X``.

    ``successor_box`` (optional, ``(lower, upper)``) is a box that every
    successor is known to lie in for every state, input and disturbance (e.g.
    the lead car's speed bounds, which the intention models respect by
    construction). Target constraints implied by it need no robustness margin
    and are left out of Pre; ``check_successor_box`` verifies the claim.

    Parameters
    ----------
    pieces : sequence of PWAPiece
        ``x+ = A_j x + B_j u + c_j + E_j w`` on the domain of piece j (the domains tile ``state_set``).
    input_set : Polyhedron
        U.
    state_set : Polyhedron
        X, the domain of the system.
    successor_box : (lower, upper), optional
    name : str
    """

    def __init__(self, pieces, input_set: Polyhedron, state_set: Polyhedron,
                 successor_box=None, name: str = ""):
        self.pieces: list[PWAPiece] = list(pieces)
        if not self.pieces:
            raise ValueError("PWASystem needs at least one piece")
        self.input_set = input_set
        self.state_set = state_set
        self.successor_box = successor_box
        self.name = name
        self.n_x = state_set.dim
        self.n_u = input_set.dim
        for p in self.pieces:
            if p.domain.dim != self.n_x or np.shape(p.B)[1] != self.n_u:
                raise ValueError(f"piece {p.label!r} does not match n_x={self.n_x}, n_u={self.n_u}")
        # every domain row at once, so piece_index is one matrix-vector product
        self._domain_A = np.vstack([p.domain.A for p in self.pieces])
        self._domain_b = np.concatenate([p.domain.b for p in self.pieces])
        self._domain_strict = np.concatenate([p.strict for p in self.pieces])
        self._domain_owner = np.repeat(np.arange(len(self.pieces)), [p.domain.n_constraints for p in self.pieces])
        self._domain_boxes: dict = {}  # (within, margin) -> per piece, the box of D_j ⊖ margin ∩ X ∩ within

    def __repr__(self) -> str:
        return f"PWASystem({self.name!r}, pieces={len(self.pieces)})"

    # ---- simulation ----------------------------------------------------
    def piece_index(self, x) -> int:
        """The first piece whose domain holds x (``PWAPiece.holds``: strict rows strict)."""
        x = np.asarray(x, dtype=float)
        s = self._domain_A @ x - self._domain_b
        broken = np.where(self._domain_strict, ~(s < -PIECE_TOL), ~(s <= PIECE_TOL))  # NaN breaks a row
        missed = np.zeros(len(self.pieces), dtype=bool)
        missed[self._domain_owner[broken]] = True
        j = int(np.argmin(missed))
        if not missed[j]:
            return j
        raise ValueError(f"{self.name}: state {x.tolist()} lies in no piece's domain")

    def step(self, x, u, w) -> np.ndarray:
        """``f(x, u, w)`` with the piece that owns x.

        Parameters
        ----------
        x, u, w : array
            State, input and disturbance.

        Returns
        -------
        ndarray
            The successor state.
        """
        x = np.asarray(x, dtype=float)
        p = self.pieces[self.piece_index(x)]
        return p.image(x, np.asarray(u, dtype=float)) + p.E @ np.asarray(w, dtype=float)

    def successor_vertices(self, x, u) -> np.ndarray:
        """Successors for every vertex of the piece's disturbance set (one per row)."""
        x = np.asarray(x, dtype=float)
        p = self.pieces[self.piece_index(x)]
        W_vertices, _ = p.W.generators()
        return p.image(x, np.asarray(u, dtype=float)) + W_vertices @ p.E.T

    # ---- robust Pre ----------------------------------------------------
    def _robust_target_rows(self, piece: PWAPiece, target: Polyhedron, margin: float):
        """Rows ``G z <= g`` that the nominal successor z must satisfy for all w."""
        G, g = target.A, target.b
        if self.successor_box is not None:
            implied = Polyhedron.from_box(*self.successor_box).support_many(G) <= g + 1e-12
            G, g = G[~implied], g[~implied]
        g = g - piece.W.support_many(G @ piece.E) - margin
        return G, g

    def lifted_pre(self, j: int, target: Polyhedron, within: Polyhedron | None = None,
                   margin: float = PRE_MARGIN, rows=None) -> Polyhedron:
        """``{(x, u) : x in D_j ∩ X ∩ within, u in U, f_j(x, u, W_j) ⊆ target ⊖ margin}``.

        ``rows``: ``_robust_target_rows(piece j, target, margin)`` when the caller has them.
        """
        p = self.pieces[j]
        G, g = rows if rows is not None else self._robust_target_rows(p, target, margin)
        nx, nu = self.n_x, self.n_u
        blocks_A = [np.hstack([G @ p.A, G @ p.B])]
        blocks_b = [g - G @ p.c]
        dom = p.closed_domain_shrunk(margin)
        for S in (dom, self.state_set) + ((within,) if within is not None else ()):
            blocks_A.append(np.hstack([S.A, np.zeros((S.n_constraints, nu))]))
            blocks_b.append(S.b)
        U = self.input_set
        blocks_A.append(np.hstack([np.zeros((U.n_constraints, nx)), U.A]))
        blocks_b.append(U.b)
        return Polyhedron(np.vstack(blocks_A), np.concatenate(blocks_b))

    def pre(self, target: Polyhedron, within: Polyhedron | None = None,
            margin: float = PRE_MARGIN, min_radius: float = 1e-6) -> list[Polyhedron]:
        """Robust Pre (2.10) of a convex target, one polyhedron per PWA piece.

        Pieces without interior (Chebyshev radius <= min_radius) are dropped,
        which only shrinks the result.

        Parameters
        ----------
        target : Polyhedron
            The convex target set.
        within : Polyhedron, optional
            Intersect the result with it (saves projecting what would be cut away).
        margin : float
            The target is eroded by this much (``PRE_MARGIN``: the result errs inside).
        min_radius : float

        Returns
        -------
        list of Polyhedron
            ``{x in X_j : exists u in U, f_j(x, u, w) in target for all w in W_j}``, one per piece j.
        """
        out = []
        inputs = np.arange(self.n_x, self.n_x + self.n_u)
        for j in range(len(self.pieces)):
            rows = self._robust_target_rows(self.pieces[j], target, margin)
            if self._misses_target(j, rows, within, margin):
                continue
            lifted = self.lifted_pre(j, target, within, margin, rows)
            if lifted.chebyshev_ball().radius <= min_radius:
                continue
            P = lifted.eliminate(inputs)
            if P.chebyshev_ball().radius > min_radius:
                out.append(P)
        return out

    def _misses_target(self, j: int, rows, within: Polyhedron | None, margin: float) -> bool:
        """No state of piece j's domain box and input of U's box reaches some robust target row.

        ``rows``: ``_robust_target_rows(piece j, target, margin)``.

        A test without an LP that the lifted set of ``lifted_pre`` is empty: the lowest value of one
        row ``G_i (A_j x + B_j u + c_j)`` over the boxes exceeds its bound by ``CERTIFICATE_MARGIN``.
        """
        lo, hi = self._domain_box(j, within, margin)
        if np.any(lo > hi):
            return True
        p = self.pieces[j]
        G, g = rows
        ulo, uhi = self.input_set.bounding_box()
        M = np.hstack([G @ p.A, G @ p.B])
        low, high = np.concatenate([lo, ulo]), np.concatenate([hi, uhi])
        least = -box_support(-M, low, high) + G @ p.c  # the lowest value of each row over the boxes
        return bool(np.any(least > g + CERTIFICATE_MARGIN))

    def _domain_box(self, j: int, within: Polyhedron | None, margin: float):
        key = (None if within is None else (within.A.tobytes(), within.b.tobytes()), margin)
        if key not in self._domain_boxes:
            boxes = []
            for p in self.pieces:
                region = p.closed_domain_shrunk(margin).intersect(self.state_set)
                boxes.append((region if within is None else region.intersect(within)).bounding_box())
            self._domain_boxes[key] = boxes
        return self._domain_boxes[key][j]

    # ---- checks ----------------------------------------------------------
    def check_successor_box(self, tol: float = 1e-9) -> list[str]:
        """Problems with the successor-box claim (empty list when it holds)."""
        if self.successor_box is None:
            return []
        lo, hi = self.successor_box
        problems = []
        box = Polyhedron.from_box(lo, hi)
        for p in self.pieces:
            # Over (x, u, w) in (D ∩ X ∩ box) x U x W, each successor coordinate stays in the box.
            dom = p.domain.intersect(self.state_set).intersect(box)
            n, m, k = self.n_x, self.n_u, p.W.dim
            lifted = Polyhedron(
                np.vstack([np.hstack([dom.A, np.zeros((dom.n_constraints, m + k))]),
                           np.hstack([np.zeros((self.input_set.n_constraints, n)), self.input_set.A,
                                      np.zeros((self.input_set.n_constraints, k))]),
                           np.hstack([np.zeros((p.W.n_constraints, n + m)), p.W.A])]),
                np.concatenate([dom.b, self.input_set.b, p.W.b]))
            M = np.hstack([p.A, p.B, p.E])
            for i in range(n):
                if np.isfinite(hi[i]):
                    top = lifted.support(M[i]) + p.c[i]
                    if top > hi[i] + tol:
                        problems.append(f"piece {p.label}: coordinate {i} reaches {top} > {hi[i]}")
                if np.isfinite(lo[i]):
                    bottom = -lifted.support(-M[i]) + p.c[i]
                    if bottom < lo[i] - tol:
                        problems.append(f"piece {p.label}: coordinate {i} reaches {bottom} < {lo[i]}")
        return problems
