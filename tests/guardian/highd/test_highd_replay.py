"""Conversion to ITHA data, calibration and override counting; workers and Dask give identical results."""
import json
import math

import numpy as np
import pandas as pd
import pytest

from guardian.highd.convert import to_itha
from guardian.highd.generate import TrafficParams, generate
from guardian.highd.reader import read_recording
from guardian.highd.rates import ReplayConfig, car_following_params, order_statistic_bounds, self_safety_overrides
from guardian.highd.replay import default_sample, replay
from itha.car_following import _headway_floor_arrays, headway_floor
from project import SHARED_DATA


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("highd-replay")
    generate(out, 2, 0.5, seed=5, prm=TrafficParams(warmup=30.0, inflow=0.45))
    return out


def test_local_states_from_boxes_in_both_directions(folder):
    rec = read_recording(folder, 1)
    data = to_itha(rec)
    t = rec.tracks.set_index(["id", "frame"])
    lead = np.isfinite(data.h)
    assert lead.any() and (~lead).any()
    for k in np.flatnonzero(lead)[:300]:
        row = t.loc[(data.vehicle[k], data.frame[k])]
        L = t.loc[(int(row["precedingId"]), data.frame[k])]
        # dhw is front to front; the bumper gap subtracts the lead's length
        assert data.h[k] == pytest.approx(row["dhw"] - L["width"], abs=0.03)
        assert data.vL[k] == pytest.approx(abs(L["xVelocity"]))
        assert data.v[k] == pytest.approx(abs(row["xVelocity"]))
    assert set(np.unique(data.direction)) == {1, 2}
    assert (data.v >= 0).all() and set(np.unique(data.lane)) <= {1, 2, 3}


def test_inputs_and_disturbances_are_forward_differences(folder):
    rec = read_recording(folder, 1)
    data = to_itha(rec)
    t = rec.tracks.set_index(["id", "frame"])
    k = int(np.flatnonzero(np.isfinite(data.d))[10])
    now, nxt = t.loc[(data.vehicle[k], data.frame[k])], t.loc[(data.vehicle[k], data.frame[k] + 1)]
    assert data.u[k] == pytest.approx((abs(nxt["xVelocity"]) - abs(now["xVelocity"])) * 25)
    L0 = t.loc[(int(now["precedingId"]), data.frame[k])]
    L1 = t.loc[(int(now["precedingId"]), data.frame[k] + 1)]
    assert data.d[k] == pytest.approx((abs(L1["xVelocity"]) - abs(L0["xVelocity"])) * 25)
    # a lane change is an event with a snapshot of its direction
    assert data.lane_changes
    e = data.lane_changes[0]
    assert e.lane[e.ego] + (1 if e.trigger == "left" else -1) in (1, 2, 3)
    assert len(e.p) == len(e.v) == len(e.lane) == len(e.length) > 1


ID_COLUMNS = ("id", "precedingId", "followingId", "leftPrecedingId", "leftAlongsideId", "leftFollowingId",
              "rightPrecedingId", "rightAlongsideId", "rightFollowingId")


def _copy_recording(folder, out, tracks=lambda t: t, tracks_meta=lambda m: m):
    import shutil

    import pandas as pd

    out.mkdir()
    shutil.copy(folder / "01_recordingMeta.csv", out / "01_recordingMeta.csv")
    tracks(pd.read_csv(folder / "01_tracks.csv")).to_csv(out / "01_tracks.csv", index=False)
    tracks_meta(pd.read_csv(folder / "01_tracksMeta.csv")).to_csv(out / "01_tracksMeta.csv", index=False)
    return out


def _same_itha(a, b, vehicle=lambda v: v) -> None:
    for k in ("frame", "direction", "lane", "v", "h", "vL", "u", "d"):
        assert getattr(a, k).tobytes() == getattr(b, k).tobytes(), k
    assert np.array_equal(vehicle(a.vehicle), b.vehicle)
    assert [(vehicle(np.array([e.vehicle]))[0], e.frame, e.trigger) for e in a.lane_changes] == \
        [(e.vehicle, e.frame, e.trigger) for e in b.lane_changes]


def test_conversion_does_not_depend_on_row_order_or_id_numbering(folder, tmp_path):
    """HighD files come sorted by (id, frame) with ids 1..N, which the fast paths use (no sort, a dense
    id table); shuffled rows and ids spread over 10^12 take the general paths and must agree."""
    original = to_itha(read_recording(folder, 1))
    rng = np.random.default_rng(4)
    shuffled = _copy_recording(folder, tmp_path / "shuffled",
                               tracks=lambda t: t.iloc[rng.permutation(len(t))],
                               tracks_meta=lambda m: m.iloc[rng.permutation(len(m))])
    _same_itha(original, to_itha(read_recording(shuffled, 1)))

    def spread(v):
        return np.where(v != 0, v * 1_000_003_001 + 7, 0)

    def respread(t):
        return t.assign(**{c: spread(t[c].to_numpy()) for c in ID_COLUMNS if c in t})

    wide = _copy_recording(folder, tmp_path / "wide", tracks=respread,
                           tracks_meta=lambda m: respread(m).iloc[rng.permutation(len(m))])
    _same_itha(original, to_itha(read_recording(wide, 1)), vehicle=spread)


def test_positions_finds_each_id_or_says_absent():
    """``reader.positions`` against a dict, through the dense table and through the sorted search."""
    from guardian.highd.reader import positions

    rng = np.random.default_rng(6)
    for keys in (rng.permutation(np.arange(1, 500)), rng.choice(10 ** 12, 500, replace=False) - 10 ** 11):
        query = np.concatenate([rng.choice(keys, 2000), rng.integers(-10 ** 12, 10 ** 12, 50), [-1, 0, 10 ** 15]])
        index = {int(k): i for i, k in enumerate(keys)}
        assert positions(keys, query).tolist() == [index.get(int(q), -1) for q in query]


def test_order_statistics_follow_the_dissertation():
    d = np.arange(1, 41, dtype=float)  # N = 40: ⌈0.025 N⌉ = 1, ⌈0.975 N⌉ = 39
    assert order_statistic_bounds(d, (0.025, 0.975)) == (1.0, 39.0)
    with pytest.raises(ValueError, match="no lead-disturbance samples"):
        order_statistic_bounds(np.array([]), (0.025, 0.975))


def test_self_safety_override_cases():
    p = car_following_params(ReplayConfig(), 0.04, (-0.5, 0.5))
    over = self_safety_overrides(p, v=[30, 30, 30, 30, 30], h=[3, 100, math.inf, math.inf, 100],
                                 vL=[20, 30, np.nan, np.nan, 30], u=[0, 0, 0, 9.0, -7.0])
    # closing fast at 3 m; comfortable; free road; free road but u > u_max; u < u_min
    assert over.tolist() == [True, False, False, True, True]


def _self_safety_arrays(p, v, h, vL, u):
    """(7.4) as array expressions: the referee of the compiled check."""
    v_next = v + p.dt * u
    ok = (u >= p.u_min) & (u <= p.u_max) & (v_next >= 0) & (v_next <= p.v_max)
    lead = np.isfinite(h)
    h_next = np.where(lead, h + p.dt * (np.nan_to_num(vL) - v), 0.0)
    vL_next = np.where(lead, np.maximum(np.nan_to_num(vL) + p.dt * p.d_min, 0.0), 0.0)
    inside = _headway_floor_arrays(p, np.clip(v_next, 0, p.v_max), h_next, np.clip(vL_next, 0, p.v_max)) >= p.h_min
    ok &= np.where(lead, inside & (np.nan_to_num(vL) <= p.v_max), True)
    return ~ok


def test_the_compiled_self_safety_check_is_the_array_expression():
    """On states near C's boundary (the headway set a little either side of the floor after one step),
    inputs at and beyond U's ends, free roads and leads above v_max."""
    p = car_following_params(ReplayConfig(), 0.04, (-0.5, 0.5))
    rng = np.random.default_rng(12)
    n = 400_000
    v, vL = rng.uniform(0, p.v_max, n), rng.uniform(0, p.v_max, n)
    u = rng.uniform(p.u_min - 1, p.u_max + 1, n)
    u[::9], u[1::9] = p.u_min, p.u_max
    h = headway_floor(p, v, np.zeros(n), vL) * -1 + p.h_min + rng.normal(0, 0.5, n)
    h[::6], vL[::6] = np.inf, np.nan
    vL[1::11] = p.v_max + 1
    got = self_safety_overrides(p, v, h, vL, u)
    assert np.array_equal(got, _self_safety_arrays(p, v, h, vL, u))
    assert 0.05 < got.mean() < 0.95  # both answers are exercised


def test_replay_contract_and_rates(folder):
    r = replay(folder, ReplayConfig(seed=1), contexts=True, sensitivity=True)
    for key in ("data_points", "trajectories", "lane_changes", "disturbance_bounds", "override_rates"):
        assert key in r
    lo, hi = r["disturbance_bounds"]
    assert lo < 0 < hi
    for v in r["override_rates"].values():
        assert 0.0 <= v <= 1.0
    assert r["override_rates"]["responsibility_trivial"] >= r["override_rates"]["responsibility_ordered"]
    assert "by_context" in r["contexts"] and len(r["sensitivity"]) >= 10


def test_workers_and_dask_give_identical_results(folder):
    base = replay(folder, ReplayConfig(seed=2))
    two = replay(folder, ReplayConfig(seed=2), workers=2)
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=1, processes=False, dashboard_address=None) as cluster:
        dsk = replay(folder, ReplayConfig(seed=2), scheduler=cluster.scheduler_address)
    for other in (two, dsk):
        for key in ("data_points", "trajectories", "lane_changes", "disturbance_bounds", "override_rates"):
            assert other[key] == base[key]


def test_shipped_sample_is_the_default():
    assert (default_sample() / "01_tracks.csv").exists()
    r = replay(None)
    assert len(r["recordings"]) == 1 and r["data_points"] > 10_000


def test_speed_above_v_max_is_refused(folder):
    with pytest.raises(ValueError, match=r"above v_max = 10\.0"):
        replay(folder, ReplayConfig(v_max=10.0))


def test_rerun_of_real_data_has_per_vehicle_series_and_a_blueprint(tmp_path):

    from rerun.chunk import RrdReader

    from guardian.cli import main
    from guardian.recording.rerun import read_entities

    folder = SHARED_DATA / "i80_sample"
    rrd = tmp_path / "i80.rrd"
    assert main(["replay", str(folder), "--rerun", str(rrd), "--json"]) == 0
    entities = read_entities(rrd)
    for name in ("speed", "gap", "input", "admissible/low", "admissible/high"):
        assert sum(1 for e in entities if e.startswith("/vehicles/") and e.endswith(name)) > 100, name
    assert entities.get("/road/vehicles", 0) == 3000 and entities.get("/road/markings") == 1
    assert len(list(RrdReader(str(rrd)).blueprints())) == 1


def _moving_in(u: float, speeds=(30.0, 25.0), gap: float = 5.1):
    """An ego at 30 m/s moves left in ``gap`` m behind a car at 25 m/s; its recorded input ``u``."""
    from guardian.highd.convert import LaneChange

    return LaneChange(1, 7, 100, 0, "left", np.array([0.0, gap + 5.0]), np.array(speeds), np.array([1, 2]),
                      np.array([5.0, 5.0]), np.array([1, 0]), 2, u)


@pytest.mark.parametrize("overapprox", ["trivial", "ordered"])
def test_a_lane_change_is_judged_on_its_recorded_input(overapprox):
    """Definition 22 constrains the recorded pair: the responsible inputs here are [-6, -2.5] m/s^2; a recorded 0
    is an override although some input was responsible (today's old rule counted none); -4 is not."""
    from guardian.highd.rates import LaneChangeCounts, car_following_params, responsibility_overrides

    p = car_following_params(ReplayConfig(), 0.1, (-1.0, 1.0))
    assert responsibility_overrides(p, [_moving_in(0.0)], overapprox) == LaneChangeCounts(1, 0, 0)
    assert responsibility_overrides(p, [_moving_in(-4.0)], overapprox) == LaneChangeCounts(0, 0, 0)
    assert responsibility_overrides(p, [_moving_in(-4.0, gap=4.5)], overapprox) == LaneChangeCounts(1, 1, 0)


def test_speeds_outside_the_state_space_are_overrides_never_safe():
    """A negative speed (a recording's noise at standstill) lies outside (7.3)'s state space: the point, and a lane
    change with one in its snapshot, count as overrides, never as safe."""
    from guardian.highd.rates import LaneChangeCounts, car_following_params, responsibility_overrides, \
        self_safety_overrides

    p = car_following_params(ReplayConfig(), 0.1, (-1.0, 1.0))
    over = self_safety_overrides(p, np.array([-0.01, 0.0, 5.0]), np.array([50.0, 50.0, np.inf]),
                                 np.array([0.0, -0.02, np.nan]), np.array([0.0, 0.0, 0.0]))
    assert over.tolist() == [True, True, False]
    assert responsibility_overrides(p, [_moving_in(0.0, speeds=(-0.05, 0.0), gap=30.0)], "trivial") == \
        LaneChangeCounts(1, 1, 1)
    assert responsibility_overrides(p, [_moving_in(-6.0, speeds=(0.3, 0.0), gap=30.0)], "trivial") == \
        LaneChangeCounts(1, 1, 1)   # its recorded next speed, 0.3 - 0.6, is negative


def _first_lane_change(t):
    """The row (in file order) where a vehicle's laneId first changes, and the change."""
    changed = (t["id"] == t["id"].shift()) & (t["laneId"] != t["laneId"].shift())
    row = int(np.flatnonzero(changed.to_numpy())[0])
    return row, int(t["laneId"].iloc[row] - t["laneId"].iloc[row - 1])


def test_consistency_refusals_name_the_file_line_and_column(folder, tmp_path):
    """A vehicle that changes two lanes in one frame, and one that follows a vehicle with no row at that frame: refused
    naming the tracks file, the line (header = line 1) and the column."""
    from guardian.errors import HighDFormatError

    def two_lanes(t):
        row, step = _first_lane_change(t)
        vid = t["id"].iloc[row]
        later = (t["id"] == vid) & (t.index >= row)
        t.loc[later, "laneId"] += step   # the change becomes two lanes
        return t

    def ghost_lead(t):
        t.loc[5, "precedingId"] = 9999
        return t

    for change, line, column in ((two_lanes, None, "laneId"), (ghost_lead, 7, "precedingId")):
        out = _copy_recording(folder, tmp_path / change.__name__, tracks=change)
        if line is None:
            line = _first_lane_change(pd.read_csv(folder / "01_tracks.csv"))[0] + 2
        with pytest.raises(HighDFormatError, match=rf"01_tracks\.csv: line {line}, column '{column}'"):
            to_itha(read_recording(out, 1, plausibility=False))


def test_contexts_say_what_they_change_and_where_their_traffic_model_failed(capsys):
    """``--contexts`` on the real I-80 sample: beside each context's rate, the single sets' rate on the same
    points (their mean over the contexts is the single rate), and the held-out lead accelerations outside the
    context's D; one context's leads all braked beyond its D, and the record says so."""
    from guardian.cli import main

    assert main(["replay", str(SHARED_DATA / "i80_sample"), "--contexts", "--input-bounds", "data", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    ctx, table = r["contexts"], r["contexts"]["by_context"].values()
    assert ctx["self_safety_single"] == r["override_rates"]["self_safety"]
    points = sum(c["test_points"] for c in table)
    assert points == r["test_data_points"]
    assert abs(sum(c["self_safety_single"] * c["test_points"] for c in table) / points - ctx["self_safety_single"]) < 1e-12
    assert ctx["test_disturbances_outside"] == sum(c["test_disturbances_outside"] for c in table) > 0
    assert sum(c["test_disturbances"] for c in table) == ctx["test_disturbances"]
    assert any(c["test_disturbances"] and c["test_disturbances_outside"] == c["test_disturbances"] for c in table)
