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
from guardian.highd.schema import RECORDING_META, TRACKS, TRACKS_META, file_name

FEET = 0.3048
COLUMNS = ("Vehicle_ID", "Frame_ID", "Total_Frames", "Global_Time", "Local_X", "Local_Y", "Global_X", "Global_Y",
           "v_Length", "v_Width", "v_Class", "v_Vel", "v_Acc", "Lane_ID", "Preceding", "Following",
           "Space_Headway", "Time_Headway")
INTEGER_COLUMNS = ("Vehicle_ID", "Frame_ID", "Total_Frames", "Global_Time", "v_Class", "Lane_ID", "Preceding",
                   "Following")
CLASSES = {1: "Motorcycle", 2: "Car", 3: "Truck"}
NO_HEADWAY = 9999.0    # NGSIM writes 9999.99 for "no vehicle ahead"
ROAD_TOP = 20.0        # [m] image y of the first lower-carriageway marking
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


def _main_line_runs(df: pd.DataFrame, main_lanes: int) -> tuple[pd.DataFrame, dict]:
    """Rows on lanes 1..main_lanes; each vehicle keeps its longest run of consecutive frames (first on ties)."""
    on_main = df["Lane_ID"].between(1, main_lanes)
    kept = df[on_main].sort_values(["Vehicle_ID", "Frame_ID"]).reset_index(drop=True)
    run = ((kept["Frame_ID"].diff() != 1) | (kept["Vehicle_ID"].diff() != 0)).cumsum()
    size = run.map(run.value_counts())
    ranked = pd.DataFrame({"vid": kept["Vehicle_ID"], "run": run, "size": size})
    best = ranked.sort_values(["vid", "size", "run"], ascending=[True, False, True]).groupby("vid")["run"].first()
    result = kept[run == kept["Vehicle_ID"].map(best)].reset_index(drop=True)
    runs_per_vehicle = ranked.groupby("vid")["run"].nunique()
    report = {"ramp_rows_dropped": int((~on_main).sum()),
              "rows_dropped_to_keep_frames_consecutive": int(len(kept) - len(result)),
              "vehicles_cut": int((runs_per_vehicle > 1).sum()),
              "vehicles_only_on_ramps": int(df["Vehicle_ID"].nunique() - result["Vehicle_ID"].nunique())}
    return result, report


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
    df, report = _main_line_runs(df, main_lanes)
    if df.empty:
        raise HighDFormatError(f"{path}: no row on the main line (lanes 1..{main_lanes})")
    length, width = df["v_Length"].to_numpy() * FEET, df["v_Width"].to_numpy() * FEET
    lateral = df["Local_X"].to_numpy() * FEET
    centres = pd.Series(lateral).groupby(df["Lane_ID"].to_numpy()).median().reindex(range(1, main_lanes + 1))
    centres = centres.interpolate(limit_direction="both").to_numpy()
    spacing = np.diff(centres).mean() if main_lanes > 1 else 3.6
    bounds = np.concatenate([[centres[0] - spacing / 2], (centres[1:] + centres[:-1]) / 2,
                             [centres[-1] + spacing / 2]])
    shift = ROAD_TOP - bounds[0]
    lower = bounds + shift
    upper = ROAD_TOP - np.array([3, 2, 1]) * 3.6 - 0.5  # two empty lanes above, as in the I-80 sample
    front = df["Local_Y"].to_numpy() * FEET
    v = df["v_Vel"].to_numpy() * FEET
    key = pd.MultiIndex.from_arrays([df["Vehicle_ID"], df["Frame_ID"]])
    present = pd.Series(np.arange(len(df)), index=key)
    tracks = pd.DataFrame({"frame": df["Frame_ID"], "id": df["Vehicle_ID"], "x": front - length,
                           "y": lateral + shift - width / 2, "width": length, "height": width,
                           "xVelocity": v, "yVelocity": 0.0, "xAcceleration": df["v_Acc"].to_numpy() * FEET,
                           "yAcceleration": 0.0})
    y_centre = lateral + shift
    same = df["Vehicle_ID"].to_numpy()[1:] == df["Vehicle_ID"].to_numpy()[:-1]
    vy = np.zeros(len(df))
    vy[:-1] = np.where(same, np.diff(y_centre) * FRAME_RATE, 0.0)
    tracks["yVelocity"] = vy
    road_end = float(front.max())
    tracks["frontSightDistance"] = road_end - front
    tracks["backSightDistance"] = front - length - float((front - length).min())
    cleared = 0
    for c in ("Preceding", "Following"):
        ref = pd.MultiIndex.from_arrays([df[c], df["Frame_ID"]])
        ok = (df[c].to_numpy() != 0) & present.reindex(ref).notna().to_numpy()
        cleared += int(((df[c].to_numpy() != 0) & ~ok).sum())
        tracks["precedingId" if c == "Preceding" else "followingId"] = np.where(ok, df[c].to_numpy(), 0)
    has_lead = tracks["precedingId"].to_numpy() != 0
    lead_rows = present.reindex(pd.MultiIndex.from_arrays([tracks["precedingId"], df["Frame_ID"]])).to_numpy()
    v_lead = np.where(has_lead, v[np.nan_to_num(lead_rows, nan=0).astype(int)], 0.0)
    dhw = np.where(has_lead, df["Space_Headway"].to_numpy() * FEET, 0.0)
    thw_raw = df["Time_Headway"].to_numpy()
    closing = has_lead & (v > v_lead)
    tracks["dhw"] = dhw
    tracks["thw"] = np.where(has_lead & (thw_raw < NO_HEADWAY), thw_raw, 0.0)
    tracks["ttc"] = np.where(closing, dhw / np.where(closing, v - v_lead, 1.0), 0.0)
    tracks["precedingXVelocity"] = v_lead
    for c in ("leftPrecedingId", "leftAlongsideId", "leftFollowingId", "rightPrecedingId", "rightAlongsideId",
              "rightFollowingId"):
        tracks[c] = 0
    tracks["laneId"] = df["Lane_ID"].to_numpy() + 4
    tracks = tracks[list(TRACKS)].sort_values(["frame", "id"]).reset_index(drop=True)
    report["neighbour_references_cleared"] = cleared
    meta = _tracks_meta(tracks, df)
    rec_meta = _recording_meta(recording_id, location_id, df, tracks, meta, upper, lower)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for kind, table in (("recordingMeta", rec_meta), ("tracksMeta", meta), ("tracks", tracks)):
        p = out / file_name(recording_id, kind)
        table.to_csv(p, index=False, float_format="%.2f")
        files.append(str(p))
    return {"source": str(path), "out": str(out), "files": files, "vehicles": int(len(meta)),
            "rows": int(len(tracks)), "main_lanes": requested, "lanes": main_lanes, "ignored_columns": extra,
            **report}


def _tracks_meta(tracks: pd.DataFrame, df: pd.DataFrame) -> pd.DataFrame:
    g = tracks.groupby("id")
    cls = df.groupby("Vehicle_ID")["v_Class"].first().map(lambda k: CLASSES.get(int(k), "Car"))
    meta = pd.DataFrame({
        "width": g["width"].first(), "height": g["height"].first(), "initialFrame": g["frame"].min(),
        "finalFrame": g["frame"].max(), "numFrames": g.size(), "class": cls.reindex(g.size().index),
        "drivingDirection": 2, "traveledDistance": g["x"].max() - g["x"].min(),
        "minXVelocity": g["xVelocity"].min(), "maxXVelocity": g["xVelocity"].max(),
        "meanXVelocity": g["xVelocity"].mean(),
    })
    for name, col in (("minDHW", "dhw"), ("minTHW", "thw"), ("minTTC", "ttc")):
        pos = tracks[col].where(tracks[col] > 0)
        meta[name] = pos.groupby(tracks["id"]).min().reindex(meta.index).fillna(-1)
    meta["numLaneChanges"] = g["laneId"].apply(lambda s: int((s.diff().fillna(0) != 0).sum()))
    return meta.reset_index().rename(columns={"index": "id"})[list(TRACKS_META)]


def _recording_meta(rid, location_id, df, tracks, meta, upper, lower) -> pd.DataFrame:
    start = dt.datetime.fromtimestamp(int(df["Global_Time"].min()) / 1000, tz=dt.timezone.utc)
    n_trucks = int((meta["class"] == "Truck").sum())
    frames = tracks["frame"]
    return pd.DataFrame([{
        "id": rid, "frameRate": FRAME_RATE, "locationId": location_id, "speedLimit": -1.0,
        "month": start.strftime("%m.%Y"), "weekDay": start.strftime("%a"), "startTime": start.strftime("%H:%M"),
        "duration": round((frames.max() - frames.min() + 1) / FRAME_RATE, 2),
        "totalDrivenDistance": round(float(meta["traveledDistance"].sum()), 2),
        "totalDrivenTime": round(len(tracks) / FRAME_RATE, 2), "numVehicles": len(meta),
        "numCars": len(meta) - n_trucks, "numTrucks": n_trucks,
        "upperLaneMarkings": ";".join(f"{m:.2f}" for m in upper),
        "lowerLaneMarkings": ";".join(f"{m:.2f}" for m in lower),
    }])[list(RECORDING_META)]
