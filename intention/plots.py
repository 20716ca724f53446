"""Pictures of the library: slices of the sets (as Fig. 6.3b) and S(x) (as Fig. 6.4)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from rcis import _kernels  # noqa: E402
from rcis.region import Region  # noqa: E402

FIG64_STATE = (25.0, -0.297, 16.52, 20.0)
COLORS = {"bounded_velocity": "#d62728", "aggressive": "#9467bd", "cautious": "#1f77b4"}


def slice_polygons(region: Region, v_ex: float, v_Lx: float, h_range=(-80.0, 80.0),
                   y_range=(-0.9, 2.7)) -> list[np.ndarray]:
    """Polygons of ``{(h, y) : (v_ex, y, h, v_Lx) in region}`` inside the plotting window."""
    G, r, starts = [], [], [0]
    for P in region.pieces:
        S = P.slice([0, 3], [v_ex, v_Lx])  # coordinates left: (y, h)
        G.append(S.A[:, ::-1])
        r.append(S.b)
        starts.append(starts[-1] + S.n_constraints)
    verts, counts = _kernels.clip_box_by_halfplanes(
        np.ascontiguousarray(np.vstack(G)), np.concatenate(r), np.asarray(starts, dtype=np.int64),
        np.array([h_range[0], y_range[0]]), np.array([h_range[1], y_range[1]]))
    return [verts[p, :counts[p]] for p in np.flatnonzero(counts > 2)]


def _fill(ax, polygons, color, label, edge=None):
    for i, P in enumerate(polygons):
        ax.fill(P[:, 0], P[:, 1], facecolor=color, edgecolor=edge or color, lw=0.8 if edge else 0,
                label=label if i == 0 else None)


def plot_slices(library, out: Path, slices=((25.0, 20.0), (30.0, 25.0), (20.0, 28.0))) -> Path:
    """Fig. 6.3b as ``out/fig6_3_slices.png`` (``slices_figure``); returns the file's path."""
    return _save(slices_figure(library, slices), Path(out) / "fig6_3_slices.png")


def plot_admissible(library, out: Path, state=FIG64_STATE) -> Path:
    """Fig. 6.4 as ``out/fig6_4_admissible_inputs.png`` (``admissible_figure``); returns the file's path."""
    return _save(admissible_figure(library, state), Path(out) / "fig6_4_admissible_inputs.png")


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=110, bbox_inches="tight")  # nothing clipped, whatever the labels
    plt.close(fig)
    return path


def slices_figure(library, slices=((25.0, 20.0), (30.0, 25.0), (20.0, 28.0))):
    """Fig. 6.3b: slices ``(h, y_e)`` of ``C_c``/``C_a`` and ``C_bnd`` at fixed speeds; the unsafe region hatched."""
    from matplotlib.patches import Patch, Rectangle

    p = library.params
    fig, axes = plt.subplots(len(slices), 2, figsize=(12, 3.2 * len(slices)), squeeze=False)
    for row, (v, vl) in enumerate(slices):
        for col, name in enumerate(("cautious", "aggressive")):
            ax = axes[row, col]
            ax.axhspan(p.y_e_bounds[0], p.left_lane_y, color="0.88", zorder=-2)  # right lane, seen where no set is
            ax.add_patch(Rectangle((-p.h_min, p.y_e_bounds[0]), 2 * p.h_min, p.left_lane_y - p.y_e_bounds[0],
                                   facecolor="none", edgecolor="0.35", hatch="///", lw=0.8, zorder=-1))
            _fill(ax, slice_polygons(library.region(name), v, vl), COLORS[name], None)
            _fill(ax, slice_polygons(library.region("bounded_velocity"), v, vl), COLORS["bounded_velocity"], None)
            ax.set_title(f"{PAPER[name]} ({name}) and C_bnd at v_ex = {v:g} m/s, v_Lx = {vl:g} m/s")
            ax.set_xlabel("h (m)")
            ax.set_ylabel("y_e (m)")
            ax.set_xlim(-80, 80)
            ax.set_ylim(*p.y_e_bounds)
            ax.legend(handles=[Patch(color=COLORS[name], label=f"{PAPER[name]} \\ C_bnd ({name})"),
                               Patch(color=COLORS["bounded_velocity"], label="C_bnd (bounded velocity)"),
                               Patch(color="0.88", label=f"in no set (right lane, y_e < {p.left_lane_y:g} m)"),
                               Patch(facecolor="none", edgecolor="0.35", hatch="///",
                                     label=f"unsafe: |h| < h_min = {p.h_min:g} m in the right lane (6.8)")],
                      loc="upper left", fontsize=7, framealpha=0.9)
    fig.tight_layout()
    return fig


PAPER = {"bounded_velocity": "C_bnd", "aggressive": "C_a", "cautious": "C_c"}
_GRID = (1201, 721)  # raster of U that measures the difference between two S(x)


def _mask(polygons, a, v) -> np.ndarray:
    """Which points of the grid ``a x v`` lie in the union of ``polygons`` (edges included)."""
    from matplotlib.path import Path as MplPath

    pts = np.column_stack([a.ravel(), v.ravel()])
    inside = np.zeros(len(pts), dtype=bool)
    for P in polygons:
        inside |= MplPath(P).contains_points(pts, radius=1e-9) | MplPath(P[::-1]).contains_points(pts, radius=1e-9)
    return inside.reshape(a.shape)


def admissible_difference(library, state=FIG64_STATE) -> dict:
    """Where ``S_a(x)`` and ``S_c(x)`` differ, measured on a grid of U.

    Parameters
    ----------
    library : OvertakeLibrary
    state : sequence of 4 floats
        ``x = (v_ex, y_e, h, v_Lx)``.

    Returns
    -------
    dict
        ``only_aggressive`` and ``only_cautious``: area (in (m/s^2)(m/s)) and bounding box
        ``[a_min, a_max, v_min, v_max]`` (None when empty); the grid's ``a``, ``v`` and the masks
        ``aggressive``, ``cautious`` for drawing.
    """
    p = library.params
    a, v = np.meshgrid(np.linspace(*p.a_ex_bounds, _GRID[0]), np.linspace(*p.v_ey_bounds, _GRID[1]))
    masks = {n: _mask(library.admissible(n).polygons(np.asarray(state)), a, v) for n in ("aggressive", "cautious")}
    cell = (a[0, 1] - a[0, 0]) * (v[1, 0] - v[0, 0])
    out = {"a": a, "v": v, **masks}
    for key, m in (("only_aggressive", masks["aggressive"] & ~masks["cautious"]),
                   ("only_cautious", masks["cautious"] & ~masks["aggressive"])):
        out[key] = {"area": float(m.sum() * cell),
                    "box": [float(a[m].min()), float(a[m].max()), float(v[m].min()), float(v[m].max())] if m.any()
                    else None, "mask": m}
    return out


def admissible_figure(library, state=FIG64_STATE):
    """Fig. 6.4: ``S(x)`` of each set (its polygons with their edges, refused inputs hatched) and where
    the aggressive and the cautious sets differ, enlarged."""
    from matplotlib.patches import Patch, Rectangle

    p = library.params
    (a_lo, a_hi), (v_lo, v_hi) = p.a_ex_bounds, p.v_ey_bounds
    diff = admissible_difference(library, state)
    boxes = [d["box"] for d in (diff["only_aggressive"], diff["only_cautious"]) if d["box"]]
    zoom = None
    if boxes:  # the enlarged window of the last panel: the difference with a margin
        lo_a, hi_a = min(b[0] for b in boxes), max(b[1] for b in boxes)
        lo_v, hi_v = min(b[2] for b in boxes), max(b[3] for b in boxes)
        pad_a, pad_v = max(0.5, hi_a - lo_a), max(0.3, hi_v - lo_v)
        zoom = (max(a_lo, lo_a - pad_a) - 0.05, min(a_hi, hi_a + pad_a) + 0.05,
                max(v_lo, lo_v - pad_v) - 0.05, min(v_hi, hi_v + pad_v) + 0.05)
    fig, axes = plt.subplots(1, 4, figsize=(18, 4.6))
    for ax, name in zip(axes, ("aggressive", "cautious", "bounded_velocity")):
        polys = library.admissible(name).polygons(np.asarray(state))
        ax.add_patch(Rectangle((a_lo, v_lo), a_hi - a_lo, v_hi - v_lo, facecolor="#fde0dd", edgecolor="#c51b8a",
                               hatch="xx", lw=1.0, zorder=0))
        for P in polys:
            ax.fill(P[:, 0], P[:, 1], facecolor="#c6dbef", edgecolor="none", zorder=1)
        for P in polys:  # every polygon's edges, over all fills
            ax.fill(P[:, 0], P[:, 1], facecolor="none", edgecolor="#08306b", lw=1.2, zorder=2)
        only = diff.get(f"only_{name}")
        if only and only["box"]:
            ax.contourf(diff["a"], diff["v"], only["mask"].astype(float), levels=[0.5, 1.5],
                        colors=["#ff7f00" if name == "aggressive" else "#33a02c"], zorder=3)
        if zoom is not None and name != "bounded_velocity":
            ax.add_patch(Rectangle((zoom[0], zoom[2]), zoom[1] - zoom[0], zoom[3] - zoom[2], facecolor="none",
                                   edgecolor="k", ls="--", lw=1.0, zorder=4))
        ax.set_xlim(a_lo - 0.3, a_hi + 0.3)
        ax.set_ylim(v_lo - 0.25, v_hi + 0.25)
        ax.set_xlabel("a_ex (m/s^2)")
        ax.set_ylabel("v_ey (m/s)")
        ax.set_title(f"{PAPER[name]} ({name}): {len(polys)} polygon(s)" + ("" if polys else ": S(x) empty"))
    ax = axes[3]
    a = diff["a"]
    colors = np.empty(a.shape + (3,))
    colors[:] = (0.99, 0.88, 0.87)  # refused by both
    colors[diff["aggressive"] & diff["cautious"]] = (0.78, 0.86, 0.94)
    colors[diff["only_aggressive"]["mask"]] = (1.0, 0.5, 0.0)
    colors[diff["only_cautious"]["mask"]] = (0.2, 0.63, 0.17)
    ax.imshow(colors, origin="lower", extent=(a_lo, a_hi, v_lo, v_hi), aspect="auto", interpolation="nearest")
    if zoom is not None:
        ax.set_xlim(*zoom[:2])
        ax.set_ylim(*zoom[2:])
        for key, who in (("only_aggressive", "only C_a"), ("only_cautious", "only C_c")):
            b = diff[key]["box"]
            if b:
                ax.annotate(f"{who}: a_ex in [{b[0]:.2f}, {b[1]:.2f}],\nv_ey in [{b[2]:.2f}, {b[3]:.2f}]",
                            xy=((b[0] + b[1]) / 2, (b[2] + b[3]) / 2), xytext=(0.45, 0.55),
                            textcoords="axes fraction", fontsize=9, arrowprops={"arrowstyle": "->"},
                            bbox={"boxstyle": "round", "fc": "white", "alpha": 0.9})
    ax.set_xlabel("a_ex (m/s^2)")
    ax.set_ylabel("v_ey (m/s)")
    ax.set_title("C_a vs C_c, enlarged (dashed box) where they differ" if boxes else "C_a vs C_c: S(x) equal")
    fig.legend(handles=[Patch(facecolor="#c6dbef", edgecolor="#08306b", label="S(x): admissible (edges: its polygons)"),
                        Patch(facecolor="#fde0dd", edgecolor="#c51b8a", hatch="xx", label="refused inputs of U"),
                        Patch(facecolor="#ff7f00", edgecolor="k",
                              label=f"only C_a allows ({diff['only_aggressive']['area']:.3f} (m/s^2)(m/s))"),
                        Patch(facecolor="#33a02c", edgecolor="k",
                              label=f"only C_c allows ({diff['only_cautious']['area']:.3f} (m/s^2)(m/s))")],
               loc="lower center", ncol=4, fontsize=9, bbox_to_anchor=(0.5, -0.02))
    fig.suptitle("Admissible inputs S(x) at x = (v_ex, y_e, h, v_Lx) = "
                 f"({', '.join(f'{c:g}' for c in state)})")
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    return fig
