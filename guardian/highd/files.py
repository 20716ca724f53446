"""Which HighD-format recordings a folder holds: ``NN_recordingMeta.csv``, ``NN_tracksMeta.csv``,
``NN_tracks.csv`` per recording ``NN``."""
from __future__ import annotations

import functools
import re
from pathlib import Path

from guardian.errors import HighDFormatError

FILE_PATTERN = re.compile(r"^(\d+)_(recordingMeta|tracksMeta|tracks)\.csv$")


def recording_files(folder: Path) -> dict[int, dict[str, Path]]:
    """``{id: {kind: path}}`` of a folder's HighD files; the id is the number before ``_`` (``1_`` = ``01_``).

    Two files of the same recording and kind (``1_tracks.csv`` and ``01_tracks.csv``) are refused,
    naming both: reading either would silently drop the other, reading both would count it twice.

    A folder is listed once while it does not change (keyed by its path and modification time, which a file
    added, removed or renamed moves): a replay asks for every recording's files, and listing a folder of 1,000
    recordings each time made the replay quadratic. Read-only: callers must not change the answer.
    """
    folder = Path(folder)
    return _listing(str(folder.resolve()), folder.stat().st_mtime_ns)


@functools.lru_cache(maxsize=16)
def _listing(folder: str, mtime_ns: int) -> dict[int, dict[str, Path]]:
    found: dict[int, dict[str, Path]] = {}
    for p in sorted(Path(folder).iterdir()):
        m = FILE_PATTERN.match(p.name)
        if not m:
            continue
        rid, kind = int(m.group(1)), m.group(2)
        other = found.setdefault(rid, {}).get(kind)
        if other is not None:
            raise HighDFormatError(f"{folder}: {other.name} and {p.name} are both recording {rid}'s {kind}; "
                                   f"keep one")
        found[rid][kind] = p
    return found


def recording_ids(path: Path) -> list[int]:
    """Recording ids in a folder (from ``NN_recordingMeta.csv``), or of the one recording a file names."""
    path = Path(path)
    if path.is_file():
        m = re.match(r"^(\d+)_", path.name)
        if not m:
            raise HighDFormatError(f"{path}: not a HighD file name (NN_recordingMeta.csv, NN_tracks.csv, ...)")
        return [int(m.group(1))]
    if not path.is_dir():
        raise HighDFormatError(f"{path}: no such file or folder")
    ids = sorted(rid for rid, kinds in recording_files(path).items() if "recordingMeta" in kinds)
    if not ids:
        raise HighDFormatError(f"{path}: no NN_recordingMeta.csv in this folder")
    return ids
