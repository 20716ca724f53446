"""Unions of closed intervals as sorted lists of ``(lo, hi)``: the one place they are combined."""
from __future__ import annotations


def intersect_intervals(a, b) -> list[tuple[float, float]]:
    """``a ∩ b`` for two unions of intervals (empty pieces dropped)."""
    out = []
    for lo1, hi1 in a:
        for lo2, hi2 in b:
            lo, hi = max(lo1, lo2), min(hi1, hi2)
            if lo <= hi:
                out.append((lo, hi))
    return out


def merge_intervals(iv, gap: float = 1e-12) -> list[tuple[float, float]]:
    """Sorted, with intervals closer than ``gap`` joined."""
    out = []
    for lo, hi in sorted(iv):
        if out and lo <= out[-1][1] + gap:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


def nearest_in_intervals(ranges, value: float) -> float | None:
    """The point of the union nearest to ``value`` (None when the union is empty)."""
    best = None
    for lo, hi in ranges:
        cand = min(max(value, lo), hi)
        if best is None or abs(cand - value) < abs(best - value):
            best = cand
    return best
