"""``Shadow``: an in-process decision object that asks a service session every question it answers, and keeps
every disagreement: how a deployment is checked against the library it came from. The decisions applied are
the in-process ones; the service's answers are compared with them bit for bit (``benchmarks/service_equivalence.py``
runs highway-env episodes so).
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

from guardian.client.bodies import step_body


def same_bits(a: float, b: float) -> bool:
    """Equal to the bit (``-0.0`` differs from ``0.0``; a NaN equals the same NaN)."""
    return struct.pack("<d", a) == struct.pack("<d", b)


@dataclass
class Disagreement:
    """One question the service answered otherwise: the step (or lane change) number, what, and both answers."""

    index: int
    what: str
    local: object
    remote: object


@dataclass
class Tally:
    """What a ``Shadow`` compared: steps and lane changes asked, and every disagreement."""

    steps: int = 0
    lane_changes: int = 0
    disagreements: list = field(default_factory=list)


class Shadow:
    """``guard`` (a ``BicycleGuardian``) deciding in-process, with every ``step`` and ``policy_lane_change`` also
    sent to ``session`` (a scene session created with ``vehicle_body(guard.kin, guard.meta)`` and
    ``guardian_body(guard.config)``, through HTTP or its stream: anything with ``step(**body)``);
    ``lane_changes``: where lane-change queries go (a ``Session``; default ``session``).

    The in-process answer is returned; ``tally`` counts the questions and keeps every answer that differs: the
    applied input to the bit, whether and how it was changed, the lanes, and each lane-change verdict.
    """

    def __init__(self, guard, session, road, lane_changes=None):
        self.guard, self.session, self.road = guard, session, road
        self.lane_changes = lane_changes if lane_changes is not None else session
        self.tally = Tally()

    def __getattr__(self, name):
        return getattr(self.guard, name)

    def reset(self) -> None:
        raise RuntimeError("a Shadow follows one session: make a new Shadow (and session) for a new episode")

    def step(self, ego, scene, proposed):
        applied, decision = self.guard.step(ego, scene, proposed)
        record = self.session.step(**step_body(ego, scene, proposed, self.road, self.guard.kin.length,
                                               self.guard.actuator is not None))
        self._compare(applied, decision, record)
        self.tally.steps += 1
        return applied, decision

    def policy_lane_change(self, ego, scene, target: int):
        allowed, reason = self.guard.policy_lane_change(ego, scene, target)
        body = step_body(ego, scene, (0.0, 0.0), self.road, self.guard.kin.length, self.guard.actuator is not None)
        answer = self.lane_changes.lane_change(body["ego"], body["cars"], int(target))
        mine = (bool(allowed), self.road.numbering.slot_text(reason) if reason else reason)  # the service says slots
        if mine != (answer["allowed"], answer["reason"]):
            self.tally.disagreements.append(Disagreement(self.tally.lane_changes, "lane change", mine, answer))
        self.tally.lane_changes += 1
        return allowed, reason

    def _compare(self, applied, decision, record: dict) -> None:
        local = [float(applied[0]), float(applied[1])]
        remote = record["applied"]
        n = self.tally.steps
        if not all(same_bits(a, b) for a, b in zip(local, remote)) or any(math.isnan(v) for v in remote):
            self.tally.disagreements.append(Disagreement(n, "applied", local, remote))
        slots = self.road.numbering.slot_set
        pairs = {"changed": (decision.changed, record["changed"]), "level": (decision.level, record["level"]),
                 "lanes": (sorted(slots(decision.lanes)), record["lanes"]),
                 "entered": (sorted(slots(decision.entered)), record["entered"])}
        for what, (mine, theirs) in pairs.items():
            if mine != theirs:
                self.tally.disagreements.append(Disagreement(n, what, mine, theirs))
