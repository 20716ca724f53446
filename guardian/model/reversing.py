"""The cover for traffic that drives backwards (outside the traffic model's speeds ``[0, v_max]``).

highway-env lets traffic reverse (``Vehicle.MIN_SPEED = -40``). The guardian takes a car seen driving
backwards longer at its rear by how far it may still back up (``GuardianConfig.reverse_reach``), more
behind a car that reverses too: a queue that reverses backs up link by link.
"""
from __future__ import annotations

from dataclasses import replace


def reverse_reaches(fronts, speeds, lanes, reach: float) -> list:
    """How far each car may still back up: 0 for a car that does not drive backwards; ``reach`` for one that
    does, plus the reach of the car it follows in its own lane (``lanes[i]``, ``fronts`` along it) when that
    car drives backwards too: a queue that reverses backs up link by link (an IDM car reverses to open its
    gap to the car ahead, and that car is moving back)."""
    out = [0.0] * len(fronts)
    order = sorted(range(len(fronts)), key=lambda i: -fronts[i])
    ahead = {}   # lane -> the index of the last car seen (the nearest ahead of the next one)
    for i in order:
        j = ahead.get(lanes[i])
        if speeds[i] < 0:
            out[i] = reach + (out[j] if j is not None and speeds[j] < 0 else 0.0)
        ahead[lanes[i]] = i
    return out


def lengthen_reversing(cars: list, own: list, reach: float) -> list:
    if not any(c.speed < 0 for c in cars):
        return cars
    extra = reverse_reaches([c.front for c in cars], [c.speed for c in cars], own, reach)
    return [replace(c, length=c.length + e) if e else c for c, e in zip(cars, extra)]


