"""On-disk cache of computed regions, keyed by everything that shaped them.

A cache entry is one ``.npz`` holding the pieces and a JSON ``meta`` record
with the full key payload (parameters, settings, seed-set key, and a
fingerprint of the source code that computes sets). The file name carries the
payload's hash. Loading checks the stored payload against the expected one and
the arrays against their checksum; any difference raises ``StaleCacheError``
with the first differing field, and the entry is never used.

The cache heals: ``try_load`` turns a truncated, corrupt, foreign or unreadable
entry (a folder where a file should be, a byte flipped) into one message naming
the file and ``None`` (the caller recomputes); ``try_save`` writes atomically
(temporary file in the same folder, flush, fsync, rename) and, when the folder
cannot be written, warns once naming it and lets the product go on without a cache.
"""
from __future__ import annotations

import ast
import functools
import hashlib
import importlib.util
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from rcis.errors import StaleCacheError
from rcis.polyhedron import Polyhedron
from rcis.region import Region

ENGINE_MODULES = ("rcis.invariant",)  # Pre, inside-out, outside-in; what they import follows


def default_cache_dir() -> Path:
    return Path(os.environ.get("GUARDIAN_CACHE_DIR", Path.home() / ".cache" / "guardian"))


def code_fingerprint(*modules: str) -> str:
    """Hash of the source of every module that shapes a set: the engine's and the model's.

    The modules hashed are ``ENGINE_MODULES`` (Pre, inside-out and outside-in), the given model
    modules, and, transitively, every module they import from their own top-level packages and
    from ``rcis`` (``source_closure``): editing any of them (a tolerance, a kernel, a parameter
    default) gives a new fingerprint, so a set computed by other code is never loaded.

    Parameters
    ----------
    *modules : str
        Dotted names of the modules that define and compute the system whose sets are cached
        (e.g. ``"itha.car_following"``); they must be importable.
    """
    h = hashlib.sha256()
    for name in source_closure(*ENGINE_MODULES, *modules):
        h.update(name.encode() + b"\0")
        h.update(_source(name))
    return h.hexdigest()[:16]


def source_closure(*modules: str) -> list[str]:
    """``modules`` and every module they import (at any depth, also inside functions) from their own
    top-level packages and from ``rcis``, read from their import statements; sorted names."""
    packages = {m.split(".")[0] for m in modules} | {"rcis"}
    seen, todo = set(), list(modules)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        todo += [m for m in _imports(name, _source(name)) if m.split(".")[0] in packages]
    return sorted(seen)


def _source(name: str) -> bytes:
    """A module's source, read through its loader (wherever the package is installed)."""
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None or not spec.has_location:
        raise ModuleNotFoundError(f"code_fingerprint: no source for module {name!r}")
    return spec.loader.get_data(spec.origin)


@functools.lru_cache(maxsize=256)
def _imports(name: str, source: bytes) -> tuple:
    """The modules ``name`` imports (``from p import m`` counts as ``p.m`` when that is a module)."""
    spec = importlib.util.find_spec(name)
    package = name if spec.submodule_search_locations is not None else name.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([base] if base else []))
            for a in node.names:
                sub = f"{base}.{a.name}"
                found.append(sub if _is_module(sub) else base)
    return tuple(found)


def _is_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


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
    """Write an entry atomically: a temporary file in the same folder, flushed and synced, then renamed."""
    arrays = {}
    for i, P in enumerate(region.pieces):
        arrays[f"A{i}"] = P.A
        arrays[f"b{i}"] = P.b
    meta = {"payload": payload, "key": payload_key(payload), "info": info, "dim": region.dim,
            "pieces": len(region), "digest": _arrays_digest(arrays)}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(fh, meta=np.array(json.dumps(meta)), **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_region(path: Path, expected_payload: dict) -> tuple[Region, dict]:
    """The region stored at path, after checking it was built from ``expected_payload``."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in z.files if k != "meta"}
    except Exception as exc:  # BadZipFile, EOFError, zlib.error, OSError, ValueError, KeyError, ...
        raise StaleCacheError(f"{path}: not a readable cache file ({type(exc).__name__}: {exc})") from exc
    if not isinstance(meta, dict):
        raise StaleCacheError(f"{path}: not a cache entry (no meta record)")
    stored = meta.get("payload", {})
    if stored != expected_payload:
        raise StaleCacheError(f"{path}: built with {_first_difference(stored, expected_payload)}")
    if meta.get("digest") != _arrays_digest(arrays):
        raise StaleCacheError(f"{path}: the stored pieces do not match their checksum")
    try:
        pieces = [Polyhedron(arrays[f"A{i}"], arrays[f"b{i}"]) for i in range(meta["pieces"])]
        return Region(pieces, meta["dim"]), meta["info"]
    except Exception as exc:
        raise StaleCacheError(f"{path}: malformed entry ({type(exc).__name__}: {exc})") from exc


def _warn(message: str) -> None:
    print(f"[cache] {message}", file=sys.stderr, flush=True)


def try_load(path: Path, payload: dict, log=_warn):
    """``(region, info)`` from a valid entry, else ``None`` (absent, or refused with one message)."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        return load_region(path, payload)
    except StaleCacheError as exc:
        log(f"refusing cache entry: {exc}; recomputing")
        return None


_UNWRITABLE: set = set()


def try_save(path: Path, region: Region, payload: dict, info: dict, log=_warn) -> bool:
    """Store an entry (replacing what is there); a folder that cannot be written is warned about once."""
    try:
        save_region(path, region, payload, info)
        return True
    except OSError as exc:
        folder = str(Path(path).parent)
        if folder not in _UNWRITABLE:
            _UNWRITABLE.add(folder)
            log(f"cannot write the cache folder {folder} ({type(exc).__name__}: {exc}); going on without a cache")
        return False


def _first_difference(stored, expected, prefix="") -> str:
    if isinstance(stored, dict) and isinstance(expected, dict):
        for k in sorted(set(stored) | set(expected)):
            if stored.get(k) != expected.get(k):
                return _first_difference(stored.get(k), expected.get(k), f"{prefix}{k}.")
    return f"{prefix.rstrip('.') or 'payload'} = {stored!r}, expected {expected!r}"


class RegionCache:
    """Cache-or-compute for regions: ``cache.get(name, payload, compute)``.

    ``compute()`` returns ``(region, info)``; ``info`` must be JSON. ``use_cache=False`` recomputes and
    replaces the entry. ``load``/``store`` are the two halves, for callers that compute in parallel.
    """

    def __init__(self, cache_dir: Path | None = None, use_cache: bool = True, log=_warn):
        self.dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        self.use_cache = use_cache
        self.log = log

    def path(self, name: str, payload: dict) -> Path:
        return entry_path(self.dir, name, payload)

    def load(self, name: str, payload: dict):
        """``(region, info)`` from a valid entry, else None."""
        return try_load(self.path(name, payload), payload, log=self.log) if self.use_cache else None

    def store(self, name: str, payload: dict, region: Region, info: dict) -> bool:
        return try_save(self.path(name, payload), region, payload, info, log=self.log)

    def get(self, name: str, payload: dict, compute) -> tuple[Region, dict, bool]:
        """The cached region of ``payload``, or ``compute()``'s, stored.

        Parameters
        ----------
        name : str
            The file name's stem.
        payload : dict
            Every parameter that shaped the region (JSON); its hash is the key and it is stored with
            the region, so a foreign or stale entry is refused.
        compute : callable
            ``compute() -> (region, info)``, ``info`` JSON.

        Returns
        -------
        (Region, dict, bool)
            The region, its info, and whether it came from the cache.
        """
        hit = self.load(name, payload)
        if hit is not None:
            return hit[0], hit[1], True
        region, info = compute()
        self.store(name, payload, region, info)
        return region, info, False
