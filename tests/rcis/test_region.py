import numpy as np

from rcis.polyhedron import Polyhedron
from rcis.region import Region, convex_union, merge_convex


def box(lo, hi):
    return Polyhedron.from_box(lo, hi)


def test_membership_matches_numpy_for_many_points():
    rng = np.random.default_rng(1)
    pieces = [box(rng.uniform(-5, 0, 3), rng.uniform(0, 5, 3)) for _ in range(20)]
    R = Region(pieces)
    X = rng.uniform(-6, 6, size=(5000, 3))
    expected = np.any([P.contains(X) for P in pieces], axis=0)
    assert np.array_equal(R.contains(X), expected)
    assert R.contains(X[0]) == expected[0]


def test_difference_and_cover_of_an_l_shape():
    R = Region([box([0, 0], [2, 1]), box([0, 0], [1, 2])])
    assert R.covers(box([0, 0], [1, 1]))
    assert R.covers(box([0.2, 0.2], [1.8, 0.8]))
    assert not R.covers(box([0, 0], [2, 2]))  # the corner [1,2]x[1,2] is missing
    rest = R.difference(box([0, 0], [2, 2]))
    area = sum(np.prod(np.diff(np.array(P.bounding_box()), axis=0)) for P in rest)
    assert np.isclose(area, 1.0)


def test_cover_with_a_budget_may_only_say_no():
    pieces = [box([i * 0.1, 0], [i * 0.1 + 0.1, 1]) for i in range(10)]
    R = Region(pieces)
    P = box([0, 0], [1, 1])
    assert R.covers(P)
    assert not R.covers(P, budget=3)  # undecided within 3 fragments: "not covered"


def test_convex_union_merges_adjacent_boxes_only():
    U = convex_union(box([0, 0], [1, 1]), box([1, 0], [2, 1]))
    assert U is not None and U.contains_polyhedron(box([0, 0], [2, 1]))
    assert box([0, 0], [2, 1]).contains_polyhedron(U)
    assert convex_union(box([0, 0], [2, 1]), box([0, 0], [1, 2])) is None  # L-shape
    assert convex_union(box([0, 0], [1, 1]), box([2, 0], [3, 1])) is None  # apart
    assert len(merge_convex([box([i, 0], [i + 1, 1]) for i in range(5)])) == 1


def test_subset_and_witness():
    small = Region([box([0, 0], [1, 1])])
    big = Region([box([0, 0], [1, 2])])
    assert small.is_subset_of(big) and not big.is_subset_of(small)
    w = big.witness_outside(small)
    assert w is not None and w[1] > 1.0
