"""Every numerical tolerance of the engine, in one place, and which side each one errs on.

A safety set must never contain a state it cannot keep safe, so every tolerance that decides what a
*computed set* is errs on the inside (the set may lose a sliver, never gain one); the tolerances
that only *judge* a point or an input are far smaller than those margins, so judging cannot undo
them.

Sets shrink, never grow:
- ``PRE_MARGIN``: robust Pre is computed against the target eroded by this much.
- ``RUNTIME_MARGIN``: run-time admissible inputs use a smaller erosion than Pre, so every state of a
  computed set has an admissible input (the set was built with the larger margin).
- ``FM_ROUNDING``: Fourier-Motzkin lowers derived right-hand sides by this relative amount, so float
  error in projection can only shrink it (lower-dimensional sets may vanish; they carry no volume).
- ``SLIVER_EPS``: a piece whose inscribed ball is thinner is dropped as empty (an inner approximation).
- ``FIXED_POINT_EPS``: outside-in stops only when ``C_k`` lies in ``C_{k+1}`` to this, far below the margin.

Judging, far below the margins:
- ``MEMBERSHIP_TOL``: ``A x <= b + tol`` in the falsifier (points on a boundary count as inside, as
  rounding; the set's own margin is 1e-6, so this cannot admit a state the margin excludes).
- ``PIECE_TOL``: which PWA piece owns a state on a closed switching boundary.
- ``BOUNDS_ROUNDING``: an input this close outside ``U`` is rounding; more is a bug and raises.

Exact up to a stated error (the same set, not a smaller one):
- ``REDUNDANCY_TOL``: a row is dropped only if the LP proves it implied to this (1e-10).
- ``INCLUSION_TOL``: ``Q ⊆ P`` when every row of P bounds Q to this (1e-7, HiGHS' feasibility).
- ``GENERATOR_TOL``: vertices lie in P, and P in their hull, to this (1e-6 absolute on unit rows).
- ``CERTIFICATE_MARGIN``: a comparison an LP would decide (a support value against a bound, a
  Chebyshev radius against ``eps``) is decided without the LP only when a cheap bound (a point known to
  lie in the set, the bounding box) clears it by this much, far above the LP's own error; closer calls
  go to the LP, so the answer is the LP's.

Numbers, not sets:
- ``ROW_NORM_EPS``: a row with a smaller norm is the constant constraint ``0 <= b``.
- ``CHEBYSHEV_CAP``: radius cap so unbounded polyhedra get a finite Chebyshev ball.
"""
PRE_MARGIN = 1e-6
RUNTIME_MARGIN = 5e-7
FM_ROUNDING = 4e-15
SLIVER_EPS = 1e-6
FIXED_POINT_EPS = 1e-9

MEMBERSHIP_TOL = 1e-9
PIECE_TOL = 1e-9
BOUNDS_ROUNDING = 1e-9

REDUNDANCY_TOL = 1e-10
INCLUSION_TOL = 1e-7
GENERATOR_TOL = 1e-6
CERTIFICATE_MARGIN = 1e-5

ROW_NORM_EPS = 1e-12
CHEBYSHEV_CAP = 1e4
