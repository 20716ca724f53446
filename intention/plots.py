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


def _fill(ax, polygons, color, label):
    for i, P in enumerate(polygons):
        ax.fill(P[:, 0], P[:, 1], color=color, lw=0, label=label if i == 0 else None)


def plot_slices(library, out: Path, slices=((25.0, 20.0), (30.0, 25.0), (20.0, 28.0))) -> Path:
    fig, axes = plt.subplots(len(slices), 2, figsize=(12, 3.2 * len(slices)), squeeze=False)
    for row, (v, vl) in enumerate(slices):
        for col, name in enumerate(("cautious", "aggressive")):
            ax = axes[row, col]
            _fill(ax, slice_polygons(library.region(name), v, vl), COLORS[name], f"C_{name[0]} (5 it.)")
            _fill(ax, slice_polygons(library.region("bounded_velocity"), v, vl), COLORS["bounded_velocity"],
                  "C_bnd")
            ax.axhspan(-0.9, 0.9, xmin=0, xmax=1, color="0.9", zorder=-1)
            ax.set_title(f"{name} vs bounded velocity, v_ex={v}, v_Lx={vl}")
            ax.set_xlabel("h (m)")
            ax.set_ylabel("y_e (m)")
            ax.set_xlim(-80, 80)
            ax.set_ylim(-0.9, 2.7)
            ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    path = Path(out) / "fig6_3_slices.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")  # nothing clipped, whatever the labels
    plt.close(fig)
    return path


def plot_admissible(library, out: Path, state=FIG64_STATE) -> Path:
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for ax, name in zip(axes, ("aggressive", "cautious", "bounded_velocity")):
        polys = library.admissible(name).polygons(np.asarray(state))
        _fill(ax, polys, "#1f77b4", "S(x)")
        ax.set_xlim(-3.1, 3.1)
        ax.set_ylim(-1.9, 1.9)
        ax.set_xlabel("a_ex (m/s^2)")
        ax.set_ylabel("v_ey (m/s)")
        ax.set_title(f"{name}: {len(polys)} polygon(s)" + ("" if polys else " — empty"))
        ax.grid(alpha=0.3)
    fig.suptitle(f"Admissible inputs at x = {list(state)}")
    fig.tight_layout()
    path = Path(out) / "fig6_4_admissible_inputs.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")  # nothing clipped, whatever the labels
    plt.close(fig)
    return path
