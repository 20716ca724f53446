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
* ``self_safety`` also counts a point outside the state space (a negative speed of the ego or its lead) as an
  override: (7.3) has no place for it, so it is never judged safe;
* ``responsibility_trivial`` / ``responsibility_ordered``: test lane changes whose **recorded input** is not
  ρ̂-responsible (Definition 22 constrains the recorded pair: the input, not some input of U) with the trivial
  ρ̂ (7.6) / the ordered one (Example 8: the cars ahead announce their recorded triggers, the cars behind
  yield) / all test lane changes; a lane change with a speed outside ``[0, v_max]`` in its snapshot (or a
  recorded next speed outside it) is not judged and counts as an override;
* ``responsibility_trivial_no_input`` / ``..._ordered_no_input``: of those, the lane changes for which no input
  of U is ρ̂-responsible (the rate this replay reported before it looked at the recorded input).

A rate whose denominator is empty (no held-out lane change, no test point) is ``None`` (printed ``-``), never 0 %.
"""
from __future__ import annotations

import time
import tracemalloc
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from guardian.highd.cache import load_itha_view
from guardian.highd.convert import ITHAData
from guardian.highd.files import recording_files, recording_ids
from guardian.highd.rates import ReplayConfig, Training, contexts_of, evaluate, sensitivity_table
from rcis.cache import default_cache_dir
from rcis.parallel import Jobs


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
                      cache_dir: str | None = None, frame_step: int = 1) -> RecordingPart:
    data, vehicle_ids, from_cache = load_itha_view(Path(folder), rid, plausibility, cache_dir, frame_step)
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


# ---- the whole replay ---------------------------------------------------------------------------------
def _map_recordings(folder, ids, cfg: ReplayConfig, jobs: Jobs, progress, keep_inputs: bool,
                    keep_contexts: bool, cache_dir: str | None):
    """Each recording read, converted and split (``process_recording``) on ``jobs``, as they finish."""
    running = {rid: jobs.submit(process_recording, str(folder), rid, cfg.seed, cfg.test_fraction, cfg.v_max,
                                keep_inputs, keep_contexts, cfg.plausibility, cache_dir, cfg.frame_step) for rid in ids}
    for n, (_, part) in enumerate(jobs.as_completed(running), 1):
        if progress:
            progress(n, len(running))
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
    # one pool for reading and for the evaluation (each costs ~1 s); a scheduler is connected to first
    with Jobs(workers, scheduler, initializer=_parse_on_one_thread) as pool:
        parts = sorted(_map_recordings(folder, ids, cfg, pool, progress, keep_inputs, contexts,
                                       str(cache_dir) if cache else None), key=lambda q: q.recording)
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
