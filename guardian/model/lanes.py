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

from dataclasses import dataclass


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
