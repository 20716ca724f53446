"""NGSIM vehicle trajectories (US-101, I-80) to HighD-format recordings that ``guardian replay`` reads.

Input: the public ``trajectories-*.txt`` files (18 whitespace-separated columns, no header) or the CSV
export (a header naming at least the 18 columns; further columns such as ``O_Zone`` or ``Location`` are
ignored and listed). The 18 columns, as NGSIM defines them: ``Vehicle_ID, Frame_ID, Total_Frames,
Global_Time`` (ms since 1970), ``Local_X`` (lateral position of the front centre, ft, from the road's left
edge), ``Local_Y`` (longitudinal position of the front bumper, ft), ``Global_X, Global_Y``, ``v_Length,
v_Width`` (ft), ``v_Class`` (1 motorcycle, 2 car, 3 truck), ``v_Vel`` (ft/s), ``v_Acc`` (ft/s²),
``Lane_ID`` (1 = leftmost), ``Preceding, Following`` (vehicle ids, 0 = none), ``Space_Headway`` (front to
front, ft), ``Time_Headway`` (s; 9999.99 = none). 10 Hz.

Choices (each reported in the conversion's JSON):

* Units: feet × 0.3048; speeds and accelerations likewise; times stay seconds.
* One carriageway: every vehicle drives right (``drivingDirection`` 2, the lower lanes); the upper
  markings describe two empty lanes, as in ``../shared/data/i80_sample``. laneId = 4 + Lane_ID.
* Lanes: by default every lane in the file is kept (ramps and auxiliary lanes become lanes of the
  carriageway; nothing is guessed about which they are). With ``main_lanes`` = K (I-80: 6, US-101: 5)
  lanes 1..K are the main line and rows on higher lane numbers are dropped; a vehicle keeps its longest
  run of consecutive main-line frames; the rows dropped and the vehicles cut are counted.
* Boxes: ``x`` = front − length (HighD's x is the rear of a right-moving box), ``width`` = length,
  ``y`` = Local_X − width / 2 (shifted so the road starts 20 m below the image top), ``height`` = width.
  Lane markings: midway between adjacent lanes' median centre lines; the outer ones half a lane out.
* ``yVelocity`` is the forward difference of the lateral position; ``yAcceleration`` is 0 (NGSIM has
  none). Neighbours left and right are 0 (NGSIM has none). ``Preceding`` / ``Following`` pointing at a
  vehicle not on the main line at that frame become 0 (counted). ``dhw`` = Space_Headway when there is a
  preceding vehicle, else 0; ``thw`` likewise (9999.99 → 0); ``ttc`` = dhw / closing speed when closing,
  else 0. ``class``: Motorcycle, Car, Truck.
* recordingMeta: ``month``, ``weekDay``, ``startTime`` from the first ``Global_Time`` (read as UTC).

A row that is not 18 numbers (or lacks a header column) is refused naming file, line and column.
"""
from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import pandas as pd

from guardian.errors import HighDFormatError
from guardian.highd.trajectories import longest_runs, write_highd

FEET = 0.3048
COLUMNS = ("Vehicle_ID", "Frame_ID", "Total_Frames", "Global_Time", "Local_X", "Local_Y", "Global_X", "Global_Y",
           "v_Length", "v_Width", "v_Class", "v_Vel", "v_Acc", "Lane_ID", "Preceding", "Following",
           "Space_Headway", "Time_Headway")
INTEGER_COLUMNS = ("Vehicle_ID", "Frame_ID", "Total_Frames", "Global_Time", "v_Class", "Lane_ID", "Preceding",
                   "Following")
CLASSES = {1: "Motorcycle", 2: "Car", 3: "Truck"}
NO_HEADWAY = 9999.0    # NGSIM writes 9999.99 for "no vehicle ahead"
FRAME_RATE = 10


def read_ngsim(path: Path) -> tuple[pd.DataFrame, list]:
    """The 18 columns as numbers; ``(frame, ignored extra columns)``. Errors name file, line, column."""
    path = Path(path)
    if not path.is_file():
        raise HighDFormatError(f"{path}: file is missing")
    with open(path, encoding="utf-8-sig", errors="strict") as fh:
        first = fh.readline()
    header = "Vehicle_ID" in first
    if header:
        raw = pd.read_csv(path, dtype=str, keep_default_na=False, encoding="utf-8-sig", skipinitialspace=True)
        missing = [c for c in COLUMNS if c not in raw.columns]
        if missing:
            raise HighDFormatError(f"{path}: line 1: missing columns {missing}")
        extra = [c for c in raw.columns if c not in COLUMNS]
        raw, first_line = raw[list(COLUMNS)], 2
    else:
        rows = []
        with open(path, encoding="utf-8-sig") as fh:
            for k, line in enumerate(fh, 1):
                fields = line.split()
                if not fields:
                    continue
                if len(fields) != len(COLUMNS):
                    raise HighDFormatError(f"{path}: line {k}: {len(fields)} fields, expected {len(COLUMNS)} "
                                           f"({', '.join(COLUMNS)})")
                rows.append(fields + [k])
        if not rows:
            raise HighDFormatError(f"{path}: line 1: no data rows")
        raw = pd.DataFrame(rows, columns=list(COLUMNS) + ["_line"])
        extra, first_line = [], None
    lines = raw.pop("_line").to_numpy() if "_line" in raw else np.arange(len(raw)) + first_line
    out = {}
    for c in COLUMNS:
        num = pd.to_numeric(raw[c].str.strip(), errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(num))
        if len(bad):
            r = bad[0]
            raise HighDFormatError(f"{path}: line {lines[r]}, column {c!r}: {raw[c].iloc[r]!r} is not a number")
        if c in INTEGER_COLUMNS:
            frac = np.flatnonzero(num != np.round(num))
            if len(frac):
                r = frac[0]
                raise HighDFormatError(f"{path}: line {lines[r]}, column {c!r}: {raw[c].iloc[r]!r} is not an integer")
            num = num.astype(np.int64)
        out[c] = num
    df = pd.DataFrame(out)
    df["_line"] = lines
    dup = df.duplicated(["Vehicle_ID", "Frame_ID"], keep=False).to_numpy()
    if dup.any():
        r = np.flatnonzero(dup)[:2]
        raise HighDFormatError(f"{path}: (Vehicle_ID {df['Vehicle_ID'].iloc[r[0]]}, Frame_ID "
                               f"{df['Frame_ID'].iloc[r[0]]}) appears on lines {lines[r[0]]} and {lines[r[1]]}")
    return df, extra


def trajectories(df: pd.DataFrame) -> pd.DataFrame:
    """NGSIM's columns as ``guardian.highd.trajectories.TRAJECTORY_COLUMNS`` (metres; ``Global_Time`` kept)."""
    thw = df["Time_Headway"].to_numpy()
    return pd.DataFrame({
        "vehicle": df["Vehicle_ID"], "frame": df["Frame_ID"], "front": df["Local_Y"] * FEET,
        "lateral": df["Local_X"] * FEET, "length": df["v_Length"] * FEET, "width": df["v_Width"] * FEET,
        "vclass": df["v_Class"].map(lambda k: CLASSES.get(int(k), "Car")), "speed": df["v_Vel"] * FEET,
        "accel": df["v_Acc"] * FEET, "lane": df["Lane_ID"], "preceding": df["Preceding"],
        "following": df["Following"], "space_headway": df["Space_Headway"] * FEET,
        "time_headway": np.where(thw < NO_HEADWAY, thw, 0.0), "Global_Time": df["Global_Time"]})


def convert_ngsim(path: Path, out: Path, main_lanes: int | None = None, recording_id: int = 1,
                  location_id: int = 0) -> dict:
    """Convert an NGSIM trajectory file to one HighD recording.

    Parameters
    ----------
    path : path
        The NGSIM file (US-101 / I-80 columns, feet).
    out : path
        Where ``NN_recordingMeta.csv``, ``NN_tracksMeta.csv`` and ``NN_tracks.csv`` are written.
    main_lanes : int, optional
        Keep lanes 1..main_lanes (ramps and shoulders dropped, and counted); None keeps every lane
        (``"main_lanes": null`` in the report).
    recording_id, location_id : int
        The ids written into the meta files.

    Returns
    -------
    dict
        What was converted and what was dropped, with counts.
    """
    if main_lanes is not None and main_lanes < 1:
        raise ValueError(f"main_lanes must be at least 1, got {main_lanes}")
    df, extra = read_ngsim(path)
    requested = main_lanes
    if main_lanes is None:
        main_lanes = int(df["Lane_ID"].max())
    t, report = longest_runs(trajectories(df), main_lanes)
    if t.empty:
        raise HighDFormatError(f"{path}: no row on the main line (lanes 1..{main_lanes})")
    start = dt.datetime.fromtimestamp(int(t["Global_Time"].min()) / 1000, tz=dt.timezone.utc)
    files, written = write_highd(t, out, main_lanes, FRAME_RATE, start, recording_id, location_id)
    return {"source": str(path), "out": str(out), "files": files, "vehicles": int(t["vehicle"].nunique()),
            "rows": int(len(t)), "main_lanes": requested, "lanes": main_lanes, "ignored_columns": extra,
            **report, **written}
