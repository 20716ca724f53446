"""A validated columnar cache of parsed HighD recordings (Parquet), so a second replay skips parsing.

``load_recording(folder, rid, plausibility, cache_dir)`` returns what ``read_recording`` returns.
The first time, it reads and validates the three CSV files and stores the tables as they came out
of validation in ``<cache_dir>/<key>/`` (``tracks.parquet``, ``tracksMeta.parquet``, ``entry.json``);
only a recording that passed every check is stored, so an entry is clean by construction.

``load_itha_view`` adds the recording's ITHA view (``convert.to_itha``'s arrays and lane-change
events, the vehicle ids and the frame rate) to the same entry, as a folder ``itha-<version of
convert.py>/`` of ``.npy`` files (read without a zip archive's CRC pass, which cost more than a third
of reading an ``.npz``), so a repeated replay neither parses nor converts.

The key hashes:

* the code's version: the source of the reader, the schema and this module;
* the plausibility flag;
* per source file: its resolved path, size, mtime (ns) and a content hash sampled from its first and
  last MiB and 64 evenly spaced 4 KiB blocks (hashing whole HighD track files on every replay would
  cost as much as parsing them).

Editing a file changes its mtime (and almost always its size and sampled blocks), so it misses the
cache and is read again; an edit that keeps size and mtime and touches no sampled block is the one
thing this cannot see: ``--no-cache`` reads everything afresh. ``entry.json`` carries the key's
inputs; an entry whose stored inputs disagree with the request, or that cannot be read, is refused
with a warning and replaced, never used.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from guardian.highd.convert import ITHAData, LaneChange, to_itha
from guardian.highd.reader import Recording, read_recording, recording_files
from guardian.highd.schema import FILES, file_name

_CODE_FILES = ("reader.py", "schema.py", "cache.py")
_BLOCK, _EDGE, _BLOCKS = 4096, 1 << 20, 64
# lz4 without dictionaries: about twice snappy's size on track files, and the fastest to write and read
_PARQUET = {"compression": "lz4", "use_dictionary": False, "write_statistics": False}


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


def _request(paths: dict, plausibility: bool) -> dict:
    return {"code": code_version(), "plausibility": plausibility,
            "sources": {kind: source_fingerprint(p) for kind, p in sorted(paths.items())}}


def _key(request: dict) -> str:
    return hashlib.sha256(json.dumps(request, sort_keys=True).encode()).hexdigest()[:24]


_POINT_ARRAYS = ("vehicle", "frame", "direction", "lane", "v", "h", "vL", "u", "d")
_EVENT_ARRAYS = ("p", "v", "lane", "length", "shift")


def _convert_version() -> str:
    return hashlib.sha256((Path(__file__).resolve().parent / "convert.py").read_bytes()).hexdigest()[:12]


def load_itha_view(folder: Path, recording_id: int, plausibility: bool = True,
                   cache_dir: Path | None = None) -> tuple[ITHAData, np.ndarray, bool]:
    """The ITHA view of a recording (``to_itha``) and its vehicle ids, from the cache or computed.

    Parameters
    ----------
    folder, recording_id, plausibility, cache_dir
        As ``load_recording``.

    Returns
    -------
    (ITHAData, ndarray, bool)
        The view (equal to ``to_itha(read_recording(...))``), the recording's vehicle ids (tracksMeta
        order), and whether it came from the cache without parsing or converting.
    """
    entry, paths, request = _entry(Path(folder), recording_id, plausibility, cache_dir)
    view = None if entry is None else entry / f"itha-{_convert_version()}"
    if view is not None and view.is_dir() and (entry / "entry.json").is_file():
        try:
            stored = json.loads((entry / "entry.json").read_text())
            if stored["request"] != request:
                raise ValueError("its stored sources or code version differ from this request")
            return (*_read_view(view, recording_id), True)
        except Exception as exc:
            print(f"guardian: refusing the HighD cache entry {entry}: {exc}; reading recording {recording_id} "
                  f"from its CSV files", file=sys.stderr)
            shutil.rmtree(entry, ignore_errors=True)
    rec, _ = load_recording(folder, recording_id, plausibility, cache_dir)
    data = to_itha(rec)
    vehicles = rec.tracks_meta["id"].to_numpy()
    if view is not None and entry.is_dir():
        _write_view(view, data, vehicles)
    return data, vehicles, False


def _write_view(path: Path, data: ITHAData, vehicles: np.ndarray) -> None:
    events = data.lane_changes
    sizes = np.array([len(e.p) for e in events], dtype=np.int64)
    arrays = {k: getattr(data, k) for k in _POINT_ARRAYS}
    arrays.update({f"event_{k}": (np.concatenate([getattr(e, k) for e in events]) if events else np.zeros(0))
                   for k in _EVENT_ARRAYS})
    arrays.update(event_sizes=sizes, vehicles=vehicles, frame_rate=np.array(data.frame_rate),
                  event_meta=np.array([[e.vehicle, e.frame, e.ego, 1 if e.trigger == "left" else -1, e.n_lanes]
                                       for e in events], dtype=np.int64).reshape(-1, 5))
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    for name, array in arrays.items():
        np.save(tmp / f"{name}.npy", np.asarray(array), allow_pickle=False)
    try:
        os.replace(tmp, path)  # atomic; another worker may have stored the same view first
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)


_VIEW_ARRAYS = (*_POINT_ARRAYS, *(f"event_{k}" for k in _EVENT_ARRAYS), "event_sizes", "vehicles",
                "frame_rate", "event_meta")


def _read_view(path: Path, recording_id: int) -> tuple[ITHAData, np.ndarray]:
    a = {k: np.load(path / f"{k}.npy", allow_pickle=False) for k in _VIEW_ARRAYS}  # a missing file: refused
    data = ITHAData(recording_id, int(a["frame_rate"]), **{k: a[k] for k in _POINT_ARRAYS})
    bounds = np.concatenate([[0], np.cumsum(a["event_sizes"])])
    for i, (vehicle, frame, ego, side, n_lanes) in enumerate(a["event_meta"]):
        s, e = bounds[i], bounds[i + 1]
        data.lane_changes.append(LaneChange(recording_id, int(vehicle), int(frame), int(ego),
                                            "left" if side > 0 else "right",
                                            *(a[f"event_{k}"][s:e] for k in _EVENT_ARRAYS), int(n_lanes)))
    return data, a["vehicles"]


def _entry(folder: Path, recording_id: int, plausibility: bool, cache_dir):
    """The cache entry folder, the source paths and the request; entry None without a cache."""
    found = recording_files(folder).get(recording_id, {})
    paths = {kind: found.get(kind, folder / file_name(recording_id, kind)) for kind in FILES}
    if cache_dir is None or not all(p.is_file() for p in paths.values()):
        return None, paths, None
    request = _request(paths, plausibility)
    return Path(cache_dir) / _key(request), paths, request


def load_recording(folder: Path, recording_id: int, plausibility: bool = True,
                   cache_dir: Path | None = None) -> tuple[Recording, bool]:
    """A recording from the cache, or read, validated and stored.

    Parameters
    ----------
    folder : path
        The folder of the recording's three CSV files.
    recording_id : int
    plausibility : bool
        As ``read_recording``; part of the key.
    cache_dir : path, optional
        The cache folder; None reads without a cache.

    Returns
    -------
    (Recording, bool)
        The recording, equal to ``read_recording``'s, and whether it came from the cache.

    Raises
    ------
    HighDFormatError
        From ``read_recording`` on the first read; a cached entry was valid when it was stored.
    """
    folder = Path(folder)
    entry, paths, request = _entry(folder, recording_id, plausibility, cache_dir)
    if entry is None:
        return read_recording(folder, recording_id, plausibility), False
    if entry.is_dir():
        rec = _load(entry, request, folder, recording_id, paths)
        if rec is not None:
            return rec, True
    rec = read_recording(folder, recording_id, plausibility)
    _store(entry, request, rec)
    return rec, False


def _load(entry: Path, request: dict, folder: Path, recording_id: int, paths: dict) -> Recording | None:
    try:
        stored = json.loads((entry / "entry.json").read_text())
        if stored["request"] != request:
            raise ValueError("its stored sources or code version differ from this request")
        tracks_meta = pd.read_parquet(entry / "tracksMeta.parquet")
        tracks = pd.read_parquet(entry / "tracks.parquet")
    except Exception as exc:  # any unreadable or foreign entry: refuse it, read the CSV files again
        print(f"guardian: refusing the HighD cache entry {entry}: {exc}; reading recording {recording_id} "
              f"from its CSV files", file=sys.stderr)
        shutil.rmtree(entry, ignore_errors=True)
        return None
    return Recording(recording_id, folder, stored["meta"], tracks_meta, tracks, stored["upper_markings"],
                     stored["lower_markings"], dict(paths))


def _store(entry: Path, request: dict, rec: Recording) -> None:
    tmp = entry.with_name(f"{entry.name}.tmp-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name, table in (("tracksMeta", rec.tracks_meta), ("tracks", rec.tracks)):
        table.to_parquet(tmp / f"{name}.parquet", index=False, **_PARQUET)
    meta = {k: (v.item() if hasattr(v, "item") else v) for k, v in rec.meta.items()}
    (tmp / "entry.json").write_text(json.dumps({"request": request, "meta": meta,
                                                "upper_markings": rec.upper_markings,
                                                "lower_markings": rec.lower_markings}))
    try:
        os.replace(tmp, entry)  # atomic; another worker may have stored the same entry first
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
