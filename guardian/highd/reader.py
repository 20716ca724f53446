"""Reading HighD-format recordings with validation that names file, row and column.

``read_recording(folder, recording_id)`` parses the three files with explicit dtypes. Any
problem raises ``HighDFormatError`` whose message names the file, the CSV line (header = line 1)
and the column: missing or extra columns, values of the wrong type, NaN or infinite values,
duplicated ``(id, frame)``, frames that skip within a track, ids the meta file lacks, meta
counts that disagree with the tracks, and lane ids that the lane markings cannot hold or that lie
on the other carriageway. Nothing is dropped, clipped or guessed.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from guardian.errors import HighDFormatError
from guardian.highd.files import recording_files
from guardian.highd.numeric_csv import read_numeric_csv
from guardian.highd.schema import FILES, FLOAT, INT, META_FORMATS, PLAUSIBILITY, STR, file_name



@dataclass
class Recording:
    id: int
    folder: Path
    meta: dict
    tracks_meta: pd.DataFrame
    tracks: pd.DataFrame
    upper_markings: list
    lower_markings: list
    paths: dict = field(default_factory=dict)  # kind -> the file read

    @property
    def frame_rate(self) -> int:
        return int(self.meta["frameRate"])

    def lanes_of(self, direction: int) -> list[int]:
        """Valid laneIds of a driving direction (1: upper carriageway, 2: lower)."""
        n_up, n_low = len(self.upper_markings) - 1, len(self.lower_markings) - 1
        if direction == 1:
            return list(range(2, n_up + 2))
        return list(range(n_up + 3, n_up + n_low + 3))


def line_of(path: Path, row_index) -> int:
    """The physical line (1-based) where data row ``row_index`` starts, as pandas numbers rows.

    pandas skips blank lines and lets quoted fields span lines, so row + 2 is not the line. The
    file is scanned only when an error is reported.
    """
    import csv
    import io

    text = Path(path).read_bytes().decode("utf-8-sig")
    reader = csv.reader(io.StringIO(text, newline=""))
    record, target = -1, int(row_index) + 1  # record 0 is the header
    while True:
        start = reader.line_num + 1
        try:
            row = next(reader)
        except StopIteration:
            return start
        if not row:
            continue  # a blank line
        record += 1
        if record == target:
            return start


def read_table(path: Path, schema: dict) -> pd.DataFrame:
    """One CSV with the columns and dtypes of ``schema``; errors name file, line and column."""
    path = Path(path)
    if not path.is_file():
        raise HighDFormatError(f"{path}: file is missing")
    df = _read_clean_csv(path, schema)
    if df is None:  # something to report: the checks, pandas' reader and the locators name it precisely
        _check_bytes(path)
        header = pd.read_csv(path, nrows=0, encoding="utf-8-sig").columns.tolist()
        missing = [c for c in schema if c not in header]
        extra = [c for c in header if c not in schema]
        if missing or extra:
            parts = (([f"missing columns {missing}"] if missing else [])
                     + ([f"unexpected columns {extra}"] if extra else []))
            raise HighDFormatError(f"{path}: " + "; ".join(parts))
        dtypes = {c: ("float64" if t == INT else t) for c, t in schema.items()}  # ints checked below
        try:
            df = pd.read_csv(path, dtype=dtypes, engine="c", na_filter=True, encoding="utf-8-sig")
        except pd.errors.ParserError as exc:  # a row with the wrong number of fields; pandas names the line
            raise HighDFormatError(f"{path}: malformed CSV: {str(exc).strip()}") from None
        except (ValueError, TypeError) as exc:
            _locate_type_error(path, schema)
            raise HighDFormatError(f"{path}: {exc}") from exc
    if len(df) == 0:
        raise HighDFormatError(f"{path}: line 1: a header but no data rows")
    _check_missing(path, df, schema)
    for c, t in schema.items():
        if t == INT and df[c].dtype.kind == "f":
            col = df[c].to_numpy()
            frac = np.flatnonzero(~_exact_integers(col))
            if len(frac):
                r = frac[0]
                raise HighDFormatError(f"{path}: line {line_of(path, r)}, column {c!r}: {float(col[r]):g} is not an integer"
                                       + (f" of at most {MAX_EXACT_INT:.0f}" if col[r] == np.round(col[r]) else ""))
            df[c] = col.astype(np.int64)
    return df


MAX_EXACT_INT = 2.0 ** 53  # integers read as float64 are exact up to this


def _exact_integers(col: np.ndarray) -> np.ndarray:
    """Which float64 values are integers that int64 holds exactly."""
    return (col == np.round(col)) & (np.abs(col) <= MAX_EXACT_INT)


PARSE_THREADS = True  # pyarrow parses with its thread pool; replay's worker processes turn it off (one core each)


def _read_clean_csv(path: Path, schema: dict) -> pd.DataFrame | None:
    """A clean file through a fast reader; None if anything needs a message.

    An all-numeric file (the tracks) goes through ``numeric_csv``'s compiled reader, which returns
    pyarrow's doubles bit for bit or declines; otherwise, or when it declines, pyarrow's
    multi-threaded CSV reader.

    Clean means: the header holds exactly the schema's columns, pyarrow parses every value as the
    schema's type (strings checked as UTF-8, numbers are ASCII), and no value is missing. Anything
    else (a bad value or byte, a short row, an empty field, a stray quote, a BOM, an empty file)
    returns None and the caller runs the byte check and pandas' reader, whose messages, and the
    locators after them, name the line and column. So a clean file is read fast and a dirty one is
    reported by the careful path.
    """
    import pyarrow as pa
    import pyarrow.csv as pcsv

    if STR not in schema.values():  # all numeric (the tracks files): the compiled reader, exact or declining
        parsed = read_numeric_csv(path, list(schema))
        if parsed is not None:  # integer columns that hold integers become int64 here; read_table names the rest
            columns, plain = parsed
            for c, values in columns.items():
                if schema[c] == INT and (c in plain or _exact_integers(values).all()):
                    columns[c] = values.astype(np.int64)
            return pd.DataFrame(columns, copy=False)
    types = {c: (pa.string() if t == STR else pa.float64()) for c, t in schema.items()}
    try:
        table = pcsv.read_csv(path, read_options=pcsv.ReadOptions(use_threads=PARSE_THREADS),
                              convert_options=pcsv.ConvertOptions(column_types=types, strings_can_be_null=True))
    except (pa.ArrowException, ValueError):
        return None
    names = table.column_names
    if sorted(names) != sorted(schema) or table.num_rows == 0 or any(col.null_count for col in table.columns):
        return None
    df = table.to_pandas()
    for c, t in schema.items():
        if t == STR:
            df[c] = df[c].astype(t)  # the dtype pandas gives the schema's strings
    return df


def _check_bytes(path: Path) -> None:
    """UTF-8 (with or without BOM), not empty; an undecodable byte is named by line and column."""
    import codecs

    decoder, blank = codecs.getincrementaldecoder("utf-8")(), True
    try:
        with open(path, "rb") as fh:
            while chunk := fh.read(1 << 24):  # 16 MiB at a time: HighD track files are ~200 MB
                blank = blank and not chunk.strip()
                decoder.decode(chunk)
        decoder.decode(b"", final=True)
    except UnicodeDecodeError:
        _name_undecodable_byte(path)
    if blank:
        raise HighDFormatError(f"{path}: line 1: the file is empty (no header)")


def _name_undecodable_byte(path: Path) -> None:
    data = path.read_bytes()
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line_start = data.rfind(b"\n", 0, exc.start) + 1
        line = data.count(b"\n", 0, exc.start) + 1
        field = data[line_start:exc.start].count(b",")
        header = data.split(b"\n", 1)[0].decode("utf-8", "replace").lstrip("\ufeff").strip().split(",")
        column = header[field] if field < len(header) and line > 1 else f"field {field + 1}"
        raise HighDFormatError(f"{path}: line {line}, column {column!r}: byte 0x{data[exc.start]:02x} is not "
                               f"UTF-8") from None


def _locate_type_error(path: Path, schema: dict) -> None:
    raw = pd.read_csv(path, dtype=str, keep_default_na=False, encoding="utf-8-sig")
    for c, t in schema.items():
        if t == STR:
            continue
        vals = raw[c].str.strip()
        num = pd.to_numeric(vals.where(vals != ""), errors="coerce")
        bad = np.flatnonzero(num.isna().to_numpy() & (vals != "").to_numpy()
                             & ~vals.str.lower().isin(["nan", "inf", "-inf", "na", "null"]).to_numpy())
        if len(bad):
            r = bad[0]
            kind = "an integer" if t == INT else "a number"
            raise HighDFormatError(f"{path}: line {line_of(path, r)}, column {c!r}: {raw[c].iloc[r]!r} is not {kind}")


def _check_missing(path: Path, df: pd.DataFrame, schema: dict) -> None:
    for c, t in schema.items():
        col = df[c]
        if col.dtype.kind in "iu":
            continue  # integers are never missing nor infinite
        if col.dtype.kind == "f":
            bad = ~np.isfinite(col.to_numpy())
        else:
            bad = col.isna().to_numpy().copy()
            if t in (FLOAT, INT):
                bad |= ~np.isfinite(col.to_numpy(dtype=float, na_value=np.nan))
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            what = "missing value (NaN)" if pd.isna(col.iloc[r]) else f"non-finite value {float(col.iloc[r]):g}"
            raise HighDFormatError(f"{path}: line {line_of(path, r)}, column {c!r}: {what}")


def _markings(path: Path, value: str, column: str) -> list[float]:
    try:
        marks = [float(v) for v in str(value).split(";")]
    except ValueError:
        raise HighDFormatError(f"{path}: line 2, column {column!r}: {value!r} is not a ';'-separated list "
                               f"of numbers") from None
    if len(marks) < 2 or any(b <= a for a, b in zip(marks, marks[1:])) or not all(np.isfinite(marks)):
        raise HighDFormatError(f"{path}: line 2, column {column!r}: {value!r} must be at least two "
                               f"increasing finite positions")
    return marks


def read_recording(folder: Path, recording_id: int, plausibility: bool = True) -> Recording:
    """Read and validate one recording's three files (``NN_recordingMeta``, ``NN_tracksMeta``, ``NN_tracks``).

    Parameters
    ----------
    folder : path
        The folder holding the files (``.csv``, or ``.csv.gz``/``.parquet`` where supported).
    recording_id : int
        NN.
    plausibility : bool
        Also apply the plausibility rules (speeds, accelerations, lane ids against the markings).

    Returns
    -------
    Recording
        The meta data, the two tables and the lane markings.

    Raises
    ------
    HighDFormatError
        Names the file, line, column and value of the first problem.
    """
    folder = Path(folder)
    found = recording_files(folder).get(recording_id, {})
    paths = {kind: found.get(kind, folder / file_name(recording_id, kind)) for kind in FILES}
    meta_df = read_table(paths["recordingMeta"], FILES["recordingMeta"])
    if len(meta_df) != 1:
        raise HighDFormatError(f"{paths['recordingMeta']}: expected one row, found {len(meta_df)}")
    meta = meta_df.iloc[0].to_dict()
    if int(meta["id"]) != recording_id:
        raise HighDFormatError(f"{paths['recordingMeta']}: line 2, column 'id': {meta['id']} does not match "
                               f"the file name's recording {recording_id}")
    for column, (pattern, form) in META_FORMATS.items():
        if not pattern.match(str(meta[column]).strip()):
            raise HighDFormatError(f"{paths['recordingMeta']}: line 2, column {column!r}: {meta[column]!r} is not "
                                   f"{form}")
    if int(meta["frameRate"]) <= 0:
        raise HighDFormatError(f"{paths['recordingMeta']}: line 2, column 'frameRate': must be positive")
    upper = _markings(paths["recordingMeta"], meta["upperLaneMarkings"], "upperLaneMarkings")
    lower = _markings(paths["recordingMeta"], meta["lowerLaneMarkings"], "lowerLaneMarkings")
    tmeta = read_table(paths["tracksMeta"], FILES["tracksMeta"])
    tracks = read_table(paths["tracks"], FILES["tracks"])
    rec = Recording(recording_id, folder, meta, tmeta, tracks, upper, lower, paths)
    _check_tracks_meta(paths["tracksMeta"], tmeta)
    direction = _check_tracks(paths["tracks"], rec)
    if plausibility:
        _check_plausibility(rec, direction)
    return rec


def _check_plausibility(rec: Recording, direction: np.ndarray) -> None:
    """The rules of ``schema.PLAUSIBILITY``; each refusal names the rule and how to go on.
    ``direction``: each tracks row's drivingDirection (``_check_tracks`` gives it)."""
    hint = "(a plausibility rule; --no-plausibility reads it anyway)"
    lo, hi = PLAUSIBILITY["frameRate"]
    if not lo <= rec.frame_rate <= hi:
        raise HighDFormatError(f"{rec.paths['recordingMeta']}: line 2, column 'frameRate': {rec.frame_rate} Hz is "
                               f"outside [{lo}, {hi}] {hint}")
    t, path = rec.tracks, rec.paths["tracks"]
    for columns, bound, what in ((("xVelocity", "yVelocity"), PLAUSIBILITY["speed"], "m/s"),
                                 (("xAcceleration", "yAcceleration"), PLAUSIBILITY["acceleration"], "m/s^2")):
        for c in columns:
            col = t[c].to_numpy()
            bad = np.flatnonzero(np.abs(col) > bound)
            if len(bad):
                r = bad[0]
                raise HighDFormatError(f"{path}: line {line_of(path, r)}, column {c!r}: |{col[r]:g}| {what} exceeds "
                                       f"{bound:g} {what} {hint}")
    centre = (t["y"] + t["height"] / 2).to_numpy()
    margin = PLAUSIBILITY["outside_markings"]
    for d, marks in ((1, rec.upper_markings), (2, rec.lower_markings)):
        bad = np.flatnonzero((direction == d) & ((centre < marks[0] - margin) | (centre > marks[-1] + margin)))
        if len(bad):
            r = bad[0]
            raise HighDFormatError(f"{path}: line {line_of(path, r)}, column 'y': the box centre {centre[r]:.2f} m lies "
                                   f"outside direction {d}'s lane markings [{marks[0]:g}, {marks[-1]:g}] by more than "
                                   f"{margin:g} m {hint}")


def _check_tracks_meta(path: Path, tmeta: pd.DataFrame) -> None:
    dup = tmeta["id"].duplicated(keep=False).to_numpy()
    if dup.any():
        rows = np.flatnonzero(dup)
        raise HighDFormatError(f"{path}: id {int(tmeta['id'].iloc[rows[0]])} appears on lines "
                               f"{[line_of(path, r) for r in rows[:5]]}")
    bad = np.flatnonzero(~tmeta["drivingDirection"].isin([1, 2]).to_numpy())
    if len(bad):
        r = bad[0]
        raise HighDFormatError(f"{path}: line {line_of(path, r)}, column 'drivingDirection': "
                               f"{int(tmeta['drivingDirection'].iloc[r])} is not 1 or 2")
    bad = np.flatnonzero((tmeta["width"] <= 0).to_numpy() | (tmeta["height"] <= 0).to_numpy())
    if len(bad):
        raise HighDFormatError(f"{path}: line {line_of(path, bad[0])}: vehicle size must be positive")
    bad = np.flatnonzero((tmeta["numFrames"] < 1).to_numpy())
    if len(bad):
        r = bad[0]
        raise HighDFormatError(f"{path}: line {line_of(path, r)}, column 'numFrames': {int(tmeta['numFrames'].iloc[r])}; "
                               f"a vehicle has at least one frame")


def positions(keys: np.ndarray, query: np.ndarray) -> np.ndarray:
    """The index in ``keys`` (distinct integers, e.g. tracksMeta's ids) of each query value; -1 where absent.

    HighD numbers vehicles 1..N, so a dense table answers in one gather; ids spread wider (or
    negative) are searched in sorted order instead.
    """
    keys, query = np.asarray(keys, dtype=np.int64), np.asarray(query, dtype=np.int64)
    if not len(keys):
        return np.full(len(query), -1, dtype=np.int64)
    low, high = int(keys.min()), int(keys.max())
    if low >= 0 and high <= 4 * len(keys) + 1024:
        table = np.full(high + 2, -1, dtype=np.int64)  # the last slot answers every id outside [0, high]
        table[keys] = np.arange(len(keys))
        return table[np.where((query >= 0) & (query <= high), query, high + 1)]
    order = np.argsort(keys, kind="stable")
    at = np.minimum(np.searchsorted(keys[order], query), len(keys) - 1)
    return np.where(keys[order][at] == query, order[at], -1)


def track_order(ids: np.ndarray, frames: np.ndarray) -> np.ndarray | None:
    """The rows sorted by (id, frame), or None when they already are, strictly (HighD's own order)."""
    same = ids[1:] == ids[:-1]
    if np.all((ids[1:] > ids[:-1]) | (same & (frames[1:] > frames[:-1]))):
        return None
    return np.lexsort((frames, ids))


def _check_tracks(path: Path, rec: Recording) -> np.ndarray:
    """The tracks file against itself and tracksMeta; returns each row's drivingDirection."""
    t = rec.tracks
    ids, frames = t["id"].to_numpy(), t["frame"].to_numpy()
    order = track_order(ids, frames)
    si, sf = (ids, frames) if order is None else (ids[order], frames[order])
    if order is None:
        order = np.arange(len(ids))
    same = si[1:] == si[:-1]
    dup = np.flatnonzero(same & (sf[1:] == sf[:-1]))
    if len(dup):
        a, b = sorted((order[dup[0]], order[dup[0] + 1]))
        raise HighDFormatError(f"{path}: (id {si[dup[0]]}, frame {sf[dup[0]]}) appears on lines {line_of(path, a)} "
                               f"and {line_of(path, b)}")
    skip = np.flatnonzero(same & (sf[1:] - sf[:-1] != 1))
    if len(skip):
        k = skip[0]
        raise HighDFormatError(f"{path}: line {line_of(path, order[k + 1])}: track {si[k]} jumps from frame {sf[k]} "
                               f"to frame {sf[k + 1]}")
    known = rec.tracks_meta.set_index("id")
    meta_ids = known.index.to_numpy()
    meta_row = positions(meta_ids, ids)
    unknown = np.flatnonzero(meta_row < 0)
    if len(unknown):
        r = unknown[0]
        raise HighDFormatError(f"{path}: line {line_of(path, r)}, column 'id': vehicle {ids[r]} is not in "
                               f"{file_name(rec.id, 'tracksMeta')}")
    starts = np.flatnonzero(np.concatenate(([True], ~same)))  # each track's first row in (id, frame) order
    track_ids, lengths = si[starts], np.diff(np.append(starts, len(si)))
    at = np.minimum(np.searchsorted(track_ids, meta_ids), len(track_ids) - 1)
    seen = track_ids[at] == meta_ids
    counts, firsts = np.where(seen, lengths[at], 0), np.where(seen, sf[starts][at], -1)
    wrong = (counts != known["numFrames"].to_numpy()) | (seen & (firsts != known["initialFrame"].to_numpy()))
    if wrong.any():
        i = int(np.argmax(wrong))
        row = known.iloc[i]
        raise HighDFormatError(f"{rec.paths['tracksMeta']}: vehicle {meta_ids[i]}: numFrames "
                               f"{int(row['numFrames'])} / initialFrame {int(row['initialFrame'])} disagree "
                               f"with {path.name} ({int(counts[i])} frames from {int(firsts[i])})")
    direction = known["drivingDirection"].to_numpy()[meta_row]
    lanes = t["laneId"].to_numpy()
    for d in (1, 2):
        ok = np.isin(lanes, rec.lanes_of(d))
        bad = np.flatnonzero((direction == d) & ~ok)
        if len(bad):
            r = bad[0]
            raise HighDFormatError(f"{path}: line {line_of(path, r)}, column 'laneId': lane {lanes[r]} cannot hold vehicle "
                                   f"{ids[r]} (direction {d}); the markings give lanes {rec.lanes_of(d)}")
    for c in ("precedingId", "followingId"):
        col = t[c].to_numpy()
        bad = np.flatnonzero((col != 0) & (positions(meta_ids, col) < 0))
        if len(bad):
            r = bad[0]
            raise HighDFormatError(f"{path}: line {line_of(path, r)}, column {c!r}: vehicle {col[r]} is not in "
                                   f"{file_name(rec.id, 'tracksMeta')}")
    return direction


def subsample(rec: Recording, step: int) -> Recording:
    """Every ``step``-th frame of the recording (counted from its first), renumbered 1, 2, ...: the same traffic seen
    at ``frameRate / step`` Hz; refused unless ``step`` divides the frame rate (HighD's frameRate is whole)."""
    if step == 1:
        return rec
    if step < 1 or rec.frame_rate % step:
        raise HighDFormatError(f"recording {rec.id}: a frame step of {step} does not divide its frame rate "
                               f"{rec.frame_rate} Hz")
    t = rec.tracks
    first = int(t["frame"].min())
    t = t[(t["frame"] - first) % step == 0].copy()
    t["frame"] = (t["frame"] - first) // step + 1
    g = t.groupby("id")["frame"]
    meta = rec.tracks_meta[rec.tracks_meta["id"].isin(t["id"].unique())].copy()
    ids = meta["id"]
    meta["initialFrame"], meta["finalFrame"] = ids.map(g.min()).to_numpy(), ids.map(g.max()).to_numpy()
    meta["numFrames"] = ids.map(g.size()).to_numpy()
    return replace(rec, meta={**rec.meta, "frameRate": rec.frame_rate // step}, tracks_meta=meta.reset_index(drop=True),
                   tracks=t.reset_index(drop=True), paths={})
