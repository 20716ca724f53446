"""The overtake RCIS library: inclusions, invariance, supervisors, cache and export."""
import json

import numpy as np
import pytest

from rcis.certify import falsify
from intention.library import SET_NAMES, build_library, export_set
from rcis.polyhedron import Polyhedron
from rcis.region import Region

FIG64 = np.array([25.0, -0.297, 16.52, 20.0])


def window(p):
    return Polyhedron.from_box([-1e3, -1e3, -(p.h_r + 100), -1e3], [1e3, 1e3, p.h_r + 100, 1e3])


def test_bounded_velocity_converges_in_twelve_iterations(library):
    s = library.sets["bounded_velocity"]
    assert s.converged and s.iterations == 12


def test_inclusions_of_proposition_22(library):
    c = library.containment()
    assert c["C_left ⊆ C_bnd"] and c["C_bnd ⊆ C_a"] and c["C_bnd ⊆ C_c"]
    assert c["C_c ⊄ C_bnd (strictly larger)"]
    w = np.array(c["witness in C_c \\ C_bnd"])
    assert library.region("cautious").contains(w) and not library.region("bounded_velocity").contains(w)


@pytest.mark.parametrize("name", SET_NAMES)
def test_falsifier_finds_no_counterexample(library, name):
    rep = falsify(library.models[name].system, library.region(name), 1500, seed=7,
                  window=window(library.params), admissible=library.admissible(name))
    assert rep.samples == 1500 and rep.counterexamples == []


def test_falsifier_catches_an_unsafe_piece(library):
    """Add right-lane states with 10-12 m headway at high closing speed: not invariant."""
    p = library.params
    bad = Polyhedron.from_box([34.0, -0.9, 10.0, 0.0], [36.0, -0.5, 12.0, 5.0])
    region = Region(library.region("bounded_velocity").pieces + [bad], 4)
    from rcis.admissible import AdmissibleInputs
    system = library.models["bounded_velocity"].system
    rep = falsify(system, region, 600, seed=1, window=window(p), admissible=AdmissibleInputs(system, region))
    assert len(rep.counterexamples) > 0


def test_admissible_inputs_at_fig_6_4_differ_between_models(library):
    polys = {n: library.admissible(n).polygons(FIG64) for n in SET_NAMES}
    assert polys["bounded_velocity"] == []  # the state is outside C_bnd: no safe input under I
    assert polys["aggressive"] and polys["cautious"]
    rng = np.random.default_rng(0)
    U = rng.uniform([-3, -1.8], [3, 1.8], size=(4000, 2))
    ok = {n: np.array([library.admissible(n).is_admissible(FIG64, u, polys[n]) for u in U])
          for n in ("aggressive", "cautious")}
    assert ok["aggressive"].any() and ok["cautious"].any()
    assert (ok["aggressive"] != ok["cautious"]).any()


def test_every_admissible_input_keeps_the_state_in_the_set(library):
    """At Fig. 6.4's state, inputs in S_c(x) keep every successor in C_c; others leave for some w."""
    adm = library.admissible("cautious")
    system = library.models["cautious"].system
    region = library.region("cautious")
    polys = adm.polygons(FIG64)
    rng = np.random.default_rng(2)
    for u in rng.uniform([-3, -1.8], [3, 1.8], size=(400, 2)):
        if adm.is_admissible(FIG64, u, polys):
            assert region.contains(system.successor_vertices(FIG64, u)).all()


def test_override_priority_and_bounds(library):
    adm = library.admissible("cautious")
    polys = adm.polygons(FIG64)
    rng = np.random.default_rng(3)
    for u in np.vstack([rng.uniform([-6, -4], [6, 4], size=(300, 2)), [[100.0, -100.0]]]):
        r = adm.override(FIG64, u, polygons=polys)
        assert r.feasible
        assert np.all(r.applied >= [-3, -1.8]) and np.all(r.applied <= [3, 1.8])
        assert adm.is_admissible(FIG64, r.applied, polys)
        if not r.overridden:
            assert np.array_equal(r.applied, u)
        elif r.changed == "throttle":
            assert r.applied[1] == u[1]
        elif r.changed == "steering":
            assert r.applied[0] == u[0]
    # steering first when asked
    r = adm.override(FIG64, [3.0, -1.8], priority=(1, 0), polygons=polys)
    assert r.changed in ("steering", "throttle", "both", "none")
    with pytest.raises(ValueError, match="finite"):
        adm.override(FIG64, [np.nan, 0.0])
    with pytest.raises(ValueError, match="state"):
        adm.polygons([25.0, 0.0, 16.0])


def test_infeasible_state_is_reported_not_faked(library):
    adm = library.admissible("bounded_velocity")
    r = adm.override(FIG64, [0.0, 0.0])
    assert not r.feasible and r.changed == "infeasible"


def test_cache_round_trip_and_refusal(library, cache_dir, tmp_path, capsys):
    import shutil

    cache_dir = shutil.copytree(cache_dir, tmp_path / "cache")  # tampered below: not the session's shared cache
    again = build_library(cache_dir=cache_dir, quiet=True)
    assert all(s.from_cache for s in again.sets.values())
    for n in SET_NAMES:
        X = np.random.default_rng(0).uniform([16, -0.9, -80, 0], [36, 2.7, 80, 33.5], size=(2000, 4))
        assert np.array_equal(again.region(n).contains(X), library.region(n).contains(X))
    # tamper with one entry: it must be refused (and rebuilt), never used
    import numpy as _np
    from rcis.cache import entry_path, load_region
    from rcis.errors import StaleCacheError
    s = library.sets["bounded_velocity"]
    path = entry_path(cache_dir, "bounded_velocity", s.payload)
    with _np.load(path) as z:
        data = {k: z[k] for k in z.files}
    data["b0"] = data["b0"] + 1.0
    _np.savez_compressed(path, **data)
    with pytest.raises(StaleCacheError, match="checksum"):
        load_region(path, s.payload)
    foreign = dict(s.payload, params=dict(s.payload["params"], h_min=12.0))
    with pytest.raises(StaleCacheError, match="h_min"):
        load_region(path, foreign)
    rebuilt = build_library(cache_dir=cache_dir, quiet=True)
    assert not rebuilt.sets["bounded_velocity"].from_cache
    assert "refusing cache entry" in capsys.readouterr().err


def test_export_json_describes_the_same_set(library, tmp_path):
    data = json.loads(json.dumps(export_set(library, "cautious")))
    assert data["state"] == ["v_ex", "y_e", "h", "v_Lx"]
    assert data["params"]["h_min"] == 10.0
    X = np.random.default_rng(5).uniform([16, -0.9, -80, 0], [36, 2.7, 80, 33.5], size=(3000, 4))
    from_json = np.any([np.all(X @ np.array(pc["A"]).T <= np.array(pc["b"]) + 1e-9, axis=1)
                        for pc in data["pieces"]], axis=0)
    assert np.array_equal(from_json, library.region("cautious").contains(X))


def test_halfplane_queries_agree_with_the_polygons(library):
    """The compiled membership and ranges must say what the clipped polygons say."""
    rng = np.random.default_rng(9)
    for name in SET_NAMES:
        adm = library.admissible(name)
        X = rng.uniform([16, -0.9, -70, 0], [36, 2.7, 70, 33.5], size=(150, 4))
        for x in X[library.region(name).contains(X)][:40]:
            q = adm.at(x)
            for u in rng.uniform([-3.2, -2], [3.2, 2], size=(20, 2)):
                in_poly = any(_poly_contains(P, u) for P in q.polygons)
                assert q.contains(u) == in_poly or _near_edge(q.polygons, u)
            for axis in (0, 1):
                v = rng.uniform(-1.8, 1.8) if axis == 0 else rng.uniform(-3, 3)
                assert _same_ranges(adm.intervals(q.polygons, axis, v), q.ranges(axis, v))


def _same_ranges(a, b, tol=1e-9):
    """Every non-degenerate range of one list matches a range of the other."""
    def covered(r, others):
        return any(abs(r[0] - o[0]) < tol and abs(r[1] - o[1]) < tol for o in others)
    wide_a = [r for r in a if r[1] - r[0] > tol]
    wide_b = [r for r in b if r[1] - r[0] > tol]
    return all(covered(r, b) for r in wide_a) and all(covered(r, a) for r in wide_b)


def _poly_contains(P, u):
    from rcis.admissible import _in_polygon
    return _in_polygon(P, u)


def _near_edge(polys, u, tol=1e-9):
    from rcis.admissible import _dist_to_segment
    return any(_dist_to_segment(P[i], P[(i + 1) % len(P)], u) < tol for P in polys for i in range(len(P)))


def test_restricting_S_to_boxes_is_the_intersection(library):
    """``AdmissibleQuery.restricted`` = membership in S(x) and in one of the boxes, on a grid."""
    adm = library.admissible("cautious")
    x = np.array([25.0, -0.297, 16.52, 20.0])
    q = adm.at(x)
    boxes = [((-2.0, 1.0), (-1.8, 0.4)), ((2.5, 3.0), (1.0, 1.8))]
    r = q.restricted(boxes)
    grid = np.stack(np.meshgrid(np.linspace(-2.97, 2.97, 61), np.linspace(-1.77, 1.77, 37)), -1).reshape(-1, 2)
    for u in grid:
        in_box = any(a0 <= u[0] <= a1 and b0 <= u[1] <= b1 for (a0, a1), (b0, b1) in boxes)
        assert r.contains(u) == (q.contains(u) and in_box)
    assert q.restricted([((-3.0, 3.0), (-1.8, 1.8))]).contains(grid[0]) == q.contains(grid[0])
    assert not q.restricted([]).polygons


def test_parallel_certification_gives_the_serial_reports_and_still_catches_the_defect(library):
    """falsify_all in two processes: the same reports as one after another, the injected defect found."""
    from rcis.admissible import AdmissibleInputs
    from rcis.certify import falsify_all

    p = library.params
    system = library.models["bounded_velocity"].system
    bad = Region(library.region("bounded_velocity").pieces + [Polyhedron.from_box([34.0, -0.9, 10.0, 0.0],
                                                                                [36.0, -0.5, 12.0, 5.0])], 4)
    jobs = {"defect": {"system": system, "invariant": bad, "samples": 400, "seed": 1, "window": window(p),
                       "admissible": AdmissibleInputs(system, bad)},
            "cautious": {"system": library.models["cautious"].system, "invariant": library.region("cautious"),
                         "samples": 400, "seed": 2, "window": window(p), "admissible": library.admissible("cautious")}}
    seen = []
    serial = falsify_all(jobs, workers=1)
    parallel = falsify_all(jobs, workers=2, progress=lambda name, done, total: seen.append(name))
    assert {n: r.as_dict() for n, r in serial.items()} == {n: r.as_dict() for n, r in parallel.items()}
    assert parallel["defect"].counterexamples and not parallel["cautious"].counterexamples
    assert set(seen) == {"defect", "cautious"}
    halves = [falsify_all(jobs, workers=w, parts=2) for w in (1, 2)]  # as `guardian rcis certify` draws
    assert [{n: r.as_dict() for n, r in h.items()} for h in halves][0] == \
        [{n: r.as_dict() for n, r in h.items()} for h in halves][1]
    assert halves[1]["defect"].samples == 400 and halves[1]["defect"].counterexamples
    assert not halves[1]["cautious"].counterexamples
