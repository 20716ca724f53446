"""A hand-built recording through the command line (issue 47): a lane change counted by its recorded input, not by
"some input of U would do", and standstill rows with a slightly negative speed counted, never judged safe."""
import datetime as dt
import json

import numpy as np
import pandas as pd
import pytest

from guardian.cli import main
from guardian.highd.trajectories import neighbours, write_highd

N = 10   # vehicles; the 80/20 split with seed 0 holds out vehicles 5 and 8 of recording 1


def _recording(out, gap: float, creep: float):
    """The ego (held out) moves at 30 m/s from lane 1 into lane 2, ``gap`` m behind a car at 25 m/s, keeping its
    speed (recorded input 0); another held-out car stands in lane 3, its speed ``creep`` on every other frame."""
    held_out = list(np.flatnonzero(np.random.default_rng([0, 1]).uniform(size=N) < 0.2) + 1)
    ego, standing = held_out[:2]
    lead, *fillers = [v for v in range(1, N + 1) if v not in held_out]
    rows = []

    def add(v, frame, front, lane, speed):
        rows.append(dict(vehicle=v, frame=frame, front=front, lateral=3.5 * lane - 1.75, length=4.5, width=1.8,
                         vclass="Car", speed=speed, accel=0.0, lane=lane))

    for k in range(1, 23):
        add(ego, k, 100.0 + 3.0 * k, 1 if k <= 20 else 2, 30.0)
    for k in range(1, 41):
        add(lead, k, 160.0 + gap + 4.5 + 2.5 * (k - 20), 2, 25.0)
        for i, v in enumerate(fillers):   # far ahead, for the training data
            add(v, k, 1000.0 + 40.0 * i + 2.0 * k, 3, 20.0)
        add(standing, k, 20.0, 3, creep if k % 2 else 0.0)
    t = neighbours(pd.DataFrame(rows).sort_values(["vehicle", "frame"]).reset_index(drop=True))
    write_highd(t, out, 3, 10, dt.datetime(2026, 1, 1))
    return out


def _replay(path, capsys) -> dict:
    assert main(["replay", str(path), "--json", "--no-cache"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("overapprox", ["trivial", "ordered"])
def test_the_recorded_input_of_a_lane_change_is_judged(tmp_path, capsys, overapprox):
    """4.35 m behind a car 5 m/s slower, braking would have made the entry responsible, but the recorded input
    (0) does not: one override, and no lane change for which no input was responsible (the rule the replay used
    before counted 0 of 1). 5 m behind, the recorded input itself is responsible: no override."""
    close = _replay(_recording(tmp_path / "close", 4.35, 0.0), capsys)
    assert (close["test_lane_changes"], close["disturbance_bounds"]) == (1, [0.0, 0.0])
    assert close["overrides"][f"responsibility_{overapprox}"] == 1
    assert close["overrides"][f"responsibility_{overapprox}_no_input"] == 0
    assert close["override_rates"][f"responsibility_{overapprox}"] == 1.0
    room = _replay(_recording(tmp_path / "room", 5.0, 0.0), capsys)
    assert room["overrides"][f"responsibility_{overapprox}"] == 0


def test_a_slightly_negative_speed_is_an_override_never_judged_safe(tmp_path, capsys):
    """The standing car's 39 points (40 frames) all have a speed of -1 cm/s now or next: each is an override;
    standing at 0 instead, none is."""
    creeping = _replay(_recording(tmp_path / "creep", 5.0, -0.01), capsys)
    still = _replay(_recording(tmp_path / "still", 5.0, 0.0), capsys)
    assert creeping["test_data_points"] == still["test_data_points"]
    assert creeping["overrides"]["self_safety"] - still["overrides"]["self_safety"] == 39


def test_the_rerun_recording_shows_the_lane_change_judged_on_its_recorded_input(tmp_path, capsys):
    """``replay --rerun``: the lane change is listed with its recorded input against the responsible inputs of
    each ρ̂ and drawn amber; a responsible one is listed as such."""
    from guardian.recording.rerun import read_texts

    for gap, verdict in ((4.35, "NOT responsible"), (5.0, "responsible")):
        rrd = tmp_path / f"{gap}.rrd"
        assert main(["replay", str(_recording(tmp_path / str(gap), gap, 0.0)), "--rerun", str(rrd), "--json",
                     "--no-cache"]) == 0
        result = json.loads(capsys.readouterr().out)
        (line,) = read_texts(rrd, "/events/lane_change")
        assert "changes right; recorded input +0.00 m/s^2" in line, line
        assert "trivial: responsible inputs [-6.00, " in line and line.endswith(f"m/s^2, {verdict}"), line
        assert result["rerun"]["lane_changes_not_responsible"] == (verdict != "responsible")


def test_a_frame_step_replays_the_same_traffic_at_a_lower_rate(tmp_path, capsys, monkeypatch):
    """``--frame-step 2`` on a 10 Hz recording: the same vehicles every other frame, dt 0.2 s, the lane change
    still seen; the views at each step are cached apart; a step that does not divide the rate is refused."""
    folder = _recording(tmp_path / "r", 4.35, 0.0)
    monkeypatch.setenv("GUARDIAN_CACHE_DIR", str(tmp_path / "cache"))
    runs = {}
    for step in (1, 2, 2, 1):
        assert main(["replay", str(folder), "--json", "--frame-step", str(step)]) == 0
        r = json.loads(capsys.readouterr().out)
        runs.setdefault(step, []).append(r)
    full, half = runs[1][0], runs[2][0]
    assert (full["dt"], half["dt"]) == (0.1, 0.2) and half["config"]["frame_step"] == 2
    assert half["trajectories"] == full["trajectories"] and half["lane_changes"] == full["lane_changes"] == 1
    assert abs(half["data_points"] - full["data_points"] / 2) <= full["trajectories"]
    assert [r["cache"]["hits"] for r in runs[2]] == [0, 1] and [r["cache"]["hits"] for r in runs[1]] == [0, 1]
    assert runs[2][1]["data_points"] == half["data_points"] and runs[1][1]["data_points"] == full["data_points"]
    assert main(["replay", str(folder), "--frame-step", "3", "--no-cache"]) == 2
    assert "a frame step of 3 does not divide its frame rate 10 Hz" in capsys.readouterr().err
