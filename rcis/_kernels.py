"""Compiled inner loops: union membership and 2-D convex polygon clipping.

A numpy membership test of a 50-piece union costs ~15 µs per state; these
early-exit loops cost ~1 µs. Both are plain functions of arrays so that the
math stays in ``Region`` and ``AdmissibleInputs``.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def first_piece(A, b, starts, x, tol):
    """Index of the first piece ``A[s:e] x <= b[s:e] + tol`` holding x, or -1."""
    n = A.shape[1]
    for p in range(starts.shape[0] - 1):
        inside = True
        for r in range(starts[p], starts[p + 1]):
            s = 0.0
            for j in range(n):
                s += A[r, j] * x[j]
            if s > b[r] + tol:
                inside = False
                break
        if inside:
            return p
    return -1


@njit(cache=True)
def first_pieces(A, b, starts, X, tol):
    out = np.empty(X.shape[0], dtype=np.int64)
    for k in range(X.shape[0]):
        out[k] = first_piece(A, b, starts, X[k], tol)
    return out


@njit(cache=True)
def _clip(poly, count, g0, g1, r, out):
    """Sutherland-Hodgman: clip the convex polygon poly[:count] by g.u <= r."""
    m = 0
    for i in range(count):
        px, py = poly[i, 0], poly[i, 1]
        qx, qy = poly[(i + 1) % count, 0], poly[(i + 1) % count, 1]
        sp = g0 * px + g1 * py - r
        sq = g0 * qx + g1 * qy - r
        if sp <= 0.0:
            out[m, 0] = px
            out[m, 1] = py
            m += 1
        if (sp < 0.0 and sq > 0.0) or (sp > 0.0 and sq < 0.0):
            t = sp / (sp - sq)
            out[m, 0] = px + t * (qx - px)
            out[m, 1] = py + t * (qy - py)
            m += 1
    return m


@njit(cache=True)
def clip_box_by_halfplanes(G, r, starts, lo, hi):
    """For each piece p, the polygon ``{u in [lo,hi] : G[s:e] u <= r[s:e]}``.

    Returns ``(vertices, counts)``: vertices[p, :counts[p]] is piece p's polygon
    (counter-clockwise); counts[p] == 0 means empty.
    """
    n_pieces = starts.shape[0] - 1
    max_rows = 0
    for p in range(n_pieces):
        max_rows = max(max_rows, starts[p + 1] - starts[p])
    cap = 4 + max_rows + 1
    verts = np.zeros((n_pieces, cap, 2))
    counts = np.zeros(n_pieces, dtype=np.int64)
    a = np.empty((cap, 2))
    tmp = np.empty((cap, 2))
    for p in range(n_pieces):
        a[0, 0], a[0, 1] = lo[0], lo[1]
        a[1, 0], a[1, 1] = hi[0], lo[1]
        a[2, 0], a[2, 1] = hi[0], hi[1]
        a[3, 0], a[3, 1] = lo[0], hi[1]
        count = 4
        for row in range(starts[p], starts[p + 1]):
            count = _clip(a, count, G[row, 0], G[row, 1], r[row], tmp)
            for i in range(count):
                a[i, 0] = tmp[i, 0]
                a[i, 1] = tmp[i, 1]
            if count == 0:
                break
        counts[p] = count
        for i in range(count):
            verts[p, i, 0] = a[i, 0]
            verts[p, i, 1] = a[i, 1]
    return verts, counts


@njit(cache=True)
def first_piece_holding_all(A, b, starts, X, tol):
    """Index of the first piece that holds every row of X, or -1."""
    n = A.shape[1]
    for p in range(starts.shape[0] - 1):
        inside = True
        for r in range(starts[p], starts[p + 1]):
            for k in range(X.shape[0]):
                s = 0.0
                for j in range(n):
                    s += A[r, j] * X[k, j]
                if s > b[r] + tol:
                    inside = False
                    break
            if not inside:
                break
        if inside:
            return p
    return -1


@njit(cache=True)
def line_intervals(G, r, starts, axis, value, lo, hi):
    """Per piece, the range of input ``axis`` on ``{u in [lo,hi] : G u <= r, u[other] = value}``.

    Row p of the result is ``(low, high)``; ``low > high`` means empty.
    """
    other = 1 - axis
    n_pieces = starts.shape[0] - 1
    out = np.empty((n_pieces, 2))
    for p in range(n_pieces):
        a, b = lo[axis], hi[axis]
        if value < lo[other] or value > hi[other]:
            a, b = 1.0, 0.0
        for row in range(starts[p], starts[p + 1]):
            g = G[row, axis]
            rr = r[row] - G[row, other] * value
            if g > 1e-14:
                b = min(b, rr / g)
            elif g < -1e-14:
                a = max(a, rr / g)
            elif rr < 0.0:
                a, b = 1.0, 0.0
                break
        out[p, 0] = a
        out[p, 1] = b
    return out
