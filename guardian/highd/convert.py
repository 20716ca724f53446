"""HighD recordings as ITHA data: local states, inputs, disturbances and lane-change events.

Along the direction of travel (``s`` grows the way the car drives; both directions):

* front bumper ``s_front = x + width`` (direction 2, moving right) or ``-x`` (direction 1, moving
  left: its front is the box's left edge); rear bumper ``s_front - width``; speed ``v = |xVelocity|``
  signed by the direction;
* headway ``h = s_rear(preceding) - s_front(ego)`` (box edge to box edge), lead speed ``v_L``; no
  preceding vehicle (``precedingId = 0``) gives ``h = inf``;
* ITHA lanes are numbered from the right of the direction of travel (1 = rightmost);
* the ego input ``u`` and the lead disturbance ``d`` are forward differences at the frame rate,
  ``u_t = (v_{t+1} - v_t) / dt``; ``d`` only where the same preceding vehicle is seen at t and
  t+1 (otherwise the lead changed: a reset, not a disturbance);
* a lane-change event is a change of ``laneId`` between t and t+1. It carries a snapshot of every
  vehicle of that direction at frame t (positions, speeds, lanes, lengths) and each one's own
  trigger at t (lane at t+1 minus lane at t; unknown at the last frame of a track): the ego's
  lane change can reset any of them (Appendix B); and the ego's recorded input ``u`` at t, which
  Definition 22 judges.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from guardian.errors import HighDFormatError
from guardian.highd.reader import Recording, line_of, positions, track_order


@dataclass
class LaneChange:
    recording: int
    vehicle: int
    frame: int
    ego: int                 # index of the ego in the snapshot arrays
    trigger: str             # "left" | "right"
    p: np.ndarray            # front bumpers along the direction of travel
    v: np.ndarray
    lane: np.ndarray         # ITHA lane numbers
    length: np.ndarray
    shift: np.ndarray        # each vehicle's own lane shift at t (+1 left, -1 right, 0, or 9 unknown)
    n_lanes: int
    u: float                 # the ego's recorded input at t, (v_{t+1} - v_t) / dt
    test: bool = False


@dataclass
class ITHAData:
    """Per data point (vehicle, frame with a next frame) arrays, and the lane-change events."""

    recording: int
    frame_rate: int
    vehicle: np.ndarray
    frame: np.ndarray
    direction: np.ndarray
    lane: np.ndarray
    v: np.ndarray
    h: np.ndarray
    vL: np.ndarray
    u: np.ndarray
    d: np.ndarray
    lane_changes: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.v)

    def take(self, mask: np.ndarray) -> "ITHAData":
        keep = {k: getattr(self, k)[mask] for k in ("vehicle", "frame", "direction", "lane", "v", "h", "vL", "u", "d")}
        return ITHAData(self.recording, self.frame_rate, lane_changes=self.lane_changes, **keep)


def _lane_numbers(rec: Recording, lane_id: np.ndarray, direction: np.ndarray) -> np.ndarray:
    n_up, n_low = len(rec.upper_markings) - 1, len(rec.lower_markings) - 1
    return np.where(direction == 1, lane_id - 1, n_up + n_low + 3 - lane_id)


def to_itha(rec: Recording) -> ITHAData:
    """The ITHA view of a recording: per data point the ego's speed, its headway and the lead's speed.

    Parameters
    ----------
    rec : Recording
        A validated recording (``read_recording``).

    Returns
    -------
    ITHAData
        Arrays per (vehicle, frame with a next frame) in the driving direction, and the lane-change
        events with the cars around them.
    """
    t = rec.tracks
    order = track_order(t["id"].to_numpy(), t["frame"].to_numpy())
    if order is not None:  # HighD files come sorted by (id, frame); others are sorted here
        t = t.iloc[order].reset_index(drop=True)
    where = _Place(rec, order)
    ids = t["id"].to_numpy()
    frames = t["frame"].to_numpy()
    direction = rec.tracks_meta["drivingDirection"].to_numpy()[positions(rec.tracks_meta["id"].to_numpy(), ids)]
    sign = np.where(direction == 2, 1.0, -1.0)
    x, w = t["x"].to_numpy(), t["width"].to_numpy()
    s_front = np.where(direction == 2, x + w, -x)
    s_rear = s_front - w
    v = sign * t["xVelocity"].to_numpy()
    lane = _lane_numbers(rec, t["laneId"].to_numpy(), direction)
    pre = t["precedingId"].to_numpy()
    lead_row = _rows_of(ids, frames, pre)
    has_lead = (pre != 0) & (ids[lead_row] == pre) & (frames[lead_row] == frames)
    if np.any((pre != 0) & ~has_lead):
        r = int(np.flatnonzero((pre != 0) & ~has_lead)[0])
        raise HighDFormatError(f"{where(r, 'precedingId')}: vehicle {ids[r]} at frame {frames[r]} follows vehicle "
                               f"{pre[r]}, which has no row at that frame (recording {rec.id})")
    h = np.where(has_lead, s_rear[lead_row] - s_front, np.inf)
    vL = np.where(has_lead, v[lead_row], np.nan)
    nxt = np.arange(1, len(ids) + 1)
    has_next = np.zeros(len(ids), dtype=bool)
    has_next[:-1] = ids[1:] == ids[:-1]
    nxt = np.where(has_next, np.minimum(nxt, len(ids) - 1), 0)
    fr = rec.frame_rate
    u = (v[nxt] - v) * fr
    same_lead = has_next & has_lead & (pre[nxt] == pre)
    lead_next = np.minimum(lead_row + 1, len(ids) - 1)
    same_lead &= ids[lead_next] == pre
    d = np.where(same_lead, (v[lead_next] - v[lead_row]) * fr, np.nan)
    shift = np.where(has_next, lane[nxt] - lane, 9)
    data = ITHAData(rec.id, fr, ids[has_next], frames[has_next], direction[has_next], lane[has_next],
                    v[has_next], h[has_next], vL[has_next], u[has_next], d[has_next])
    data.lane_changes = _lane_changes(rec, ids, frames, direction, s_front, v, lane, w, shift, u, where)
    return data


class _Place:
    """Where sorted row ``r`` of a recording's tracks is in its file: ``path: line L, column 'C'``."""

    def __init__(self, rec: Recording, order):
        self.path, self.order = rec.paths.get("tracks"), order

    def __call__(self, r: int, column: str) -> str:
        if self.path is None:
            return f"tracks row {r}, column {column!r}"
        row = int(r if self.order is None else self.order[r])
        return f"{self.path}: line {line_of(self.path, row)}, column {column!r}"


def _rows_of(ids: np.ndarray, frames: np.ndarray, vehicle: np.ndarray) -> np.ndarray:
    """The row of (``vehicle``, the same frame) for each row, in rows sorted by (id, frame) whose
    frames run without gaps (a validated recording); an index to check, not an answer, where that
    vehicle has no such row."""
    starts = np.flatnonzero(np.concatenate(([True], ids[1:] != ids[:-1])))
    track = positions(ids[starts], vehicle)
    row = starts[track] + (frames - frames[starts][track])
    return np.where((track >= 0) & (row >= 0) & (row < len(ids)), row, 0)


def _lane_changes(rec, ids, frames, direction, s_front, v, lane, length, shift, u, where) -> list[LaneChange]:
    events = np.flatnonzero((shift != 0) & (shift != 9))
    if not len(events):
        return []
    n_up, n_low = len(rec.upper_markings) - 1, len(rec.lower_markings) - 1
    group = frames.astype(np.int64) * 4 + direction  # (frame, direction), direction in {1, 2}
    order = np.argsort(group, kind="stable")       # rows of a group stay in increasing order
    sorted_group = group[order]
    out = []
    for r in events:
        if abs(shift[r]) != 1:
            raise HighDFormatError(f"{where(r + 1, 'laneId')}: vehicle {ids[r]} changes {abs(shift[r])} lanes between "
                                   f"frames {frames[r]} and {frames[r] + 1} (recording {rec.id})")
        k = group[r]
        rows = order[np.searchsorted(sorted_group, k, "left"):np.searchsorted(sorted_group, k, "right")]
        out.append(LaneChange(rec.id, int(ids[r]), int(frames[r]), int(np.flatnonzero(rows == r)[0]),
                              "left" if shift[r] > 0 else "right", s_front[rows], v[rows], lane[rows],
                              length[rows], shift[rows], n_up if direction[r] == 1 else n_low, float(u[r])))
    return out
