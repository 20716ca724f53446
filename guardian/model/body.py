"""A car's body on the road: a ``length`` x ``width`` rectangle turned by its heading.

``half_extents`` is the reach of the turned rectangle along and across a reference direction (the road's,
or a lane's); ``lanes_overlapped`` the lanes of equal width that a lateral interval meets. The guardian's
readers and kinematics use these; the fault judge (``guardian.evaluation.judge``) keeps its own geometry on
purpose, so that a mistake here cannot hide from it.
"""
from __future__ import annotations

import math

import numpy as np


def half_extents(length: float, width: float, angle):
    """``(along, across)``: half the reach of the rectangle turned by ``angle`` (against the reference
    direction) along it and across it, ``L/2 |cos a| + W/2 |sin a|`` and ``L/2 |sin a| + W/2 |cos a|``.
    ``angle`` is a float or an array (then both are arrays)."""
    if isinstance(angle, np.ndarray):
        c, s = np.abs(np.cos(angle)), np.abs(np.sin(angle))
    else:
        c, s = abs(math.cos(angle)), abs(math.sin(angle))
    return length / 2 * c + width / 2 * s, length / 2 * s + width / 2 * c


def lanes_overlapped(lo: float, hi: float, n_lanes: int, width: float) -> frozenset:
    """Slots ``k = 0..n_lanes-1`` (centre line at ``k * width``) that the open interval ``(lo, hi)`` meets."""
    return frozenset(k for k in range(n_lanes) if lo < (k + 0.5) * width and hi > (k - 0.5) * width)
