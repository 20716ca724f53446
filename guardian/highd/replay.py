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
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np

from guardian.highd.convert import ITHAData
from guardian.highd.cache import load_itha_view
from guardian.highd.reader import recording_files, recording_ids
from rcis.cache import default_cache_dir
from rcis.parallel import process_executor
from itha.rss import RSSParams, cut_in_safe, longitudinal_violations
from itha.car_following import CarFollowingParams, MaximalSet, unsafe_inputs
from itha.responsibility import EgoSupervisor
from itha.road import HighwayParams

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

    def __post_init__(self):
        if self.input_bounds not in ("fixed", "data"):
            raise ValueError(f"input_bounds must be 'fixed' or 'data', got {self.input_bounds!r}")
        if not 0 < self.test_fraction < 1:
            raise ValueError(f"test_fraction must be in (0, 1), got {self.test_fraction}")
        if not self.u_min < 0 < self.u_max:  # as CarFollowingParams: the ego must be able to brake
            raise ValueError(f"need u_min < 0 < u_max, got u_min {self.u_min}, u_max {self.u_max}")
        for name in ("h_min", "v_max"):
            if not 0 < getattr(self, name) < math.inf:
                raise ValueError(f"{name} must be positive and finite, got {getattr(self, name)}")


def default_sample() -> Path:
    """The shipped HighD-format sample, found through the installed package ``guardian.data``.

    Returns
    -------
    Path
        The folder holding ``01_recordingMeta.csv``, ``01_tracksMeta.csv`` and ``01_tracks.csv``.
    """
    folder = resources.files("guardian.data") / "highd_sample"
    if not isinstance(folder, Path):  # e.g. a zip import: the reader needs real files
        raise FileNotFoundError(f"the shipped sample is not a folder on disk ({folder}); install guardian unzipped")
    return folder


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
    train_u_ctx: np.ndarray      # their contexts
    test: ITHAData               # float32 arrays
    test_lane_changes: list
    frame_rate: int
    from_cache: bool = False     # the recording's view came from the cache (guardian.highd.cache)


def process_recording(folder: str, rid: int, seed: int, test_fraction: float, v_max: float,
                      keep_inputs: bool = True, keep_contexts: bool = True, plausibility: bool = True,
                      cache_dir: str | None = None) -> RecordingPart:
    data, vehicle_ids, from_cache = load_itha_view(Path(folder), rid, plausibility, cache_dir)
    too_fast = np.flatnonzero(data.v > v_max)
    if len(too_fast):
        k = too_fast[0]
        raise ValueError(f"recording {rid}: vehicle {data.vehicle[k]} at frame {data.frame[k]} drives "
                         f"{data.v[k]:.2f} m/s, above v_max = {v_max} (raise --v-max)")
    vehicles = np.sort(vehicle_ids)
    draw = np.random.default_rng([seed, rid]).uniform(size=len(vehicles))
    test_ids = vehicles[draw < test_fraction]
    is_test = np.isin(data.vehicle, test_ids)
    train = ~is_test & np.isfinite(data.d)
    train_d = data.d[train].astype(np.float32)
    none = np.zeros(0, dtype=np.int16)
    train_ctx = contexts_of(data.lane[train], data.v[train]).astype(np.int16) if keep_contexts else none
    train_u = data.u[~is_test].astype(np.float32) if keep_inputs else none.astype(np.float32)
    train_u_ctx = (contexts_of(data.lane[~is_test], data.v[~is_test]).astype(np.int16)
                   if keep_inputs and keep_contexts else none)
    test = data.take(is_test)
    test.lane_changes = []
    for k, dtype in (("v", np.float32), ("h", np.float32), ("vL", np.float32), ("u", np.float32),
                     ("d", np.float32), ("vehicle", np.int32), ("frame", np.int32), ("direction", np.int8),
                     ("lane", np.int8)):
        setattr(test, k, getattr(test, k).astype(dtype))
    test_set = set(test_ids.tolist())
    test_lc = [e for e in data.lane_changes if e.vehicle in test_set]
    return RecordingPart(rid, len(data), len(vehicles), len(data.lane_changes), train_d, train_ctx, train_u,
                         train_u_ctx, test, test_lc, data.frame_rate, from_cache)


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
    """Boolean per point: the recorded input is not self-safe (7.4) (``car_following.unsafe_inputs``)."""
    return unsafe_inputs(p, v, h, vL, u)


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


CHUNK = 1 << 20  # points evaluated at once: bounds the temporaries of the vectorised check


def _overrides_chunked(p: CarFollowingParams, test: ITHAData, mask=None) -> np.ndarray:
    n = len(test.v) if mask is None else int(np.count_nonzero(mask))
    idx = None if mask is None else np.flatnonzero(mask)
    out = np.empty(n, dtype=bool)
    for a in range(0, n, CHUNK):
        k = slice(a, a + CHUNK) if idx is None else idx[a:a + CHUNK]
        out[a:a + CHUNK] = self_safety_overrides(p, test.v[k], test.h[k], test.vL[k], test.u[k])
    return out


def _responsibility(p, events, overapprox: str, pool=None):
    """Refused lane changes, as a callable that returns the count.

    With a pool (executor or Dask client) the chunks are submitted at once and run on its workers
    while the caller goes on (the self-safety check in this process); the callable collects them.
    """
    if pool is None or len(events) < 64:
        return lambda: responsibility_overrides(p, events, overapprox)
    n = 16
    chunks = [events[k::n] for k in range(n)]
    if hasattr(pool, "gather"):  # dask.distributed.Client
        futures = pool.map(responsibility_overrides, [p] * n, chunks, [overapprox] * n, pure=False)
        return lambda: sum(pool.gather(futures))
    results = pool.map(responsibility_overrides, [p] * n, chunks, [overapprox] * n)  # submitted now
    return lambda: sum(results)


def evaluate(cfg: ReplayConfig, dt: float, train: Training, test: ITHAData, events, contexts: bool,
             pool=None) -> dict:
    bounds = order_statistic_bounds(train.d, cfg.quantiles)
    p = car_following_params(cfg, dt, bounds, train.u_bounds(cfg))
    refused = {k: _responsibility(p, events, k, pool) for k in ("trivial", "ordered")}
    over = _overrides_chunked(p, test)
    rss_default, rss_calibrated = RSSParams(), calibrated_rss(p, dt)
    rss_over = longitudinal_violations(rss_default, test.v, test.h, test.vL)
    rss_cal_over = longitudinal_violations(rss_calibrated, test.v, test.h, test.vL)
    out = {"disturbance_bounds": [bounds[0], bounds[1]], "input_bounds": [p.u_min, p.u_max],
           "override_rates": {"self_safety": float(over.mean()) if len(over) else 0.0,
                              "responsibility_trivial": _rate(refused["trivial"](), events),
                              "responsibility_ordered": _rate(refused["ordered"](), events),
                              "rss_longitudinal": float(rss_over.mean()) if len(rss_over) else 0.0,
                              "rss_longitudinal_calibrated": float(rss_cal_over.mean()) if len(rss_cal_over) else 0.0,
                              "rss_cut_in": _rate(sum(not _rss_cut_in(rss_default, e) for e in events), events),
                              "rss_cut_in_calibrated": _rate(sum(not _rss_cut_in(rss_calibrated, e) for e in events),
                                                             events)},
           "rss_params": {"default": asdict(rss_default), "calibrated": asdict(rss_calibrated),
                          "default_source": "ad-rss vehicle dynamics as CARLA sets them "
                                            "(LibCarla/source/carla/rss/RssCheck.cpp, GetDefaultVehicleDynamics)"},
           "overrides": {"self_safety": int(over.sum()), "rss_longitudinal": int(rss_over.sum())}}
    if contexts:
        out["contexts"] = _context_rates(cfg, dt, train, test, bounds)
    return out


def calibrated_rss(p, dt: float) -> RSSParams:
    """RSS with the same calibration as the car-following set: response time one data step, the ego's
    acceleration and braking from U, the front car's braking from D."""
    return RSSParams(response_time=dt, accel_max=max(p.u_max, 0.0), brake_min=-p.u_min, brake_max=-p.d_min)


def _rss_cut_in(params: RSSParams, e) -> bool:
    target = int(e.lane[e.ego]) + (1 if e.trigger == "left" else -1)
    return cut_in_safe(params, e.p, e.v, e.lane, e.length, e.ego, target)


def _rate(n: int, events) -> float:
    return n / len(events) if events else 0.0


def _context_rates(cfg, dt, train: Training, test, global_bounds) -> dict:
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
        table[f"lane{lane}_v{int(SPEED_BANDS[band])}-{SPEED_BANDS[band + 1]:g}"] = {
            "train_samples": int(len(samples)), "bounds": list(bounds), "input_bounds": [p.u_min, p.u_max],
            "test_points": int(mask.sum()),
            "self_safety": float(over[mask].mean())}
    return {"self_safety": float(over.mean()) if len(over) else 0.0, "by_context": table,
            "note": "contexts with fewer than 200 training samples use the single-context bounds"}


# ---- the whole replay ---------------------------------------------------------------------------------
def _map_recordings(folder, ids, cfg: ReplayConfig, workers: int, scheduler: str | None, progress,
                    keep_inputs: bool, keep_contexts: bool, cache_dir: str | None, pool=None):
    args = [(str(folder), rid, cfg.seed, cfg.test_fraction, cfg.v_max, keep_inputs, keep_contexts, cfg.plausibility,
             cache_dir) for rid in ids]
    if scheduler:  # pool is the dask.distributed Client of _pool
        from dask.distributed import as_completed

        futures = {pool.submit(process_recording, *a, pure=False): a[1] for a in args}
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
    for n, part in enumerate(pool.map(process_recording, *zip(*args)), 1):
        if progress:
            progress(n, len(args))
        yield part


def _parse_on_one_thread() -> None:
    """Pool initializer: the workers are the parallelism; pyarrow's threads would only contend with them.
    A worker reuses freed memory for the next recording (``keep_freed_memory``)."""
    from guardian.highd import reader

    reader.PARSE_THREADS = False
    keep_freed_memory()


def keep_freed_memory() -> None:
    """Keep freed blocks of up to 32 MB in this process's heap instead of returning them to the kernel.

    glibc hands a freed block of more than a few MB back to the kernel (its mmap threshold), so each
    recording's arrays came back as fresh pages that the kernel zeroes on first touch: a first
    replay of the 60-recording benchmark took 1.07 M page faults and 12.5 s of system time in 19 s.
    With the threshold at glibc's ceiling (32 MB) and trimming at 1 GB, a worker reuses its own
    memory: 0.25 M faults. Only replay's worker processes call this (a library caller's process
    keeps its own allocator settings); a no-op where the C library is not glibc.
    """
    import ctypes

    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return
    m_trim_threshold, m_mmap_threshold = -1, -3  # glibc's malloc.h
    mallopt(m_mmap_threshold, 32 << 20)
    mallopt(m_trim_threshold, 1 << 30)


@contextmanager
def _pool(workers: int, scheduler: str | None):
    if scheduler:
        from guardian.scheduler import client

        with client(scheduler) as c:  # SchedulerError (one line) if no scheduler answers there
            yield c
    elif workers > 1:
        with process_executor(workers, _parse_on_one_thread) as ex:  # terminated, not drained, on Ctrl-C
            yield ex
    else:
        yield None


def _listing(folder: Path, ids) -> list[dict]:
    """What was read: each recording's id and its three files."""
    files = recording_files(folder)
    return [{"id": rid, **{kind: str(path) for kind, path in sorted(files.get(rid, {}).items())}} for rid in ids]


def replay(path: Path | None = None, cfg: ReplayConfig = ReplayConfig(), contexts: bool = False,
           workers: int = 1, scheduler: str | None = None, progress=None, sensitivity: bool = False,
           measure_memory: bool = False, cache: bool = True, cache_dir: Path | None = None) -> dict:
    """Override rates of the ITHA supervisors on HighD-format recordings (Section 7.4.3).

    Parameters
    ----------
    path : path, optional
        A folder of recordings, or one of a recording's files; default: the embedded sample.
    cfg : ReplayConfig
        The open choices (split, quantiles, input bounds, plausibility rules).
    contexts : bool
        Also report the self-safety rate per lane and speed band, each with its own calibration.
    workers : int
        Processes that read, convert and evaluate the recordings.
    scheduler : str, optional
        A Dask scheduler address instead of local processes (connected to before any recording is read).
    progress : callable, optional
        ``progress(done, total)`` per recording.
    sensitivity : bool
        Also report the sensitivity table of the open choices.
    measure_memory : bool
        Report the peak traced memory.
    cache : bool
        Keep each validated recording's ITHA view in the cache and read it from there next time
        (``guardian.highd.cache``); False parses every file.
    cache_dir : path, optional
        The cache's folder (default: ``<GUARDIAN_CACHE_DIR or ~/.cache/guardian>/highd``).

    Returns
    -------
    dict
        ``recordings, data_points, trajectories, lane_changes, test_data_points, test_lane_changes,
        train_disturbance_samples, dt, config``, the ``override_rates`` (``self_safety``,
        ``responsibility_trivial``, ``responsibility_ordered``, RSS beside them), the calibrated
        ``disturbance_bounds`` and ``input_bounds``, ``timings`` and ``seconds``.

    Raises
    ------
    HighDFormatError
        A file that breaks the format or a plausibility rule, named with its line and column.
    SchedulerError
        No Dask scheduler answers at ``scheduler`` (``guardian.errors``; a ``ConnectionError``).
    """
    t0 = time.perf_counter()
    if measure_memory:
        tracemalloc.start()
    folder = Path(path) if path is not None else default_sample()
    ids = recording_ids(folder)
    if folder.is_file():
        folder = folder.parent
    keep_inputs = sensitivity or cfg.input_bounds == "data"
    if cache:
        cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir() / "highd"
    with _pool(workers, scheduler) as pool:  # one pool for reading and for the evaluation (each costs ~1 s)
        parts = sorted(_map_recordings(folder, ids, cfg, workers, scheduler, progress, keep_inputs, contexts,
                                       str(cache_dir) if cache else None, pool), key=lambda q: q.recording)
        t_map = time.perf_counter() - t0
        rates = {q.frame_rate for q in parts}
        if len(rates) != 1:
            raise ValueError(f"recordings have different frame rates {sorted(rates)}; replay them separately")
        dt = 1.0 / rates.pop()
        train = Training(np.concatenate([q.train_d for q in parts]),
                         np.concatenate([q.train_ctx for q in parts]),
                         np.concatenate([q.train_u for q in parts]),
                         np.concatenate([q.train_u_ctx for q in parts]))
        test = _concat([q.test for q in parts])
        events = [e for q in parts for e in q.test_lane_changes]
        counts = [(q.points, q.trajectories, q.lane_changes) for q in parts]
        hits = sum(q.from_cache for q in parts)
        del parts  # the concatenated arrays are all that is needed from here on
        result = {
            "recordings": _listing(folder, ids),
            "data_points": int(sum(c[0] for c in counts)),
            "trajectories": int(sum(c[1] for c in counts)), "lane_changes": int(sum(c[2] for c in counts)),
            "test_data_points": int(len(test.v)), "test_lane_changes": len(events),
            "train_disturbance_samples": int(len(train.d)), "dt": dt, "config": asdict(cfg),
            "cache": {"dir": str(cache_dir), "hits": hits, "misses": len(counts) - hits} if cache else None,
        }
        if not cfg.plausibility:
            result["plausibility"] = False  # named in the output: the reader's plausibility rules were off
        t1 = time.perf_counter()
        result.update(evaluate(cfg, dt, train, test, events, contexts, pool))
        if sensitivity:
            result["sensitivity"] = sensitivity_table(cfg, dt, train, test, events, pool)
    result["timings"] = {"read_convert_split": round(t_map, 3), "evaluate": round(time.perf_counter() - t1, 3)}
    result["seconds"] = round(time.perf_counter() - t0, 3)
    if measure_memory:
        result["peak_traced_memory_mb"] = round(tracemalloc.get_traced_memory()[1] / 1e6, 1)
        tracemalloc.stop()
    return result


def _concat(items) -> ITHAData:
    keys = ("vehicle", "frame", "direction", "lane", "v", "h", "vL", "u", "d")
    return ITHAData(-1, items[0].frame_rate if items else 25,
                    **{k: np.concatenate([getattr(i, k) for i in items]) for k in keys})


def sensitivity_table(cfg: ReplayConfig, dt: float, train: Training, test: ITHAData, events,
                      pool=None) -> list[dict]:
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
        r = evaluate(c, dt, train, test, events, contexts=False, pool=pool)
        rows.append({"variant": name, "disturbance_bounds": r["disturbance_bounds"],
                     "input_bounds": r["input_bounds"], **r["override_rates"]})
    return rows
