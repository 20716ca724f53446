"""Faithful HighD-format recordings from simulated two-carriageway traffic.

Each carriageway is simulated along its direction of travel (coordinate ``s``, front bumper) at
the recording's frame rate with IDM car following and MOBIL lane changes (the models highway-env's
``IDMVehicle`` uses), cars and trucks, vehicles entering upstream and leaving downstream. A lane
change moves the vehicle sideways over ``lane_change_time`` seconds; as in HighD, ``laneId`` follows
the box centre across the markings. The recording window is ``[0, window]`` m; a vehicle is in a
frame while its whole box is inside. Every HighD column is filled from the simulation: boxes in image
coordinates (x to the right, y down, upper-left corner), signed velocities and accelerations,
neighbour ids by ``laneId`` relative to the direction of travel, dhw (front to front), thw, ttc,
sight distances, and the two meta files.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from guardian.highd.schema import RECORDING_META, TRACKS, TRACKS_META, file_name
from itha.idm import idm_acceleration

JAM_DISTANCE = 2.0  # m, IDM s0 of every generated vehicle


@dataclass(frozen=True)
class TrafficParams:
    lanes: int = 3                  # per carriageway
    window: float = 420.0           # recorded stretch (HighD: about 420 m)
    upstream: float = 300.0         # simulated road before the window
    downstream: float = 200.0       # and after it
    frame_rate: int = 25            # Hz (HighD's); every derivative in the files uses it
    inflow: float = 0.35            # vehicles per second and lane entering upstream
    truck_share: float = 0.15
    warmup: float = 50.0            # seconds simulated before recording starts
    car_speed: tuple = (27.0, 40.0)     # desired speeds, uniform
    truck_speed: tuple = (22.0, 25.0)
    lane_width: float = 3.75
    lane_change_time: float = 4.0
    mobil_period: float = 1.0
    politeness: float = 0.3
    threshold: float = 0.2
    keep_right: float = 0.2
    b_safe: float = 3.0
    time_gap: tuple = (0.6, 1.6)    # IDM time gaps of cars, uniform (trucks 1.6 s)
    noise: float = 0.3              # m/s^2: drivers' acceleration fluctuation (Ornstein-Uhlenbeck)
    noise_time: float = 1.5         # s: its correlation time
    location_id: int = 7
    speed_limit: float = -1.0

    def __post_init__(self):
        if isinstance(self.frame_rate, bool) or int(self.frame_rate) != self.frame_rate or self.frame_rate < 1:
            raise ValueError(f"frame_rate must be a positive whole number of Hz, got {self.frame_rate!r}")

    def markings(self, upper: bool) -> list[float]:
        top = 6.0 if upper else 6.0 + self.lanes * self.lane_width + 2.5
        return [round(top + k * self.lane_width, 2) for k in range(self.lanes + 1)]


class Carriageway:
    """IDM + MOBIL traffic along one direction (lane 1 = rightmost)."""

    def __init__(self, prm: TrafficParams, rng: np.random.Generator, first_id: int):
        self.prm, self.rng = prm, rng
        self.dt = 1.0 / prm.frame_rate
        self.next_id = first_id
        cols = ("id", "s", "v", "lane", "length", "width", "v0", "T", "a", "b", "truck", "y", "y_from",
                "y_to", "progress", "phase", "lc_count", "noise")
        self.cols = cols
        self.X = {c: np.zeros(0) for c in cols}

    # ---- state helpers -----------------------------------------------------------------------------
    def __len__(self):
        return len(self.X["id"])

    def _spawn(self):
        prm = self.prm
        for lane in range(1, prm.lanes + 1):
            if self.rng.uniform() > prm.inflow * self.dt:
                continue
            truck = self.rng.uniform() < prm.truck_share and lane <= 2
            length = self.rng.uniform(12.0, 18.0) if truck else self.rng.uniform(4.2, 5.2)
            v0 = self.rng.uniform(*(prm.truck_speed if truck else prm.car_speed))
            s0 = -prm.upstream
            in_lane = self.X["lane"] == lane
            v = v0
            if in_lane.any():
                last = np.argmin(np.where(in_lane, self.X["s"], np.inf))
                gap = self.X["s"][last] - self.X["length"][last] - s0
                if gap < 2.0 + 1.0 * self.X["v"][last] + 5:
                    continue
                v = min(v0, self.X["v"][last] + 2.0)
            row = {"id": self.next_id, "s": s0, "v": v, "lane": lane, "length": length,
                   "width": self.rng.uniform(2.4, 2.6) if truck else self.rng.uniform(1.75, 2.05),
                   "v0": v0, "T": 1.6 if truck else self.rng.uniform(*prm.time_gap), "a": 0.8 if truck else 1.4,
                   "b": 2.0, "truck": float(truck), "y": lane, "y_from": lane, "y_to": lane, "progress": 1.0,
                   "phase": self.rng.uniform(0, self.prm.mobil_period), "lc_count": 0, "noise": 0.0}
            self.next_id += 1
            for c in self.cols:
                self.X[c] = np.append(self.X[c], row[c])

    def _leaders(self, s, lane):
        """Per vehicle: index of the vehicle ahead in the same lane (-1 if none)."""
        n = len(s)
        lead = np.full(n, -1)
        for ln in np.unique(lane):
            idx = np.flatnonzero(lane == ln)
            order = idx[np.argsort(s[idx])]
            lead[order[:-1]] = order[1:]
        return lead

    def _idm(self, k, gap, v_lead):
        """IDM (7.8, ``itha.idm``) with per-vehicle desired speed, time gap, a and b; jam distance 2 m."""
        X = self.X
        a = idm_acceleration(X["v"][k], gap, v_lead, X["v0"][k], X["a"][k], X["b"][k], JAM_DISTANCE, X["T"][k],
                             gap_floor=0.1)
        return np.maximum(a, -9.0)

    def _acc_in_lane(self, k, lane):
        """IDM acceleration of vehicle k if it were in ``lane`` (and who leads/follows it there)."""
        X = self.X
        s = X["s"]
        others = np.flatnonzero((X["lane"] == lane) & (np.arange(len(s)) != k))
        ahead = others[s[others] >= s[k]]
        behind = others[s[others] < s[k]]
        lead = ahead[np.argmin(s[ahead])] if len(ahead) else -1
        foll = behind[np.argmax(s[behind])] if len(behind) else -1
        gap = s[lead] - X["length"][lead] - s[k] if lead >= 0 else np.inf
        a = self._idm(np.array([k]), np.array([gap]), np.array([X["v"][lead] if lead >= 0 else X["v"][k]]))[0]
        return a, lead, foll, gap

    def _mobil(self, t: float):
        X, prm = self.X, self.prm
        due = np.flatnonzero((X["progress"] >= 1.0) &
                             (np.floor((t - X["phase"]) / prm.mobil_period) !=
                              np.floor((t - self.dt - X["phase"]) / prm.mobil_period)))
        for k in due:
            a_now, _, foll_now, _ = self._acc_in_lane(k, X["lane"][k])
            best, best_gain = None, prm.threshold
            for shift in (1, -1):
                ln = X["lane"][k] + shift
                if not 1 <= ln <= prm.lanes or (X["truck"][k] and ln > 2):
                    continue
                a_new, lead, foll, gap = self._acc_in_lane(k, ln)
                if gap < 2.0:
                    continue
                gain = a_new - a_now + (prm.keep_right if shift < 0 else -prm.keep_right)
                if foll >= 0:
                    back_gap = X["s"][k] - X["length"][k] - X["s"][foll]
                    if back_gap < 2.0:
                        continue
                    a_f_new = self._idm(np.array([foll]), np.array([back_gap]), np.array([X["v"][k]]))[0]
                    if a_f_new < -prm.b_safe:
                        continue
                    a_f_old, _, _, _ = self._acc_in_lane(foll, ln)
                    gain += prm.politeness * (a_f_new - a_f_old)
                if gain > best_gain:
                    best, best_gain = ln, gain
            if best is not None:
                X["y_from"][k], X["y_to"][k], X["progress"][k] = X["y"][k], best, 0.0
                X["lane"][k] = best
                X["lc_count"][k] += 1

    def step(self, t: float):
        X, dt = self.X, self.dt
        self._spawn()
        if not len(self):
            return
        self._mobil(t)
        lead = self._leaders(X["s"], X["lane"])
        has = lead >= 0
        gap = np.where(has, X["s"][lead] - X["length"][lead] - X["s"], np.inf)
        v_lead = np.where(has, X["v"][lead], X["v"])
        prm = self.prm
        decay = np.exp(-dt / prm.noise_time)
        X["noise"] = decay * X["noise"] + prm.noise * np.sqrt(1 - decay ** 2) * self.rng.standard_normal(len(self))
        acc = self._idm(np.arange(len(self)), gap, v_lead) + X["noise"]
        X["s"] = X["s"] + dt * X["v"]
        X["v"] = np.maximum(X["v"] + dt * acc, 0.0)
        moving = X["progress"] < 1.0
        X["progress"] = np.where(moving, np.minimum(X["progress"] + dt / self.prm.lane_change_time, 1.0),
                                 X["progress"])
        w = 0.5 - 0.5 * np.cos(np.pi * X["progress"])
        X["y"] = np.where(moving, X["y_from"] + (X["y_to"] - X["y_from"]) * w, X["y"])
        keep = X["s"] - X["length"] <= self.prm.window + self.prm.downstream
        for c in self.cols:
            X[c] = X[c][keep]


def _neighbours(s, length, lane_id, ids, left_of, right_of):
    """HighD neighbour ids among the vehicles of one direction in one frame (0 = none)."""
    n = len(s)
    out = {c: np.zeros(n, dtype=np.int64) for c in
           ("precedingId", "followingId", "leftPrecedingId", "leftAlongsideId", "leftFollowingId",
            "rightPrecedingId", "rightAlongsideId", "rightFollowingId")}
    rear = s - length
    for i in range(n):
        same = (lane_id == lane_id[i]) & (np.arange(n) != i)
        ahead = np.flatnonzero(same & (s > s[i]))
        behind = np.flatnonzero(same & (s < s[i]))
        if len(ahead):
            out["precedingId"][i] = ids[ahead[np.argmin(s[ahead])]]
        if len(behind):
            out["followingId"][i] = ids[behind[np.argmax(s[behind])]]
        for side, lane_fn in (("left", left_of), ("right", right_of)):
            other = np.flatnonzero(lane_id == lane_fn(lane_id[i]))
            if not len(other):
                continue
            pre = other[rear[other] >= s[i]]
            fol = other[s[other] <= rear[i]]
            along = other[(s[other] > rear[i]) & (rear[other] < s[i])]
            if len(pre):
                out[f"{side}PrecedingId"][i] = ids[pre[np.argmin(rear[pre])]]
            if len(fol):
                out[f"{side}FollowingId"][i] = ids[fol[np.argmax(s[fol])]]
            if len(along):
                out[f"{side}AlongsideId"][i] = ids[along[np.argmin(np.abs(s[along] - s[i]))]]
    return out


def simulate_recording(recording_id: int, minutes: float, seed: int, prm: TrafficParams = TrafficParams(),
                       progress=None):
    """Simulate both carriageways and return the three HighD tables (recordingMeta, tracksMeta, tracks)."""
    rng = np.random.default_rng([seed, recording_id])
    dt = 1.0 / prm.frame_rate
    upper_m, lower_m = prm.markings(True), prm.markings(False)
    n_up = len(upper_m) - 1
    roads = {1: Carriageway(prm, rng, 1), 2: Carriageway(prm, rng, 1_000_000)}
    frames_total = int(round(minutes * 60 * prm.frame_rate))
    warm = int(round(prm.warmup * prm.frame_rate))
    rows = []
    for f in range(-warm, frames_total):
        t = (f + warm) * dt
        for direction, road in roads.items():
            road.step(t)
            if f < 0 or not len(road):
                continue
            X = road.X
            vis = np.flatnonzero((X["s"] - X["length"] >= 0) & (X["s"] <= prm.window))
            if not len(vis):
                continue
            rows.append(_frame_rows(prm, direction, f + 1, X, vis, upper_m, lower_m, n_up))
        if progress and (f + 1) % (prm.frame_rate * 10) == 0 and f >= 0:
            progress(f + 1, frames_total)
    tracks = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=list(TRACKS))
    tracks = _fill_kinematics(_renumber(tracks), prm.frame_rate)
    tracks = tracks.sort_values(["id", "frame"], kind="stable").reset_index(drop=True)
    meta = _tracks_meta(tracks, n_up)
    rec = _recording_meta(recording_id, prm, tracks, meta, minutes, upper_m, lower_m, seed)
    return rec, meta, tracks[list(TRACKS)]


def _frame_rows(prm, direction, frame, X, vis, upper_m, lower_m, n_up):
    s, length, width = X["s"][vis], X["length"][vis], X["width"][vis]
    v = X["v"][vis]
    lanes = X["y"][vis]  # continuous lane coordinate, 1 = rightmost
    if direction == 2:  # lower carriageway, moving right: lane 1 (rightmost) is the lowest
        y_centre = lower_m[-1] - (lanes - 0.5) * prm.lane_width
        x = s - length
        sign = 1.0
        lane_id = 1 + np.searchsorted(upper_m + lower_m, y_centre)
        left_of, right_of = (lambda L: L - 1), (lambda L: L + 1)
    else:  # upper carriageway, moving left: lane 1 (rightmost in its direction) is the highest
        y_centre = upper_m[0] + (lanes - 0.5) * prm.lane_width
        x = prm.window - s
        sign = -1.0
        lane_id = 1 + np.searchsorted(upper_m + lower_m, y_centre)
        left_of, right_of = (lambda L: L + 1), (lambda L: L - 1)
    ids = X["id"][vis].astype(np.int64)
    nb = _neighbours(s, length, lane_id, ids, left_of, right_of)
    idx = {int(i): k for k, i in enumerate(ids)}
    pre = nb["precedingId"]
    pk = np.array([idx.get(int(p), -1) for p in pre])
    has = pk >= 0
    dhw = np.where(has, s[pk] - s, 0.0)
    v_pre = np.where(has, v[pk], 0.0)
    thw = np.where(has & (v > 0), dhw / np.maximum(v, 1e-9), 0.0)
    gap = np.where(has, s[pk] - length[pk] - s, 0.0)
    closing = has & (v > v_pre)
    ttc = np.where(closing, gap / np.maximum(v - v_pre, 1e-9), 0.0)
    y_lat_speed = np.zeros_like(v)
    out = pd.DataFrame({
        "frame": frame, "id": ids, "x": np.round(x, 2), "y": np.round(y_centre - width / 2, 2),
        "width": np.round(length, 2), "height": np.round(width, 2), "xVelocity": np.round(sign * v, 2),
        "yVelocity": y_lat_speed, "xAcceleration": 0.0, "yAcceleration": 0.0,
        "frontSightDistance": np.round(prm.window - s, 2), "backSightDistance": np.round(s - length, 2),
        "dhw": np.round(dhw, 2), "thw": np.round(thw, 2), "ttc": np.round(ttc, 2),
        "precedingXVelocity": np.round(sign * v_pre, 2), "laneId": lane_id.astype(np.int64),
        **{k: val for k, val in nb.items()},
    })
    return out


def _renumber(tracks: pd.DataFrame) -> pd.DataFrame:
    """Vehicle ids 1..N in order of first appearance (neighbour ids follow)."""
    if tracks.empty:
        return tracks
    first = tracks.groupby("id")["frame"].min().sort_values(kind="stable")
    mapping = {int(old): k + 1 for k, old in enumerate(first.index)}
    mapping[0] = 0
    for c in ("id",) + tuple(c for c in TRACKS if c.endswith("Id") and c != "laneId"):
        tracks[c] = tracks[c].map(lambda i: mapping.get(int(i), 0)).astype(np.int64)
    return tracks


def _fill_kinematics(tracks: pd.DataFrame, frame_rate: float) -> pd.DataFrame:
    """yVelocity and the accelerations by central differences along each track, at ``frame_rate`` (Hz)."""
    tracks = tracks.sort_values(["id", "frame"], kind="stable").reset_index(drop=True)
    g = tracks.groupby("id", sort=False)
    fr = float(frame_rate)
    tracks["yVelocity"] = np.round(g["y"].transform(lambda s: np.gradient(s.to_numpy()) * fr if len(s) > 1 else 0.0)
                                   .fillna(0.0), 2)
    tracks["xAcceleration"] = np.round(g["xVelocity"].transform(
        lambda s: np.gradient(s.to_numpy()) * fr if len(s) > 1 else 0.0), 4)
    tracks["yAcceleration"] = np.round(tracks.groupby("id", sort=False)["yVelocity"].transform(
        lambda s: np.gradient(s.to_numpy()) * fr if len(s) > 1 else 0.0), 4)
    return tracks


def _tracks_meta(tracks: pd.DataFrame, n_up: int) -> pd.DataFrame:
    g = tracks.groupby("id", sort=True)
    meta = pd.DataFrame({
        "id": g["id"].first(), "width": g["width"].first(), "height": g["height"].first(),
        "initialFrame": g["frame"].min(), "finalFrame": g["frame"].max(), "numFrames": g["frame"].size(),
    })
    meta["class"] = np.where(meta["width"] > 8.0, "Truck", "Car")
    meta["drivingDirection"] = np.where(g["laneId"].first() <= n_up + 1, 1, 2)
    meta["traveledDistance"] = np.round((g["x"].max() - g["x"].min()), 2)
    speed = tracks["xVelocity"].abs()
    meta["minXVelocity"] = speed.groupby(tracks["id"]).min().round(2)
    meta["maxXVelocity"] = speed.groupby(tracks["id"]).max().round(2)
    meta["meanXVelocity"] = speed.groupby(tracks["id"]).mean().round(2)
    for col, name in (("dhw", "minDHW"), ("thw", "minTHW"), ("ttc", "minTTC")):
        pos = tracks[col].where(tracks[col] > 0)
        meta[name] = pos.groupby(tracks["id"]).min().fillna(-1).round(2)
    meta["numLaneChanges"] = g["laneId"].apply(lambda s: int((s.diff().fillna(0) != 0).sum()))
    return meta.reset_index(drop=True)[list(TRACKS_META)]


def _recording_meta(rid, prm, tracks, meta, minutes, upper_m, lower_m, seed):
    n_trucks = int((meta["class"] == "Truck").sum())
    return pd.DataFrame([{
        "id": rid, "frameRate": prm.frame_rate, "locationId": prm.location_id, "speedLimit": prm.speed_limit,
        "month": f"{1 + seed % 12:02d}.2026", "weekDay": "Tue", "startTime": "08:00", "duration": round(minutes * 60, 2),
        "totalDrivenDistance": round(float(meta["traveledDistance"].sum()), 2),
        "totalDrivenTime": round(len(tracks) / prm.frame_rate, 2), "numVehicles": len(meta),
        "numCars": len(meta) - n_trucks, "numTrucks": n_trucks,
        "upperLaneMarkings": ";".join(f"{m:.2f}" for m in upper_m),
        "lowerLaneMarkings": ";".join(f"{m:.2f}" for m in lower_m),
    }])[list(RECORDING_META)]


def write_recording(out_dir: Path, recording_id: int, tables) -> list[Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for kind, df in zip(("recordingMeta", "tracksMeta", "tracks"), tables):
        path = out_dir / file_name(recording_id, kind)
        tmp = path.with_name(f".{path.name}.tmp")
        try:  # whole or absent: an interrupted run leaves no half-written file
            df.to_csv(tmp, index=False)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        paths.append(path)
    return paths


def generate(out_dir: Path, recordings: int, minutes: float, seed: int, prm: TrafficParams = TrafficParams(),
             progress=None, first_id: int = 1) -> list[Path]:
    """Simulate IDM + MOBIL traffic on both carriageways and write it as HighD recordings.

    Parameters
    ----------
    out_dir : path
        Where the three files of each recording are written.
    recordings : int
        How many recordings, numbered from ``first_id``.
    minutes : float
        Length of each recording.
    seed : int
        Recording k is seeded with ``[seed, k]``.
    prm : TrafficParams
        The traffic's parameters.
    progress : callable, optional
        ``progress(recording_id, done, total)``.
    first_id : int
        The first recording's id.

    Returns
    -------
    list of Path
        The files written.
    """
    written = []
    for k in range(recordings):
        rid = first_id + k
        tables = simulate_recording(rid, minutes, seed, prm,
                                    progress=(lambda d, t, rid=rid: progress(rid, d, t)) if progress else None)
        written += write_recording(out_dir, rid, tables)
    return written
