"""Linear programs over ``{x : A x <= b}`` solved with HiGHS directly.

scipy's ``linprog`` costs about 1 ms per call here; building the HiGHS model
once and re-solving it after changing the cost or one row bound costs about
0.1 ms, which is what the set computations need (thousands of LPs per set).
"""
from __future__ import annotations

import functools
import threading
from dataclasses import dataclass

import highspy
import numpy as np

from rcis.errors import LPError

INF = highspy.kHighsInf
_STATUS = highspy.HighsModelStatus
_DEFAULT_TOL = 1e-7  # HiGHS' primal and dual feasibility tolerances
_POOL = threading.local()  # per thread: Highs objects of dropped LPs, reused (creating one costs ~60 µs)
_POOL_SIZE = 32


def quiet_highs():
    """A HiGHS solver that prints nothing.

    highspy's ``Highs`` (1.16) enables its Python callbacks in its constructor, and the first time in
    a process that prints HiGHS' banner on stdout, where a service's or a ``--json`` command's output
    goes. We use no callbacks, so the core class is taken where highspy has one.
    """
    core = getattr(getattr(highspy, "_core", None), "_Highs", None)
    h = core() if core is not None else highspy.Highs()
    h.setOptionValue("output_flag", False)
    return h


def _solver():
    free = getattr(_POOL, "free", None)
    if free:
        return free.pop()
    h = quiet_highs()
    h.setOptionValue("presolve", "off")
    return h


def _release(h, tuned: bool) -> None:
    """Back to this thread's pool with the options every LP starts from (passModel replaces the model)."""
    if tuned:
        h.setOptionValue("primal_feasibility_tolerance", _DEFAULT_TOL)
        h.setOptionValue("dual_feasibility_tolerance", _DEFAULT_TOL)
    h.setOptionValue("presolve", "off")  # _retry may have left presolve or the interior-point solver on
    h.setOptionValue("solver", "choose")
    free = _POOL.__dict__.setdefault("free", [])
    if len(free) < _POOL_SIZE:
        h.clearSolver()
        free.append(h)


_BOX = 1e9  # the bounding box of the last retry (InequalityLP._within_box)
_ROWWISE = int(highspy.MatrixFormat.kRowwise)
_MAXIMIZE = int(highspy.ObjSense.kMaximize)


@functools.lru_cache(maxsize=512)
def _rowwise_pattern(m: int, n: int):
    """Row starts and column indices of a dense m x n matrix stored row-wise."""
    start = np.arange(0, m * n + 1, n, dtype=np.int32)
    index = np.tile(np.arange(n, dtype=np.int32), m)
    start.flags.writeable = index.flags.writeable = False
    return start, index


@dataclass(frozen=True)
class LPResult:
    status: str  # "optimal" | "infeasible" | "unbounded"
    value: float  # objective value of the maximisation (+inf when unbounded, -inf when infeasible)
    x: np.ndarray | None


class InequalityLP:
    """``maximize c^T x  s.t.  A x <= b`` with the model kept between solves.

    ``lower``/``upper`` bound the variables (default free). Rows may be
    switched off and on (``relax_row``/``restore_row``) and the cost changed,
    which is what redundancy removal and support-function queries need.
    """

    def __init__(self, A: np.ndarray, b: np.ndarray, lower=None, upper=None, feasibility_tol: float | None = None):
        A = np.ascontiguousarray(A, dtype=float)
        b = np.asarray(b, dtype=float)
        m, n = A.shape
        self.m, self.n = m, n
        self._b = b.copy()
        self._h = _solver()
        self._tuned = feasibility_tol is not None
        if feasibility_tol is not None:  # HiGHS' default is 1e-7 on the scaled model
            self._h.setOptionValue("primal_feasibility_tolerance", feasibility_tol)
            self._h.setOptionValue("dual_feasibility_tolerance", feasibility_tol)
        start, index = _rowwise_pattern(m, n)
        col_lower = np.full(n, -INF) if lower is None else np.asarray(lower, float)
        col_upper = np.full(n, INF) if upper is None else np.asarray(upper, float)
        self._col_bounds = (col_lower, col_upper)
        # the array form of passModel (a HighsLp object costs ~25 µs more to fill); no integer columns
        self._h.passModel(n, m, m * n, _ROWWISE, _MAXIMIZE, 0.0, np.zeros(n), col_lower, col_upper,
                          np.full(m, -INF), b.copy(), start, index, A.ravel(), np.zeros(n, dtype=np.int32))
        self._cols = np.arange(n, dtype=np.int32)

    def __del__(self):
        h = getattr(self, "_h", None)
        if h is not None:
            _release(h, self._tuned)

    def maximize(self, c: np.ndarray) -> LPResult:
        self._h.changeColsCost(self.n, self._cols, np.asarray(c, dtype=float))
        return self._solve()

    def relax_row(self, i: int) -> None:
        self._h.changeRowBounds(int(i), -INF, INF)

    def set_row_bound(self, i: int, upper: float) -> None:
        self._h.changeRowBounds(int(i), -INF, float(upper))

    def restore_row(self, i: int) -> None:
        self._h.changeRowBounds(int(i), -INF, float(self._b[i]))

    def _solve(self) -> LPResult:
        self._h.run()
        status = self._h.getModelStatus()
        result = self._decided(status)
        return result if result is not None else self._retry(status)

    def _decided(self, status) -> LPResult | None:
        """The result for a status HiGHS decided (None when it could not decide)."""
        if status == _STATUS.kOptimal:
            sol = np.array(self._h.getSolution().col_value)
            return LPResult("optimal", self._h.getObjectiveValue(), sol)
        if status in (_STATUS.kUnbounded,):
            return LPResult("unbounded", np.inf, None)
        if status in (_STATUS.kInfeasible,):
            return LPResult("infeasible", -np.inf, None)
        if status == _STATUS.kUnboundedOrInfeasible:
            # Decide with a zero objective: feasible means the LP was unbounded.
            self._h.changeColsCost(self.n, self._cols, np.zeros(self.n))
            self._h.run()
            if self._h.getModelStatus() == _STATUS.kOptimal:
                return LPResult("unbounded", np.inf, None)
            return LPResult("infeasible", -np.inf, None)
        return None

    def _retry(self, status) -> LPResult:
        """Re-solve a model HiGHS could not decide: with presolve, then interior point.

        The answer is read from the run that decided it (re-running with the default options could
        fail again the same way), then the options are put back.
        """
        try:
            for option, value in (("presolve", "on"), ("solver", "ipm")):
                self._h.setOptionValue(option, value)
                self._h.clearSolver()
                self._h.run()
                status = self._h.getModelStatus()
                result = self._decided(status)
                if result is not None:
                    return result
        finally:
            self._h.setOptionValue("presolve", "off")
            self._h.setOptionValue("solver", "choose")
        result = self._within_box()
        if result is not None:
            return result
        raise LPError(f"HiGHS returned {self._h.modelStatusToString(status)} "
                      f"on a {self.m}x{self.n} LP, also with presolve, interior point and a bounding box")

    def _within_box(self) -> LPResult | None:
        """Last resort (HiGHS 1.16 answers "Unknown" on some unbounded LPs): solve inside ``|x_i| <= BOX``.

        An optimum off the box's faces is the LP's own (the box is inactive there); an optimum on a
        face means the cost improves up to the box: reported unbounded. A finite optimum beyond
        ``BOX`` in some coordinate would be misread as unbounded; the engine's sets live within
        ``|x| <= 1e4``. Infeasible inside the box decides nothing (None).
        """
        lower, upper = self._col_bounds
        boxed_lower, boxed_upper = np.maximum(lower, -_BOX), np.minimum(upper, _BOX)
        self._h.changeColsBounds(self.n, self._cols, boxed_lower, boxed_upper)
        try:
            self._h.clearSolver()
            self._h.run()
            if self._h.getModelStatus() != _STATUS.kOptimal:
                return None
            x = np.array(self._h.getSolution().col_value)
            on_face = ((np.abs(x - boxed_lower) <= _BOX * 1e-9) & (boxed_lower > lower)) | \
                      ((np.abs(x - boxed_upper) <= _BOX * 1e-9) & (boxed_upper < upper))
            if np.any(on_face):
                return LPResult("unbounded", np.inf, None)
            return LPResult("optimal", self._h.getObjectiveValue(), x)
        finally:
            self._h.changeColsBounds(self.n, self._cols, lower, upper)
            self._h.clearSolver()


def maximize(c, A, b, lower=None, upper=None) -> LPResult:
    """One-shot ``max c^T x s.t. A x <= b``."""
    return InequalityLP(A, b, lower, upper).maximize(c)
