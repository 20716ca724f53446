"""The cheap certificates that spare LPs give the LP's answers.

Each test compares a fast path with a referee that solves the LPs: support values, the Chebyshev
radius, the envelope test of a convex union, the exact coverage search. A certificate that decided
one comparison wrongly would fail here.
"""
import numpy as np
import pytest

from intention.models import cautious, safe_set
from intention.params import OvertakeParams
from rcis import region as region_module
from rcis.lp import InequalityLP
from rcis.polyhedron import Polyhedron, _hull_reach, _kept_radius
from rcis.region import Region, _deepest_probe, convex_union


def random_polytope(rng, n, m, shift=None):
    """Bounded (HiGHS cannot decide some unbounded LPs; the sets we build are bounded)."""
    A = np.vstack([rng.normal(size=(m, n)), np.eye(n), -np.eye(n)])
    P = Polyhedron(A, np.concatenate([np.abs(rng.normal(size=m)) + 0.5, np.full(2 * n, 10.0)]))
    if shift is not None:
        P = Polyhedron(P.A, P.b + P.A @ shift)
    return P


def with_certificates(P):
    """Compute what the certificates read: the bounding box (and its maximisers) and the ball."""
    P.bounding_box()
    P.chebyshev_ball()
    return P


def lp_support(P, D):
    lp = InequalityLP(P.A, P.b)
    return np.array([lp.maximize(d).value for d in D])


@pytest.mark.parametrize("seed", range(4))
def test_exceeds_is_the_lp_comparison(seed):
    rng = np.random.default_rng(seed)
    decided = 0
    for _ in range(20):
        n = int(rng.integers(2, 6))
        P = with_certificates(random_polytope(rng, n, int(rng.integers(2 * n + 2, 4 * n + 4))))
        D = rng.normal(size=(40, n))
        D = np.vstack([D / np.linalg.norm(D, axis=1)[:, None], np.eye(n), -np.eye(n)])  # axes: bounds are tight
        h = lp_support(P, D)
        limits = h + rng.choice([-1.0, -1e-3, -5e-6, 5e-6, 1e-3, 1.0], size=len(D))
        assert np.array_equal(P.exceeds(D, limits), h > limits)
        lower, upper = P.support_bounds(D)
        assert np.all(lower <= h + 1e-7) and np.all(upper >= h - 1e-7)
        decided += int(np.sum((lower > limits + 1e-5) | (upper <= limits - 1e-5)))
    assert decided > 0  # the cheap bounds did decide some rows


@pytest.mark.parametrize("seed", range(4))
def test_contains_polyhedron_is_the_lp_answer(seed):
    rng = np.random.default_rng(seed)
    for _ in range(30):
        n = int(rng.integers(2, 5))
        P = with_certificates(random_polytope(rng, n, 3 * n))
        Q = with_certificates(random_polytope(rng, n, 3 * n, shift=rng.normal(scale=0.3, size=n)))
        Q = with_certificates(Polyhedron(Q.A, Q.b * rng.uniform(0.2, 1.2)))
        near = [with_certificates(Polyhedron(P.A, P.b + d)) for d in (-1e-4, -1e-6, 1e-6, 1e-4)]  # touching
        one_row = np.zeros(len(P.b))
        one_row[-1] = 1e-6  # only the last row (an axis row: the box bound is tight there) moves out
        near.append(with_certificates(Polyhedron(P.A, P.b + one_row)))
        for inner in [Q] + near:
            referee = bool(np.all(lp_support(inner, P.A) <= P.b + 1e-7))
            assert P.contains_polyhedron(inner) == referee


@pytest.mark.parametrize("seed", range(4))
def test_has_ball_with_hints_is_the_chebyshev_answer(seed):
    rng = np.random.default_rng(seed)
    for _ in range(40):
        n = int(rng.integers(2, 5))
        P = random_polytope(rng, n, 3 * n)
        radius = P.chebyshev_ball().radius
        for eps in (1e-6, 0.5 * radius, radius - 1e-3, radius + 1e-3):
            fresh = Polyhedron(P.A, P.b)
            hints = [rng.normal(scale=0.3, size=n), P.chebyshev_ball().center, None]
            assert fresh.has_ball(eps, hints) == (radius > eps)


def envelope_union(P, Q, tol=1e-9):
    """The referee: Bemporad-Fukuda-Torrisi's envelope test with LP support values only."""
    if P.intersect(Q).chebyshev_ball().radius < -tol:
        return None
    p_ok = lp_support(Q, P.A) <= P.b + tol
    q_ok = lp_support(P, Q.A) <= Q.b + tol
    env = Polyhedron(np.vstack([P.A[p_ok], Q.A[q_ok]]), np.concatenate([P.b[p_ok], Q.b[q_ok]]))
    for a, bi in zip(P.A[~p_ok], P.b[~p_ok]):
        beyond = env.intersect(Polyhedron([-a], [-bi]))
        if not np.all(lp_support(beyond, Q.A) <= Q.b + tol):
            return None
    return env


def split(rng, whole, n, overlap=0.0):
    """Two halves of a polytope along a random hyperplane through its centre (the first one reaching
    ``overlap`` past the cut)."""
    a = rng.normal(size=n)
    a /= np.linalg.norm(a)
    cut = float(a @ whole.chebyshev_ball().center)
    return [whole.intersect(Polyhedron([a], [cut + overlap])), whole.intersect(Polyhedron([-a], [-cut]))]


@pytest.mark.parametrize("seed", range(4))
def test_convex_union_is_the_envelope_answer(seed):
    """Halves of one polytope (convex union) and unrelated pairs (mostly not): the certificates
    (segments between known points, shared points, support bounds) agree with the LP envelope."""
    rng = np.random.default_rng(seed)
    merged = 0
    for _ in range(25):
        n = int(rng.integers(2, 5))
        whole = random_polytope(rng, n, 3 * n)
        halves = [with_certificates(h) for h in split(rng, whole, n, overlap=rng.choice([0.0, 0.05]))]
        other = with_certificates(random_polytope(rng, n, 3 * n, shift=rng.normal(size=n)))
        for P, Q in ((halves[0], halves[1]), (halves[0], other), (other, halves[1])):
            got, want = convex_union(P, Q), envelope_union(P, Q)
            assert (got is None) == (want is None)
            if got is not None:
                merged += 1
                assert got.contains_polyhedron(want) and want.contains_polyhedron(got)
    assert merged >= 25  # every pair of halves merged back


@pytest.mark.parametrize("seed", range(3))
def test_probe_balls_lie_in_the_piece_and_outside_the_union(seed):
    rng = np.random.default_rng(seed)
    found = 0
    for _ in range(30):
        n = int(rng.integers(2, 4))
        R = with_certificates(random_polytope(rng, n, 3 * n))
        pieces = [random_polytope(rng, n, 3 * n, shift=rng.normal(scale=1.0, size=n)) for _ in range(3)]
        point, radius = _deepest_probe(R, Region(pieces, n).stacked(), 0)
        if radius <= 1e-3:
            continue
        found += 1
        u = rng.normal(size=(500, n))
        X = point + 0.999 * radius * u / np.linalg.norm(u, axis=1)[:, None] * rng.uniform(0, 1, (500, 1))
        assert np.all(R.contains(X, tol=0.0))
        assert not np.any(Region(pieces, n).contains(X, tol=0.0))
    assert found > 5


@pytest.mark.parametrize("seed", range(3))
def test_covers_with_probes_is_the_search_answer(seed, monkeypatch):
    """Random overlaps, and polytopes that only the union of two halves covers (probes there sit
    near a cut, inside the union)."""
    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(10):
        n = int(rng.integers(2, 4))
        whole = random_polytope(rng, n, 3 * n)
        for d in (-1e-3, 1e-3):
            cases.append((split(rng, whole, n), Polyhedron(whole.A, whole.b + d), n))
    for _ in range(25):
        n = int(rng.integers(2, 4))
        pieces = [random_polytope(rng, n, 3 * n, shift=rng.normal(scale=0.5, size=n)) for _ in range(4)]
        cand = random_polytope(rng, n, 3 * n, shift=rng.normal(scale=0.3, size=n))
        cand = Polyhedron(cand.A, cand.b * rng.uniform(0.2, 1.0))
        cases.append((pieces, cand, n))
    fast = [Region([Polyhedron(P.A, P.b) for P in pieces], n).covers(Polyhedron(c.A, c.b)) for pieces, c, n in cases]
    monkeypatch.setattr(region_module, "_probe_finds_uncovered_ball", lambda *a: False)
    slow = [Region([Polyhedron(P.A, P.b) for P in pieces], n).covers(Polyhedron(c.A, c.b)) for pieces, c, n in cases]
    assert fast == slow
    assert 0 < sum(fast) < len(fast)
    assert sum(fast[:20]) == 10  # the union of the halves covers the shrunk polytope only


@pytest.mark.parametrize("seed", range(3))
def test_a_shared_point_is_in_both(seed):
    from rcis.region import _share_a_point

    rng = np.random.default_rng(seed)
    shared = 0
    for _ in range(40):
        n = int(rng.integers(2, 4))
        P = with_certificates(random_polytope(rng, n, 3 * n))
        Q = with_certificates(random_polytope(rng, n, 3 * n, shift=rng.normal(scale=2.0, size=n)))
        if _share_a_point(P, Q):
            shared += 1
            assert P.intersect(Q).chebyshev_ball().radius >= 0
        elif P.intersect(Q).chebyshev_ball().radius < 0:
            assert not _share_a_point(P, Q)
    assert shared > 0


def test_a_missed_target_has_an_empty_lifted_set():
    """``_misses_target`` skips a PWA piece only when the lifted set of Pre is empty."""
    system = cautious(OvertakeParams()).system
    rng = np.random.default_rng(0)
    S = safe_set(OvertakeParams())
    skipped = 0
    for _ in range(30):
        c = np.array([rng.uniform(16, 30), rng.uniform(-1, 3), rng.uniform(-40, 40), rng.uniform(0, 30)])
        target = Polyhedron.from_box(c - rng.uniform(0.5, 5, 4), c + rng.uniform(0.5, 5, 4))
        for within in S.pieces:
            for j in range(len(system.pieces)):
                rows = system._robust_target_rows(system.pieces[j], target, 1e-6)
                if system._misses_target(j, rows, within, 1e-6):
                    skipped += 1
                    assert system.lifted_pre(j, target, within, 1e-6).chebyshev_ball().radius <= 1e-9
    assert skipped > 0


@pytest.mark.parametrize("seed", range(6))
def test_hull_reach_bounds_the_lp_reach(seed):
    """The reach bound read off the dual hull is an upper bound (and not a loose one)."""
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(seed)
    P = random_polytope(rng, 4, 30)
    ball = P.chebyshev_ball()
    slack = P.b - P.A @ ball.center
    points = P.A / slack[:, None]
    hull = ConvexHull(points)
    kept = np.zeros(len(P.b), dtype=bool)
    kept[hull.vertices] = True
    bound = _hull_reach(points, hull, kept)
    exact = _kept_radius(P.A[kept], P.b[kept], ball.center)
    assert exact - 1e-9 <= bound <= 2 * exact + 1e-6
