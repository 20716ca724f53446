"""A status panel under highway-env's ``rgb_array`` frames: what the guardian allowed and did.

The strip shows the active set and the valid intentions, the admissible acceleration band
(green) on an axis over the input bounds, the agent's proposed acceleration (red tick) and the
applied one (black tick), and the reasons of the last override.
"""
from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw

PANEL_HEIGHT = 64  # [px]


def with_panel(frame: np.ndarray, record: dict, bounds: tuple[float, float]) -> np.ndarray:
    """``frame`` (H x W x 3) with the panel appended below it."""
    h, w = frame.shape[:2]
    img = Image.new("RGB", (w, PANEL_HEIGHT), (245, 245, 245))
    draw = ImageDraw.Draw(img)
    valid = ", ".join(record.get("valid_intentions") or []) or "-"
    draw.text((6, 3), f"set {record.get('active_set', '-')}   valid {valid}   "
                      f"{'OVERRIDE ' + str(record.get('changed')) if record.get('overridden') else 'pass-through'}",
              fill=(0, 0, 0))
    lo, hi = bounds
    x0, x1, y = 40, w - 40, 32

    def px(a: float) -> int:
        return int(round(x0 + (min(max(a, lo), hi) - lo) / (hi - lo) * (x1 - x0)))

    draw.line([(x0, y), (x1, y)], fill=(120, 120, 120), width=1)
    draw.text((6, y - 6), f"{lo:g}", fill=(80, 80, 80))
    draw.text((x1 + 4, y - 6), f"{hi:g}", fill=(80, 80, 80))
    for a, b in record.get("admissible_acceleration") or []:
        draw.rectangle([px(a), y - 5, px(b), y + 5], fill=(60, 180, 80))
    for key, colour in (("proposed_input", (220, 40, 40)), ("applied_input", (0, 0, 0))):
        u = record.get(key)
        if u:
            draw.line([(px(u[0]), y - 9), (px(u[0]), y + 9)], fill=colour, width=3)
    reasons = "; ".join(record.get("reasons") or [])
    draw.text((6, y + 12), ("a [m/s^2]   " + reasons)[: w // 6], fill=(90, 0, 0) if reasons else (80, 80, 80))
    return np.concatenate([frame, np.asarray(img, dtype=frame.dtype)], axis=0)
