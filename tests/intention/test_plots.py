"""The pictures a person reads: Fig. 6.3 explains its grey region, Fig. 6.4 draws polygon edges and shows
where the aggressive and the cautious sets differ (before: borderless blue boxes, the difference invisible)."""
import matplotlib.image as mpimg
import numpy as np

from intention.plots import (FIG64_STATE, admissible_difference, admissible_figure, plot_admissible, plot_slices,
                             slices_figure)


def _legend_texts(fig):
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend()]
    return [t.get_text() for lg in legends for t in lg.get_texts()]


def _pixels_near(png, rgb, tol=0.04):
    img = mpimg.imread(png)[..., :3]
    return int(np.sum(np.all(np.abs(img - np.asarray(rgb) / 255.0) < tol, axis=-1)))


def test_fig_6_4_difference_between_the_intentions(library):
    d = admissible_difference(library)
    assert d["only_aggressive"]["area"] + d["only_cautious"]["area"] > 0.01  # the two S(x) differ here
    a0, a1, v0, v1 = d["only_aggressive"]["box"]
    U = library.params
    assert U.a_ex_bounds[0] <= a0 < a1 <= U.a_ex_bounds[1] and U.v_ey_bounds[0] <= v0 < v1 <= U.v_ey_bounds[1]
    # every grid point said to be only in S_a is admissible for C_a and not for C_c
    ia, ic = library.admissible("aggressive"), library.admissible("cautious")
    x = np.asarray(FIG64_STATE)
    pts = np.column_stack([d["a"][d["only_aggressive"]["mask"]], d["v"][d["only_aggressive"]["mask"]]])
    inner = pts[(pts[:, 0] > a0 + 0.02) & (pts[:, 0] < a1 - 0.02) & (pts[:, 1] > v0 + 0.02) & (pts[:, 1] < v1 - 0.02)]
    assert len(inner) > 3
    qa, qc = ia.at(x), ic.at(x)
    for u in inner[::7]:
        assert qa.contains(u) and not qc.contains(u)


def test_fig_6_4_draws_edges_the_difference_and_a_legend(library, tmp_path):
    fig = admissible_figure(library)
    texts = _legend_texts(fig)
    assert any("only C_a" in t for t in texts) and any("refused" in t for t in texts)
    assert any("edges" in t for t in texts)
    png = plot_admissible(library, tmp_path)
    assert _pixels_near(png, (8, 48, 107)) > 500      # polygon edges (#08306b)
    assert _pixels_near(png, (255, 127, 0)) > 200     # the C_a-only inputs (#ff7f00)


def test_fig_6_3_legend_names_the_grey_and_the_unsafe_region(library, tmp_path):
    fig = slices_figure(library)
    texts = _legend_texts(fig)
    assert any(t.startswith("in no set") for t in texts) and any(t.startswith("unsafe") for t in texts)
    assert _pixels_near(plot_slices(library, tmp_path), (224, 224, 224), tol=0.01) > 500  # the grey is drawn
