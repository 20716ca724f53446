"""A validated columnar cache of HighD recordings, so a repeated replay neither parses nor converts.

``load_itha_view(folder, rid, plausibility, cache_dir)`` returns the recording's ITHA view
(``convert.to_itha`` of ``reader.read_recording``) and its vehicle ids. The first time, it reads and
validates the three CSV files, converts them and stores the view's columns in ``<cache_dir>/<key>/``
as one ``.npy`` file per array beside ``entry.json``; only a recording that passed every check is
stored, so an entry is clean by construction. A repeated replay reads the arrays (no zip archive's
CRC pass, no decoding: ~0.01 s per 22-minute recording).

Why the view and not the parsed tables (as Parquet): measured on the
60-recording benchmark, writing each recording's tables as Parquet cost 8 s of a 28 s first run,
and the tables saved a parse only when ``convert.py`` changed while the reader did not; the view
as Parquet (lz4) reads 3.5 times slower than ``.npy`` (0.031 against 0.009 s per recording), which
the repeated run's 5 s cannot afford. NOTES.md has the figures.

The key hashes:

* the code's version: the source of the reader, the compiled CSV reader, the schema, the
  conversion and this module;
* the plausibility flag;
* per source file: its resolved path, size, mtime (ns) and a content hash sampled from its first and
  last MiB and 64 evenly spaced 4 KiB blocks (hashing whole HighD track files on every replay would
  cost as much as parsing them).

Editing a file changes its mtime (and almost always its size and sampled blocks), so it misses the
cache and is read again; an edit that keeps size and mtime and touches no sampled block is the one
thing this cannot see: ``--no-cache`` reads everything afresh. ``entry.json`` carries the key's
inputs; an entry whose stored inputs disagree with the request, that lacks an array or that cannot
be read, is refused with a warning and replaced, never used.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from guardian.highd.convert import ITHAData, LaneChange, to_itha
from guardian.highd.files import recording_files
from guardian.highd.reader import read_recording, subsample
from guardian.highd.schema import FILES, file_name

_CODE_FILES = ("reader.py", "numeric_csv.py", "schema.py", "convert.py", "cache.py")
_BLOCK, _EDGE, _BLOCKS = 4096, 1 << 20, 64


def code_version() -> str:
    here = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for name in _CODE_FILES:
        h.update((here / name).read_bytes())
    return h.hexdigest()[:16]


def source_fingerprint(path: Path) -> dict:
    """Resolved path, size, mtime and the sampled content hash of one source file."""
    path = Path(path).resolve()
    st = path.stat()
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        h.update(fh.read(_EDGE))
        if st.st_size > 2 * _EDGE:
            step = (st.st_size - 2 * _EDGE) // _BLOCKS
            for k in range(_BLOCKS):
                fh.seek(_EDGE + k * step)
                h.update(fh.read(_BLOCK))
        fh.seek(max(st.st_size - _EDGE, 0))
        h.update(fh.read(_EDGE))
    return {"path": str(path), "size": st.st_size, "mtime_ns": st.st_mtime_ns, "sampled_sha256": h.hexdigest()}


def _request(paths: dict, plausibility: bool, frame_step: int = 1) -> dict:
    request = {"code": code_version(), "plausibility": plausibility,
               "sources": {kind: source_fingerprint(p) for kind, p in sorted(paths.items())}}
    if frame_step != 1:   # the key of a full-rate view stays what it was
        request["frame_step"] = frame_step
    return request


def _key(request: dict) -> str:
    return hashlib.sha256(json.dumps(request, sort_keys=True).encode()).hexdigest()[:24]


_POINT_ARRAYS = ("vehicle", "frame", "direction", "lane", "v", "h", "vL", "u", "d")
_EVENT_ARRAYS = ("p", "v", "lane", "length", "shift")


def load_itha_view(folder: Path, recording_id: int, plausibility: bool = True,
                   cache_dir: Path | None = None, frame_step: int = 1) -> tuple[ITHAData, np.ndarray, bool]:
    """The ITHA view of a recording (``to_itha``) and its vehicle ids, from the cache or computed.

    Parameters
    ----------
    folder : path
        The folder of the recording's three CSV files.
    recording_id : int
    plausibility : bool
        As ``read_recording``; part of the key.
    cache_dir : path, optional
        The cache folder; None reads without a cache.
    frame_step : int
        View every ``frame_step``-th frame (``reader.subsample``); part of the key.

    Returns
    -------
    (ITHAData, ndarray, bool)
        The view (equal to ``to_itha(read_recording(...))``), the recording's vehicle ids (tracksMeta
        order), and whether it came from the cache without parsing or converting.

    Raises
    ------
    HighDFormatError
        From ``read_recording``; a cached entry was valid when it was stored.
    """
    folder = Path(folder)
    entry, request = _entry(folder, recording_id, plausibility, cache_dir, frame_step)
    if entry is not None and entry.is_dir():
        try:
            stored = json.loads((entry / "entry.json").read_text())
            if stored["request"] != request:
                raise ValueError("its stored sources or code version differ from this request")
            return (*_read_view(entry, recording_id), True)
        except Exception as exc:  # any unreadable, partial or foreign entry: refuse it, read the CSV files
            print(f"guardian: refusing the HighD cache entry {entry}: {exc}; reading recording {recording_id} "
                  f"from its CSV files", file=sys.stderr)
            shutil.rmtree(entry, ignore_errors=True)
    rec = subsample(read_recording(folder, recording_id, plausibility), frame_step)
    data = to_itha(rec)
    vehicles = rec.tracks_meta["id"].to_numpy()
    if entry is not None:
        _write_view(entry, request, data, vehicles)
    return data, vehicles, False


def _write_view(entry: Path, request: dict, data: ITHAData, vehicles: np.ndarray) -> None:
    events = data.lane_changes
    sizes = np.array([len(e.p) for e in events], dtype=np.int64)
    arrays = {k: getattr(data, k) for k in _POINT_ARRAYS}
    arrays.update({f"event_{k}": (np.concatenate([getattr(e, k) for e in events]) if events else np.zeros(0))
                   for k in _EVENT_ARRAYS})
    arrays.update(event_sizes=sizes, vehicles=vehicles, frame_rate=np.array(data.frame_rate),
                  event_input=np.array([e.u for e in events], dtype=float),
                  event_meta=np.array([[e.vehicle, e.frame, e.ego, 1 if e.trigger == "left" else -1, e.n_lanes]
                                       for e in events], dtype=np.int64).reshape(-1, 5))
    tmp = entry.with_name(f"{entry.name}.tmp-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name, array in arrays.items():
        np.save(tmp / f"{name}.npy", _narrowest(np.asarray(array)), allow_pickle=False)
    (tmp / "entry.json").write_text(json.dumps({"request": request}))
    try:
        os.replace(tmp, entry)  # atomic; another worker may have stored the same entry first
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)


_VIEW_ARRAYS = (*_POINT_ARRAYS, *(f"event_{k}" for k in _EVENT_ARRAYS), "event_sizes", "vehicles",
                "frame_rate", "event_meta", "event_input")


def _narrowest(a: np.ndarray) -> np.ndarray:
    """An int64 array in the narrowest integer type that holds its values (ids, frames and lanes fit
    in 1-4 bytes: a third fewer bytes to write, and writing is most of the view's cost); others as they are."""
    if a.dtype != np.int64 or not a.size:
        return a
    low, high = a.min(), a.max()
    for t in (np.int8, np.int16, np.int32):
        if np.iinfo(t).min <= low and high <= np.iinfo(t).max:
            return a.astype(t)
    return a


def _read_view(path: Path, recording_id: int) -> tuple[ITHAData, np.ndarray]:
    a = {k: np.load(path / f"{k}.npy", allow_pickle=False) for k in _VIEW_ARRAYS}  # a missing file: refused
    a = {k: (v.astype(np.int64) if v.dtype.kind == "i" else v) for k, v in a.items()}  # stored narrowed
    data = ITHAData(recording_id, int(a["frame_rate"]), **{k: a[k] for k in _POINT_ARRAYS})
    bounds = np.concatenate([[0], np.cumsum(a["event_sizes"])])
    for i, (vehicle, frame, ego, side, n_lanes) in enumerate(a["event_meta"]):
        s, e = bounds[i], bounds[i + 1]
        data.lane_changes.append(LaneChange(recording_id, int(vehicle), int(frame), int(ego),
                                            "left" if side > 0 else "right",
                                            *(a[f"event_{k}"][s:e] for k in _EVENT_ARRAYS), int(n_lanes),
                                            float(a["event_input"][i])))
    return data, a["vehicles"]


def _entry(folder: Path, recording_id: int, plausibility: bool, cache_dir, frame_step: int = 1):
    """The cache entry folder and the request; (None, None) without a cache or when a file is missing
    (``read_recording`` then names it)."""
    found = recording_files(folder).get(recording_id, {})
    paths = {kind: found.get(kind, folder / file_name(recording_id, kind)) for kind in FILES}
    if cache_dir is None or not all(p.is_file() for p in paths.values()):
        return None, None
    request = _request(paths, plausibility, frame_step)
    return Path(cache_dir) / _key(request), request
