"""CommonRoad scenarios (recorded traffic: NGSIM US-101, highD, ...) to HighD-format recordings.

Read with commonroad-io (the ``commonroad`` extra), the CommonRoad project's own reader, so the file format
is its business. One carriageway, lanes from lanelets:

* Lanes: a lanelet's lane is 1 + the number of same-direction ``adjacentLeft`` steps to the road's left edge
  (1 = leftmost). The leftmost lanelets (no left neighbour) must form one chain of successors: it is the
  reference line. A lanelet with an opposite-direction neighbour (a second carriageway), a lane that does
  not continue the leftmost chain, or no lanelet at all is refused, naming the lanelets.
* Lane markings: per lane the median of its lanelets' left bounds (and the rightmost lane's right bound),
  projected like the positions.
* Positions: each state's centre is projected onto the reference line (the leftmost chain's centre
  vertices): ``front`` = the arc length of the projection + half the length (times the cosine of the heading
  against the line), ``lateral`` = the distance to the right of the line. The speed along the road is the
  state's velocity times that cosine; the acceleration, when the states carry none, is the forward
  difference of the speed (reported).
* A state's lane is the lane of the lanelet its centre lies in (the nearest centre line when several
  overlap). States on no lanelet are dropped and counted, and each vehicle keeps its longest run of
  consecutive frames (``guardian.highd.trajectories.longest_runs``).
* Neighbours: per frame and lane, the nearest front ahead and behind; ``space_headway`` front to front,
  ``time_headway`` = space_headway / speed (0 at standstill).
* The time step comes from the file: ``frameRate`` = 1 / timeStepSize, refused unless that is a whole number;
  frames are CommonRoad's time steps. It is checked against the motion (the median, over consecutive states at
  1 m/s or more, of the distance moved over the mean speed): more than 10 % off, the file is refused, naming
  both (published highD-derived files declare 0.1 s where the motion says 0.2 s); ``time_step`` (``--time-step``)
  converts with another step, checked the same way. Vehicles: CAR, TAXI, PRIORITY_VEHICLE as Car; TRUCK, BUS as Truck;
  MOTORCYCLE; a rectangle each. Any other obstacle type or shape, a dynamic obstacle without a trajectory,
  is refused naming it. Static obstacles are counted and left out.
* recordingMeta's ``month`` and ``weekDay`` come from the file's ``date`` attribute (when the scenario was
  made; CommonRoad keeps no time of recording), ``startTime`` is 00:00: both reported.

The HighD tables are written by ``guardian.highd.trajectories.write_highd`` (its docstring has the rest).
"""
from __future__ import annotations

import datetime as dt
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pandas as pd

from guardian.errors import HighDFormatError
from guardian.highd.trajectories import longest_runs, neighbours, write_highd

CLASSES = {"CAR": "Car", "TAXI": "Car", "PRIORITY_VEHICLE": "Car", "TRUCK": "Truck", "BUS": "Truck",
           "MOTORCYCLE": "Motorcycle"}
RECTANGLES = ("Rectangle", "RectObstacleShape")   # commonroad-io before 2025 and after
STEP_TOLERANCE = 0.1   # the motion's step may differ this much (relative) from the declared one: noise, rounding


def _open(path: Path):
    try:
        from commonroad.common.file_reader import CommonRoadFileReader
    except ImportError as exc:
        raise HighDFormatError(f"{path}: reading CommonRoad needs commonroad-io: pip install "
                               f"'guardian[commonroad]'") from exc
    if not path.is_file():
        raise HighDFormatError(f"{path}: file is missing")
    try:
        scenario, _ = CommonRoadFileReader(str(path)).open()
    except Exception as exc:  # noqa: BLE001 - commonroad-io's own refusal, passed on with the file named
        raise HighDFormatError(f"{path}: not a CommonRoad scenario commonroad-io can read "
                               f"({type(exc).__name__}: {exc})") from exc
    return scenario


def _frame_rate(path: Path, step: float, what: str) -> int:
    rate = round(1.0 / step)
    if rate < 1 or abs(rate * step - 1.0) > 1e-9:
        raise HighDFormatError(f"{path}: {what} {step:g} s is not 1/n s: HighD's frameRate is a whole number")
    return rate


def motion_step(raw: pd.DataFrame) -> float | None:
    """The time step the vehicles' motion implies: the median over consecutive states (at least 1 m/s) of the
    distance moved over the mean of the two speeds; None when no vehicle moves."""
    raw = raw.sort_values(["vehicle", "frame"])
    same = (raw["vehicle"].to_numpy()[1:] == raw["vehicle"].to_numpy()[:-1]) & (np.diff(raw["frame"].to_numpy()) == 1)
    xy = raw[["x", "y"]].to_numpy()
    moved = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    speed = np.abs(raw["velocity"].to_numpy())
    mean = (speed[1:] + speed[:-1]) / 2
    ok = same & (mean >= 1.0)
    return float(np.median(moved[ok] / mean[ok])) if ok.any() else None


def _checked_step(path: Path, declared: float, given: float | None, raw: pd.DataFrame) -> tuple[float, dict]:
    """The time step to convert with: the file's, or ``given``; refused when the motion says otherwise."""
    step = declared if given is None else given
    implied = motion_step(raw)
    check = {"declared": declared, "used": step, "motion": None if implied is None else round(implied, 4)}
    if implied is not None and abs(implied / step - 1.0) > STEP_TOLERANCE:
        hint = (f"give the time step the motion says (guardian data convert commonroad --time-step {implied:.2g})"
                if given is None else "the step given does not fit either")
        told = "" if given is None else f" (given {given:g} s)"
        raise HighDFormatError(f"{path}: timeStepSize {declared:g} s{told}, "
                               f"but the vehicles move as if a step were {implied:.4g} s (median distance over speed "
                               f"between states): {hint}")
    return step, check


def lane_numbers(path: Path, network) -> dict:
    """``{lanelet id: lane}``, 1 = leftmost, from the same-direction left neighbours."""
    lanelets = {ll.lanelet_id: ll for ll in network.lanelets}
    if not lanelets:
        raise HighDFormatError(f"{path}: the scenario has no lanelet")
    lanes = {}
    for lid, ll in lanelets.items():
        for side in ("left", "right"):
            other, same = _beside(ll, side)
            if other is not None and other in lanelets and not same:
                raise HighDFormatError(f"{path}: lanelet {lid} has lanelet {other} beside it in the opposite "
                                       f"direction: the converter maps one carriageway")
        k, seen, here = 1, {lid}, ll
        while (step := _beside(here, "left"))[0] is not None and step[1]:
            if step[0] in seen or step[0] not in lanelets:
                raise HighDFormatError(f"{path}: lanelet {lid}: its left neighbours do not end at a road edge")
            seen.add(step[0])
            here, k = lanelets[step[0]], k + 1
        lanes[lid] = k
    return lanes


def _beside(lanelet, side: str) -> tuple:
    """(the lanelet beside it on ``side``, whether it runs the same way); commonroad-io's names changed in 2025."""
    for prefix in ("adj_", "adjacent_"):
        if hasattr(lanelet, prefix + side):
            return getattr(lanelet, prefix + side), bool(getattr(lanelet, f"{prefix}{side}_same_direction"))
    raise AttributeError(f"commonroad-io's Lanelet has no {side} neighbour attribute")


def reference_line(path: Path, network, lanes: dict) -> np.ndarray:
    """The leftmost lanelets' centre vertices, joined along their successors (refused unless one chain)."""
    left = {lid for lid, k in lanes.items() if k == 1}
    by_id = {ll.lanelet_id: ll for ll in network.lanelets}
    starts = [lid for lid in left if not set(by_id[lid].predecessor or ()) & left]
    if len(starts) != 1:
        raise HighDFormatError(f"{path}: the leftmost lanelets {sorted(left)} do not form one chain of "
                               f"successors (chains start at {sorted(starts)})")
    chain, lid = [], starts[0]
    while lid is not None:
        chain.append(lid)
        nxt = [s for s in (by_id[lid].successor or ()) if s in left and s not in chain]
        lid = nxt[0] if nxt else None
    if set(chain) != left:
        raise HighDFormatError(f"{path}: the leftmost lanelets {sorted(left - set(chain))} are not on the chain "
                               f"{chain}: the lanes do not continue one road")
    points = [by_id[chain[0]].center_vertices]
    points += [by_id[c].center_vertices[1:] for c in chain[1:]]
    line = np.concatenate(points)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(line, axis=0), axis=1) > 1e-9])
    return line[keep]


def markings(path: Path, network, lanes: dict, line: np.ndarray) -> np.ndarray:
    """The lane markings' distances to the right of the reference line, left to right: the median over the
    lane's lanelets of their left bounds (and the rightmost lane's right bound)."""
    n = max(lanes.values())
    sides = {k: ([], []) for k in range(1, n + 1)}
    for ll in network.lanelets:
        left, right = sides[lanes[ll.lanelet_id]]
        left.append(project(line, np.asarray(ll.left_vertices, dtype=float))[1])
        right.append(project(line, np.asarray(ll.right_vertices, dtype=float))[1])
    out = np.array([float(np.median(np.concatenate(sides[k][0]))) for k in range(1, n + 1)]
                   + [float(np.median(np.concatenate(sides[n][1])))])
    if np.any(np.diff(out) <= 0):
        raise HighDFormatError(f"{path}: the lanes' bounds do not lie left to right ({np.round(out, 2).tolist()} m "
                               f"right of the leftmost lanes' centre line)")
    return out


def project(line: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arc length along ``line``, signed distance to its right, and the line's heading, per point of ``xy``."""
    a, b = line[:-1], line[1:]
    seg = b - a
    seg_len = np.linalg.norm(seg, axis=1)
    start = np.concatenate([[0.0], np.cumsum(seg_len)[:-1]])
    rel = xy[:, None, :] - a[None, :, :]
    tau = np.clip((rel * seg[None]).sum(-1) / seg_len**2, 0.0, 1.0)
    foot = a[None] + tau[..., None] * seg[None]
    dist = np.linalg.norm(xy[:, None, :] - foot, axis=-1)
    best = dist.argmin(axis=1)
    rows = np.arange(len(xy))
    unit = seg[best] / seg_len[best, None]
    offset = xy - foot[rows, best]
    right = unit[:, 1] * offset[:, 0] - unit[:, 0] * offset[:, 1]   # > 0 to the right of the direction
    s = start[best] + tau[rows, best] * seg_len[best]
    return s, right, np.arctan2(unit[:, 1], unit[:, 0])


def _vehicle_rows(path: Path, obstacle) -> tuple[list, str]:
    oid, kind = obstacle.obstacle_id, obstacle.obstacle_type.name
    if kind not in CLASSES:
        raise HighDFormatError(f"{path}: dynamic obstacle {oid}: type {kind} is not a vehicle the converter maps "
                               f"({', '.join(CLASSES)})")
    shape = obstacle.obstacle_shape
    if type(shape).__name__ not in RECTANGLES or getattr(shape, "origin_x_shift", 0.0):
        raise HighDFormatError(f"{path}: dynamic obstacle {oid}: shape {type(shape).__name__} "
                               f"(origin shift {getattr(shape, 'origin_x_shift', 0.0)}): the converter maps a "
                               f"rectangle centred on the position")
    if type(obstacle.prediction).__name__ != "TrajectoryPrediction":
        raise HighDFormatError(f"{path}: dynamic obstacle {oid}: no trajectory (a "
                               f"{type(obstacle.prediction).__name__})")
    states = [obstacle.initial_state, *obstacle.prediction.trajectory.state_list]
    rows = []
    for st in states:
        for attr in ("position", "orientation", "velocity"):
            if getattr(st, attr, None) is None:
                raise HighDFormatError(f"{path}: dynamic obstacle {oid}, time step {st.time_step}: no {attr}")
        acc = getattr(st, "acceleration", None)
        rows.append((oid, int(st.time_step), float(st.position[0]), float(st.position[1]), float(st.orientation),
                     float(st.velocity), np.nan if acc is None else float(acc)))
    return rows, CLASSES[kind]


def _file_date(path: Path) -> tuple[dt.datetime, str]:
    for _, element in ElementTree.iterparse(path, events=("start",)):
        date = element.get("date")
        break
    try:
        return dt.datetime.strptime(date or "", "%Y-%m-%d"), f"the file's date attribute ({date}); startTime 00:00"
    except ValueError:
        return dt.datetime(1970, 1, 1), f"none in the file (date attribute {date!r}): 01.1970, Thu, 00:00"


def _lanes_of(network, lanes: dict, line: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The lane of the lanelet each point lies in (the nearest centre line when several hold it); 0 on none."""
    found = network.find_lanelet_by_position([p for p in xy])
    out = np.zeros(len(xy), dtype=np.int64)
    by_id = {ll.lanelet_id: ll for ll in network.lanelets}
    for i, ids in enumerate(found):
        if len(ids) == 1:
            out[i] = lanes[ids[0]]
        elif ids:
            near = min(ids, key=lambda lid: np.min(np.linalg.norm(by_id[lid].center_vertices - xy[i], axis=1)))
            out[i] = lanes[near]
    return out


def convert_commonroad(path: Path, out: Path, recording_id: int = 1, location_id: int = 0,
                       time_step: float | None = None) -> dict:
    """Convert a CommonRoad scenario's recorded vehicles to one HighD recording (the module docstring has
    every choice). ``time_step`` replaces the file's ``timeStepSize`` (both are checked against the motion).
    Returns what was converted and what was dropped, with counts."""
    path = Path(path)
    scenario = _open(path)
    network = scenario.lanelet_network
    lanes = lane_numbers(path, network)
    line = reference_line(path, network, lanes)
    rows, classes = [], {}
    for obstacle in scenario.dynamic_obstacles:
        r, classes[obstacle.obstacle_id] = _vehicle_rows(path, obstacle)
        rows += r
    if not rows:
        raise HighDFormatError(f"{path}: no dynamic obstacle: nothing was recorded")
    raw = pd.DataFrame(rows, columns=["vehicle", "frame", "x", "y", "heading", "velocity", "acceleration"])
    if time_step is None:
        _frame_rate(path, float(scenario.dt), "timeStepSize")
    step, step_check = _checked_step(path, float(scenario.dt), time_step, raw)
    frame_rate = _frame_rate(path, step, "the time step given")
    dims = {o.obstacle_id: (o.obstacle_shape.length, o.obstacle_shape.width) for o in scenario.dynamic_obstacles}
    xy = raw[["x", "y"]].to_numpy()
    s, right, road_heading = project(line, xy)
    cos = np.cos(raw["heading"].to_numpy() - road_heading)
    length = raw["vehicle"].map(lambda v: dims[v][0]).to_numpy(dtype=float)
    t = pd.DataFrame({"vehicle": raw["vehicle"], "frame": raw["frame"], "front": s + 0.5 * length * cos,
                      "lateral": right, "length": length,
                      "width": raw["vehicle"].map(lambda v: dims[v][1]).to_numpy(dtype=float),
                      "vclass": raw["vehicle"].map(classes), "speed": raw["velocity"].to_numpy() * cos,
                      "accel": raw["acceleration"].to_numpy(), "lane": _lanes_of(network, lanes, line, xy)})
    t = t.sort_values(["vehicle", "frame"]).reset_index(drop=True)
    differenced = int(t["accel"].isna().sum())
    if differenced:
        nxt = t.groupby("vehicle")["speed"].shift(-1)
        prev = t.groupby("vehicle")["speed"].shift(1)
        diff = np.where(nxt.notna(), (nxt - t["speed"]) * frame_rate, (t["speed"] - prev) * frame_rate)
        t["accel"] = t["accel"].fillna(pd.Series(np.nan_to_num(diff), index=t.index))
    n_lanes = max(lanes.values())
    t, report = longest_runs(t, n_lanes)
    if t.empty:
        raise HighDFormatError(f"{path}: no vehicle state lies on a lanelet")
    t = neighbours(t)
    start, start_source = _file_date(path)
    files, written = write_highd(t, out, n_lanes, frame_rate, start, recording_id, location_id,
                                 markings=markings(path, network, lanes, line))
    report = {"states_on_no_lanelet": report.pop("ramp_rows_dropped"),
              "vehicles_on_no_lanelet": report.pop("vehicles_only_on_ramps"), **report}
    return {"source": str(path), "out": str(out), "files": files, "benchmark_id": str(scenario.scenario_id),
            "frame_rate": frame_rate, "time_step": step_check, "lanes": n_lanes, "lanelets": len(lanes),
            "vehicles": int(t["vehicle"].nunique()),
            "rows": int(len(t)), "static_obstacles_left_out": len(scenario.static_obstacles),
            "accelerations_from_speed_differences": differenced, "start": start_source, **report, **written}
