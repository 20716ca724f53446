"""The one interval module."""
from rcis.intervals import intersect_intervals, merge_intervals, nearest_in_intervals


def test_intersect_merge_nearest():
    assert intersect_intervals([(0, 2), (5, 9)], [(1, 6)]) == [(1, 2), (5, 6)]
    assert intersect_intervals([(0, 1)], [(2, 3)]) == []
    assert merge_intervals([(5, 6), (0, 2), (2, 3), (3 + 1e-13, 4)]) == [(0, 4), (5, 6)]
    assert nearest_in_intervals([(0, 1), (4, 5)], 3.0) == 4 and nearest_in_intervals([], 3.0) is None
    assert nearest_in_intervals([(0, 1), (4, 5)], 0.5) == 0.5
