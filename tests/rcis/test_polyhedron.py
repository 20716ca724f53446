import numpy as np
import pytest

from rcis.lp import InequalityLP
from rcis.polyhedron import Polyhedron
from project import ROOT


def random_polytope(rng, n, m):
    A = rng.normal(size=(m, n))
    return Polyhedron(A, np.abs(rng.normal(size=m)) + 0.5)  # contains a ball around 0


def lp_feasible_lift(P, x, keep):
    """Independent oracle: is there z with z[keep] = x and z in P?"""
    n = P.dim
    free = np.setdiff1d(np.arange(n), keep)
    A = P.A[:, free]
    b = P.b - P.A[:, keep] @ x
    return InequalityLP(A, b).maximize(np.zeros(free.size)).status != "infeasible"


@pytest.mark.parametrize("seed", range(8))
def test_projection_agrees_with_lp_oracle(seed):
    rng = np.random.default_rng(seed)
    P = random_polytope(rng, 5, 14).intersect(Polyhedron.from_box(-3 * np.ones(5), 3 * np.ones(5)))
    keep = np.array([0, 1, 2])
    Q = P.project(keep)
    lo, hi = P.bounding_box()
    X = rng.uniform(lo[keep] - 0.5, hi[keep] + 0.5, size=(300, 3))
    inside = Q.contains(X, tol=0.0)
    oracle = np.array([lp_feasible_lift(P, x, keep) for x in X])
    # The projection may be smaller by rounding, never larger: no point of Q outside the oracle.
    assert not np.any(inside & ~oracle)
    # And it is not smaller by anything visible: every oracle point strictly inside Q's slack is in Q.
    near_boundary = np.max(X @ Q.A.T - Q.b, axis=1) > -1e-6
    assert not np.any(oracle & ~inside & ~near_boundary)


def test_minimal_keeps_the_set_and_drops_redundant_rows():
    rng = np.random.default_rng(3)
    box = Polyhedron.from_box(-np.ones(3), np.ones(3))
    extra = Polyhedron(np.vstack([box.A, box.A * 2.0, [[1, 1, 1]], [[1, 0, 0]]]),
                       np.concatenate([box.b, box.b * 2.0 + 1.0, [10.0], [5.0]]))
    M = extra.minimal()
    assert M.n_constraints == 6
    X = rng.uniform(-2, 2, size=(2000, 3))
    assert np.array_equal(M.contains(X), extra.contains(X))


def test_chebyshev_ball_of_box_unbounded_and_empty():
    ball = Polyhedron.from_box([0, 0], [2, 4]).chebyshev_ball()
    assert ball.radius == pytest.approx(1.0)
    assert np.allclose(ball.center[0], 1.0)
    half = Polyhedron([[1.0, 0.0]], [0.0])  # unbounded: radius is capped, not infinite
    assert half.chebyshev_ball().radius == pytest.approx(1e4)
    empty = Polyhedron([[1.0], [-1.0]], [0.0, -1.0])  # x <= 0 and x >= 1
    assert empty.is_empty()


def test_robust_tighten_is_the_pontryagin_difference():
    P = Polyhedron.from_box([0, 0], [10, 10])
    W = Polyhedron.from_box([-1, -0.5], [1, 0.5])
    E = np.array([[1.0, 0.0], [0.0, 2.0]])
    T = P.robust_tighten(E, W)
    rng = np.random.default_rng(0)
    Wv, _ = W.generators()
    for z in rng.uniform(-1, 11, size=(500, 2)):
        all_in = all(P.contains(z + E @ w, tol=0.0) for w in Wv)
        assert T.contains(z, tol=1e-12) == all_in


def test_contains_polyhedron_and_intersection():
    big = Polyhedron.from_box([0, 0], [4, 4])
    small = Polyhedron.from_box([1, 1], [2, 2])
    assert big.contains_polyhedron(small)
    assert not small.contains_polyhedron(big)
    assert big.intersect(Polyhedron.from_box([3, 3], [5, 5])).chebyshev_ball().radius == pytest.approx(0.5)


def test_generators_of_an_unbounded_polyhedron():
    P = Polyhedron([[0.0, -1.0], [-1.0, 0.0]], [0.0, 0.0])  # first quadrant
    V, R = P.generators()
    assert V.shape == (1, 2) and np.allclose(V, [[0, 0]])  # cddlib omits a cone's apex; we do not
    assert len(R) == 2


def test_bad_input_is_refused_with_a_message():
    with pytest.raises(ValueError, match="finite"):
        Polyhedron([[np.nan, 1.0]], [1.0])
    with pytest.raises(ValueError, match="rows"):
        Polyhedron([[1.0, 0.0]], [1.0, 2.0])
    with pytest.raises(ValueError, match="dimension"):
        Polyhedron.from_box([0, 0], [1, 1]).contains([1.0, 2.0, 3.0])


def test_engine_never_calls_cddlib_canonicalize():
    """Regression: cddlib's float canonicalize aborted the process (free(): invalid pointer)
    when its linearity LP failed. The engine removes redundancy with its own LPs instead."""

    for path in ROOT.joinpath("rcis").glob("*.py"):
        code = "\n".join(line.split("#")[0] for line in path.read_text().splitlines()
                         if not line.strip().startswith(("#", '"', "'")))
        assert "canonicalize(" not in code, path


def _lp_minimal(P):
    """The referee: one LP per row, nothing else."""
    A, b = P.A, P.b
    keep = np.ones(len(b), dtype=bool)
    for i in range(len(b)):
        others = InequalityLP(A[keep & (np.arange(len(b)) != i)], b[keep & (np.arange(len(b)) != i)])
        res = others.maximize(A[i])
        if res.status == "optimal" and res.value <= b[i] + 1e-9:
            keep[i] = False
    return Polyhedron(A[keep], b[keep])


def _fm_rows(rng, n=4, m=24):
    """Many weakly redundant rows, as Fourier-Motzkin makes them: the hull filter's home ground."""
    A = rng.normal(size=(m, n + 1))
    P = Polyhedron(A, np.abs(rng.normal(size=m)) + 0.5).intersect(
        Polyhedron.from_box(-2 * np.ones(n + 1), 2 * np.ones(n + 1)))
    from rcis.polyhedron import _fourier_motzkin
    return _fourier_motzkin(P.A, P.b, n)


@pytest.mark.parametrize("seed", range(6))
def test_minimal_by_hull_certificates_is_the_lp_answer(seed):
    """Every row the dual-hull certificates drop is implied (the referee agrees on the set), and
    every facet survives: the same set, with no more rows than the referee keeps."""
    P = _fm_rows(np.random.default_rng(seed))
    M, R = P.minimal(), _lp_minimal(P)
    assert M.contains_polyhedron(R) and R.contains_polyhedron(M)
    assert M.n_constraints <= R.n_constraints


def test_a_wrong_hull_costs_speed_never_the_set(monkeypatch):
    """A hull that misses a vertex (a facet of P) or lies about its facets cannot drop a facet."""
    import scipy.spatial

    import rcis.polyhedron as ph

    real = scipy.spatial.ConvexHull
    P = _fm_rows(np.random.default_rng(11))
    truth = _lp_minimal(P)

    class MissingVertex:
        def __init__(self, points):
            far = int(np.argmax(np.linalg.norm(points, axis=1)))
            idx = np.delete(np.arange(len(points)), far)
            h = real(points[idx])
            self.vertices, self.simplices, self.equations = idx[h.vertices], idx[h.simplices], h.equations

    class MissingVertexLyingFacets(MissingVertex):
        def __init__(self, points):
            super().__init__(points)
            self.equations = self.equations.copy()
            self.equations[:, -1] *= 3.0  # claims to reach the missing vertex: only the certificate can tell

    for fake in (MissingVertex, MissingVertexLyingFacets):
        monkeypatch.setattr(scipy.spatial, "ConvexHull", fake)
        M = P.minimal()
        assert M.contains_polyhedron(truth) and truth.contains_polyhedron(M), fake.__name__
    monkeypatch.setattr(scipy.spatial, "ConvexHull", real)
    assert ph._dual_hull_filter(P.A, P.b) is not None  # the real hull does apply here


def test_an_lp_maximiser_outside_the_set_is_polished_into_it():
    """HiGHS may return a maximiser outside P by its scaled feasibility tolerance; a vertex that
    generators() returns must lie in P, so the maximiser is re-solved from its active rows."""
    from rcis.polyhedron import GENERATOR_TOL, _polished_vertex

    P = Polyhedron(np.vstack([np.eye(2), -np.eye(2), [[1.0, 1e-7]]]), np.array([1.0, 1.0, 1.0, 1.0, 1.0]))
    for x in ([1 + 3e-6, 1.0], [1.0, 1 + 4e-6], [1 + 2e-6, -1 - 2e-6]):
        v = _polished_vertex(P, np.array(x), np.array([1.0, np.sign(x[1])]))
        assert P.contains(v, tol=GENERATOR_TOL) and np.abs(v - x).max() < 1e-5


def test_an_lp_highs_leaves_undecided_is_decided_with_presolve():
    """Without presolve HiGHS answers "Unknown" on this unbounded LP; with presolve it decides.
    The retry once re-ran the model with the default options afterwards, got "Unknown" again and
    recursed until Python's stack ran out."""
    A = np.array([[-0.45900456984336346, 0.888433905736892], [-0.37484642916662736, 0.9270869185470307],
                  [-0.9718622678253135, 0.2355498511513829], [-0.8693432587506975, -0.4942087600040268],
                  [-0.9292455927550922, 0.36946262103931116], [-0.6656303409023627, -0.7462816152567371]])
    b = np.array([0.6946119890411945, 1.7668802809297361, 1.062835002483509, 0.5969128999403096,
                  0.3743126282648966, 0.39317876290765014])
    d = np.array([0.7962162108981448, 0.6050121862433855])
    lp = InequalityLP(A, b)
    assert lp.maximize(d).status == "unbounded"
    res = lp.maximize(-d)  # the same object keeps working, with its default options back
    assert res.status == "optimal" and abs(res.value - 0.4347278672062611) < 1e-9


def test_solving_lps_prints_nothing_on_stdout():
    """highspy 1.16's ``Highs()`` prints a banner on stdout the first time in a process; stdout carries
    the JSON of ``--json`` commands and the service's address, so no LP may print anything."""
    import subprocess
    import sys

    code = ("import numpy as np\n"
            "from rcis.lp import InequalityLP\n"
            "from intention.estimator import _SlidingFeasibilityLP\n"
            "_SlidingFeasibilityLP(np.eye(2), -np.ones(2), np.ones(2), 3, 1e-9)\n"
            "print(InequalityLP(np.eye(2), np.ones(2)).maximize(np.ones(2)).status)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout == "optimal\n"


def test_an_unbounded_lp_highs_cannot_decide_is_decided_inside_a_box():
    """HiGHS 1.16 answers "Unknown" on this unbounded LP with and without presolve and with interior
    point; the last retry solves it inside |x| <= 1e9, where the optimum lies on the box: unbounded.
    The same object then answers a bounded direction normally."""
    from scipy.optimize import linprog

    A = np.array([[-0.7545752913242896, 0.585438109954037, -0.2964428260833928],
                  [-0.9071345847550834, -0.4110367592071348, 0.09030851411532864],
                  [-0.08625701612660147, -0.5986716044923988, -0.7963366355652816],
                  [-0.02206670535295478, 0.8011432793628833, -0.5980656372393846],
                  [0.24158900247217852, -0.8122883097581262, 0.5308695279584091],
                  [0.5279150116731121, -0.6181786579358994, -0.5823752118031367],
                  [-0.9867539349881891, 0.0335452013480188, -0.1587179613397479],
                  [-0.8926465524611507, -0.2966142401097528, 0.33941438529227974],
                  [0.22081249976794667, 0.36977143412885166, -0.9025025908264879]])
    b = np.array([0.8456433880159002, 1.0306105547609912, 3.1665656598378136, 1.9151983727340114,
                  2.2093673075958766, 2.0031584597553183, 0.4292082193907565, 1.24107330438191,
                  1.8659701494640486])
    lp = InequalityLP(A, b)
    assert lp.maximize(np.array([1.0, 0.0, 0.0])).status == "unbounded"
    d = A[0] + A[6]  # a direction the rows bound (a sum of two rows)
    ref = linprog(-d, A_ub=A, b_ub=b, bounds=[(None, None)] * 3)
    res = lp.maximize(d)
    assert ref.status == 0 and res.status == "optimal" and abs(res.value + ref.fun) < 1e-7


def test_a_2d_polygon_by_clipping_is_the_polyhedron_cut_to_its_window():
    """``rcis.planar.polygon`` (no LP, for drawing a slice every step) against the LP-checked generators of the
    polyhedron intersected with the window: the same area and every vertex inside; empty where it is empty."""
    from scipy.spatial import ConvexHull

    from rcis.planar import polygon

    rng = np.random.default_rng(7)
    window = (np.array([-20.0, -20.0]), np.array([20.0, 20.0]))
    compared = 0
    for _ in range(300):
        m = int(rng.integers(3, 9))
        P = Polyhedron(rng.normal(size=(m, 2)), rng.uniform(-0.5, 2.0, size=m))
        V = polygon(P, window)
        Q = P.intersect(Polyhedron.from_box(*window))
        if Q.is_empty():
            assert len(V) == 0
            continue
        G, _ = Q.generators()
        if len(G) < 3 or ConvexHull(G).volume < 1e-9:
            continue
        compared += 1
        assert np.all(Q.contains(V, tol=1e-7))
        assert ConvexHull(V).volume == pytest.approx(ConvexHull(G).volume, rel=1e-6)
    assert compared > 100
    with pytest.raises(ValueError, match="dimension 3"):
        polygon(Polyhedron.from_box([0, 0, 0], [1, 1, 1]), window)
