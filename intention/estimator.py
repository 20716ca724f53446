"""The LP intention estimator of Section 6.4.2 and the switching rule (6.9).

For intention i, LP_i asks for disturbances ``w(k)`` (which include the
intention's external-input variability ``w_Delta``) over the last N steps such
that each observed transition is the closed-loop PWA dynamics of intention i:

    x(k+1) = A_j x(k) + B u_e(k) + c_j + E w(k),   x(k) in D_j,   w(k) in W.

An intention whose LP is infeasible is invalidated for good; the valid set
never grows (6.9).

How it is decided. The LP's constraint matrix is ``kron(I_N, E)`` and W is a
box per slot, so the window LP is *separable*: it is feasible iff every slot's
own LP is. Older slots were decided when they were written (and a failing
intention is dropped for good), so an update only has to decide the new slot.
When every disturbance column of ``E`` enters one row at most (the overtake
models: ``w_ex``, ``w_ey`` each in one row, ``w_Lx`` and ``w_Delta`` both in
the lead-speed row, none in the headway row), the slot's LP is one interval
test per row: row r is feasible iff ``[res_r - tol, res_r + tol]`` meets
``[sum_j min(E_rj lo_j, E_rj hi_j), sum_j max(...)]``. No solver runs.

HiGHS decides the same LP within its feasibility tolerance (1e-7, on its
scaled model: measured, it accepts a slot up to 1.1e-8 .. 1.1e-7 outside the
exact interval, depending on the row and on its warm start), so the interval
test alone would disagree with it just outside the boundary. Hence three cases:

* inside the exact interval: feasible (HiGHS finds the same point);
* more than ``LP_BAND`` (1e-6) outside: infeasible (beyond any tolerance HiGHS
  applies here; ``tests/intention/test_estimator.py`` measures HiGHS' threshold on each
  row and side);
* in between: the window LP decides, exactly as before (one HiGHS model per
  thread and model shape, shared by every estimator, solved from a cleared
  state), and while such a slot stays in the window every update is decided by
  the window LP, as the old estimator re-solved it at each step.

A model whose ``E`` has a column in two rows is always decided by the window
LP. Either way no estimator owns a solver: an estimator keeps its last N
residuals per intention (a few hundred bytes).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field

import highspy
import numpy as np

from rcis.lp import quiet_highs
from rcis.validate import finite_vector


INF = highspy.kHighsInf
OBSERVATION_TOL = 1e-9  # equality slack for rounding in the observed states
LP_BAND = 1e-6  # a slot this far outside its exact interval, or less, goes to the LP (HiGHS' tolerance)
_SHARED = threading.local()  # per thread: window LPs keyed by model shape (see _shared_lp)
_SHARED_MAX = 64


class _SlidingFeasibilityLP:
    """``exists w(k) in W for k in the window: E w(k) = r(k)`` with r written per slot."""

    def __init__(self, E: np.ndarray, w_lower: np.ndarray, w_upper: np.ndarray, horizon: int, tol: float):
        n_x, n_w = E.shape
        self.n_x, self.n_w, self.N, self.tol = n_x, n_w, horizon, tol
        h = quiet_highs()
        lp = highspy.HighsLp()
        lp.num_col_ = n_w * horizon
        lp.num_row_ = n_x * horizon
        lp.col_cost_ = np.zeros(lp.num_col_)
        lp.col_lower_ = np.tile(w_lower, horizon)
        lp.col_upper_ = np.tile(w_upper, horizon)
        lp.row_lower_ = np.full(lp.num_row_, -INF)  # empty slots constrain nothing
        lp.row_upper_ = np.full(lp.num_row_, INF)
        M = np.kron(np.eye(horizon), E)
        starts, index, value = [0], [], []
        for row in M:
            nz = np.flatnonzero(row)
            index.extend(nz)
            value.extend(row[nz])
            starts.append(len(index))
        lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
        lp.a_matrix_.start_ = np.array(starts, dtype=np.int32)
        lp.a_matrix_.index_ = np.array(index, dtype=np.int32)
        lp.a_matrix_.value_ = np.array(value, dtype=float)
        h.passModel(lp)
        self._h = h
        self._rows = np.arange(lp.num_row_, dtype=np.int32)
        self._lower = np.full(lp.num_row_, -INF)
        self._upper = np.full(lp.num_row_, INF)

    def clear(self) -> None:
        self._lower[:] = -INF
        self._upper[:] = INF

    def write_slot(self, slot: int, residual: np.ndarray) -> None:
        s = slice(slot * self.n_x, (slot + 1) * self.n_x)
        self._lower[s] = residual - self.tol
        self._upper[s] = residual + self.tol

    def feasible(self, fresh: bool = False) -> bool:
        """Solve with the bounds written; ``fresh`` first drops HiGHS' basis (a history-free answer)."""
        self._h.changeRowsBounds(len(self._rows), self._rows, self._lower, self._upper)
        if fresh:
            self._h.clearSolver()
        self._h.run()
        status = self._h.getModelStatus()
        if status == highspy.HighsModelStatus.kOptimal:
            return True
        if status == highspy.HighsModelStatus.kInfeasible:
            return False
        raise RuntimeError(f"intention LP ended with {self._h.modelStatusToString(status)}")


def _shared_lp(E: np.ndarray, lo: np.ndarray, hi: np.ndarray, horizon: int, tol: float) -> _SlidingFeasibilityLP:
    """This thread's window LP for one model shape (built once, reused by every estimator)."""
    pool = getattr(_SHARED, "lps", None)
    if pool is None:
        pool = _SHARED.lps = {}
    key = (E.shape, E.tobytes(), lo.tobytes(), hi.tobytes(), horizon, tol)
    lp = pool.get(key)
    if lp is None:
        if len(pool) >= _SHARED_MAX:
            pool.pop(next(iter(pool)))
        lp = pool[key] = _SlidingFeasibilityLP(E, lo, hi, horizon, tol)
    return lp


class _Intention:
    """One candidate's fixed data: its pieces, ``E``, the box W and (when separable) each row's interval."""

    def __init__(self, name: str, model, tol: float):
        system = model.system
        piece = system.pieces[0]
        self.system = system
        self.pieces = system.pieces
        self.E = np.asarray(piece.E, dtype=float)
        self.lo, self.hi = (np.asarray(v, dtype=float) for v in piece.W._box)
        self.tol = tol
        self.rows = None  # (lower, upper) of E w over W per row, when every column is in one row at most
        if np.all(np.count_nonzero(self.E, axis=0) <= 1):
            lo_terms, hi_terms = self.E * self.lo, self.E * self.hi
            lower, upper = np.minimum(lo_terms, hi_terms).sum(axis=1), np.maximum(lo_terms, hi_terms).sum(axis=1)
            self.rows = list(zip(lower.tolist(), upper.tolist()))

    def residual(self, x: np.ndarray, u: np.ndarray, x_next: np.ndarray) -> np.ndarray:
        piece = self.pieces[self.system.piece_index(x)]
        return x_next - (piece.A @ x + piece.B @ u + piece.c)

    def excess(self, r: np.ndarray) -> float:
        """How far ``[r - tol, r + tol]`` lies outside the rows' intervals (<= 0: feasible exactly)."""
        tol, worst = self.tol, -np.inf
        for value, (lower, upper) in zip(r.tolist(), self.rows):  # four rows: plain floats beat numpy here
            worst = max(worst, lower - (value + tol), (value - tol) - upper)
        return worst


@dataclass
class EstimatorUpdate:
    valid: tuple           # names of the intentions still valid
    invalidated: tuple     # names invalidated by this update
    identified: str | None  # the single remaining intention, if any


@dataclass
class IntentionEstimator:
    """Maintains the valid intentions ``I_v(t+1) = E(xu^t)`` of Definition 16.

    Parameters
    ----------
    models : dict of str to IntentionModel
        The candidate intentions (e.g. ``aggressive`` and ``cautious``); each needs one ``E`` for all
        its pieces and a box disturbance set.
    horizon : int
        N, the number of past transitions each LP_i (6.9) keeps.
    tol : float
        Slack of the feasibility LPs (measurement rounding).
    """

    models: dict  # name -> IntentionModel (the candidate intentions, e.g. aggressive and cautious)
    horizon: int = 10
    tol: float = OBSERVATION_TOL
    valid: list = field(init=False)
    steps: int = field(init=False, default=0)
    identified_at: int | None = field(init=False, default=None)

    def __post_init__(self):
        if self.horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {self.horizon}")
        for name, model in self.models.items():
            E = model.system.pieces[0].E
            if any(not np.array_equal(p.E, E) for p in model.system.pieces):
                raise ValueError(f"intention {name}: the estimator needs one E for all pieces")
            if model.system.pieces[0].W._box is None:
                raise ValueError(f"intention {name}: the estimator needs a box disturbance set")
        self._candidates = {name: _Intention(name, model, self.tol) for name, model in self.models.items()}
        self.reset()

    def reset(self) -> None:
        """Forget the history: every intention is valid again."""
        self.valid = list(self.models)
        self.steps = 0
        self.identified_at = None
        # per intention: the window's residuals (slot = step mod N) and the step until which a
        # slot decided inside HiGHS' tolerance band is in the window (the window LP decides until then)
        self._window = {name: np.zeros((self.horizon, c.E.shape[0])) for name, c in self._candidates.items()}
        self._lp_until = dict.fromkeys(self._candidates, 0)
        self.lp_solves = 0  # window LPs solved (boundary cases and non-separable models), for tests

    def update(self, x, u_e, x_next) -> EstimatorUpdate:
        """Add the transition ``(x(t), u_e(t)) -> x(t+1)`` and decide LP_i for the valid i.

        Parameters
        ----------
        x, x_next : array of 4 floats
            The state before and after the step.
        u_e : array of 2 floats
            The ego input that was applied.

        Returns
        -------
        EstimatorUpdate
            The intentions still valid, those this step invalidated, and the single remaining one.
        """
        x, u_e, x_next = (finite_vector(v, None, f"estimator update: {name}")
                          for v, name in ((x, "x"), (u_e, "u_e"), (x_next, "x_next")))
        slot = self.steps % self.horizon
        self.steps += 1
        invalidated = []
        for name in self.valid:
            if not self._feasible(name, slot, x, u_e, x_next):
                invalidated.append(name)
        # (6.9) keeps an identified intention for good; we keep checking it, so a lead that
        # fits no model empties the valid set (the guardian then falls back to C_bnd).
        remaining = [n for n in self.valid if n not in invalidated]
        self.valid = remaining
        if len(remaining) == 1 and self.identified_at is None:
            self.identified_at = self.steps
        return EstimatorUpdate(tuple(self.valid), tuple(invalidated),
                               self.valid[0] if len(self.valid) == 1 else None)

    def _feasible(self, name: str, slot: int, x, u_e, x_next) -> bool:
        c = self._candidates[name]
        r = c.residual(x, u_e, x_next)
        self._window[name][slot] = r
        if c.rows is not None and self.steps > self._lp_until[name]:
            excess = c.excess(r)
            if excess <= 0.0:
                return True
            if excess > LP_BAND:
                return False
            self._lp_until[name] = self.steps + self.horizon - 1  # this slot leaves the window then
        return self._window_lp(name)

    def _window_lp(self, name: str) -> bool:
        """The window LP of ``name`` over the transitions written so far, solved from a cleared state."""
        c = self._candidates[name]
        lp = _shared_lp(c.E, c.lo, c.hi, self.horizon, self.tol)
        lp.clear()
        for k in range(min(self.steps, self.horizon)):
            lp.write_slot(k, self._window[name][k])
        self.lp_solves += 1
        return lp.feasible(fresh=True)
