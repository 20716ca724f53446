"""Planar polyhedra drawn: a 2-D polyhedron's vertices by clipping, for a set's slice at a state, every step.

Kept apart from ``rcis.polyhedron``: nothing that computes a set imports it, so it is outside every cached set's
code fingerprint (``rcis.cache.code_fingerprint``) and drawing code can change without invalidating a cache.
"""
from __future__ import annotations

import numpy as np

from rcis.polyhedron import Polyhedron


def polygon(P: Polyhedron, window) -> np.ndarray:
    """``P``'s vertices (``P`` of dimension 2) in order (counter-clockwise), clipped to the box ``window = (lower,
    upper)``: the box cut by each half-plane in turn (Sutherland-Hodgman), no LP. Shape (0, 2) where nothing is left.
    Cheap enough for a slice every step; ``Polyhedron.generators`` is the LP-checked referee (tested)."""
    if P.dim != 2:
        raise ValueError(f"polygon: the polyhedron has dimension {P.dim}, not 2")
    (x0, y0), (x1, y1) = (np.asarray(w, dtype=float) for w in window)
    pts = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    for (a0, a1), bi in zip(P.A, P.b):
        out = []
        for k, p in enumerate(pts):
            q = pts[(k + 1) % len(pts)]
            sp, sq = a0 * p[0] + a1 * p[1] - bi, a0 * q[0] + a1 * q[1] - bi
            if sp <= 0:
                out.append(p)
            if (sp < 0 < sq) or (sq < 0 < sp):
                t = sp / (sp - sq)
                out.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
        pts = out
        if len(pts) < 3:
            return np.zeros((0, 2))
    return np.array(pts)
