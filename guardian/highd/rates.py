"""Calibration and override rates on ITHA data (Section 7.4.3): the disturbance bounds from training data,
the car-following RCIS they give, and the self-safety, responsibility and RSS rates on test data
(``guardian.highd.replay`` says which points and lane changes form each rate)."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from guardian.highd.convert import ITHAData
from itha.car_following import CarFollowingParams, MaximalSet, unsafe_inputs
from itha.responsibility import EgoSupervisor
from itha.road import HighwayParams
from itha.rss import RSSParams, cut_in_safe, longitudinal_violations

SPEED_BANDS = (0.0, 20.0, 30.0, math.inf)  # m/s: context = (lane, speed band)


@dataclass(frozen=True)
class ReplayConfig:
    """Open choices of Section 7.4.3 (documented in the README with their sensitivity)."""

    seed: int = 0
    test_fraction: float = 0.2
    quantiles: tuple = (0.025, 0.975)
    h_min: float = 2.0      # m, bumper to bumper
    u_min: float = -6.0     # m/s^2, the ego's input bounds U
    u_max: float = 4.0
    v_max: float = 60.0     # m/s; a speed above it is refused as outside the model
    input_bounds: str = "fixed"  # "fixed": U = [u_min, u_max]; "data": the training inputs' order statistics
    plausibility: bool = True    # the reader's plausibility rules (schema.PLAUSIBILITY); off: --no-plausibility
    frame_step: int = 1          # every k-th frame: the data at frameRate / k (the time step is an open choice)

    def __post_init__(self):
        if self.input_bounds not in ("fixed", "data"):
            raise ValueError(f"input_bounds must be 'fixed' or 'data', got {self.input_bounds!r}")
        if not 0 < self.test_fraction < 1:
            raise ValueError(f"test_fraction must be in (0, 1), got {self.test_fraction}")
        if not self.u_min < 0 < self.u_max:  # as CarFollowingParams: the ego must be able to brake
            raise ValueError(f"need u_min < 0 < u_max, got u_min {self.u_min}, u_max {self.u_max}")
        if not (isinstance(self.frame_step, int) and self.frame_step >= 1):
            raise ValueError(f"frame_step must be a whole number >= 1, got {self.frame_step!r}")
        for name in ("h_min", "v_max"):
            if not 0 < getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be positive and finite, got {getattr(self, name)}")


# ---- calibration and evaluation --------------------------------------------------------------------
def order_statistic_bounds(d: np.ndarray, quantiles) -> tuple[float, float]:
    """``[d_(⌈q_lo N⌉), d_(⌈q_hi N⌉)]`` (1-based order statistics)."""
    if len(d) == 0:
        raise ValueError("no lead-disturbance samples in the training split (no car follows another)")
    n = len(d)
    ks = [min(max(math.ceil(q * n), 1), n) - 1 for q in quantiles]
    part = np.partition(d, ks)
    return float(part[ks[0]]), float(part[ks[1]])


def car_following_params(cfg: ReplayConfig, dt: float, bounds, u_bounds=None) -> CarFollowingParams:
    lo, hi = bounds
    u_lo, u_hi = (cfg.u_min, cfg.u_max) if u_bounds is None else u_bounds
    return CarFollowingParams(dt=dt, v_max=cfg.v_max, h_min=cfg.h_min, u_min=min(u_lo, -1e-3),
                              u_max=max(u_hi, 1e-3), d_min=min(lo, -1e-6), d_max=max(hi, 0.0))


@dataclass
class Training:
    """What calibration needs from the training split."""

    d: np.ndarray
    d_ctx: np.ndarray | None = None
    u: np.ndarray | None = None
    u_ctx: np.ndarray | None = None

    def u_bounds(self, cfg: ReplayConfig, ctx=None):
        if cfg.input_bounds == "fixed":
            return None
        u = self.u if ctx is None else self.u[self.u_ctx == ctx]
        return order_statistic_bounds(u, cfg.quantiles) if len(u) >= 200 else order_statistic_bounds(self.u, cfg.quantiles)


def self_safety_overrides(p: CarFollowingParams, v, h, vL, u) -> np.ndarray:
    """Boolean per point: the recorded input is not self-safe (7.4) (``car_following.unsafe_inputs``), or the
    point lies outside the state space (a negative speed of the ego or its lead: a recording's noise at
    standstill, which (7.3) has no place for; counted as an override, never judged safe)."""
    with np.errstate(invalid="ignore"):   # vL is NaN without a lead: not outside
        outside = (np.asarray(v) < 0) | (np.asarray(vL) < 0)
    return unsafe_inputs(p, v, h, vL, u) | outside


@dataclass(frozen=True)
class LaneChangeCounts:
    """Lane changes judged by Definition 22 on the recorded input: ``overrides`` whose recorded input is not
    ρ̂-responsible (the rate's numerator), ``no_input`` of them for which no input of U is (today's lower bound),
    ``outside`` of them with a speed outside ``[0, v_max]`` in the snapshot (not judged: counted as overrides)."""

    overrides: int = 0
    no_input: int = 0
    outside: int = 0

    def __add__(self, other):
        return LaneChangeCounts(self.overrides + other.overrides, self.no_input + other.no_input,
                                self.outside + other.outside)


def responsible(inputs, u: float) -> bool:
    """Is the recorded input ``u`` in one of the responsible input intervals (closed)?"""
    return any(lo <= u <= hi for lo, hi in inputs)


def judge_lane_change(p: CarFollowingParams, S: MaximalSet, e, overapprox: str):
    """The inputs of U that make lane change ``e`` ρ̂-responsible (Definition 22, (7.5)), or None when a speed in its
    snapshot (or the ego's recorded next speed) lies outside ``[0, v_max]``: outside the state space, not judged."""
    if np.any(e.v < 0) or np.any(e.v > p.v_max) or not 0 <= e.v[e.ego] + p.dt * e.u <= p.v_max:
        return None
    prm = HighwayParams(car_following=p, n_lanes=e.n_lanes, n_cars=len(e.p) - 1, ego_lane=int(e.lane[e.ego]))
    announced = {}
    if overapprox == "ordered":  # Example 8: ahead first; aligned, slower (lower) lane first
        key = [(-e.p[k], e.lane[k], k) for k in range(len(e.p))]
        me = key[e.ego]
        shift_name = {1: "left", -1: "right", 0: "stay"}
        announced = {k: shift_name.get(int(e.shift[k]), "stay") for k in range(len(e.p))
                     if k != e.ego and key[k] < me and int(e.shift[k]) in shift_name}
    sup = EgoSupervisor(prm, S, overapprox)
    return sup.lane_change([float(a) for a in e.p], [float(a) for a in e.v], [int(a) for a in e.lane], e.ego,
                           e.trigger, announced, lengths=[float(a) for a in e.length]).inputs


def responsibility_overrides(p: CarFollowingParams, events, overapprox: str) -> LaneChangeCounts:
    S = MaximalSet(p)
    overrides = no_input = outside = 0
    for e in events:
        inputs = judge_lane_change(p, S, e, overapprox)
        if inputs is None:  # outside the state space: counted against us
            overrides, no_input, outside = overrides + 1, no_input + 1, outside + 1
            continue
        overrides += not responsible(inputs, float(e.u))
        no_input += not inputs
    return LaneChangeCounts(overrides, no_input, outside)


def contexts_of(lane: np.ndarray, v: np.ndarray) -> np.ndarray:
    band = np.searchsorted(SPEED_BANDS, v, side="right") - 1
    return lane.astype(np.int64) * 10 + band


CHUNK = 1 << 20  # points evaluated at once: bounds the temporaries of the vectorised check


def _overrides_chunked(p: CarFollowingParams, test: ITHAData, mask=None) -> np.ndarray:
    n = len(test.v) if mask is None else int(np.count_nonzero(mask))
    idx = None if mask is None else np.flatnonzero(mask)
    out = np.empty(n, dtype=bool)
    for a in range(0, n, CHUNK):
        k = slice(a, a + CHUNK) if idx is None else idx[a:a + CHUNK]
        out[a:a + CHUNK] = self_safety_overrides(p, test.v[k], test.h[k], test.vL[k], test.u[k])
    return out


def _responsibility(p, events, overapprox: str, jobs=None):
    """Lane changes judged (``LaneChangeCounts``), as a callable that returns them.

    With jobs that run beside this process (``rcis.parallel.Jobs``) the chunks are submitted at once and run
    on its workers while the caller goes on (the self-safety check here); the callable collects them.
    """
    if jobs is None or not jobs.parallel or len(events) < 64:
        return lambda: responsibility_overrides(p, events, overapprox)
    n = 16
    futures = [jobs.submit(responsibility_overrides, p, events[k::n], overapprox) for k in range(n)]
    return lambda: sum((f.result() for f in futures), LaneChangeCounts())


def evaluate(cfg: ReplayConfig, dt: float, train: Training, test: ITHAData, events, contexts: bool,
             jobs=None) -> dict:
    bounds = order_statistic_bounds(train.d, cfg.quantiles)
    p = car_following_params(cfg, dt, bounds, train.u_bounds(cfg))
    judged = {k: _responsibility(p, events, k, jobs) for k in ("trivial", "ordered")}
    over = _overrides_chunked(p, test)
    rss_default, rss_calibrated = RSSParams(), calibrated_rss(p, dt)
    rss_over = longitudinal_violations(rss_default, test.v, test.h, test.vL)
    rss_cal_over = longitudinal_violations(rss_calibrated, test.v, test.h, test.vL)
    refused = {k: collect() for k, collect in judged.items()}   # judged on the workers meanwhile
    out = {"disturbance_bounds": [bounds[0], bounds[1]], "input_bounds": [p.u_min, p.u_max],
           "override_rates": {"self_safety": _mean(over),
                              "responsibility_trivial": _rate(refused["trivial"].overrides, events),
                              "responsibility_ordered": _rate(refused["ordered"].overrides, events),
                              "responsibility_trivial_no_input": _rate(refused["trivial"].no_input, events),
                              "responsibility_ordered_no_input": _rate(refused["ordered"].no_input, events),
                              "rss_longitudinal": _mean(rss_over),
                              "rss_longitudinal_calibrated": _mean(rss_cal_over),
                              "rss_cut_in": _rate(sum(not _rss_cut_in(rss_default, e) for e in events), events),
                              "rss_cut_in_calibrated": _rate(sum(not _rss_cut_in(rss_calibrated, e) for e in events),
                                                             events)},
           "rss_params": {"default": asdict(rss_default), "calibrated": asdict(rss_calibrated),
                          "default_source": "ad-rss vehicle dynamics as CARLA sets them "
                                            "(LibCarla/source/carla/rss/RssCheck.cpp, GetDefaultVehicleDynamics)"},
           "overrides": {"self_safety": int(over.sum()), "rss_longitudinal": int(rss_over.sum()),
                         **{f"responsibility_{k}{part}": n for k, c in refused.items()
                            for part, n in (("", c.overrides), ("_no_input", c.no_input), ("_outside", c.outside))}}}
    if contexts:
        out["contexts"] = _context_rates(cfg, dt, train, test, bounds, over)
    return out


def calibrated_rss(p, dt: float) -> RSSParams:
    """RSS with the same calibration as the car-following set: response time one data step, the ego's
    acceleration and braking from U, the front car's braking from D."""
    return RSSParams(response_time=dt, accel_max=max(p.u_max, 0.0), brake_min=-p.u_min, brake_max=-p.d_min)


def _rss_cut_in(params: RSSParams, e) -> bool:
    target = int(e.lane[e.ego]) + (1 if e.trigger == "left" else -1)
    return cut_in_safe(params, e.p, e.v, e.lane, e.length, e.ego, target)


def _rate(n: int, events) -> float | None:
    """``n`` of the events, or None when there is none: a rate of nothing is not 0 %."""
    return n / len(events) if events else None


def _mean(flags: np.ndarray) -> float | None:
    return float(flags.mean()) if len(flags) else None


def _outside(d: np.ndarray, bounds) -> tuple[int, int]:
    """(held-out lead accelerations seen, how many lie outside ``bounds``): where the guarantee's traffic model
    did not hold."""
    seen = d[np.isfinite(d)]
    return int(len(seen)), int(np.count_nonzero((seen < bounds[0]) | (seen > bounds[1])))


def _context_rates(cfg, dt, train: Training, test, global_bounds, global_over: np.ndarray) -> dict:
    """Per context (lane x speed band): its own D (and U from the data), the self-safety rate of its sets beside the
    single sets' rate on the same held-out points, and the held-out lead accelerations outside its D."""
    ctx_test = contexts_of(test.lane, test.v)
    over = np.zeros(len(test.v), dtype=bool)
    table = {}
    for c in np.unique(ctx_test):
        mask = ctx_test == c
        samples = train.d[train.d_ctx == c]
        bounds = order_statistic_bounds(samples, cfg.quantiles) if len(samples) >= 200 else global_bounds
        p = car_following_params(cfg, dt, bounds, train.u_bounds(cfg, c))
        over[mask] = _overrides_chunked(p, test, mask)
        lane, band = divmod(int(c), 10)
        seen, outside = _outside(test.d[mask], bounds)
        table[f"lane{lane}_v{int(SPEED_BANDS[band])}-{SPEED_BANDS[band + 1]:g}"] = {
            "train_samples": int(len(samples)), "bounds": list(bounds), "input_bounds": [p.u_min, p.u_max],
            "test_points": int(mask.sum()),
            "self_safety": float(over[mask].mean()), "self_safety_single": float(global_over[mask].mean()),
            "test_disturbances": seen, "test_disturbances_outside": outside}
    seen, outside = _outside(test.d, global_bounds)
    return {"self_safety": _mean(over), "self_safety_single": _mean(global_over), "by_context": table,
            "test_disturbances": seen,
            "test_disturbances_outside": sum(c["test_disturbances_outside"] for c in table.values()),
            "test_disturbances_outside_single": outside,
            "note": "contexts with fewer than 200 training samples use the single-context bounds"}


def sensitivity_table(cfg: ReplayConfig, dt: float, train: Training, test: ITHAData, events,
                      jobs=None) -> list[dict]:
    """The rates when one open choice changes at a time."""
    variants = [("baseline", {})]
    variants += [(f"h_min={h}", {"h_min": h}) for h in (1.0, 5.0, 10.0)]
    variants += [(f"U=[{a},{b}]", {"u_min": a, "u_max": b, "input_bounds": "fixed"})
                 for a, b in ((-3.0, 2.0), (-4.0, 3.0), (-9.0, 6.0))]
    variants.append(("U=training quantiles", {"input_bounds": "data"}))
    variants += [(f"quantiles={q}", {"quantiles": q}) for q in ((0.01, 0.99), (0.05, 0.95), (0.1, 0.9))]
    rows = []
    for name, change in variants:
        c = replace(cfg, **change)
        r = evaluate(c, dt, train, test, events, contexts=False, jobs=jobs)
        rows.append({"variant": name, "disturbance_bounds": r["disturbance_bounds"],
                     "input_bounds": r["input_bounds"], **r["override_rates"]})
    return rows
