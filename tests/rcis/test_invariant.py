"""Pre, outside-in and inside-out on systems where the answer can be checked independently."""
import numpy as np

from intention.models import cautious, safe_set
from intention.params import OvertakeParams
from rcis.certify import falsify
from rcis.invariant import outside_in
from rcis.lp import InequalityLP
from rcis.polyhedron import Polyhedron
from rcis.pwa import PWAPiece, PWASystem
from rcis.region import Region


def linear_system(A, B, E, W_lo, W_hi):
    piece = PWAPiece(Polyhedron.universe(2), np.array(A), np.array(B), np.zeros(2), np.array(E),
                     Polyhedron.from_box(W_lo, W_hi))
    return PWASystem([piece], Polyhedron.from_box([-1, -1], [1, 1]), Polyhedron.universe(2), name="lin")


def test_outside_in_converges_to_an_invariant_set_that_the_falsifier_accepts():
    sys = linear_system([[0.8, 0.3], [0.0, 0.9]], [[0.1, 0.0], [0.0, 0.1]], [[0.0], [0.05]], [-1], [1])
    safe = Region([Polyhedron([[1, 0], [-1, 0], [0, 1], [0, -1], [1, 1]], [1, 1, 1, 1, 1.2])])
    res = outside_in(sys, safe, max_iterations=50)
    assert res.converged
    assert falsify(sys, res.region, 3000, seed=0).counterexamples == []


def test_double_integrator_outside_in_result_is_invariant_and_the_box_is_not():
    """A double integrator cannot stop at the wall: the safe box is not invariant, the
    converged outside-in set is (the falsifier must be able to tell them apart)."""
    sys = linear_system([[1.0, 0.1], [0.0, 1.0]], [[0.0, 0.0], [0.1, 0.0]], [[0.0], [0.1]], [-0.5], [0.5])
    safe = Region([Polyhedron.from_box([-1, -1], [1, 1])])
    res = outside_in(sys, safe, max_iterations=60)
    assert res.converged
    assert res.region.is_subset_of(safe) and not safe.is_subset_of(res.region)
    assert falsify(sys, res.region, 4000, seed=0).counterexamples == []
    assert len(falsify(sys, safe, 3000, seed=0).counterexamples) > 0


def test_robust_pre_matches_an_lp_oracle_on_the_cautious_model():
    p = OvertakeParams()
    model = cautious(p)
    sys = model.system
    target = safe_set(p).pieces[0].intersect(Polyhedron([[0, 0, -1, 0], [1, 0, 0, -1]], [-20.0, 4.0]))
    rng = np.random.default_rng(0)
    pres = sys.pre(target)
    region = Region(pres, 4)
    Wv, _ = sys.pieces[0].W.generators()
    checked = 0
    for _ in range(600):
        x = rng.uniform([16, -0.9, 0, 0], [36, 2.7, 80, 33.5])
        j = sys.piece_index(x)
        p_j = sys.pieces[j]
        # oracle: exists u in U with f_j(x, u, w) in target for all vertices w
        rows_A, rows_b = [], []
        for w in Wv:
            rows_A.append(target.A @ p_j.B)
            rows_b.append(target.b - target.A @ (p_j.A @ x + p_j.c + p_j.E @ w))
        U = sys.input_set
        A = np.vstack(rows_A + [U.A])
        b = np.concatenate(rows_b + [U.b])
        exists = InequalityLP(A, b).maximize(np.zeros(2)).status == "optimal"
        if region.contains(x, tol=0.0):
            assert exists, x  # soundness: Pre never claims a state the oracle rejects
            checked += 1
        elif exists:
            # completeness up to the margins: a rejected state fails with a slightly smaller target
            shrunk = InequalityLP(A, b - 1e-5 * np.ones_like(b)).maximize(np.zeros(2))
            assert shrunk.status != "optimal" or p_j.strict.any(), x
    assert checked > 50
