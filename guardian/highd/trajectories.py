"""Trajectories of one carriageway in metres, and the HighD recording written from them.

The converters (``guardian.highd.ngsim``, ``guardian.highd.commonroad``) read their source into one table,
``TRAJECTORY_COLUMNS``, one row per vehicle and frame, every vehicle driving the same way:

* ``vehicle``, ``frame`` (integers; a vehicle's frames consecutive), ``front`` [m] (front bumper along the
  direction of travel), ``lateral`` [m] (the centre's distance from the road's left edge, growing to the
  right), ``length``, ``width`` [m], ``vclass`` (``Car``, ``Truck``, ``Motorcycle``), ``speed`` [m/s],
  ``accel`` [m/s²], ``lane`` (1 = leftmost);
* ``preceding``, ``following``: vehicle ids in the same lane (0 = none); ``space_headway`` [m]: front to
  front, where there is a preceding vehicle; ``time_headway`` [s]: 0 where there is none.

``write_highd`` writes it as the lower carriageway of a HighD recording (``drivingDirection`` 2, moving right):

* Boxes: ``x`` = front − length (HighD's x is the rear of a right-moving box), ``width`` = length, ``y`` =
  lateral − width / 2 (shifted so the road starts ``ROAD_TOP`` m below the image top), ``height`` = width.
  Lane markings: as the converter knows them, or midway between adjacent lanes' median centre lines (the
  outer ones half a lane out). Two
  empty upper lanes, as in ``../shared/data/i80_sample``; laneId = 4 + lane.
* ``yVelocity`` is the forward difference of the lateral position; ``yAcceleration`` is 0. Neighbours left
  and right are 0. ``preceding`` / ``following`` pointing at a vehicle absent at that frame become 0 (counted).
  ``dhw`` = space_headway where there is a preceding vehicle, else 0; ``thw`` likewise; ``ttc`` = dhw /
  closing speed when closing, else 0.
"""
from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import pandas as pd

from guardian.highd.schema import RECORDING_META, TRACKS, TRACKS_META, file_name

TRAJECTORY_COLUMNS = ("vehicle", "frame", "front", "lateral", "length", "width", "vclass", "speed", "accel", "lane",
                      "preceding", "following", "space_headway", "time_headway")
ROAD_TOP = 20.0        # [m] image y of the first lower-carriageway marking


def longest_runs(t: pd.DataFrame, lanes: int) -> tuple[pd.DataFrame, dict]:
    """Rows on lanes 1..lanes; each vehicle keeps its longest run of consecutive frames (first on ties)."""
    on_main = t["lane"].between(1, lanes)
    kept = t[on_main].sort_values(["vehicle", "frame"]).reset_index(drop=True)
    run = ((kept["frame"].diff() != 1) | (kept["vehicle"].diff() != 0)).cumsum()
    size = run.map(run.value_counts())
    ranked = pd.DataFrame({"vid": kept["vehicle"], "run": run, "size": size})
    best = ranked.sort_values(["vid", "size", "run"], ascending=[True, False, True]).groupby("vid")["run"].first()
    result = kept[run == kept["vehicle"].map(best)].reset_index(drop=True)
    runs_per_vehicle = ranked.groupby("vid")["run"].nunique()
    report = {"ramp_rows_dropped": int((~on_main).sum()),
              "rows_dropped_to_keep_frames_consecutive": int(len(kept) - len(result)),
              "vehicles_cut": int((runs_per_vehicle > 1).sum()),
              "vehicles_only_on_ramps": int(t["vehicle"].nunique() - result["vehicle"].nunique())}
    return result, report


def neighbours(t: pd.DataFrame) -> pd.DataFrame:
    """``t`` with ``preceding``, ``following``, ``space_headway`` and ``time_headway`` from the positions: per frame
    and lane, the nearest front ahead and behind; front to front; space headway / speed (0 at standstill)."""
    t = t.assign(preceding=0, following=0, space_headway=0.0, time_headway=0.0)
    order = t.sort_values(["frame", "lane", "front"]).index
    s = t.loc[order]
    frame, lane = s["frame"].to_numpy(), s["lane"].to_numpy()
    same = (frame[1:] == frame[:-1]) & (lane[1:] == lane[:-1])   # consecutive rows of one (frame, lane)
    ahead_same = np.concatenate([same, [False]])
    behind_same = np.concatenate([[False], same])
    ids, front = s["vehicle"].to_numpy(), s["front"].to_numpy()
    preceding = np.where(ahead_same, np.roll(ids, -1), 0)
    following = np.where(behind_same, np.roll(ids, 1), 0)
    headway = np.where(ahead_same, np.roll(front, -1) - front, 0.0)
    speed = s["speed"].to_numpy()
    t.loc[order, "preceding"] = preceding
    t.loc[order, "following"] = following
    t.loc[order, "space_headway"] = headway
    t.loc[order, "time_headway"] = np.where(ahead_same & (speed > 0), headway / np.where(speed > 0, speed, 1.0), 0.0)
    return t


def write_highd(t: pd.DataFrame, out: Path, lanes: int, frame_rate: int, start: dt.datetime, recording_id: int = 1,
                location_id: int = 0, markings=None) -> tuple[list, dict]:
    """Write trajectories (``TRAJECTORY_COLUMNS``, lanes 1..``lanes``) as HighD recording ``recording_id``.

    ``markings``: the ``lanes + 1`` lane markings' lateral positions, left to right, as ``lateral`` measures
    them (default: midway between adjacent lanes' median centre lines, the outer ones half a lane out).
    Returns the files written and what was changed on the way (``neighbour_references_cleared``).
    """
    length, width = t["length"].to_numpy(), t["width"].to_numpy()
    lateral = t["lateral"].to_numpy()
    bounds = _median_markings(t, lanes) if markings is None else np.asarray(markings, dtype=float)
    shift = ROAD_TOP - bounds[0]
    lower = bounds + shift
    upper = ROAD_TOP - np.array([3, 2, 1]) * 3.6 - 0.5  # two empty lanes above, as in the I-80 sample
    front, v = t["front"].to_numpy(), t["speed"].to_numpy()
    key = pd.MultiIndex.from_arrays([t["vehicle"], t["frame"]])
    present = pd.Series(np.arange(len(t)), index=key)
    tracks = pd.DataFrame({"frame": t["frame"], "id": t["vehicle"], "x": front - length,
                           "y": lateral + shift - width / 2, "width": length, "height": width,
                           "xVelocity": v, "yVelocity": 0.0, "xAcceleration": t["accel"].to_numpy(),
                           "yAcceleration": 0.0})
    y_centre = lateral + shift
    same = t["vehicle"].to_numpy()[1:] == t["vehicle"].to_numpy()[:-1]
    vy = np.zeros(len(t))
    vy[:-1] = np.where(same, np.diff(y_centre) * frame_rate, 0.0)
    tracks["yVelocity"] = vy
    road_end = float(front.max())
    tracks["frontSightDistance"] = road_end - front
    tracks["backSightDistance"] = front - length - float((front - length).min())
    cleared = 0
    for c, column in (("preceding", "precedingId"), ("following", "followingId")):
        ref = pd.MultiIndex.from_arrays([t[c], t["frame"]])
        ok = (t[c].to_numpy() != 0) & present.reindex(ref).notna().to_numpy()
        cleared += int(((t[c].to_numpy() != 0) & ~ok).sum())
        tracks[column] = np.where(ok, t[c].to_numpy(), 0)
    has_lead = tracks["precedingId"].to_numpy() != 0
    lead_rows = present.reindex(pd.MultiIndex.from_arrays([tracks["precedingId"], t["frame"]])).to_numpy()
    v_lead = np.where(has_lead, v[np.nan_to_num(lead_rows, nan=0).astype(int)], 0.0)
    dhw = np.where(has_lead, t["space_headway"].to_numpy(), 0.0)
    closing = has_lead & (v > v_lead)
    tracks["dhw"] = dhw
    tracks["thw"] = np.where(has_lead, t["time_headway"].to_numpy(), 0.0)
    tracks["ttc"] = np.where(closing, dhw / np.where(closing, v - v_lead, 1.0), 0.0)
    tracks["precedingXVelocity"] = v_lead
    for c in ("leftPrecedingId", "leftAlongsideId", "leftFollowingId", "rightPrecedingId", "rightAlongsideId",
              "rightFollowingId"):
        tracks[c] = 0
    tracks["laneId"] = t["lane"].to_numpy() + 4
    tracks = tracks[list(TRACKS)].sort_values(["frame", "id"]).reset_index(drop=True)
    meta = _tracks_meta(tracks, t)
    rec_meta = _recording_meta(recording_id, location_id, frame_rate, start, tracks, meta, upper, lower)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for kind, table in (("recordingMeta", rec_meta), ("tracksMeta", meta), ("tracks", tracks)):
        p = out / file_name(recording_id, kind)
        table.to_csv(p, index=False, float_format="%.2f")
        files.append(str(p))
    return files, {"neighbour_references_cleared": cleared}


def _median_markings(t: pd.DataFrame, lanes: int) -> np.ndarray:
    centres = pd.Series(t["lateral"].to_numpy()).groupby(t["lane"].to_numpy()).median().reindex(range(1, lanes + 1))
    centres = centres.interpolate(limit_direction="both").to_numpy()
    spacing = np.diff(centres).mean() if lanes > 1 else 3.6
    return np.concatenate([[centres[0] - spacing / 2], (centres[1:] + centres[:-1]) / 2, [centres[-1] + spacing / 2]])


def _tracks_meta(tracks: pd.DataFrame, t: pd.DataFrame) -> pd.DataFrame:
    g = tracks.groupby("id")
    cls = t.groupby("vehicle")["vclass"].first()
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


def _recording_meta(rid, location_id, frame_rate, start, tracks, meta, upper, lower) -> pd.DataFrame:
    n_trucks = int((meta["class"] == "Truck").sum())
    frames = tracks["frame"]
    return pd.DataFrame([{
        "id": rid, "frameRate": frame_rate, "locationId": location_id, "speedLimit": -1.0,
        "month": start.strftime("%m.%Y"), "weekDay": start.strftime("%a"), "startTime": start.strftime("%H:%M"),
        "duration": round((frames.max() - frames.min() + 1) / frame_rate, 2),
        "totalDrivenDistance": round(float(meta["traveledDistance"].sum()), 2),
        "totalDrivenTime": round(len(tracks) / frame_rate, 2), "numVehicles": len(meta),
        "numCars": len(meta) - n_trucks, "numTrucks": n_trucks,
        "upperLaneMarkings": ";".join(f"{m:.2f}" for m in upper),
        "lowerLaneMarkings": ";".join(f"{m:.2f}" for m in lower),
    }])[list(RECORDING_META)]
