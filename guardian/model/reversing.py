"""The cover for traffic that drives backwards (outside the traffic model's speeds ``[0, v_max]``).

highway-env lets traffic reverse (``Vehicle.MIN_SPEED = -40``; IDM brakes into reverse when it stands inside
its desired gap). The guardian takes a car that may be driving backwards before it looks again longer at its
rear by how far it may still back up (``ReversingCover.reach``), more behind a car that reverses: a queue that
reverses backs up link by link. A car may be driving backwards soon when it is slower than
``ReversingCover.below`` (the traffic's braking bound times ``GuardianConfig.reverse_horizon``): a car seen at
0.73 m/s backed 2.8 m into a guarded car that had entered its lane behind it while it still crept forward.
Only a car seen driving backwards swings into the lanes beside its own (the readers' ``swings``): a slow car
covered in its own lanes lets a guarded car pass it on the next lane (at an on-ramp's end a standing car
beside would otherwise hold it for good).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class ReversingCover:
    """``reach`` [m]: how far a reversing car may still back up; ``below`` [m/s]: a car slower than this may be
    reversing before the next look (0: only a car seen driving backwards)."""

    reach: float
    below: float = 0.0

    def __post_init__(self):
        if not self.below >= 0:   # a car driving backwards is always covered: speed < 0 <= below
            raise ValueError(f"ReversingCover.below must be >= 0, got {self.below!r}")

    def may_reverse(self, speed: float) -> bool:
        return speed < self.below

    def any_may(self, speeds) -> bool:
        return bool(np.any(np.asarray(speeds, dtype=float) < self.below))

    def reaches(self, fronts, speeds, lanes) -> list:
        """How far each car may still back up: 0 for a car that may not reverse; ``reach`` for one that may,
        plus the reach of the car it follows in its own lane (``lanes[i]``, ``fronts`` along it) when that car
        drives backwards: a queue that reverses backs up link by link (an IDM car reverses to open its gap to
        the car ahead, and that car is moving back). A slow car ahead that does not yet reverse adds nothing:
        a standing queue would otherwise hold a guarded car a reach per car behind it."""
        out = [0.0] * len(fronts)
        order = sorted(range(len(fronts)), key=lambda i: -fronts[i])
        ahead = {}   # lane -> the index of the last car seen (the nearest ahead of the next one)
        for i in order:
            j = ahead.get(lanes[i])
            if self.may_reverse(speeds[i]):
                out[i] = self.reach + (out[j] if j is not None and speeds[j] < 0 else 0.0)
            ahead[lanes[i]] = i
        return out

    def lengthen(self, cars: list, own: list) -> list:
        """``cars`` (``Car``), each that may reverse longer at its rear by its reach (``own``: their own lanes)."""
        if not any(self.may_reverse(c.speed) for c in cars):
            return cars
        extra = self.reaches([c.front for c in cars], [c.speed for c in cars], own)
        return [replace(c, length=c.length + e) if e else c for c, e in zip(cars, extra)]
