"""On-disk cache of computed regions, keyed by everything that shaped them.

A cache entry is one ``.npz`` holding the pieces and a JSON ``meta`` record
with the full key payload (parameters, settings, seed-set key, and a
fingerprint of the source code that computes sets). The file name carries the
payload's hash. Loading checks the stored payload against the expected one and
the arrays against their checksum; any difference raises ``StaleCacheError``
with the first differing field, and the entry is never used.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from rcis.polyhedron import Polyhedron
from rcis.region import Region

_FINGERPRINT_FILES = ("rcis/lp.py", "rcis/polyhedron.py", "rcis/region.py", "rcis/pwa.py",
                      "rcis/invariant.py", "intention/models.py",
                      "itha/car_following.py")


class StaleCacheError(RuntimeError):
    """A cache file exists but was built from other parameters or code."""


def default_cache_dir() -> Path:
    return Path(os.environ.get("GUARDIAN_CACHE_DIR", Path.home() / ".cache" / "guardian"))


def code_fingerprint() -> str:
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for rel in _FINGERPRINT_FILES:
        h.update(rel.encode())
        h.update((root / rel).read_bytes())
    return h.hexdigest()[:16]


def payload_key(payload: dict) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def entry_path(cache_dir: Path, name: str, payload: dict) -> Path:
    return Path(cache_dir) / f"{name}-{payload_key(payload)[:16]}.npz"


def _arrays_digest(arrays: dict) -> str:
    h = hashlib.sha256()
    for k in sorted(arrays):
        h.update(k.encode())
        h.update(np.ascontiguousarray(arrays[k]).tobytes())
    return h.hexdigest()


def save_region(path: Path, region: Region, payload: dict, info: dict) -> None:
    arrays = {}
    for i, P in enumerate(region.pieces):
        arrays[f"A{i}"] = P.A
        arrays[f"b{i}"] = P.b
    meta = {"payload": payload, "key": payload_key(payload), "info": info, "dim": region.dim,
            "pieces": len(region), "digest": _arrays_digest(arrays)}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, meta=np.array(json.dumps(meta)), **arrays)
    os.replace(tmp, path)


def load_region(path: Path, expected_payload: dict) -> tuple[Region, dict]:
    """The region stored at path, after checking it was built from ``expected_payload``."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in z.files if k != "meta"}
    except (OSError, ValueError, KeyError) as exc:
        raise StaleCacheError(f"{path}: not a readable cache file ({exc})") from exc
    stored = meta.get("payload", {})
    if stored != expected_payload:
        raise StaleCacheError(f"{path}: built with {_first_difference(stored, expected_payload)}")
    if meta.get("digest") != _arrays_digest(arrays):
        raise StaleCacheError(f"{path}: the stored pieces do not match their checksum")
    pieces = [Polyhedron(arrays[f"A{i}"], arrays[f"b{i}"]) for i in range(meta["pieces"])]
    return Region(pieces, meta["dim"]), meta["info"]


def _first_difference(stored, expected, prefix="") -> str:
    if isinstance(stored, dict) and isinstance(expected, dict):
        for k in sorted(set(stored) | set(expected)):
            if stored.get(k) != expected.get(k):
                return _first_difference(stored.get(k), expected.get(k), f"{prefix}{k}.")
    return f"{prefix.rstrip('.') or 'payload'} = {stored!r}, expected {expected!r}"
