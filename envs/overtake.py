"""What the overtake scenario draws (Section 6.3): its disturbances and its initial states.

Disturbances ``w = [w_ex, w_ey, w_Lx, w_Delta]`` are drawn uniformly from their box (``"random"``) or
chosen at the box's vertices against the ego (``"adversarial"``: the lead brakes as hard as its
intention allows while the ego is behind and speeds up while it is ahead; the ego's noise pushes it
towards the lead and the right lane). The environments are ``envs.highway_overtake``'s.
"""
from __future__ import annotations

import numpy as np

from intention.params import OvertakeParams

DISTURBANCE_MODES = ("random", "adversarial")


def disturbance_box(p: OvertakeParams) -> tuple[np.ndarray, np.ndarray]:
    """The box of ``w = [w_ex, w_ey, w_Lx, w_Delta]`` (Table 6.1)."""
    return (np.array([p.w_ex_bounds[0], p.w_ey_bounds[0], p.w_Lx_bounds[0], p.w_delta_bounds[0]]),
            np.array([p.w_ex_bounds[1], p.w_ey_bounds[1], p.w_Lx_bounds[1], p.w_delta_bounds[1]]))


def draw_disturbance(p: OvertakeParams, mode: str, x, rng: np.random.Generator) -> np.ndarray:
    """One disturbance ``w``: uniform in its box, or the adversarial vertex at state ``x``.

    Adversarial: while the ego is behind (``h > 0``) the lead brakes as hard as its
    intention allows and the ego's noise speeds it up; once ahead, the reverse. The
    ego's lateral noise always pushes it towards the right lane.
    """
    lo, hi = disturbance_box(p)
    if mode == "random":
        return rng.uniform(lo, hi)
    if mode != "adversarial":
        raise ValueError(f"disturbance must be one of {DISTURBANCE_MODES}, got {mode!r}")
    behind = x[2] > 0
    return np.array([hi[0] if behind else lo[0], lo[1], lo[2] if behind else hi[2], lo[3] if behind else hi[3]])


def sample_initial_state(box, region, rng: np.random.Generator, who: str) -> np.ndarray:
    """A state uniform in ``box`` (and inside ``region``, a ``rcis.Region``, when given)."""
    lo, hi = (np.asarray(v, dtype=float) for v in box)
    for _ in range(10_000):
        x = rng.uniform(lo, hi)
        if region is None or region.contains(x):
            return x
    raise RuntimeError(f"{who}: no initial state of initial_box lies in initial_region")
