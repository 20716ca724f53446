"""Lane numberings, and the one converter between them.

Two numberings meet in the guardian:

* a road's **slots**: the lateral positions of its lanes, 0 the leftmost. On one straight road they are
  highway-env's lane ids (lane 0 at ``y = 0``, y growing to the right of the direction of travel); on a
  ``guardian.model.roads.RoadMap`` they are the corridor's slots;
* **ITHA lanes** (Chapter 7, Appendix B): 1 the rightmost, ``n_lanes`` the leftmost.

``LaneNumbering(n_lanes)`` converts between them. Readers of a simulator and the kinematics work in slots;
the traffic rules (``guardian.decide.traffic``), the scene's cars and every ``Decision`` are in ITHA lanes.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

_LANE_WORDS = re.compile(r"\b(lanes? )(\[[0-9, ]*\]|\d+(?![\d.]))")  # "lane 2", "lanes [1, 2]" in a decision's text


@dataclass(frozen=True)
class LaneNumbering:
    """Slot ``k`` (0 = leftmost) is ITHA lane ``n_lanes - k`` (1 = rightmost), and back."""

    n_lanes: int

    def itha(self, slot: int) -> int:
        """The ITHA lane of ``slot``."""
        return self.n_lanes - slot

    def slot(self, lane: int) -> int:
        """The slot of ITHA lane ``lane``."""
        return self.n_lanes - lane

    def itha_set(self, slots) -> frozenset:
        """The ITHA lanes of ``slots``."""
        return frozenset(self.n_lanes - k for k in slots)

    def slot_set(self, lanes) -> frozenset:
        """The slots of ITHA ``lanes``."""
        return frozenset(self.n_lanes - lane for lane in lanes)

    def slot_text(self, text: str) -> str:
        """A decision's text (which says ITHA lanes) with its lanes as slots."""
        def slots(m) -> str:
            value = m.group(2)
            if value.startswith("["):
                return m.group(1) + str(sorted(self.slot(int(k)) for k in value[1:-1].split(",") if k.strip()))
            return m.group(1) + str(self.slot(int(value)))
        return _LANE_WORDS.sub(slots, text)
