"""Shadows: what lets SUMO's drivers see a guarded body that is over a lane line.

SUMO's cars react to the vehicles on their own lane only (a vehicle's lane index, whatever its body overlaps;
with the sublane model too, for a vehicle moved by ``moveToXY``). A guarded vehicle whose body is over the line
is therefore invisible to the cars behind in the lane it overlaps, while the guardian's entry check (7.5) counts
on those cars to brake for it, as real drivers brake for a body they see. SUMO maps a vehicle moved by position
to the lane of its centre; every *other* lane its body overlaps gets a shadow: a SUMO vehicle of the guarded
vehicle's length on that lane's centre line, at the same front-bumper position and speed, moved with it every
step and removed when the body leaves that lane. The cars of that lane then follow the shadow and do not cut
into it: what they would do for the body they see.

Shadows are a perception aid for SUMO's drivers, never a car: the scene, the judge and the traffic's model
coverage skip them (``is_shadow``), and a SUMO-reported collision of a shadow is counted apart (a traffic car
reaching a lane's centre where the body only overlaps the lane's edge has not touched the body; the judge
decides on the bodies).
"""
from __future__ import annotations

import math

SHADOW_TYPE = "shadow"
_MARK = "~shadow"


def is_shadow(vid: str) -> bool:
    return _MARK in vid


def owner(vid: str) -> str:
    """The guarded vehicle a shadow stands for (``vid`` itself for any other vehicle)."""
    return vid.split(_MARK, 1)[0]


def shadow_id(vid: str, slot: int) -> str:
    return f"{vid}{_MARK}{slot}"


class Shadows:
    """The shadows of guarded vehicles on one straight edge (``guardian.adapters.sumo.scene.Frame``)."""

    def __init__(self, frame):
        self.frame = frame
        self.live: dict = {}   # guarded vehicle -> {slot: shadow id}

    def update(self, traci, vid: str, x: float, y: float, heading: float, speed: float, length: float,
               slots: frozenset, own: int) -> None:
        """Shadows of ``vid`` (body centred at ``(x, y)``, SUMO told it is on slot ``own``) on every other slot of
        ``slots`` (the lanes its body overlaps), at its next state; SUMO moves them in its next step."""
        mine = self.live.setdefault(vid, {})
        wanted = {k for k in slots if k != own and self.frame.on_corridor(k, x)}   # a ramp's or exit's: none
        for slot in [s for s in mine if s not in wanted]:
            traci.vehicle.remove(mine.pop(slot))
        front = x + length / 2 * math.cos(heading)
        along = max(speed * math.cos(heading), 0.0)
        for slot in sorted(wanted):
            sid = mine.get(slot)
            edge, lane = self.frame.lane_at(slot, front - length / 2)
            xs, ys, angle = self.frame.to_sumo(front - length / 2, self.frame.centre_y(slot), 0.0, length)
            if sid is None:
                sid = mine[slot] = shadow_id(vid, slot)
                # SUMO refuses to insert a vehicle above the lane's limit: a faster body's shadow is slower for its
                # first step (its followers brake more, not less)
                limit = traci.lane.getMaxSpeed(f"{edge}_{lane}")
                traci.vehicle.add(sid, f"from_{edge}", typeID=SHADOW_TYPE, departLane=str(lane), departPos="0",
                                  departSpeed=f"{min(along, limit):.6f}")
                traci.vehicle.setSpeedMode(sid, 0)
                traci.vehicle.setLaneChangeMode(sid, 0)
            traci.vehicle.moveToXY(sid, edge, lane, xs, ys, angle, keepRoute=2)
            traci.vehicle.setSpeed(sid, along)

    def drop(self, traci, vid: str) -> None:
        """Remove ``vid``'s shadows (it left the road, or crashed)."""
        present = set(traci.vehicle.getIDList())
        for sid in self.live.pop(vid, {}).values():
            if sid in present:
                traci.vehicle.remove(sid)

    def lanes_seen(self, traci, vid: str) -> set:
        """The slots where SUMO has ``vid`` or one of its shadows now (its drivers see the body there)."""
        present = set(traci.vehicle.getIDList())
        ids = [vid, *self.live.get(vid, {}).values()]
        return {self.frame.slot_of(traci, v) for v in ids if v in present} - {None}
