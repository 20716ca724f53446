"""The car-following agent (7.3) and its robust controlled invariant set.

State ``x = [v, h, v_L]`` (ego speed, bumper-to-bumper headway, lead speed),
input ``u = a`` (ego acceleration), disturbance ``d = a_L`` (lead acceleration):

    v+ = v + dt u,   h+ = h + dt (v_L - v),   v_L+ = v_L + dt d,

with ``v_L+`` kept in ``[0, v_max]`` (a lead car does not reverse). Safe set:
``h >= h_min``, ``v, v_L in [0, v_max]``. "No lead car" is ``h = inf``,
``v_L = v_max`` and is handled explicitly: such a state is in the set when
``v in [0, v_max]`` (nothing is ahead; a car can only appear ahead through a
reset, which the responsibility rule (7.5) covers).

``CarFollowingParams(integration="exact")`` moves the cars by constant accelerations over the step instead of
the Euler step (``itha.exact``: a vehicle that moves continuously); the closed-form set, its intervals and the
self-safe inputs then use the exact kinematics and the gap's minimum inside each step. With the default
``"euler"`` everything below is (7.3) as the dissertation states it.

Two representations of the same set, checked against each other in the tests:

* ``MaximalSet``: closed form. The dynamics are monotone (v+ grows with v, u;
  h+ grows with h, v_L and falls with v; v_L+ grows with v_L, d) and the safe set
  is ``h >= h_min``, so the worst disturbance is the hardest lead braking
  (clipped at standstill) and the best input the hardest ego braking. The
  maximal RCIS is therefore ``{x : min_t Φ_t(x) >= h_min}``, with ``Φ_t`` the
  headway after t steps of both cars braking as hard as they may (``Φ_0 = h``).
  Proof sketch: a state outside fails under full braking, and any other input
  sequence keeps the ego faster, so it fails too; a state inside stays inside
  under full braking for every disturbance (the lead is never slower than in the
  worst case). ``min_t Φ_t`` is evaluated exactly at the O(1) candidate times
  where the headway's increment changes sign, so membership is vectorised and
  exact for any time step (used for data at 25 Hz).
* ``PolyhedralSet``: the same set computed by ``rcis`` (outside-in on the
  worst-case PWA system: by monotonicity ``Pre`` of the robust system equals
  ``Pre`` of the deterministic system driven by the hardest lead braking). It
  runs with no erosion margin on a safe set tightened by ``H_TIGHTEN`` so that
  rounding never reaches the real ``h_min``; a converged result is an RCIS.
"""
from __future__ import annotations

import math
from typing import Protocol, runtime_checkable
from dataclasses import asdict, dataclass

import numpy as np

from itha import _kernels, exact
from rcis.cache import RegionCache, code_fingerprint
from rcis.invariant import outside_in
from rcis.polyhedron import Polyhedron
from rcis.pwa import PWAPiece, PWASystem
from rcis.region import Region
from rcis.intervals import merge_intervals

H_TIGHTEN = 1e-6   # the polyhedral set keeps h >= h_min + this (rounding is ~1e-12)
INNER = 1e-9       # input and speed intervals aim this far inside the set, membership tests allow
                   # this much outside: the rounding of a simulated step falls in between
SPEED_BISECTIONS = 48
INPUT_BISECTIONS = 60  # exact integration: the highest self-safe input, to ~1e-17 m/s^2 of U's width
INTEGRATIONS = ("euler", "exact")
AXIS_SHRINK = 1e-7  # m/s: speed intervals of the polyhedral set stay this far from its boundary


@dataclass(frozen=True)
class CarFollowingParams:
    """Bounds of (7.3); defaults are Section 7.4.1's (dt = 0.1 s, U = D = [-10, 10])."""

    dt: float = 0.1
    v_max: float = 30.0
    h_min: float = 5.0
    u_min: float = -10.0
    u_max: float = 10.0
    d_min: float = -10.0
    d_max: float = 10.0
    drag: float = 0.0        # [1/s] ego: v+ = (1 - drag dt) v + dt u (the overtake ego of (6.3): b_e)
    lead_drag: float = 0.0   # [1/s] lead: v_L+ = max((1 - lead_drag dt) v_L + dt d, 0)
    integration: str = "euler"  # "euler": (7.3); "exact": constant accelerations over the step (itha.exact)

    def __post_init__(self):
        for name in ("dt", "v_max", "h_min"):
            if not (getattr(self, name) > 0 and math.isfinite(getattr(self, name))):
                raise ValueError(f"CarFollowingParams.{name} must be positive and finite, got {getattr(self, name)}")
        if not self.u_min < 0 < self.u_max:
            raise ValueError(f"need u_min < 0 < u_max (the ego must be able to brake), got [{self.u_min}, {self.u_max}]")
        if not self.d_min < 0 <= self.d_max:
            raise ValueError(f"need d_min < 0 <= d_max, got [{self.d_min}, {self.d_max}]")
        for name in ("drag", "lead_drag"):
            if not 0 <= getattr(self, name) * self.dt < 1:
                raise ValueError(f"CarFollowingParams.{name} must be in [0, 1/dt), got {getattr(self, name)}")
        if self.integration not in INTEGRATIONS:
            raise ValueError(f"CarFollowingParams.integration must be one of {INTEGRATIONS}, got {self.integration!r}")
        if self.exact and self.has_drag:
            raise ValueError("exact integration is implemented for (7.3) without drag; "
                             f"got drag={self.drag}, lead_drag={self.lead_drag}")

    @property
    def exact(self) -> bool:
        return self.integration == "exact"

    @property
    def has_drag(self) -> bool:
        return self.drag > 0 or self.lead_drag > 0

    @property
    def keep(self) -> float:
        """The share of the ego's speed kept over a step without input, ``1 - drag dt``."""
        return 1.0 - self.drag * self.dt

    def next_speed(self, v, u):
        """The ego's speed after a step with input ``u`` (before the standstill clip)."""
        return self.keep * v + self.dt * u

    @property
    def ego_step(self) -> float:
        """Speed the ego loses per step of full braking."""
        return -self.u_min * self.dt

    @property
    def lead_step(self) -> float:
        """Speed the lead loses per step of full braking."""
        return -self.d_min * self.dt

    def worst_lead_speed(self, vL):
        """The lead's slowest next speed (full braking, stopped at 0)."""
        keep = 1.0 - self.lead_drag * self.dt
        vL = np.asarray(vL, float)
        return np.maximum((keep * vL if self.lead_drag else vL) + self.dt * self.d_min, 0.0)


def _braking_distance(v, a, t):
    """``Σ_{k<t} max(v - k a, 0)`` (speeds summed over t steps of braking by a per step)."""
    n = np.minimum(t, np.ceil(v / a))
    return n * v - a * n * (n - 1) / 2


def _floor_scalar(p: CarFollowingParams, v: float, h: float, vL: float) -> float:
    """``headway_floor`` for one state, in plain floats (the hot path of run-time queries)."""
    ae, aL, dt = p.ego_step, p.lead_step, p.dt

    def dist(s, a, t):
        n = min(t, math.ceil(s / a))
        return n * s - a * n * (n - 1) / 2

    ke, kL = math.ceil(v / ae), math.ceil(vL / aL)
    t1, t_end = min(ke, kL), max(ke, kL)
    cands = [0, t1, t_end]
    if ae > aL:
        cands.append(min(math.ceil(max(v - vL, 0.0) / (ae - aL)), t1))
    return min(h + dt * (dist(vL, aL, t) - dist(v, ae, t)) for t in cands)


def headway_floor(p: CarFollowingParams, v, h, vL):
    """``min_t Φ_t``: the smallest headway when both cars brake as hard as they may.

    Finite speeds in 1-D arrays take the compiled loop (``_kernels.floor``: the same arithmetic in the
    same order, equal bit for bit, tested); anything else the array expression below.
    """
    v, h, vL = (np.asarray(a, float) for a in np.broadcast_arrays(v, h, vL))
    if p.exact:
        shape, flat = _kernels.flat_floats(v, h, vL)
        return exact.floor_many(-p.u_min, -p.d_min, *flat).reshape(shape)
    if p.has_drag:
        out = np.array([_floor(p, a, b, c) for a, b, c in zip(v.ravel(), h.ravel(), vL.ravel())])
        return out.reshape(v.shape)
    if v.ndim == 1 and np.isfinite(v).all() and np.isfinite(vL).all():
        return _kernels.floor_many(p.ego_step, p.lead_step, p.dt, np.ascontiguousarray(v),
                                   np.ascontiguousarray(h), np.ascontiguousarray(vL))
    return _headway_floor_arrays(p, v, h, vL)


def _floor(p: CarFollowingParams, v: float, h: float, vL: float) -> float:
    """``min_t Φ_t`` of one state, compiled: the closed form, the braking sequences with drag, or the least gap
    over all time under exact integration."""
    if p.exact:
        return exact.floor(-p.u_min, -p.d_min, v, h, vL)
    if p.has_drag:
        return _kernels.floor_drag(p.keep, p.ego_step, 1.0 - p.lead_drag * p.dt, p.lead_step, p.dt, v, h, vL)
    return _kernels.floor(p.ego_step, p.lead_step, p.dt, v, h, vL)


def _bisect_speed(p: CarFollowingParams, a: float, b: float, threshold: float, over_lead: bool) -> tuple:
    if p.exact:
        return exact.bisect_speed(-p.u_min, -p.d_min, a, b, threshold, p.v_max, SPEED_BISECTIONS, over_lead)
    if p.has_drag:
        return _kernels._bisect_drag(p.keep, p.ego_step, 1.0 - p.lead_drag * p.dt, p.lead_step, p.dt, a, b,
                                     threshold, p.v_max, SPEED_BISECTIONS, over_lead)
    return _kernels._bisect(p.ego_step, p.lead_step, p.dt, a, b, threshold, p.v_max, SPEED_BISECTIONS, over_lead)


def unsafe_inputs(p: CarFollowingParams, v, h, vL, u) -> np.ndarray:
    """Per recorded point, whether the input is not self-safe (7.4): outside ``U``, or the next state
    under the worst lead (full braking ``d_min``) leaves C (``headway_floor < h_min``), or the lead is
    faster than ``v_max``. ``h = inf``: no lead, only ``U`` and the speed limits apply.

    Compiled (``_kernels.unsafe_inputs``); its referee in the tests is the array expression.
    """
    if p.has_drag:
        raise ValueError("unsafe_inputs checks recorded data against (7.3) without drag")
    shape, flat = _kernels.flat_floats(v, h, vL, u)
    if p.exact:
        return exact.unsafe_inputs(-p.u_min, -p.d_min, p.dt, p.u_min, p.u_max, p.v_max, p.h_min,
                                   *flat).reshape(shape)
    return _kernels.unsafe_inputs(p.ego_step, p.lead_step, p.dt, p.u_min, p.u_max, p.d_min, p.v_max, p.h_min,
                                  *flat).reshape(shape)


def _headway_floor_arrays(p: CarFollowingParams, v, h, vL):
    ae, aL = p.ego_step, p.lead_step
    ke, kL = np.ceil(v / ae), np.ceil(vL / aL)
    t1, t_end = np.minimum(ke, kL), np.maximum(ke, kL)
    cands = [np.zeros_like(v), t1, t_end]
    if ae > aL:  # relative speed rises while both brake: it may turn from - to +
        k_star = np.ceil(np.maximum(v - vL, 0.0) / (ae - aL))
        cands.append(np.minimum(k_star, t1))
    floor = np.full(v.shape, np.inf)
    for t in cands:
        phi = h + p.dt * (_braking_distance(vL, aL, t) - _braking_distance(v, ae, t))
        floor = np.minimum(floor, phi)
    return floor


def _boundary(low_side, top: float) -> tuple[float, float]:
    """Bisection on ``[0, top]`` for a predicate true below a threshold: ``(last true, first false)``."""
    lo, hi = 0.0, top
    for _ in range(SPEED_BISECTIONS):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if low_side(mid) else (lo, mid)
    return lo, hi


@runtime_checkable
class CarFollowingSet(Protocol):
    """What ITHA asks of a car-following RCIS (7.3): the closed form and the computed set both answer it.

    ``contains`` tests states ``(v, h, v_L)`` (rows); the interval methods give, at the other coordinates
    fixed, the ego speeds, lead speeds and ego inputs that keep the state in the set, as unions of intervals.
    """

    kind: str
    params: CarFollowingParams

    def contains(self, X) -> np.ndarray: ...

    def speed_intervals(self, h: float, vL: float) -> list[tuple[float, float]]: ...

    def lead_speed_intervals(self, v: float, h: float) -> list[tuple[float, float]]: ...

    def input_intervals(self, v: float, h_next: float, vL_next: float) -> list[tuple[float, float]]: ...


class MaximalSet:
    """The maximal RCIS of (7.3) in closed form (see the module docstring)."""

    kind = "closed-form"

    def __init__(self, params: CarFollowingParams = CarFollowingParams()):
        self.params = params

    def contains(self, X) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, float))
        p = self.params
        if X.shape == (1, 3):  # one state, as ITHA asks: the compiled floor, the same numbers
            v, h, vL = (float(a) for a in X[0])
            if not (0 <= v <= p.v_max):
                return np.zeros(1, dtype=bool)
            if h == math.inf:
                return np.ones(1, dtype=bool)
            ok = 0 <= vL <= p.v_max and _floor(p, v, h, vL) >= p.h_min
            return np.array([ok])
        v, h, vL = X[:, 0], X[:, 1], X[:, 2]
        ok = (v >= 0) & (v <= p.v_max)
        free = np.isposinf(h)
        hf = np.where(free, 0.0, h)
        lead_ok = (vL >= 0) & (vL <= p.v_max) & (headway_floor(p, v, hf, np.clip(vL, 0, p.v_max)) >= p.h_min)
        return ok & (free | lead_ok)

    def min_lead_speed(self, v: float, h: float) -> float:
        """``inf {v_L in [0, v_max] : (v, h, v_L) in C}``; inf where none is."""
        p = self.params
        if math.isinf(h):
            return 0.0 if 0 <= v <= p.v_max else math.inf
        if not 0 <= v <= p.v_max:
            return math.inf

        def safe(s):  # monotone in s; the compiled floor, equal to _floor_scalar bit for bit
            return _floor(p, float(v), float(h), s) >= p.h_min + INNER

        if safe(0.0):
            return 0.0
        if not safe(p.v_max):
            return math.inf
        return _bisect_speed(p, float(v), float(h), p.h_min + INNER, True)[1]

    def speed_intervals(self, h: float, vL: float) -> list[tuple[float, float]]:
        """Ego speeds v with ``(v, h, vL)`` in C."""
        p = self.params
        if math.isinf(h):
            return [(0.0, p.v_max)]
        if not 0 <= vL <= p.v_max:
            return []

        def safe(s):  # monotone in s; the compiled floor, equal to _floor_scalar bit for bit
            return _floor(p, s, float(h), float(vL)) >= p.h_min + INNER

        if not safe(0.0):
            return []
        if safe(p.v_max):
            return [(0.0, p.v_max)]
        return [(0.0, _bisect_speed(p, float(h), float(vL), p.h_min + INNER, False)[0])]

    def lead_speed_intervals(self, v: float, h: float) -> list[tuple[float, float]]:
        """Lead speeds v_L with ``(v, h, v_L)`` in C."""
        lo = self.min_lead_speed(v, h)
        return [(lo, self.params.v_max)] if lo <= self.params.v_max else []

    def input_intervals(self, v: float, h_next: float, vL_next: float) -> list[tuple[float, float]]:
        """Inputs u in U with ``(v + dt u, h_next, vL_next)`` in C (one interval or none)."""
        _euler_only(self.params, "input_intervals (a next gap that does not depend on the input)")
        return speeds_to_inputs(self.params, v, self.speed_intervals(h_next, vL_next))


class PolyhedralSet:
    """The same RCIS as a union of polyhedra computed by ``rcis`` (outside-in)."""

    kind = "polyhedral"

    def __init__(self, params: CarFollowingParams, region: Region, info: dict):
        self.params = params
        self.region = region
        self.info = info

    def contains(self, X) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, float))
        free = np.isposinf(X[:, 1])
        ok = (X[:, 0] >= 0) & (X[:, 0] <= self.params.v_max)
        finite = np.where(free[:, None], 0.0, X)
        return ok & (free | self.region.contains(finite, tol=INNER))

    def _axis_intervals(self, axis: int, point) -> list[tuple[float, float]]:
        """Speeds (``axis`` 0 or 2) that put ``point`` (other coordinates fixed) in the set.

        Ends inside ``(0, v_max)`` move inwards by ``AXIS_SHRINK`` so that a state
        built from them stays inside after rounding (``contains`` allows ``INNER``).
        """
        vmax = self.params.v_max
        if np.isposinf(point[1]):
            return [(0.0, vmax)]
        out = []
        for lo, hi in merge_intervals(self.region.line_intervals(np.asarray(point, float), axis, tol=INNER)):
            lo = 0.0 if lo <= 0.0 else lo + AXIS_SHRINK
            hi = vmax if hi >= vmax else hi - AXIS_SHRINK
            if lo <= hi:
                out.append((lo, hi))
        return out

    def speed_intervals(self, h: float, vL: float) -> list[tuple[float, float]]:
        return self._axis_intervals(0, (0.0, h, vL))

    def lead_speed_intervals(self, v: float, h: float) -> list[tuple[float, float]]:
        return self._axis_intervals(2, (v, h, 0.0))

    def input_intervals(self, v: float, h_next: float, vL_next: float) -> list[tuple[float, float]]:
        _euler_only(self.params, "input_intervals (a next gap that does not depend on the input)")
        return speeds_to_inputs(self.params, v, self.speed_intervals(h_next, vL_next))


def speeds_to_inputs(p: CarFollowingParams, v: float, speeds) -> list[tuple[float, float]]:
    """Inputs u in U whose next speed ``v + dt u`` lies in one of the speed intervals."""
    out = []
    kv = p.keep * v
    for lo, hi in speeds:
        lo, hi = max(lo, 0.0), min(hi, p.v_max)
        a, b = max(p.u_min, (lo - kv) / p.dt), min(p.u_max, (hi - kv) / p.dt)
        while kv + p.dt * a < lo:  # rounding: the next speed itself must be in the interval
            a = math.nextafter(a, math.inf)
        while kv + p.dt * b > hi:
            b = math.nextafter(b, -math.inf)
        if a <= b:
            out.append((a, b))
    return out


def _euler_only(p: CarFollowingParams, what: str):
    if p.exact:
        raise ValueError(f"{what} is built on (7.3)'s Euler step; these parameters declare exact integration")


def admissible_inputs(S, x) -> list[tuple[float, float]]:
    """Self-safe inputs (7.4) at ``x = (v, h, v_L)``: ``f(x, u, D) ⊆ C`` (under exact integration also the gap
    inside the step: ``_exact_admissible_inputs``)."""
    v, h, vL = (float(a) for a in x)
    p = S.params
    if math.isinf(h):
        return speeds_to_inputs(p, v, [(0.0, p.v_max)])
    if p.exact:
        return _exact_admissible_inputs(S, v, h, vL)
    return S.input_intervals(v, h + p.dt * (vL - v), float(p.worst_lead_speed(vL)))


def _exact_admissible_inputs(S, v: float, h: float, vL: float) -> list[tuple[float, float]]:
    """``[u_min, u*]``: the inputs holding which the gap stays ``>= h_min`` through the step and the next state
    stays in the closed-form set, whatever the lead does (``exact.keeps_set``; monotone in u, so one interval
    found by bisection). Aims ``INNER`` inside the set, like the Euler intervals; full braking from a state in
    the set is always self-safe."""
    p = S.params
    if not isinstance(S, MaximalSet):
        raise ValueError("exact integration has the closed-form set only (MaximalSet)")
    if not (0 <= v <= p.v_max and 0 <= vL <= p.v_max):
        return []
    hi = p.u_max
    while v + p.dt * hi > p.v_max:  # the next speed stays in [0, v_max]
        hi = min(math.nextafter(hi, -math.inf), (p.v_max - v) / p.dt)
    if hi < p.u_min:
        return []
    top = exact.highest_input(-p.u_min, -p.d_min, p.dt, p.v_max, p.h_min + INNER, v, h, vL, p.u_min, hi,
                              INPUT_BISECTIONS)
    if not math.isnan(top):
        return [(p.u_min, top)]
    # Within INNER of the boundary: full braking continues the very trajectory whose least gap is the floor,
    # so from a state in the set it keeps the gap and the next state there (only rounding could say otherwise).
    return [(p.u_min, p.u_min)] if _floor(p, v, h, vL) >= p.h_min else []


# ---- the polyhedral computation ------------------------------------------------------
def _box(lo, hi) -> Polyhedron:
    rows, rhs = [], []
    for i, (a, b) in enumerate(zip(lo, hi)):
        e = np.eye(3)[i]
        if np.isfinite(b):
            rows.append(e)
            rhs.append(b)
        if np.isfinite(a):
            rows.append(-e)
            rhs.append(-a)
    return Polyhedron(np.array(rows), np.array(rhs))


def worst_case_system(p: CarFollowingParams) -> PWASystem:
    """(7.3) driven by the hardest lead braking, stopped at 0: two affine pieces.

    The pieces' closed domains meet at ``v_L = dt |d_min|`` where both maps agree.
    """
    inf, c = np.inf, p.lead_step
    A = np.array([[1.0, 0, 0], [-p.dt, 1, p.dt], [0, 0, 1]])
    B = np.array([[p.dt], [0.0], [0.0]])
    A_stop = A.copy()
    A_stop[2, 2] = 0.0
    no_w, E0 = Polyhedron.from_box([0.0], [0.0]), np.zeros((3, 1))
    pieces = [PWAPiece(_box([-inf, -inf, c], [inf, inf, inf]), A, B, np.array([0, 0, -c]), E0, no_w, label="braking"),
              PWAPiece(_box([-inf, -inf, -inf], [inf, inf, c]), A_stop, B, np.zeros(3), E0, no_w, label="stopped")]
    X = _box([0, -inf, 0], [p.v_max, inf, p.v_max])
    return PWASystem(pieces, Polyhedron.from_box([p.u_min], [p.u_max]), X, name="car-following (worst case)")


def safe_set(p: CarFollowingParams, tighten: float = 0.0) -> Polyhedron:
    return _box([0, p.h_min + tighten, 0], [p.v_max, np.inf, p.v_max])


def compute_polyhedral(p: CarFollowingParams, max_iterations: int = 400, progress=None) -> PolyhedralSet:
    if p.has_drag or p.exact:
        raise ValueError("the polyhedral car-following set is computed for (7.3) without drag and with its Euler "
                         "step; use MaximalSet")
    res = outside_in(worst_case_system(p), Region([safe_set(p, H_TIGHTEN)]), max_iterations=max_iterations,
                     progress=progress, margin=0.0)
    if not res.converged:
        raise RuntimeError(f"car-following outside-in did not converge in {max_iterations} iterations "
                           f"({len(res.region)} pieces); raise max_iterations")
    info = {"iterations": res.iterations, "pieces": len(res.region), "seconds": res.seconds}
    return PolyhedralSet(p, res.region, info)


def load_or_build(p: CarFollowingParams, cache_dir=None, rebuild: bool = False, progress=None,
                  log=None) -> PolyhedralSet:
    """The polyhedral car-following set from the disk cache, or computed and stored.

    Parameters
    ----------
    p : CarFollowingParams
        The model's parameters; the cache key hashes all of them and the code.
    cache_dir : path, optional
        The cache folder (default: ``GUARDIAN_CACHE_DIR`` or the user cache).
    rebuild : bool
        Recompute even when the cache holds the set.
    progress, log : callable, optional
        Iteration progress; cache messages.

    Returns
    -------
    PolyhedralSet
    """
    cache = RegionCache(cache_dir, use_cache=not rebuild, **({"log": log} if log else {}))
    payload = {"set": "car-following", "params": asdict(p), "tighten": H_TIGHTEN, "code": code_fingerprint(__name__)}

    def compute():
        S = compute_polyhedral(p, progress=progress)
        return S.region, S.info

    region, info, _ = cache.get("car-following", payload, compute)
    return PolyhedralSet(p, region, info)


def make_set(p: CarFollowingParams, kind: str = "closed-form", **kw) -> CarFollowingSet:
    """The car-following set of ``p``: ``closed-form`` (``MaximalSet``) or ``polyhedral`` (``load_or_build``).

    Parameters
    ----------
    p : CarFollowingParams
    kind : str
        ``closed-form`` or ``polyhedral``.
    **kw
        Passed to ``load_or_build``.

    Returns
    -------
    CarFollowingSet
    """
    if kind == "closed-form":
        return MaximalSet(p)
    if kind == "polyhedral":
        return load_or_build(p, **kw)
    raise ValueError(f"unknown set kind {kind!r}; choose 'closed-form' or 'polyhedral'")
