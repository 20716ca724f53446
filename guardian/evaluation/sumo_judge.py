"""The SUMO judge: who is at fault for a contact between two bodies (docs/sumo.md, "What is counted").

On the bodies at contact, the first rule that decides:

1. *lane entry*: a body that began to overlap a lane the other body is in within ``ENTRY_WINDOW`` s before the
   contact entered; the entrant is at fault; both entered: the first body (the guarded vehicle);
2. *side contact*: the bodies were alongside (overlapping along the road) at the observation before; the one that
   moved sideways towards the other faster than ``SIDEWAYS`` is at fault; both: the first body;
3. *rear-end*: the body that was behind at the observation before the contact is at fault (at 0.1 s a car passes up
   to 4 m in a step), unless the one ahead drives backwards.

The judge keeps its own geometry on purpose (an independent referee); ties go against the first body.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

ENTRY_WINDOW = 3.0   # [s]
SIDEWAYS = 0.25      # [m/s] lateral speed below this is lane keeping (the same as highway-env's judge)


@dataclass
class Tracks:
    """When each body began to overlap each lane (the entry rule), and each body at the last two observations (the
    side rule)."""

    lanes: dict = field(default_factory=dict)      # name -> slots now
    entered: dict = field(default_factory=dict)    # name -> {slot: time of the last entry}
    seen: dict = field(default_factory=dict)       # name -> [(time, body) before, (time, body) now]

    def see(self, name: str, slots: frozenset, t: float, body=None) -> None:
        before = self.lanes.get(name)
        if before is not None:
            for k in slots - before:
                self.entered.setdefault(name, {})[k] = t
        self.lanes[name] = slots
        self.seen[name] = [*self.seen.get(name, [])[-1:], (t, body)]

    def entered_lane_of(self, name: str, other: str, t: float) -> bool:
        """Did ``name``'s body begin to overlap a lane ``other``'s body is in within ``ENTRY_WINDOW`` s?"""
        theirs = self.lanes.get(other, frozenset())
        return any(k in theirs and t - when <= ENTRY_WINDOW + 1e-9 for k, when in self.entered.get(name, {}).items())

    def before(self, name: str):
        """``(time, body)`` at the observation before the last, or None."""
        seen = self.seen.get(name, [])
        return seen[0] if len(seen) == 2 and seen[0][1] is not None else None


def _sideways(tracks: Tracks, me, other) -> bool | None:
    """The side rule: were the bodies alongside at the observation before (overlapping along the road)? Then
    True if ``me`` moved sideways towards ``other`` faster than ``SIDEWAYS`` (or both did), False if only ``other``
    did; None when they were not alongside or neither moved sideways."""
    a, b = tracks.before(me.name), tracks.before(other.name)
    if a is None or b is None or a[0] != b[0]:
        return None
    (t0, m0), (_, o0) = a, b
    dt = tracks.seen[me.name][-1][0] - t0
    if dt <= 0 or abs(m0.x - o0.x) >= (m0.length + o0.length) / 2:
        return None
    towards = math.copysign(1.0, o0.y - m0.y)
    mine, theirs = (me.y - m0.y) / dt * towards > SIDEWAYS, (other.y - o0.y) / dt * -towards > SIDEWAYS
    return True if mine else (False if theirs else None)


def at_fault(ego, partner, tracks: Tracks, t: float) -> tuple[bool, str]:
    """Is the guarded vehicle (``ego``, a ``Sensed`` body) at fault for touching ``partner``? With the rule that
    decided: entry, then side contact, then rear-end (highway-env's judge's order)."""
    ego_entered = tracks.entered_lane_of(ego.name, partner.name, t)
    partner_entered = tracks.entered_lane_of(partner.name, ego.name, t)
    if ego_entered or partner_entered:
        return ego_entered, "entry"
    side = _sideways(tracks, ego, partner)
    if side is not None:
        return side, "side"
    e0, p0 = tracks.before(ego.name), tracks.before(partner.name)
    if e0 is not None and p0 is not None and e0[0] == p0[0]:
        ego_x, partner_x = e0[1].x, p0[1].x   # who was behind before they touched (a step is up to 4 m)
    else:
        ego_x, partner_x = ego.x, partner.x
    if ego_x <= partner_x:
        return partner.speed >= 0, "rear-end"
    return ego.speed < 0, "rear-end"
