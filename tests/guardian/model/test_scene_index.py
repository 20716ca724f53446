"""The scene's lane index answers every lane query as a walk over every car does (the rules written out below),
with or without a shared index that holds the ego's own body; and it fails when a query's bound is cut short."""
from __future__ import annotations

import bisect

import numpy as np
import pytest

from guardian.model.scene import Car, LaneIndex, Scene


# ---- the rules, walking every car (the scene's answers before the index) -----------------------------------
def ref_neighbours(others, lane, front):
    ahead = behind = None
    for c in others:
        if lane not in c.lanes:
            continue
        if c.front >= front:
            if ahead is None or c.front < ahead.front:
                ahead = c
        elif behind is None or c.front > behind.front:
            behind = c
    return ahead, behind


def ref_leaders(others, lane, front):
    lead = ref_neighbours(others, lane, front)[0]
    return () if lead is None else (lead, *(
        c for c in others if c is not lead and lane in c.lanes and c.front >= front and c.front - c.length < lead.front))


def ref_followers(others, lane, front):
    behind = [c for c in others if lane in c.lanes and c.front < front]
    first = ref_neighbours(others, lane, front)[1]
    foremost_rears = sorted(behind, key=lambda o: o.front - o.length, reverse=True)[:2]

    def hidden(c) -> bool:
        other = [o for o in foremost_rears if o is not c][:1]
        return bool(other) and other[0].front - other[0].length >= c.front

    return () if first is None else (first, *(c for c in behind if c is not first and not hidden(c)))


def ref_leads_of(others, car, lane):
    cars = sorted((c for c in others if lane in c.lanes), key=lambda c: c.front)
    fronts = [c.front for c in cars]
    k = bisect.bisect_right(fronts, car.front)
    if k == len(cars):
        return ()
    lead = cars[k]
    return (lead, *(c for c in cars[k + 1:] if c.front - c.length < lead.front))


def random_cars(rng, n: int) -> list:
    """Fronts on a coarse grid (many ties), lengths 0-12 m (overlapping bodies, zero-length lane ends), one or
    two lanes each."""
    cars = []
    for i in range(n):
        lane = int(rng.integers(1, 4))
        lanes = {lane} | ({lane + 1} if rng.random() < 0.3 else set())
        cars.append(Car(float(rng.integers(0, 40)) * 2.5, float(rng.uniform(0, 30)), frozenset(lanes),
                        float(rng.choice([0.0, 4.0, 5.0, 12.0])), f"car {i}"))
    return cars


def same(a, b) -> bool:
    return len(a) == len(b) and all(x is y for x, y in zip(a, b))


@pytest.mark.parametrize("seed", range(60))
def test_the_index_answers_as_the_walk_over_every_car(seed):
    rng = np.random.default_rng(seed)
    cars = random_cars(rng, int(rng.integers(1, 40)))
    ego_front = float(rng.integers(0, 40)) * 2.5
    ego = Car(ego_front, 20.0, frozenset({2}), 5.0, "ego")
    own = cars[int(rng.integers(0, len(cars)))]
    others = tuple(c for c in cars if c is not own)
    scenes = {"own index": Scene(ego, others, 4),
              "shared index": Scene(ego, others, 4, index=LaneIndex(tuple(cars)), own=own)}
    for how, scene in scenes.items():
        for lane in range(1, 6):
            assert same(scene._neighbours(lane), ref_neighbours(others, lane, ego_front)), how
            assert same(scene.leaders(lane), ref_leaders(others, lane, ego_front)), how
            assert same(scene.followers(lane), ref_followers(others, lane, ego_front)), how
            for car in others:
                assert same(scene.leads_of(car, lane), ref_leads_of(others, car, lane)), how


def test_a_bound_cut_short_would_be_seen(monkeypatch):
    """The reach a query reads ahead of the lead is what makes a long body overlapping it count: set it short and
    the comparison above fails."""
    lead = Car(50.0, 20.0, frozenset({1}), 4.0, "lead")
    long = Car(60.0, 20.0, frozenset({1}), 12.0, "long")   # its rear (48 m) is nearer than the lead's front
    ego = Car(40.0, 20.0, frozenset({1}), 5.0, "ego")
    others = (lead, long)
    assert same(Scene(ego, others, 2).leaders(1), ref_leaders(others, 1, 40.0))
    monkeypatch.setattr(LaneIndex, "REACH_SLACK", -9.0)
    assert not same(Scene(ego, others, 2).leaders(1), ref_leaders(others, 1, 40.0))
