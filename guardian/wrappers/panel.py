"""A status panel under highway-env's ``rgb_array`` frames: what the guardian allowed and did.

Labelled fields, one row each::

    set: cautious      valid intentions: aggressive, cautious      guardian: OVERRIDE (throttle)
    a_ex [m/s^2]    -3 |====[admissible]====|  3     | proposed   | applied
    steering [rad]  -0.785 |--------|----------|  0.785   (the second input: steering, or v_ey)
    why: <the reasons of the last override>
    cars: ■ ego  ■ lead  ■ traffic  ■ crashed

Each input has an axis over its bounds: the admissible band green (where the guardian has one), the agent's
proposed input a red tick and the applied one a black tick, so a steering override shows on the steering axis;
the last row is the legend of the car colours of the frame (``envs.vehicles.COLOURS``).
"""
from __future__ import annotations

import functools

import numpy as np
from PIL import Image, ImageDraw, ImageFont

PANEL_HEIGHT = 114  # [px]
ROW = 22           # [px] per row
FONT_SIZE = 13     # [px]
GREY, BLACK, GREEN, RED, DARK_RED = (95, 95, 95), (0, 0, 0), (60, 180, 80), (220, 40, 40), (150, 0, 0)


@functools.lru_cache(maxsize=2)
def _font(bold: bool = False):
    """DejaVu Sans (shipped with matplotlib, a dependency), so spaces and widths are real on every machine."""
    try:
        from matplotlib import font_manager

        path = font_manager.findfont(font_manager.FontProperties(family="DejaVu Sans",
                                                                 weight="bold" if bold else "normal"))
        return ImageFont.truetype(path, FONT_SIZE)
    except Exception:  # no FreeType: Pillow's own scalable default
        return ImageFont.load_default(FONT_SIZE)


def _field(draw, x: int, y: int, label: str, value: str, colour=BLACK) -> int:
    """``label: value`` at (x, y), label grey and value bold; returns the x after it plus a gap."""
    draw.text((x, y), f"{label}:", fill=GREY, font=_font())
    x += int(draw.textlength(f"{label}: ", font=_font()))
    draw.text((x, y), value, fill=colour, font=_font(True))
    return x + int(draw.textlength(value, font=_font(True))) + 28


def _verdict(record: dict) -> str:
    """What the guardian changed, as the agent's own actions say it: a meta action by name (a refused lane change
    is named so), else the input that changed."""
    proposed, applied = record.get("proposed"), record.get("applied")
    if isinstance(proposed, str) and isinstance(applied, str):
        refused = " (lane change refused)" if record.get("refused_lane_change") else ""
        return f"OVERRIDE: {proposed} -> {applied}{refused}"
    return f"OVERRIDE ({record.get('changed')})"


def _axis(draw, y: int, w: int, label: str, bounds, band, record: dict, index: int, legend: bool) -> None:
    """One input's axis over its bounds: the admissible band, the proposed and applied ticks (input ``index``)."""
    lo, hi = bounds
    lo_text = f"{lo:.3g}"
    draw.text((8, y), label, fill=GREY, font=_font())
    x0 = 8 + int(draw.textlength("steering [rad]", font=_font())) + 10 + int(draw.textlength("-0.785", font=_font())) + 6
    x1 = w - 300
    yc = y + 8

    def px(a: float) -> int:
        return int(round(x0 + (min(max(a, lo), hi) - lo) / (hi - lo) * (x1 - x0)))

    draw.text((x0 - 6 - int(draw.textlength(lo_text, font=_font())), y), lo_text, fill=GREY, font=_font())
    draw.text((x1 + 6, y), f"{hi:.3g}", fill=GREY, font=_font())
    draw.line([(x0, yc), (x1, yc)], fill=(120, 120, 120), width=1)
    draw.line([(px(0.0), yc - 3), (px(0.0), yc + 3)], fill=(120, 120, 120), width=1)
    for a, b in band or []:
        draw.rectangle([px(a), yc - 5, px(b), yc + 5], fill=GREEN)
    for key, colour in (("proposed_input", RED), ("applied_input", BLACK)):
        u = record.get(key)
        if u is not None and len(u) > index:
            draw.line([(px(u[index]), yc - 9), (px(u[index]), yc + 9)], fill=colour, width=3)
    if not legend:
        return
    lx = x1 + 40
    for name, colour, bar in (("admissible", GREEN, False), ("proposed", RED, True), ("applied", BLACK, True)):
        if bar:
            draw.line([(lx + 5, yc - 7), (lx + 5, yc + 7)], fill=colour, width=3)
        else:
            draw.rectangle([lx, yc - 5, lx + 12, yc + 5], fill=colour)
        draw.text((lx + 16, y), name, fill=GREY, font=_font())
        lx += 16 + int(draw.textlength(name, font=_font())) + 14


def with_panel(frame: np.ndarray, record: dict, bounds: tuple[float, float], lateral: tuple | None = None) -> np.ndarray:
    """``frame`` (H x W x 3) with the panel appended below it.

    Parameters
    ----------
    frame : ndarray
        highway-env's ``rgb_array`` frame.
    record : dict
        The guardian's last record (``active_set``, ``valid_intentions``, ``overridden``, ``changed``,
        ``admissible_acceleration``, ``proposed_input``, ``applied_input``, ``reasons``).
    bounds : (float, float)
        The acceleration axis (the input bounds).
    lateral : (str, (float, float)), optional
        The second input's axis: its label and bounds (steering on roads, lateral speed on the overtake road),
        with the band ``admissible_lateral`` where the guardian has one.

    Returns
    -------
    ndarray
        ``PANEL_HEIGHT`` rows more than ``frame``.
    """
    from envs.vehicles import COLOURS

    h, w = frame.shape[:2]
    img = Image.new("RGB", (w, PANEL_HEIGHT), (245, 245, 245))
    draw = ImageDraw.Draw(img)
    y = 3
    x = _field(draw, 8, y, "set", str(record.get("active_set", "-")))
    x = _field(draw, x, y, "valid intentions", ", ".join(record.get("valid_intentions") or []) or "-")
    overridden = bool(record.get("overridden"))
    _field(draw, x, y, "guardian", _verdict(record) if overridden else "pass-through", DARK_RED if overridden else BLACK)

    y += ROW
    _axis(draw, y, w, "a_ex [m/s^2]", bounds, record.get("admissible_acceleration"), record, 0, legend=True)
    if lateral is not None:
        y += ROW
        _axis(draw, y, w, lateral[0], lateral[1], record.get("admissible_lateral"), record, 1, legend=False)

    y += ROW
    reasons = "; ".join(record.get("reasons") or []) or "-"
    draw.text((8, y), "why:", fill=GREY, font=_font())
    wx = 8 + int(draw.textlength("why: ", font=_font()))
    while reasons and draw.textlength(reasons, font=_font()) > w - wx - 8:  # cut to the width, marked
        reasons = reasons[:-2].rstrip() + "…"
    draw.text((wx, y), reasons, fill=DARK_RED if record.get("reasons") else GREY, font=_font())

    y += ROW
    draw.text((8, y), "cars:", fill=GREY, font=_font())
    lx = 8 + int(draw.textlength("cars: ", font=_font()))
    for name in ("ego", "lead", "traffic", "crashed"):
        draw.rectangle([lx, y + 3, lx + 18, y + 13], fill=tuple(COLOURS[name]), outline=(60, 60, 60))
        draw.text((lx + 23, y), name, fill=BLACK, font=_font())
        lx += 23 + int(draw.textlength(name, font=_font())) + 16
    return np.concatenate([frame, np.asarray(img, dtype=frame.dtype)], axis=0)
