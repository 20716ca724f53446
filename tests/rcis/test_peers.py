"""rcis beside a peer (tulip's ``polytope``), with LP support functions (scipy's linprog) as the referee.

On random polytopes of 2-6 dimensions (bounded, unbounded, with duplicate, near-parallel and
scaled rows, flat, empty) and on the shipped sets, every answer of ours must agree with the referee;
the peer's answers are compared too and its disagreements with the referee are counted (printed
with ``-s``), never asserted: the peer is not our oracle where it is wrong.
"""
import warnings
from collections import Counter

import numpy as np
import pytest
from scipy.optimize import linprog

from rcis.polyhedron import Polyhedron

pc = pytest.importorskip("polytope")
warnings.filterwarnings("ignore", module="polytope")

TOL = 1e-6
PEER_WRONG: Counter = Counter()
CASES: Counter = Counter()


def referee_support(A, b, d) -> float:
    res = linprog(-np.asarray(d, float), A_ub=A, b_ub=b, bounds=[(None, None)] * A.shape[1], method="highs")
    if res.status == 3:
        return np.inf
    if res.status == 2:
        return -np.inf
    return -res.fun


def referee_chebyshev_radius(A, b) -> float:
    norms = np.linalg.norm(A, axis=1)
    c = np.zeros(A.shape[1] + 1)
    c[-1] = -1
    res = linprog(c, A_ub=np.hstack([A, norms[:, None]]), b_ub=b,
                  bounds=[(None, None)] * A.shape[1] + [(None, 1e4)], method="highs")
    return -res.fun if res.status == 0 else -1.0


def random_polytope(rng, n: int, kind: str) -> Polyhedron:
    m = int(rng.integers(n + 2, 3 * n + 6))
    A = rng.normal(size=(m, n))
    A /= np.linalg.norm(A, axis=1, keepdims=True)
    b = 1.0 + rng.uniform(0, 0.5, m)
    if kind == "unbounded":
        A[:, 0] = -np.abs(A[:, 0])  # +e_1 is a ray
    else:
        A, b = np.vstack([A, np.eye(n), -np.eye(n)]), np.concatenate([b, np.full(2 * n, 3.0)])
    if kind == "degenerate":
        i = int(rng.integers(m))
        near = A[i] + 1e-9 * rng.normal(size=n)
        A = np.vstack([A, A[i], near / np.linalg.norm(near), 2 * A[i]])
        b = np.concatenate([b, [b[i], b[i] + 1e-12, 2 * b[i]]])
    if kind == "flat":
        a = A[0]
        A, b = np.vstack([A, a, -a]), np.concatenate([b, [0.2, -0.2]])
    if kind == "empty":
        a = A[0]
        A, b = np.vstack([A, a, -a]), np.concatenate([b, [-0.5, 0.4]])
    return Polyhedron(A, b)


def same_set(P: Polyhedron, A, b, directions) -> bool:
    """Both describe the same set: equal support (referee) in every direction."""
    for d in directions:
        h1, h2 = referee_support(P.A, P.b, d), referee_support(A, b, d)
        if not (np.isinf(h1) and np.isinf(h2) and np.sign(h1) == np.sign(h2)) and not abs(h1 - h2) <= TOL * max(1, abs(h1)):
            return False
    return True


KINDS = ["bounded", "unbounded", "degenerate", "flat", "empty"]
# 6-D polytopes take 5-40 s each (the peer's vertex enumeration): two seeds of the degenerate ones, four of the rest,
# all in the slow checks (``-m slow``)
POLYTOPES = [pytest.param(n, kind, seed, marks=[pytest.mark.slow] if n == 6 else []) for n in range(2, 7)
             for kind in KINDS for seed in range(2 if (n, kind) == (6, "degenerate") else 4)]


@pytest.mark.parametrize("n,kind,seed", POLYTOPES)
def test_random_polytopes_against_the_referee_and_the_peer(n, kind, seed):
    rng = np.random.default_rng(1000 * n + 10 * KINDS.index(kind) + seed)
    P = random_polytope(rng, n, kind)
    peer = pc.Polytope(P.A, P.b, normalize=False)
    dirs = np.vstack([P.A, rng.normal(size=(24, n))])
    empty = referee_chebyshev_radius(P.A, P.b) < -1e-9 or referee_support(P.A, P.b, np.zeros(n)) == -np.inf

    # membership
    X = rng.uniform(-3.5, 3.5, size=(300, n))
    truth = np.all(X @ P.A.T <= P.b + 1e-9, axis=1)
    assert np.array_equal(P.contains(X), truth)
    CASES["membership"] += len(X)
    PEER_WRONG[("membership", kind)] += int(np.sum(peer.contains(X.T, abs_tol=1e-9) != truth))

    # emptiness
    assert P.is_empty() == empty
    CASES["emptiness"] += 1
    PEER_WRONG[("emptiness", kind)] += int(bool(pc.is_empty(peer)) != empty)
    if empty:
        return

    # Chebyshev ball
    r = referee_chebyshev_radius(P.A, P.b)
    assert abs(P.chebyshev_ball().radius - min(r, 1e4)) <= 1e-6 * max(1, r)
    CASES["chebyshev"] += 1
    PEER_WRONG[("chebyshev", kind)] += int(kind != "unbounded" and not abs(peer.chebR - r) <= 1e-6 * max(1, r))

    # redundancy removal
    M = P.minimal()
    assert same_set(M, P.A, P.b, dirs) and M.n_constraints <= P.n_constraints
    CASES["redundancy"] += 1
    try:
        R = pc.reduce(peer)
        PEER_WRONG[("redundancy", kind)] += int(not same_set(Polyhedron(R.A, R.b), P.A, P.b, dirs))
    except Exception:  # noqa: BLE001 - a crash is a wrong answer
        PEER_WRONG[("redundancy", kind)] += 1

    # inclusion
    inner = Polyhedron(P.A, P.b - 0.05)
    if not inner.is_empty():
        assert P.contains_polyhedron(inner) and not inner.contains_polyhedron(P)
        CASES["inclusion"] += 2
        PEER_WRONG[("inclusion", kind)] += int(not pc.is_subset(pc.Polytope(inner.A, inner.b), peer))
        PEER_WRONG[("inclusion", kind)] += int(bool(pc.is_subset(peer, pc.Polytope(inner.A, inner.b))))

    bounded = np.all(np.isfinite(P.bounding_box()[1])) and np.all(np.isfinite(P.bounding_box()[0]))
    # projection onto the first two coordinates
    if 3 <= n <= 5 and bounded:  # 6-D projection is LP-bound (seconds each)
        Q = P.project([0, 1])
        lifted = rng.normal(size=(16, 2))
        for d in lifted:  # an inner approximation always (FM_ROUNDING lowers right-hand sides), exact when full-dim
            h, truth = Q.support(d), referee_support(P.A, P.b, np.r_[d, np.zeros(n - 2)])
            assert h <= truth + 1e-6 and (kind == "flat" or abs(h - truth) <= 1e-6)
        CASES["projection"] += 1
        try:
            pq = pc.projection(peer, [1, 2])
            wrong = any(abs(referee_support(pq.A, pq.b, d) - referee_support(P.A, P.b, np.r_[d, np.zeros(n - 2)]))
                        > 1e-6 for d in lifted)
        except Exception:  # noqa: BLE001
            wrong = True
        PEER_WRONG[("projection", kind)] += int(wrong)

    # vertex (and ray) enumeration
    V, Rays = P.generators()
    for d in dirs:
        h = referee_support(P.A, P.b, d)
        gen = np.inf if Rays.size and np.any(Rays @ d > 1e-9) else float(np.max(V @ d))
        assert (np.isinf(h) and np.isinf(gen)) or abs(h - gen) <= 1e-6 * max(1, abs(h))
    CASES["vertices"] += 1
    if bounded and n <= 5:  # the peer's enumeration takes seconds in 6-D
        try:
            E = pc.extreme(peer)
            wrong = E is None or any(abs(float(np.max(E @ d)) - referee_support(P.A, P.b, d)) > 1e-6 for d in dirs)
        except Exception:  # noqa: BLE001
            wrong = True
        PEER_WRONG[("vertices", kind)] += int(wrong)


@pytest.mark.slow
def test_vertex_enumeration_is_complete_on_every_shipped_piece(library):
    """cddlib in floating point misses vertices of some windowed C_a / C_c pieces; generators() must not."""
    window = Polyhedron.from_box([16, -0.9, -100, 0], [36, 2.7, 100, 33.5])
    rng = np.random.default_rng(0)
    checked = 0
    for name in ("bounded_velocity", "aggressive", "cautious"):
        for P in library.region(name).pieces:
            Q = P.intersect(window)
            if Q.is_empty():
                continue
            V, R = Q.generators()
            assert R.size == 0 and np.all(Q.contains(V, tol=1e-6))
            D = np.vstack([Q.A, rng.normal(size=(16, 4))])
            gap = Q.support_many(D) - (D @ V.T).max(axis=1)
            assert np.max(np.abs(gap)) <= 1e-6 * max(1.0, float(np.abs(V).max())), (name, float(np.max(gap)))
            checked += 1
    assert checked > 300


def test_peer_summary(capsys):
    """Prints the case counts and the peer's wrong answers (run with -s); fails only if nothing ran."""
    with capsys.disabled():
        print("\npeer check cases:", dict(CASES))
        print("polytope's answers the referee rejects (check, kind):", {k: v for k, v in sorted(PEER_WRONG.items()) if v})
    assert sum(CASES.values()) > 0
