"""Override rates of the ITHA guardian on HighD-format data (Section 7.4.3, Table 7.2).

Pipeline (one recording at a time, so memory is bounded by one recording plus the kept arrays):

1. read and validate a recording, convert it to ITHA data (``convert.to_itha``);
2. split its vehicles 80/20 with a generator seeded by ``(seed, recording id)`` (the split does
   not depend on which process handles the recording);
3. keep the training vehicles' lead disturbances ``d`` and the test vehicles' data points and
   lane-change events (float32);
4. calibrate ``D = [d_(⌈0.025 N⌉), d_(⌈0.975 N⌉)]`` (order statistics, as in the dissertation) and
   build the car-following RCIS (closed form, exact at the data's ``dt``);
5. count overrides on the test data.

Rates (numerator / denominator):

* ``self_safety``: test data points (vehicle-frames with a next frame) where the recorded input is
  not self-safe (7.4) — outside ``U``, or ``f(x, u, D) ⊄ C`` — / all test data points;
* ``responsibility_trivial`` / ``responsibility_ordered``: test lane changes that are not
  ρ̂-responsible (Definition 22) with the trivial ρ̂ (7.6) / the ordered one (Example 8: the cars
  ahead announce their recorded triggers, the cars behind yield) / all test lane changes.
"""
from __future__ import annotations

import math
import time
import tracemalloc
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from guardian.highd.convert import ITHAData, to_itha
from guardian.highd.reader import read_recording, recording_ids
from itha.car_following import CarFollowingParams, MaximalSet, headway_floor
from itha.highway import EgoSupervisor, HighwayParams

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


def default_sample() -> Path:
    return Path(__file__).resolve().parents[2] / "data" / "highd_sample"


# ---- per recording (runs in workers) ------------------------------------------------------------
@dataclass
class RecordingPart:
    recording: int
    points: int
    trajectories: int
    lane_changes: int
    train_d: np.ndarray          # float32
    train_ctx: np.ndarray        # context of each training disturbance (lane, speed band)
    train_u: np.ndarray          # float32 training inputs (for input bounds calibrated on data)
    test: ITHAData               # float32 arrays
    test_lane_changes: list
    frame_rate: int


def process_recording(folder: str, rid: int, seed: int, test_fraction: float, v_max: float) -> RecordingPart:
    rec = read_recording(Path(folder), rid)
    data = to_itha(rec)
    too_fast = np.flatnonzero(data.v > v_max)
    if len(too_fast):
        k = too_fast[0]
        raise ValueError(f"recording {rid}: vehicle {data.vehicle[k]} at frame {data.frame[k]} drives "
                         f"{data.v[k]:.2f} m/s, above v_max = {v_max} (raise --v-max)")
    vehicles = np.sort(rec.tracks_meta["id"].to_numpy())
    draw = np.random.default_rng([seed, rid]).uniform(size=len(vehicles))
    test_ids = vehicles[draw < test_fraction]
    is_test = np.isin(data.vehicle, test_ids)
    train = ~is_test & np.isfinite(data.d)
    train_d = data.d[train].astype(np.float32)
    train_ctx = contexts_of(data.lane[train], data.v[train]).astype(np.int16)
    train_u = data.u[~is_test].astype(np.float32)
    test = data.take(is_test)
    for k in ("v", "h", "vL", "u", "d"):
        setattr(test, k, getattr(test, k).astype(np.float32))
    test_lc = [e for e in data.lane_changes if e.vehicle in set(test_ids.tolist())]
    return RecordingPart(rid, len(data), len(vehicles), len(data.lane_changes), train_d, train_ctx, train_u,
                         test, test_lc, rec.frame_rate)


# ---- calibration and evaluation --------------------------------------------------------------------
def order_statistic_bounds(d: np.ndarray, quantiles) -> tuple[float, float]:
    """``[d_(⌈q_lo N⌉), d_(⌈q_hi N⌉)]`` (1-based order statistics)."""
    if len(d) == 0:
        raise ValueError("no lead-disturbance samples in the training split (no car follows another)")
    n = len(d)
    ks = [min(max(math.ceil(q * n), 1), n) - 1 for q in quantiles]
    part = np.partition(d, ks)
    return float(part[ks[0]]), float(part[ks[1]])


def car_following_params(cfg: ReplayConfig, dt: float, bounds) -> CarFollowingParams:
    lo, hi = bounds
    return CarFollowingParams(dt=dt, v_max=cfg.v_max, h_min=cfg.h_min, u_min=cfg.u_min, u_max=cfg.u_max,
                              d_min=min(lo, -1e-6), d_max=max(hi, 0.0))


def self_safety_overrides(p: CarFollowingParams, v, h, vL, u) -> np.ndarray:
    """Boolean per point: the recorded input is not self-safe (7.4)."""
    v, h, vL, u = (np.asarray(a, float) for a in (v, h, vL, u))
    v_next = v + p.dt * u
    ok = (u >= p.u_min) & (u <= p.u_max) & (v_next >= 0) & (v_next <= p.v_max)
    lead = np.isfinite(h)
    h_next = np.where(lead, h + p.dt * (np.nan_to_num(vL) - v), 0.0)
    vL_next = np.where(lead, np.maximum(np.nan_to_num(vL) + p.dt * p.d_min, 0.0), 0.0)
    inside = headway_floor(p, np.clip(v_next, 0, p.v_max), h_next, np.clip(vL_next, 0, p.v_max)) >= p.h_min
    ok &= np.where(lead, inside & (np.nan_to_num(vL) <= p.v_max), True)
    return ~ok


def responsibility_overrides(p: CarFollowingParams, events, overapprox: str) -> int:
    S = MaximalSet(p)
    refused = 0
    for e in events:
        prm = HighwayParams(car_following=p, n_lanes=e.n_lanes, n_cars=len(e.p) - 1, ego_lane=int(e.lane[e.ego]))
        announced = {}
        if overapprox == "ordered":  # Example 8: ahead first; aligned, slower (lower) lane first
            key = [(-e.p[k], e.lane[k], k) for k in range(len(e.p))]
            me = key[e.ego]
            shift_name = {1: "left", -1: "right", 0: "stay"}
            announced = {k: shift_name.get(int(e.shift[k]), "stay") for k in range(len(e.p))
                         if k != e.ego and key[k] < me and int(e.shift[k]) in shift_name}
        sup = EgoSupervisor(prm, S, overapprox)
        verdict = sup.lane_change([float(a) for a in e.p], [min(max(float(a), 0.0), p.v_max) for a in e.v],
                                  [int(a) for a in e.lane], e.ego, e.trigger, announced,
                                  lengths=[float(a) for a in e.length])
        refused += not verdict.inputs
    return refused


def contexts_of(lane: np.ndarray, v: np.ndarray) -> np.ndarray:
    band = np.searchsorted(SPEED_BANDS, v, side="right") - 1
    return lane.astype(np.int64) * 10 + band


def evaluate(cfg: ReplayConfig, dt: float, train_d, train_ctx, test: ITHAData, events, contexts: bool) -> dict:
    bounds = order_statistic_bounds(train_d, cfg.quantiles)
    p = car_following_params(cfg, dt, bounds)
    over = self_safety_overrides(p, test.v, test.h, test.vL, test.u)
    out = {"disturbance_bounds": [bounds[0], bounds[1]],
           "override_rates": {"self_safety": float(over.mean()) if len(over) else 0.0,
                              "responsibility_trivial": _rate(responsibility_overrides(p, events, "trivial"), events),
                              "responsibility_ordered": _rate(responsibility_overrides(p, events, "ordered"), events)},
           "overrides": {"self_safety": int(over.sum())}}
    if contexts:
        out["contexts"] = _context_rates(cfg, dt, train_d, train_ctx, test, bounds)
    return out


def _rate(n: int, events) -> float:
    return n / len(events) if events else 0.0


def _context_rates(cfg, dt, train_d, train_ctx, test, global_bounds) -> dict:
    ctx_test = contexts_of(test.lane, test.v)
    over = np.zeros(len(test.v), dtype=bool)
    table = {}
    for c in np.unique(ctx_test):
        mask = ctx_test == c
        samples = train_d[train_ctx == c]
        bounds = order_statistic_bounds(samples, cfg.quantiles) if len(samples) >= 200 else global_bounds
        p = car_following_params(cfg, dt, bounds)
        over[mask] = self_safety_overrides(p, test.v[mask], test.h[mask], test.vL[mask], test.u[mask])
        lane, band = divmod(int(c), 10)
        table[f"lane{lane}_v{int(SPEED_BANDS[band])}-{SPEED_BANDS[band + 1]:g}"] = {
            "train_samples": int(len(samples)), "bounds": list(bounds), "test_points": int(mask.sum()),
            "self_safety": float(over[mask].mean())}
    return {"self_safety": float(over.mean()) if len(over) else 0.0, "by_context": table,
            "note": "contexts with fewer than 200 training samples use the single-context bounds"}


# ---- the whole replay ---------------------------------------------------------------------------------
def _map_recordings(folder, ids, cfg: ReplayConfig, workers: int, scheduler: str | None, progress):
    args = [(str(folder), rid, cfg.seed, cfg.test_fraction, cfg.v_max) for rid in ids]
    if scheduler:
        from dask.distributed import Client, as_completed

        with Client(scheduler) as client:
            futures = {client.submit(process_recording, *a, pure=False): a[1] for a in args}
            for n, fut in enumerate(as_completed(futures), 1):
                if progress:
                    progress(n, len(args))
                yield fut.result()
        return
    if workers <= 1:
        for n, a in enumerate(args, 1):
            part = process_recording(*a)
            if progress:
                progress(n, len(args))
            yield part
        return
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for n, part in enumerate(pool.map(process_recording, *zip(*args)), 1):
            if progress:
                progress(n, len(args))
            yield part


def replay(path: Path | None = None, cfg: ReplayConfig = ReplayConfig(), contexts: bool = False,
           workers: int = 1, scheduler: str | None = None, progress=None, sensitivity: bool = False,
           measure_memory: bool = False) -> dict:
    t0 = time.perf_counter()
    if measure_memory:
        tracemalloc.start()
    folder = Path(path) if path is not None else default_sample()
    ids = recording_ids(folder)
    if folder.is_file():
        folder = folder.parent
    parts = sorted(_map_recordings(folder, ids, cfg, workers, scheduler, progress), key=lambda q: q.recording)
    rates = {q.frame_rate for q in parts}
    if len(rates) != 1:
        raise ValueError(f"recordings have different frame rates {sorted(rates)}; replay them separately")
    dt = 1.0 / rates.pop()
    train_d = np.concatenate([q.train_d for q in parts])
    test = _concat([q.test for q in parts])
    events = [e for q in parts for e in q.test_lane_changes]
    train_ctx = np.concatenate([q.train_ctx for q in parts]) if contexts else None
    result = {
        "recordings": len(parts), "data_points": int(sum(q.points for q in parts)),
        "trajectories": int(sum(q.trajectories for q in parts)),
        "lane_changes": int(sum(q.lane_changes for q in parts)),
        "test_data_points": int(len(test.v)), "test_lane_changes": len(events),
        "train_disturbance_samples": int(len(train_d)), "dt": dt, "config": asdict(cfg),
    }
    result.update(evaluate(cfg, dt, train_d, train_ctx, test, events, contexts))
    if sensitivity:
        train_u = np.concatenate([q.train_u for q in parts])
        result["sensitivity"] = sensitivity_table(cfg, dt, train_d, train_u, test, events)
    result["seconds"] = round(time.perf_counter() - t0, 3)
    if measure_memory:
        result["peak_traced_memory_mb"] = round(tracemalloc.get_traced_memory()[1] / 1e6, 1)
        tracemalloc.stop()
    return result


def _concat(items) -> ITHAData:
    keys = ("vehicle", "frame", "direction", "lane", "v", "h", "vL", "u", "d")
    return ITHAData(-1, items[0].frame_rate if items else 25,
                    **{k: np.concatenate([getattr(i, k) for i in items]) for k in keys})


def sensitivity_table(cfg: ReplayConfig, dt: float, train_d, train_u, test: ITHAData, events) -> list[dict]:
    """The rates when one open choice changes at a time."""
    variants = [("baseline", {})]
    variants += [(f"h_min={h}", {"h_min": h}) for h in (1.0, 5.0, 10.0)]
    variants += [(f"U=[{a},{b}]", {"u_min": a, "u_max": b}) for a, b in ((-3.0, 2.0), (-4.0, 3.0), (-9.0, 6.0))]
    u_lo, u_hi = order_statistic_bounds(train_u, cfg.quantiles)
    variants.append((f"U=training quantiles [{u_lo:g},{u_hi:g}]", {"u_min": min(u_lo, -1e-3), "u_max": max(u_hi, 1e-3)}))
    variants += [(f"quantiles={q}", {"quantiles": q}) for q in ((0.01, 0.99), (0.05, 0.95), (0.1, 0.9))]
    rows = []
    for name, change in variants:
        c = replace(cfg, **change)
        r = evaluate(c, dt, train_d, None, test, events, contexts=False)
        rows.append({"variant": name, "disturbance_bounds": r["disturbance_bounds"], **r["override_rates"]})
    return rows
