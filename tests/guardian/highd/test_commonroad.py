"""CommonRoad scenarios to HighD recordings: scenarios written by commonroad-io's own writer convert, read and
replay; what cannot be mapped is refused naming the file and the element."""
import json

import numpy as np
import pandas as pd
import pytest

from commonroad.common.common_scenario import Location
from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile
from commonroad.common.util import FileFormat
from commonroad.geometry.obstacle_shapes.rect_obstacle_shape import RectObstacleShape
from commonroad.planning.planning_problem import PlanningProblemSet
from commonroad.prediction.prediction import TrajectoryPrediction
from commonroad.scenario.lanelet import Lanelet, LaneletNetwork
from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType
from commonroad.scenario.scenario import Scenario, ScenarioID, Tag
from commonroad.scenario.state import InitialState, KSState
from commonroad.scenario.trajectory import Trajectory

from guardian.cli import main
from guardian.errors import HighDFormatError
from guardian.highd.commonroad import convert_commonroad
from guardian.highd.reader import read_recording

WIDTH = 3.5


def _rotate(points, angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.asarray(points, dtype=float) @ np.array([[c, s], [-s, c]])


def _lanelet(lid, lane, angle, left, right, opposite=False):
    xs = np.linspace(0.0, 400.0, 9)
    top = -WIDTH * (lane - 1)
    lv, rv = np.stack([xs, np.full(9, top)], 1), np.stack([xs, np.full(9, top - WIDTH)], 1)
    lv, rv = _rotate(lv, angle), _rotate(rv, angle)
    return Lanelet(lv, (lv + rv) / 2, rv, lid, adjacent_left=left, adjacent_left_same_direction=left and not opposite,
                   adjacent_right=right, adjacent_right_same_direction=True if right else None)


def _vehicle(oid, x0, y0, v, angle, steps=30, vy=0.0, kind=ObstacleType.CAR, length=4.5, step=0.1):
    shape = RectObstacleShape(1.8, length)
    pos = [_rotate([[x0 + v * step * k, y0 + vy * step * k]], angle)[0] for k in range(steps)]
    heading = angle + np.arctan2(vy, v)
    speed = float(np.hypot(v, vy))
    states = [KSState(time_step=k, position=pos[k], orientation=heading, velocity=speed, steering_angle=0.0)
              for k in range(1, steps)]
    init = InitialState(time_step=0, position=pos[0], orientation=heading, velocity=speed, acceleration=0.0,
                        yaw_rate=0.0, slip_angle=0.0)
    return DynamicObstacle(oid, kind, shape, init, TrajectoryPrediction(Trajectory(1, states), shape))


def _scenario(path, angle=0.0, vehicles=None, dt=0.1, opposite=False):
    net = LaneletNetwork.create_from_lanelet_list([_lanelet(1, 1, angle, None, 2), _lanelet(2, 2, angle, 1, 3),
                                                   _lanelet(3, 3, angle, 2, None, opposite)])
    sc = Scenario(dt, ScenarioID(country_id="ZAM", map_name="Guardian", map_id=1))
    sc.add_objects(net)
    if vehicles is None:   # two cars in lane 2, one moving over from lane 1 to lane 2
        vehicles = [_vehicle(10, 50.0, -5.25, 20.0, angle), _vehicle(11, 80.0, -5.25, 18.0, angle),
                    _vehicle(12, 30.0, -1.75, 25.0, angle, vy=-1.2)]
    sc.add_objects(vehicles)
    CommonRoadFileWriter(sc, PlanningProblemSet(), "guardian tests", "-", "hand-built", tags={Tag.HIGHWAY},
                         location=Location(), file_format=FileFormat.XML).write_to_file(
        str(path), OverwriteExistingFile.ALWAYS)
    return path


def _tracks(out):
    return pd.read_csv(out / "01_tracks.csv")


def test_a_scenario_converts_with_lanes_neighbours_and_lane_changes(tmp_path):
    report = convert_commonroad(_scenario(tmp_path / "s.xml"), tmp_path / "out")
    assert (report["frame_rate"], report["lanes"], report["vehicles"], report["rows"]) == (10, 3, 3, 90)
    t = _tracks(tmp_path / "out").set_index(["frame", "id"])
    assert t.loc[(0, 10), "laneId"] == t.loc[(0, 11), "laneId"] == 4 + 2
    assert t.loc[(0, 10), "precedingId"] == 11 and t.loc[(0, 11), "followingId"] == 10
    assert t.loc[(0, 10), "dhw"] == pytest.approx(30.0)            # front to front
    assert t.loc[(0, 10), "x"] == pytest.approx(50.0 - 4.5 / 2)     # the rear of a right-moving box
    lanes = t.xs(12, level="id")["laneId"]
    assert lanes.iloc[0] == 5 and lanes.iloc[-1] == 6 and (lanes.diff().fillna(0) != 0).sum() == 1
    meta = pd.read_csv(tmp_path / "out" / "01_recordingMeta.csv")
    assert meta["lowerLaneMarkings"][0] == "20.00;23.50;27.00;30.50"
    rec = read_recording(tmp_path / "out", 1)
    assert rec.frame_rate == 10


def test_the_conversion_does_not_depend_on_how_the_map_is_turned(tmp_path):
    """The same road and traffic turned by 0.7 rad (a map not aligned with x) give the same recording."""
    convert_commonroad(_scenario(tmp_path / "a.xml"), tmp_path / "a")
    convert_commonroad(_scenario(tmp_path / "b.xml", angle=0.7), tmp_path / "b")
    a, b = _tracks(tmp_path / "a"), _tracks(tmp_path / "b")
    cols = ["frame", "id", "laneId", "precedingId", "followingId"]
    assert a[cols].equals(b[cols])
    for c in ("x", "y", "xVelocity", "dhw"):
        assert np.allclose(a[c], b[c], atol=0.011), c   # 2-decimal rounding and the file's 4-decimal positions


def test_states_off_the_lanelets_are_dropped_and_counted(tmp_path):
    """A car that starts 10 m beside the road and comes onto it keeps its frames on the road; the ones off it
    are counted, never written."""
    cars = [_vehicle(10, 50.0, -5.25, 20.0, 0.0),
            _vehicle(20, 10.0, -14.0, 20.0, 0.0, vy=20.0)]   # from 14 m right of lane 1's top: on the road at k >= 3
    report = convert_commonroad(_scenario(tmp_path / "s.xml", vehicles=cars), tmp_path / "out")
    t = _tracks(tmp_path / "out")
    assert report["states_on_no_lanelet"] == 30 - int((t["id"] == 20).sum()) > 0
    assert report["rows"] == len(t)


@pytest.mark.parametrize("kind, what", [("opposite", "lanelet 3 has lanelet 2 beside it in the opposite direction"),
                                        ("pedestrian", "dynamic obstacle 30: type PEDESTRIAN"),
                                        ("time step", "timeStepSize 0.03 s is not 1/n s"),
                                        ("empty", "no dynamic obstacle")])
def test_what_cannot_be_mapped_is_refused_naming_the_file_and_element(tmp_path, kind, what):
    path = tmp_path / f"{kind.replace(' ', '_')}.xml"
    if kind == "opposite":
        _scenario(path, opposite=True)
    elif kind == "pedestrian":
        _scenario(path, vehicles=[_vehicle(10, 50.0, -5.25, 20.0, 0.0),
                                  _vehicle(30, 60.0, -1.75, 1.0, 0.0, kind=ObstacleType.PEDESTRIAN)])
    elif kind == "time step":
        _scenario(path, dt=0.03)
    else:
        _scenario(path, vehicles=[])
    with pytest.raises(HighDFormatError) as err:
        convert_commonroad(path, tmp_path / "out")
    assert str(path) in str(err.value) and what in str(err.value)


def test_the_time_step_is_checked_against_the_motion(tmp_path):
    """A file that declares 0.1 s while its vehicles move as if a step were 0.2 s (as published highD-derived files
    do) is refused naming both; converted with the motion's step it gives 5 Hz; a step given that fits neither is
    refused too."""
    cars = [_vehicle(10 + k, 40.0 * k, -5.25, 20.0, 0.0, step=0.2) for k in range(3)]
    path = _scenario(tmp_path / "s.xml", vehicles=cars)
    with pytest.raises(HighDFormatError, match=r"timeStepSize 0.1 s, but the vehicles move as if a step were 0.2 s"):
        convert_commonroad(path, tmp_path / "out")
    report = convert_commonroad(path, tmp_path / "out", time_step=0.2)
    assert report["frame_rate"] == 5 and report["time_step"] == {"declared": 0.1, "used": 0.2, "motion": 0.2}
    assert pd.read_csv(tmp_path / "out" / "01_recordingMeta.csv")["frameRate"][0] == 5
    with pytest.raises(HighDFormatError, match="given 0.5 s.*the step given does not fit either"):
        convert_commonroad(path, tmp_path / "out", time_step=0.5)


def test_a_folder_converts_through_the_command_and_replays(tmp_path, capsys):
    src = tmp_path / "scenarios"
    src.mkdir()
    _scenario(src / "a.xml")
    _scenario(src / "b.xml", angle=0.3)
    assert main(["data", "convert", "commonroad", str(src), "--out", str(tmp_path / "out"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [r["files"][0].split("/")[-1] for r in result["recordings"]] == ["01_recordingMeta.csv",
                                                                            "02_recordingMeta.csv"]
    assert main(["replay", str(tmp_path / "out"), "--json"]) == 0
    replayed = json.loads(capsys.readouterr().out)
    assert len(replayed["recordings"]) == 2 and replayed["lane_changes"] == 2
    assert main(["data", "convert", "commonroad", str(tmp_path / "out" / "01_tracks.csv"), "--out",
                 str(tmp_path / "x")]) == 2
    assert "01_tracks.csv: not a CommonRoad scenario" in capsys.readouterr().err


def test_a_rate_of_no_lane_change_is_none_not_zero(tmp_path, capsys):
    """Recorded traffic in which nobody changes lanes has no responsibility rate: the replay says so (None,
    printed "-") rather than 0 %, which would read as a lane change judged and passed."""
    cars = [_vehicle(10 + k, 20.0 + 30.0 * (k // 3), -1.75 - WIDTH * (k % 3), 20.0, 0.0, steps=60) for k in range(15)]
    convert_commonroad(_scenario(tmp_path / "s.xml", vehicles=cars), tmp_path / "out")
    assert main(["replay", str(tmp_path / "out"), "--json", "--no-cache"]) == 0
    result = json.loads(capsys.readouterr().out)
    rates = result["override_rates"]
    assert result["lane_changes"] == 0 and result["test_data_points"] > 0
    assert rates["responsibility_trivial"] is None and rates["responsibility_ordered"] is None
    assert rates["rss_cut_in"] is None and isinstance(rates["self_safety"], float)
    assert main(["replay", str(tmp_path / "out"), "--no-cache"]) == 0
    assert "trivial -, ordered -" in capsys.readouterr().out
