"""The LP intention estimator of Section 6.4.2 and the switching rule (6.9).

For intention i, LP_i asks for disturbances ``w(k)`` (which include the
intention's external-input variability ``w_Delta``) over the last N steps such
that each observed transition is the closed-loop PWA dynamics of intention i:

    x(k+1) = A_j x(k) + B u_e(k) + c_j + E w(k),   x(k) in D_j,   w(k) in W.

The matrix ``E`` is the same in every piece, so the LP's constraint matrix is
fixed: one HiGHS model per intention is built once, with a slot of rows per
step of the horizon, and each update only rewrites the bounds of one slot
(``x(k+1) - A_j x(k) - B u_e(k) - c_j``) and re-solves. An intention whose LP
is infeasible is invalidated for good; the valid set never grows (6.9).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import highspy
import numpy as np

from rcis.lp import quiet_highs
from rcis.validate import finite_vector


INF = highspy.kHighsInf
OBSERVATION_TOL = 1e-9  # equality slack for rounding in the observed states


class _SlidingFeasibilityLP:
    """``exists w(k) in W for k in the window: E w(k) = r(k)`` with r written per slot."""

    def __init__(self, E: np.ndarray, w_lower: np.ndarray, w_upper: np.ndarray, horizon: int, tol: float):
        self._args = (E, w_lower, w_upper, horizon, tol)
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

    def __getstate__(self) -> dict:
        """The constructor's arguments and the window's row bounds (a HiGHS model cannot be pickled)."""
        return {"args": self._args, "lower": self._lower, "upper": self._upper}

    def __setstate__(self, state: dict) -> None:
        """A fresh HiGHS model with the same rows; the window's bounds are written at the next solve."""
        self.__init__(*state["args"])
        self._lower[:], self._upper[:] = state["lower"], state["upper"]

    def clear(self) -> None:
        self._lower[:] = -INF
        self._upper[:] = INF

    def write_slot(self, slot: int, residual: np.ndarray) -> None:
        s = slice(slot * self.n_x, (slot + 1) * self.n_x)
        self._lower[s] = residual - self.tol
        self._upper[s] = residual + self.tol

    def feasible(self) -> bool:
        self._h.changeRowsBounds(len(self._rows), self._rows, self._lower, self._upper)
        self._h.run()
        status = self._h.getModelStatus()
        if status == highspy.HighsModelStatus.kOptimal:
            return True
        if status == highspy.HighsModelStatus.kInfeasible:
            return False
        raise RuntimeError(f"intention LP ended with {self._h.modelStatusToString(status)}")


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
        self._lps = {}
        self.reset()

    def reset(self) -> None:
        """Forget the history: every intention is valid again (the LP models are kept)."""
        self.valid = list(self.models)
        self.steps = 0
        self.identified_at = None
        for name, model in self.models.items():
            if name not in self._lps:
                piece = model.system.pieces[0]
                lo, hi = (np.asarray(v) for v in piece.W._box)
                self._lps[name] = _SlidingFeasibilityLP(piece.E, lo, hi, self.horizon, self.tol)
            self._lps[name].clear()

    def update(self, x, u_e, x_next) -> EstimatorUpdate:
        """Add the transition ``(x(t), u_e(t)) -> x(t+1)`` and re-solve LP_i for the valid i.

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
        for name in list(self.valid):
            system = self.models[name].system
            piece = system.pieces[system.piece_index(x)]
            lp = self._lps[name]
            lp.write_slot(slot, x_next - piece.image(x, u_e))
            if not lp.feasible():
                invalidated.append(name)
        # (6.9) keeps an identified intention for good; we keep checking it, so a lead that
        # fits no model empties the valid set (the guardian then falls back to C_bnd).
        remaining = [n for n in self.valid if n not in invalidated]
        self.valid = remaining
        if len(remaining) == 1 and self.identified_at is None:
            self.identified_at = self.steps
        return EstimatorUpdate(tuple(self.valid), tuple(invalidated),
                               self.valid[0] if len(self.valid) == 1 else None)
