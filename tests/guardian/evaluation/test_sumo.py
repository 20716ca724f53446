"""Guarded episodes in Eclipse SUMO: the counting rules on hand-built cases, the frame, and real SUMO runs."""
import math
from dataclasses import replace

import numpy as np
import pytest

from guardian.adapters.sumo.network import HighwayNet
from guardian.adapters.sumo.scene import BicycleModel, Frame, overlap, place
from guardian.evaluation.sumo import run_episode, summary
from guardian.evaluation.sumo_setting import SumoSetting
from guardian.evaluation.sumo_judge import ENTRY_WINDOW, Tracks, at_fault
from guardian.model.roads import road_from_dict
from guardian.model.sensing import Sensed


def body(name, x, y, heading=0.0, speed=20.0, length=5.0, width=2.0):
    return Sensed(name, x, y, heading, speed, length, width, x + length / 2, 0)


# ---- the judge's rules, hand-built -------------------------------------------------------------------------
def tracks_with(entries: dict, lanes: dict) -> Tracks:
    t = Tracks()
    t.lanes = {k: frozenset(v) for k, v in lanes.items()}
    t.entered = entries
    return t


def test_the_body_that_entered_the_others_lane_is_at_fault():
    ego, car = body("guarded", 0, 0), body("car", 4, 0)
    assert at_fault(ego, car, tracks_with({"guarded": {1: 9.0}}, {"guarded": {0, 1}, "car": {1}}), 10.0) == (True, "entry")
    assert at_fault(ego, car, tracks_with({"car": {0: 9.0}}, {"guarded": {0}, "car": {0, 1}}), 10.0) == (False, "entry")


def test_both_entering_counts_against_the_guarded_vehicle():
    ego, car = body("guarded", 0, 0), body("car", 4, 0)
    tracks = tracks_with({"guarded": {1: 9.0}, "car": {0: 9.5}}, {"guarded": {0, 1}, "car": {0, 1}})
    assert at_fault(ego, car, tracks, 10.0) == (True, "entry")


def test_an_entry_older_than_the_window_is_not_an_entry():
    ego, car = body("guarded", 10, 0), body("car", 4, 0)  # the car behind runs into the ego
    tracks = tracks_with({"guarded": {1: 10.0 - ENTRY_WINDOW - 0.5}}, {"guarded": {1}, "car": {1}})
    assert at_fault(ego, car, tracks, 10.0) == (False, "rear-end")


def test_rear_end_the_body_behind_unless_the_one_ahead_reverses():
    behind, ahead = body("guarded", 0, 0), body("car", 4.5, 0)
    assert at_fault(behind, ahead, Tracks(), 1.0) == (True, "rear-end")
    assert at_fault(behind, body("car", 4.5, 0, speed=-1.0), Tracks(), 1.0) == (False, "rear-end")
    assert at_fault(body("guarded", 4.5, 0), body("car", 0, 0), Tracks(), 1.0) == (False, "rear-end")
    assert at_fault(body("guarded", 4.5, 0, speed=-2.0), body("car", 0, 0), Tracks(), 1.0) == (True, "rear-end")


def side_by_side(ego_dy: float, car_dy: float, ego_x: float = 0.0, car_x: float = 1.0):
    """The guarded vehicle in lane 1 (y 3.5) and a car in lane 2 (y 7.0) alongside, each moving sideways by its dy
    over 0.1 s; both already in these lanes long before (no entry in the window)."""
    t = Tracks()
    e0, c0 = body("guarded", ego_x, 3.5), body("car", car_x, 7.0)
    e1, c1 = body("guarded", ego_x + 2, 3.5 + ego_dy), body("car", car_x + 2, 7.0 + car_dy)
    for when, e, c in ((0.0, e0, c0), (0.0, e0, c0), (0.1, e1, c1)):
        t.see("guarded", frozenset({1}), when, e)
        t.see("car", frozenset({2}), when, c)
    return e1, c1, t


def test_rear_end_goes_by_who_was_behind_before_the_contact():
    """A car passing the guarded vehicle at 16 m/s clips its body, which sticks 0.25 m into the car's lane: at the
    contact the car's centre is already 0.55 m ahead, before it it was 1 m behind; the car ran into it."""
    t = Tracks()
    slow0, fast0 = body("guarded", 100.0, 4.5, speed=1.5), body("car", 99.0, 7.0, speed=16.5)
    slow1, fast1 = body("guarded", 100.15, 4.5, speed=1.5), body("car", 100.7, 7.0, speed=16.5)
    for when, a, b in ((0.0, slow0, fast0), (0.0, slow0, fast0), (0.1, slow1, fast1)):
        t.see("guarded", frozenset({1, 2}), when, a)
        t.see("car", frozenset({2}), when, b)
    t.entered = {}  # both in their lanes for long
    assert at_fault(slow1, fast1, t, 0.1) == (False, "rear-end")
    assert at_fault(fast1, slow1, t, 0.1) == (True, "rear-end")  # the same crash, the car in the guarded seat


def test_side_contact_the_body_that_moved_sideways_is_at_fault():
    ego, car, t = side_by_side(ego_dy=0.1, car_dy=0.0)          # the guarded vehicle drifts towards the car, 1 m/s
    assert at_fault(ego, car, t, 0.1) == (True, "side")
    ego, car, t = side_by_side(ego_dy=0.0, car_dy=-0.1)         # the car drifts towards the guarded vehicle
    assert at_fault(ego, car, t, 0.1) == (False, "side")
    ego, car, t = side_by_side(ego_dy=0.1, car_dy=-0.1)         # both: against the guarded vehicle
    assert at_fault(ego, car, t, 0.1) == (True, "side")
    ego, car, t = side_by_side(ego_dy=0.01, car_dy=0.0, ego_x=2.0, car_x=0.0)  # neither: the rear-end rule (car behind)
    assert at_fault(ego, car, t, 0.1) == (False, "rear-end")
    ego, car, t = side_by_side(ego_dy=0.1, car_dy=0.0, ego_x=6.0, car_x=0.0)   # not alongside before: rear-end
    assert at_fault(ego, car, t, 0.1) == (False, "rear-end")


def test_tracks_record_an_entry_when_a_body_begins_to_overlap_a_lane():
    t = Tracks()
    t.see("car", frozenset({0}), 0.0)
    t.see("car", frozenset({0, 1}), 0.5)
    t.see("guarded", frozenset({1}), 0.5)
    assert t.entered == {"car": {1: 0.5}} and t.entered_lane_of("car", "guarded", 1.0)
    assert not t.entered_lane_of("guarded", "car", 1.0)


def test_overlap_of_rotated_bodies():
    a = body("a", 0, 0)
    assert overlap(a, body("b", 4.9, 0)) and not overlap(a, body("b", 5.1, 0))
    assert not overlap(a, body("b", 0, 2.1)) and overlap(a, body("b", 0, 1.9))
    # rotated by 90 degrees: its half length now lies across the road
    assert overlap(a, body("b", 3.4, 0, heading=math.pi / 2)) and not overlap(a, body("b", 3.6, 0, heading=math.pi / 2))
    # corner against corner at 45 degrees: the separating axis is one of the rotated body's
    assert not overlap(a, body("b", 2.5 + 2.5 * math.cos(math.pi / 4) + 1.8, 1.0, heading=math.pi / 4))


def test_the_frame_maps_sumo_to_the_road_model_and_back():
    frame = Frame.__new__(Frame)
    frame.n_lanes, frame.lane_width, frame.x0, frame.y_left, frame.edge = 3, 3.5, 0.0, -1.75, "highway"
    frame.lanes_of = {"highway": 3}
    frame.road = road_from_dict({"lanes": 3, "lane_width": 3.5})
    xs, ys, angle = frame.to_sumo(100.0, 3.5, 0.1, 5.0)   # slot 1's centre, turning right by 0.1 rad
    assert angle == pytest.approx(90 + math.degrees(0.1))
    assert ys == pytest.approx(-1.75 - 3.5 - 2.5 * math.sin(0.1)) and xs == pytest.approx(100 + 2.5 * math.cos(0.1))
    assert [frame.slot(k) for k in range(3)] == [2, 1, 0] and frame.sumo_lane(0) == 2


def test_the_ego_model_is_highway_envs_bicycle():
    m = BicycleModel(5.0, 0.1)
    x, y, h, v = m.step(0.0, 0.0, 0.0, 20.0, 2.0, 0.0)
    assert (x, y, h, v) == pytest.approx((2.0, 0.0, 0.0, 20.2))
    x, y, h, v = m.step(0.0, 0.0, 0.0, 20.0, 0.0, 0.1)
    beta = math.atan(0.5 * math.tan(0.1))
    assert y == pytest.approx(2.0 * math.sin(beta)) and h == pytest.approx(2.0 * math.sin(beta) / 2.5)


# ---- real SUMO ---------------------------------------------------------------------------------------------
libsumo = pytest.importorskip("libsumo")
SHORT = SumoSetting(seconds=25.0, warmup=30.0)


def test_the_traffic_model_is_read_from_sumos_vehicle_types():
    r = run_episode(SHORT, "random", seed=3)
    assert r["inserted"] and r["traffic_accel"] == SHORT.traffic.emergency_decel
    assert r["steps"] > 0 and r["ego_uncovered"] == 0, r  # SUMO puts the guarded car where the model says


def test_reckless_drivers_crash_unguarded_and_cause_none_guarded():
    unguarded = summary([run_episode(SHORT, "reckless", seed, guarded=False) for seed in range(4)])
    guarded = summary([run_episode(SHORT, "reckless", seed) for seed in range(4)])
    assert unguarded["collisions"] >= 2 and unguarded["at_fault"] >= 2, unguarded
    assert guarded["at_fault_after_inside"] == 0 and guarded["safety_overrides"] > 0, guarded


def test_through_the_service_every_decision_is_the_in_process_one_to_the_bit(library):
    from guardian.client import GuardianClient
    from guardian.client.bodies import guardian_body, vehicle_body
    from guardian.client.shadow import Shadow
    from guardian.service import ServiceConfig, ServiceThread

    with ServiceThread(library, ServiceConfig(port=0)) as service, GuardianClient(service.url) as client:
        def ask(guard, road):
            session = client.create_scene_session(road, vehicle_body(guard.kin, guard.meta, guard.actuator),
                                                  guardian_body(guard.config))
            return Shadow(guard, session, road)

        r = run_episode(SumoSetting(seconds=15.0, warmup=30.0), "seek", seed=1, ask=ask)
        jerky = run_episode(SumoSetting(seconds=15.0, warmup=30.0, jerk=5.0), "seek", seed=1, ask=ask)
        lagged = run_episode(SumoSetting(seconds=15.0, warmup=30.0, jerk=10.0, lag=0.3), "seek", seed=1, ask=ask)
    assert r["service_steps"] == r["steps"] > 0 and r["service_disagreements"] == 0, r
    assert r["safety_overrides"] > 0
    for run in (jerky, lagged):
        assert run["service_steps"] == run["steps"] > 0 and run["service_disagreements"] == 0, run
        assert run["actuator_clipped"] == 0 and run["safety_overrides"] > 0


def test_the_command_prints_clean_json_and_refuses_options_that_do_not_apply():
    import json
    import subprocess
    import sys

    run = [sys.executable, "-m", "guardian.cli", "sumo", "--episodes", "1", "--seconds", "5", "--warmup", "20"]
    done = subprocess.run(run + ["--json"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    (row,) = json.loads(done.stdout)["rows"]
    assert row["guardian"] and row["episodes"] == 1 and row["steps"] == 50
    for extra, why in ((["--no-guardian", "--through-service"], "does not apply"),
                       (["--campaign", "--no-guardian"], "do(es) not apply with --campaign"),
                       (["--campaign", "--agent", "seek"], "--agent do(es) not apply with --campaign"),
                       (["--through-service", "--workers", "2"], "--workers 1"),
                       (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers does not apply"),
                       (["--scheduler", "notanaddress"], "--scheduler:"),
                       (["--flow", "1e7"], "--flow must be at most"),
                       (["--sigma", "5"], "--sigma must be in [0, 1]"),
                       (["--emergency-decel", "1"], "--emergency-decel must be at least"),
                       (["--overapprox", "ordered"], "does not apply to one guarded vehicle"),
                       (["--length", "100"], "--length must be at least"),
                       (["--connection", "nowhere"], "libsumo, traci or HOST:PORT"),
                       (["--connection", "127.0.0.1:1"], "no SUMO server answers at 127.0.0.1:1"),
                       (["--connection", "127.0.0.1:1", "--workers", "2"], "drives one SUMO server"),
                       (["--write-scenario", "x", "--campaign"], "--write-scenario writes one setting"),
                       (["--rerun", "x.rrd", "--workers", "2"], "--rerun records in this process"),
                       (["--jerk", "0"], "--jerk"), (["--lag", "-1"], "--lag"), (["--lag", "1e9"], "at most 60 s")):
        done = subprocess.run(run + extra, capture_output=True, text=True, timeout=300)
        lines = [line for line in done.stderr.splitlines() if "pyarrow" not in line]
        assert done.returncode == 2 and len(lines) == 1 and why in lines[0], done.stderr


def _crawler_and_follower(shadows: bool, seconds: float = 12.0):
    """A guarded vehicle crawling at 3 m/s with its centre in slot 1 and 0.6 m of its body over the line into slot 0;
    a SUMO car coming up behind in slot 0 at 25 m/s. The smallest gap between the two bodies, and the lanes SUMO's
    drivers saw the guarded body in."""
    import tempfile
    from pathlib import Path

    from guardian.adapters.sumo.network import Traffic
    from guardian.adapters.sumo.scene import place
    from guardian.adapters.sumo.shadows import Shadows
    from guardian.evaluation.sumo_setting import sumo_args
    from guardian.adapters.sumo.connection import open_sumo

    setting = SumoSetting(traffic=Traffic(vehicles_per_hour=1.0))
    with tempfile.TemporaryDirectory() as tmp:
        traci = open_sumo("libsumo", sumo_args(setting, Path(tmp), seed=0))
        try:
            frame, shade = Frame(traci, setting.net.edge), None
            traci.vehicle.add("guarded", "from_highway", typeID="guarded", departLane=str(frame.sumo_lane(1)), departPos="600",
                              departSpeed="3")
            traci.vehicle.add("car", "from_highway", typeID="traffic", departLane=str(frame.sumo_lane(0)), departPos="400",
                              departSpeed="25")
            traci.simulationStep()
            traci.vehicle.setLaneChangeMode("car", 0)   # it keeps its lane: it must brake
            shade = Shadows(frame) if shadows else None
            x, y = 600.0, frame.lane_width - (frame.lane_width / 2 - 1.0 + 0.6)   # 0.6 m over the line
            gap, seen = math.inf, set()
            for _ in range(round(seconds / setting.step_length)):
                x += 3.0 * setting.step_length
                own = place(traci, frame, "guarded", x, y, 0.0, 3.0)
                if shade is not None:
                    shade.update(traci, "guarded", x, y, 0.0, 3.0, 5.0, frozenset({0, 1}), own)
                traci.simulationStep()
                if shade is not None:
                    seen |= shade.lanes_seen(traci, "guarded")
                me, car = frame.body(traci, "guarded"), frame.body(traci, "car")
                gap = min(gap, me.x - me.length / 2 - (car.x + car.length / 2))
            return gap, seen
        finally:
            traci.close()


def test_sumo_is_blind_to_a_body_over_the_line_and_the_shadow_lets_its_drivers_see_it():
    blind_gap, _ = _crawler_and_follower(shadows=False)
    assert blind_gap < 0, blind_gap   # SUMO's car drives into the body: it only sees its own lane's vehicles
    gap, seen = _crawler_and_follower(shadows=True)
    assert gap > 1.0 and seen == {0, 1}, (gap, seen)


def test_a_shadow_follows_its_body_and_leaves_with_it():
    from guardian.adapters.sumo.shadows import is_shadow, owner, shadow_id

    assert owner(shadow_id("guarded.3", 2)) == "guarded.3" and is_shadow(shadow_id("guarded", 0))
    assert not is_shadow("guarded") and owner("traffic.7") == "traffic.7"


def test_many_guarded_vehicles_cause_no_collision_under_either_overapproximation():
    from guardian.config import GuardianConfig

    setting = SumoSetting(seconds=15.0, warmup=30.0, guarded=10)
    for overapprox in ("trivial", "ordered"):
        r = run_episode(setting, "random", seed=2, config=GuardianConfig(overapprox=overapprox))
        assert r["inserted"] and r["vehicle_steps"] > 5 * r["steps"] > 0, r
        assert r["at_fault"] == 0 and r["between_guarded"] == 0 and r["guarded_lost"] == 0, r["crashes"]
        assert r["ego_lane_unseen"] == 0 and r["ego_uncovered"] == 0, r


def test_a_collision_counts_by_the_start_of_the_vehicle_at_fault():
    from guardian.evaluation.sumo import Guarded, _Episode

    run = _Episode.__new__(_Episode)
    run.recorder = None
    run.out = {"collisions": 0, "sumo_collisions": 0, "between_guarded": 0, "at_fault": 0, "at_fault_after_inside": 0,
               "at_fault_after_outside": 0, "crashes": [], "steps": 7}
    a, b = body("guarded.0", 0.0, 3.5), body("guarded.1", 5.5, 3.5, speed=10.0)   # a behind b: a at fault
    run.tracks = tracks_with({}, {"guarded.0": {1}, "guarded.1": {1}})
    run.tracks.seen = {"guarded.0": [(0.0, a)], "guarded.1": [(0.0, b)]}
    run.cars = [Guarded("guarded.0", None, None, 0.0, start_inside=False), Guarded("guarded.1", None, None, 0.0,
                                                                                  start_inside=True)]
    run._count_crash(run.cars[1], a, by_sumo=False, t=0.0)   # asked for the one ahead: the one behind is at fault
    (crash,) = run.out["crashes"]
    assert crash["culprit"] == "guarded.0" and crash["between_guarded"] and crash["start_inside"] is False
    assert run.out["at_fault_after_outside"] == 1 and run.out["at_fault_after_inside"] == 0
    run._count_crash(run.cars[0], body("traffic.1", 5.5, 3.5), by_sumo=True, t=0.0)   # it ran into traffic
    assert run.out["at_fault_after_outside"] == 2 and run.out["sumo_collisions"] == 1 and run.out["collisions"] == 2


# ---- the connections: libsumo, SUMO in its own process over TraCI, a SUMO server ----------------------------
def test_traci_and_a_sumo_server_give_the_episodes_libsumo_gives(tmp_path):
    import socket
    import subprocess

    from guardian.adapters.sumo.connection import close_servers
    from guardian.adapters.sumo.network import sumo_home
    from guardian.evaluation.sumo_setting import write_scenario

    setting = SumoSetting(seconds=8.0, warmup=20.0, guarded=2)
    here = [run_episode(setting, "seek", seed) for seed in (1, 2)]
    local = [run_episode(SumoSetting(seconds=8.0, warmup=20.0, guarded=2, connection="traci"), "seek", seed)
             for seed in (1, 2)]
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cfg = write_scenario(setting, tmp_path)
    server = subprocess.Popen([str(sumo_home() / "bin" / "sumo"), "-c", str(cfg), "--remote-port", str(port)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        remote = SumoSetting(seconds=8.0, warmup=20.0, guarded=2, connection=f"127.0.0.1:{port}")
        served = [run_episode(remote, "seek", seed, folder=tmp_path) for seed in (1, 2)]
        close_servers()
        assert server.wait(timeout=30) == 0   # the server ends when its client closes
    finally:
        if server.poll() is None:
            server.kill()
    assert here[0]["steps"] > 0 and here[0]["vehicle_steps"] > here[0]["steps"]
    assert local == here and served == here


def test_a_connection_is_checked_before_any_work():
    from guardian.adapters.sumo.connection import parse_connection
    from guardian.errors import ConfigError

    assert parse_connection("traci") == "traci" and parse_connection("sim.example:8813") == "sim.example:8813"
    for bad in ("libsumo2", "host:", ":8813", "host:0", "host:70000", "host:port"):
        with pytest.raises(ConfigError, match="libsumo, traci or HOST:PORT"):
            SumoSetting(connection=bad)


def test_a_rerun_recording_shows_every_body_and_every_safety_override(tmp_path):
    from guardian.recording.rerun import read_entities, read_texts
    from guardian.recording.sumo import SumoRecorder

    path = tmp_path / "sumo.rrd"
    with SumoRecorder(path) as recorder:
        r = run_episode(SumoSetting(seconds=10.0, warmup=20.0, guarded=2), "random", seed=1, recorder=recorder)
    rows = read_entities(path)
    assert rows["/road/guarded"] == rows["/road/traffic"] == rows["/road/shadows"] == r["steps"] > 0
    assert rows["/road/follow"] == rows["/road/follow/labels"] == r["steps"]   # the view follows the first guarded vehicle
    assert rows["/inputs/guarded.0/acceleration/applied"] == r["steps"]
    overrides = read_texts(path, "/events/override")
    assert len(overrides) == r["safety_overrides"] > 0 and all(t.startswith("t=") for t in overrides)
    assert read_texts(path, "/events/episode") == ["random seed 1 starts"]


# ---- an on-ramp merge ----------------------------------------------------------------------------------------
MERGE = SumoSetting(seconds=20.0, warmup=30.0, net=HighwayNet(ramp_at=1000.0))
EXIT = SumoSetting(seconds=20.0, warmup=30.0, net=HighwayNet(exit_at=1000.0))


def test_an_on_ramp_is_read_as_a_road_map_with_its_branch_and_its_dead_end(tmp_path):
    from guardian.adapters.sumo.connection import open_sumo
    from guardian.evaluation.sumo_setting import sumo_args
    from guardian.model.roads import RoadMap

    traci = open_sumo("libsumo", sumo_args(MERGE, tmp_path, seed=0))
    try:
        frame = Frame(traci, MERGE.net.corridor, MERGE.net.ramp)
        road = frame.road
        assert isinstance(road, RoadMap) and road.n_lanes == 4 and frame.lanes_of == {"in": 3, "acc": 4, "out": 3}
        (lo, hi), = road.spans[3]
        assert lo == pytest.approx(1000.0, abs=3) and hi == pytest.approx(1250.0, abs=5) and road.ends == ((3, hi),)
        (ramp,) = road.branches
        assert ramp.slot == 3 and ramp.s0 + ramp.length == pytest.approx(lo)   # the ramp's chain runs on into slot 3
        assert road.slot_at(3, 1100.0) and not road.slot_at(3, 1300.0) and road.slot_at(2, 1300.0)
        assert frame.lane_at(3, 1100.0) == ("acc", 0) and frame.lane_at(0, 500.0) == ("in", 2)
        assert frame.lane_at(0, 1100.0) == ("acc", 3) and frame.lane_at(2, 2000.0) == ("out", 0)
        # a car on the ramp is in slot 3's lane, its front along the ramp's chain
        x, y = ramp.position(100.0)
        assert road.nearest_slot(x, y) == 3 and frame.along(x, y) == pytest.approx(ramp.s0 + 100.0)
    finally:
        traci.close()


def test_an_exit_is_a_branch_leaving_the_deceleration_lane_which_is_no_dead_end(tmp_path):
    from guardian.adapters.sumo.connection import open_sumo
    from guardian.evaluation.sumo_setting import sumo_args

    traci = open_sumo("libsumo", sumo_args(EXIT, tmp_path, seed=0))
    try:
        road = Frame(traci, EXIT.net.corridor, EXIT.net.ramp, EXIT.net.exit).road
        (lo, hi), = road.spans[3]
        (exit_,) = road.branches
        assert road.ends == () and exit_.slot == 3 and exit_.s0 == pytest.approx(hi) and exit_.open_after
        x, y = exit_.position(50.0)
        assert road.nearest_slot(x, y) == 3 and not road.slot_at(3, x)
    finally:
        traci.close()


@pytest.mark.parametrize("setting", ["merge", "exit"])
def test_on_a_merge_or_exit_road_guarded_vehicles_cause_no_collision(setting):
    for agent, guarded in (("seek", 1), ("random", 1), ("random", 6)):
        rows = [run_episode(replace(MERGE if setting == "merge" else EXIT, guarded=guarded), agent, seed)
                for seed in range(3)]
        total = summary(rows)
        assert total["steps"] > 0 and total["at_fault"] == 0 and total["guarded_lost"] == 0, (agent, total)
        assert total["ego_uncovered"] == 0, total


def test_roads_that_cannot_be_built_are_refused_by_name():
    from guardian.errors import ConfigError

    for bad, match in (({"ramp_at": 1000.0, "exit_at": 1500.0}, "not both"), ({"ramp_at": 100.0}, "ramp_at must"),
                       ({"exit_at": 2900.0}, "exit_at must"), ({"ramp_offset": -1.0}, "ramp_offset")):
        with pytest.raises(ConfigError, match=match):
            HighwayNet(**bad)


def test_a_vehicle_driven_off_the_lanes_near_a_ramp_is_counted_not_a_crash_of_the_process():
    """Seed 7: the unguarded seeking driver leaves the main road towards the on-ramp, where SUMO has it on no lane;
    asking libsumo for its edge then killed the process (a segmentation fault)."""
    import json
    import subprocess
    import sys

    run = [sys.executable, "-m", "guardian.cli", "sumo", "--road", "merge", "--agent", "seek", "--no-guardian",
           "--episodes", "1", "--seed", "7", "--json"]
    done = subprocess.run(run, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    (row,) = json.loads(done.stdout)["rows"]
    assert row["collisions"] == 1 and row["ego_lane_unseen"] > 0   # it crashed, and SUMO's drivers lost sight of it


def test_a_guarded_vehicle_that_takes_the_exit_leaves_at_its_end():
    """Seed 0: the reckless driver takes the exit; the road model goes on past the exit's end, SUMO's network does
    not: the vehicle leaves there (before, it drove on off the network, unseen by SUMO on every later step)."""
    r = run_episode(replace(EXIT, seconds=60.0), "reckless", 0, guarded=True)
    assert r["inserted"] and r["collisions"] == 0 and r["guarded_lost"] == 0
    assert r["ego_lane_unseen"] == 0 and r["steps"] < 600, r   # it left before the episode's end


def _sumo_driver_beside_a_blocker(steps: int = 12):
    """SUMO's driver (unguarded, moved by the model) 55 m behind a car at 10 m/s, a car driving beside it on the left
    lane: per step its proposal and SUMO's lane-change state towards the left."""
    import tempfile
    from pathlib import Path

    from guardian.adapters.sumo.connection import open_sumo
    from guardian.adapters.sumo.network import Traffic
    from guardian.adapters.sumo.scene import BicycleModel
    from guardian.evaluation.sumo_agents import agent_of
    from guardian.evaluation.sumo_setting import sumo_args

    setting = SumoSetting(traffic=Traffic(vehicles_per_hour=1.0))
    with tempfile.TemporaryDirectory() as tmp:
        traci = open_sumo("libsumo", sumo_args(setting, Path(tmp), seed=0))
        try:
            frame = Frame(traci, setting.net.edge)
            for vid, vtype, slot, pos, speed in (("guarded", "guarded", 2, 500, 20), ("slow", "traffic", 2, 560, 10),
                                                 ("beside", "traffic", 1, 500, 20)):
                traci.vehicle.add(vid, "from_highway", typeID=vtype, departLane=str(frame.sumo_lane(slot)),
                                  departPos=str(pos), departSpeed=str(speed))
            traci.simulationStep()
            for vid in ("slow", "beside"):
                traci.vehicle.setLaneChangeMode(vid, 0)
            traci.vehicle.setSpeed("slow", 10.0)
            drive = agent_of("sumo", setting, np.random.default_rng(0), traci=traci, vehicle="guarded", frame=frame)
            model, out = BicycleModel(setting.ego_length, setting.step_length), []
            for k in range(steps):
                me = frame.body(traci, "guarded")
                traci.vehicle.setSpeed("beside", me.speed)
                a, steer = drive(me, [], k * setting.step_length)
                out.append((a, steer, traci.vehicle.getLaneChangeState("guarded", 1)[0]))
                place(traci, frame, "guarded", *model.step(me.x, me.y, me.heading, me.speed, a, steer))
                traci.simulationStep()
            return out
        finally:
            traci.close()


def test_sumos_driver_follows_its_car_following_model_and_changes_lanes_with_its_checks_off():
    """The ``sumo`` agent brakes for the slower car ahead as SUMO's car-following model does, and steers into the
    left lane as soon as SUMO's lane-change model wants to go there for speed, although SUMO says the change is
    blocked by the car beside (its gap check is off)."""
    from guardian.evaluation.sumo_agents import LCA_LEFT, LCA_WISHES

    blocked = 512 | 1024 | 8192   # SUMO's LCA_BLOCKED_BY_LEFT_LEADER, _LEFT_FOLLOWER, LCA_OVERLAPPING
    steps = _sumo_driver_beside_a_blocker()
    assert all(a < 0 for a, _, _ in steps[1:]), steps
    wanted = [k for k, (_, _, state) in enumerate(steps) if state & LCA_LEFT and state & LCA_WISHES]
    assert wanted and steps[wanted[0]][2] & blocked, steps
    assert steps[wanted[0] + 1][1] < 0, steps   # steering left (towards the smaller slot) from the next step


def test_sumos_driver_guarded_causes_no_collision():
    for seed in range(3):
        r = run_episode(SHORT, "sumo", seed)
        assert r["inserted"] and r["at_fault"] == 0 and r["guarded_lost"] == 0, r["crashes"]
        assert r["ego_uncovered"] == 0, r
        braking, position = r["traffic_uncovered_braking"], r["traffic_uncovered_position"]
        assert max(braking, position) <= r["traffic_uncovered"] <= braking + position   # every step by its cause
        assert position > 0 and braking == 0   # Krauss' speed-by-new-speed update; nobody beyond emergencyDecel


def test_a_vehicle_that_starts_on_the_ramp_is_guarded_there_and_counted_when_it_merges():
    """Started on the on-ramp: SUMO's own driver merges unguarded (and, with its checks off, may crash); guarded it
    causes no collision, merges when the guardian finds a responsible entry and is otherwise held before the
    acceleration lane's end, and every start and merge is counted."""
    ramp, seeds = replace(MERGE, start="ramp"), (2, 3, 4, 5)
    unguarded = summary([run_episode(ramp, "sumo", seed, guarded=False) for seed in seeds])
    assert unguarded["ramp_starts"] == 4 and unguarded["merged"] == 4
    guarded = [run_episode(ramp, "sumo", seed) for seed in seeds]
    assert [r["merged"] for r in guarded] == [1, 1, 1, 0], guarded   # seed 5: held at the lane's end in 20 s
    assert guarded[-1]["failsafe_steps"] > 0
    guarded = summary(guarded)
    assert guarded["ramp_starts"] == 4 and guarded["at_fault"] == 0 and guarded["guarded_lost"] == 0 and guarded["ego_uncovered"] == 0, guarded
    main_start = summary([run_episode(MERGE, "sumo", 0)])
    assert main_start["ramp_starts"] == 0 and main_start["merged"] == 0


def test_a_ramp_start_needs_a_ramp_and_one_vehicle():
    from guardian.errors import ConfigError

    with pytest.raises(ConfigError, match="start 'ramp' needs a road with an on-ramp"):
        SumoSetting(start="ramp")
    with pytest.raises(ConfigError, match="one guarded vehicle"):
        replace(MERGE, start="ramp", guarded=2)
    with pytest.raises(ConfigError, match="'main' or 'ramp'"):
        replace(MERGE, start="shoulder")


def test_sumo_standing_a_guarded_vehicle_on_a_junction_is_undone_and_counted():
    """Moved by position onto the exit junction's internal lane, SUMO stood the guarded vehicle still from 35 m/s
    in one step; the guardian then read speed 0, the traffic behind in the lane its body overlapped ran into it, and
    the judge gave the crash to the guarded vehicle (exit road, IDM traffic, the reckless driver, seed 932). The
    model's speed is now restored after the step, and the step counted."""
    from guardian.adapters.sumo.network import Traffic

    setting = SumoSetting(net=HighwayNet(exit_at=1000.0), traffic=Traffic(car_following="IDM"))
    r = run_episode(setting, "reckless", 932)
    assert r["ego_speed_reset"] >= 1 and r["collisions"] == 0, r["crashes"]


def test_a_jerk_limited_guarded_vehicle_asks_only_for_what_its_actuator_reaches_and_causes_no_collision():
    """The guarded vehicle's actuator follows at most jerk * dt a step (``SumoSetting.jerk``); the guardian decides
    on the rate-limited set. Unguarded, the random driver's jumps are clipped and counted."""
    setting = replace(MERGE, jerk=5.0)
    guarded = summary([run_episode(replace(setting, guarded=g), agent, seed)
                       for agent, g in (("seek", 1), ("random", 3)) for seed in range(2)])
    assert guarded["actuator_clipped"] == 0 and guarded["at_fault"] == 0 and guarded["ego_uncovered"] == 0, guarded
    assert guarded["safety_overrides"] > 0
    unguarded = summary([run_episode(setting, "random", 0, guarded=False)])
    assert unguarded["actuator_clipped"] > 0
    assert summary([run_episode(MERGE, "random", 0)])["actuator_clipped"] is None


def test_a_lag_no_actuator_has_is_refused_by_name():
    from guardian.errors import ConfigError

    with pytest.raises(ConfigError, match="beyond 60 s"):
        SumoSetting(lag=100.0)


def test_a_lagged_guarded_vehicle_causes_no_collision_and_its_model_covers_it():
    """The guarded vehicles' actuator follows a command as a 0.5 s lag (``SumoSetting.lag``): no jerk clip, no
    collision at their fault, every step of theirs moved as the model says."""
    setting = replace(MERGE, lag=0.5)
    guarded = summary([run_episode(replace(setting, guarded=g), agent, seed)
                       for agent, g in (("seek", 1), ("reckless", 3)) for seed in range(2)])
    assert guarded["actuator_clipped"] == 0 and guarded["at_fault"] == 0 and guarded["ego_uncovered"] == 0, guarded
    assert guarded["safety_overrides"] > 0
