"""NGSIM import: a fixture written from the published column definitions converts and replays."""
import json

import numpy as np
import pytest

from guardian.cli import main
from guardian.highd.ngsim import convert_ngsim
from guardian.errors import HighDFormatError
from guardian.highd.reader import read_recording

T0 = 1113433135300  # ms: 2005-04-13 23:38:55 UTC


def _row(vid, frame, lane, y_ft, v_fts, preceding=0, following=0, headway_ft=0.0, cls=2):
    x_ft = 6.0 + 12.0 * (lane - 1)  # lane centres 12 ft apart, lane 1 leftmost
    thw = headway_ft / v_fts if preceding else 9999.99
    return (f"{vid} {frame} 40 {T0 + 100 * frame} {x_ft:.3f} {y_ft:.3f} 6042000.0 2133000.0 15.0 6.0 {cls} "
            f"{v_fts:.2f} 0.00 {lane} {preceding} {following} {headway_ft:.2f} {thw:.2f}")


def _fixture(path, extra_rows=()):
    rows = []
    for f in range(1, 41):
        lead_y, follow_y = 200.0 + 60.0 * f / 10, 120.0 + 58.0 * f / 10
        rows.append(_row(2, f, 2, lead_y, 60.0, following=1))
        rows.append(_row(1, f, 2, follow_y, 58.0, preceding=2, headway_ft=lead_y - follow_y))
        lane3 = 7 if f <= 10 else 6  # vehicle 3 comes from the on-ramp (lane 7) into lane 6
        rows.append(_row(3, f, lane3, 100.0 + 50.0 * f / 10, 50.0, cls=3))
    path.write_text("\n".join(list(rows) + list(extra_rows)) + "\n")
    return path


def test_a_ngsim_file_converts_reads_and_replays(tmp_path, capsys):
    src = _fixture(tmp_path / "trajectories-0400-0415.txt")
    out = tmp_path / "highd"
    report = convert_ngsim(src, out, main_lanes=6)
    assert report["vehicles"] == 3 and report["ramp_rows_dropped"] == 10
    rec = read_recording(out, 1)
    assert rec.frame_rate == 10 and rec.meta["month"] == "04.2005" and rec.meta["weekDay"] == "Wed"
    t = rec.tracks.set_index(["id", "frame"])
    # units, boxes and neighbours as documented: x is the rear of a right-moving box, lengths in metres
    assert np.isclose(t.loc[(1, 5), "width"], 15 * 0.3048, atol=0.01)
    assert np.isclose(t.loc[(1, 5), "x"] + t.loc[(1, 5), "width"], (120 + 58 * 0.5) * 0.3048, atol=0.01)
    assert t.loc[(1, 5), "precedingId"] == 2 and t.loc[(2, 5), "followingId"] == 1
    assert np.isclose(t.loc[(1, 5), "xVelocity"], 58 * 0.3048, atol=0.01)
    assert t.loc[(1, 5), "laneId"] == 6 and t.loc[(3, 11), "laneId"] == 10
    assert rec.tracks_meta.set_index("id").loc[3, "initialFrame"] == 11  # the ramp part is dropped
    assert main(["replay", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["trajectories"] == 3


@pytest.mark.parametrize("bad,pattern", [
    ("1 41 40 x 6.0 100.0 0 0 15 6 2 50 0 2 0 0 0 9999.99", r"line 121, column 'Global_Time': 'x' is not a number"),
    ("1 41 40 0 6.0 100.0 0 0 15 6 2 50 0 2.5 0 0 0 9999.99", r"line 121, column 'Lane_ID': '2\.5' is not an integer"),
    ("1 41 40 0 6.0 100.0", r"line 121: 6 fields, expected 18"),
    ("1 40 40 0 6.0 100.0 0 0 15 6 2 50 0 2 0 0 0 9999.99", r"\(Vehicle_ID 1, Frame_ID 40\) appears on lines"),
])
def test_malformed_ngsim_rows_are_refused_with_their_place(tmp_path, bad, pattern):
    src = _fixture(tmp_path / "t.txt", [bad])
    with pytest.raises(HighDFormatError, match=pattern):
        convert_ngsim(src, tmp_path / "out", main_lanes=6)
    assert main(["data", "convert", "ngsim", str(src), "--out", str(tmp_path / "o"), "--main-lanes", "6"]) == 2


def test_the_csv_export_with_a_header_and_extra_columns_converts(tmp_path):
    txt = _fixture(tmp_path / "t.txt")
    header = ("Vehicle_ID,Frame_ID,Total_Frames,Global_Time,Local_X,Local_Y,Global_X,Global_Y,v_Length,v_Width,"
              "v_Class,v_Vel,v_Acc,Lane_ID,Preceding,Following,Space_Headway,Time_Headway,Location")
    csv = tmp_path / "export.csv"
    csv.write_text(header + "\n" + "\n".join(",".join(line.split()) + ",i-80" for line in
                                             txt.read_text().splitlines()) + "\n")
    report = convert_ngsim(csv, tmp_path / "out", main_lanes=6)
    assert report["ignored_columns"] == ["Location"] and report["vehicles"] == 3


def test_the_command_as_the_issue_writes_it_keeps_every_lane(tmp_path, capsys):
    src = _fixture(tmp_path / "trajectories-0400-0415.txt")
    out = tmp_path / "highd"
    assert main(["data", "convert", "ngsim", str(src), "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["main_lanes"] is None and report["lanes"] == 7 and report["ramp_rows_dropped"] == 0
    assert read_recording(out, 1).tracks_meta.set_index("id").loc[3, "initialFrame"] == 1  # the ramp is a lane
