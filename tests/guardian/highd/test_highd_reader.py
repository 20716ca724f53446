"""HighD-format reader: a generated recording round-trips; every malformed case names file, line, column."""
import shutil

import numpy as np
import pandas as pd
import pytest

from guardian.highd.generate import TrafficParams, generate
from guardian.errors import HighDFormatError
from guardian.highd.files import recording_ids
from guardian.highd.reader import read_recording
from guardian.highd.schema import TRACKS, TRACKS_META
from project import SHARED_DATA


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    out = tmp_path_factory.mktemp("highd")
    generate(out, 1, 0.4, seed=3, prm=TrafficParams(warmup=30.0))
    return out


def test_generated_recording_round_trips(generated):
    assert recording_ids(generated) == [1]
    rec = read_recording(generated, 1)
    assert list(rec.tracks.columns) == list(TRACKS) and list(rec.tracks_meta.columns) == list(TRACKS_META)
    assert rec.frame_rate == 25 and len(rec.upper_markings) == 4 and len(rec.lower_markings) == 4
    t, m = rec.tracks, rec.tracks_meta.set_index("id")
    assert rec.meta["numVehicles"] == len(m) == t["id"].nunique()
    assert (m["numFrames"] == t.groupby("id").size()).all()
    # direction 1 moves left with negative velocities in the upper lanes, direction 2 the opposite
    d = m["drivingDirection"].reindex(t["id"]).to_numpy()
    assert (t["xVelocity"].to_numpy()[d == 1] < 0).all() and (t["xVelocity"].to_numpy()[d == 2] > 0).all()
    assert set(t["laneId"][d == 1]) <= {2, 3, 4} and set(t["laneId"][d == 2]) <= {6, 7, 8}
    # the preceding vehicle is in the same lane, ahead in the direction of travel, and dhw is front to front
    idx = t.set_index(["id", "frame"])
    rows = t[t["precedingId"] > 0].head(500)
    lead = idx.loc[list(zip(rows["precedingId"], rows["frame"]))]
    assert (lead["laneId"].to_numpy() == rows["laneId"].to_numpy()).all()
    sign = np.sign(rows["xVelocity"].to_numpy())
    front = np.where(sign > 0, rows["x"] + rows["width"], rows["x"])
    lead_front = np.where(sign > 0, lead["x"] + lead["width"], lead["x"])
    assert np.allclose(np.abs(lead_front - front), rows["dhw"], atol=0.03)
    changes = t.groupby("id")["laneId"].apply(lambda s: int((s.diff().fillna(0) != 0).sum()))
    assert (m["numLaneChanges"] == changes.reindex(m.index)).all()


def _copy(generated, tmp_path):
    for p in generated.iterdir():
        shutil.copy(p, tmp_path / p.name)
    return tmp_path


def _edit(folder, kind, fn):
    path = folder / f"01_{kind}.csv"
    df = pd.read_csv(path, dtype=str, keep_default_na=False)
    df = fn(df)
    df.to_csv(path, index=False)
    return path


CASES = {
    "missing column": ("tracks", lambda df: df.drop(columns=["ttc"]), r"01_tracks\.csv: missing columns \['ttc'\]"),
    "extra column": ("tracks", lambda df: df.assign(speed="1"), r"unexpected columns \['speed'\]"),
    "wrong type": ("tracks", lambda df: df.assign(xVelocity=df["xVelocity"].mask(df.index == 7, "fast")),
                   r"01_tracks\.csv: line 9, column 'xVelocity': 'fast' is not a number"),
    "non-integer id": ("tracks", lambda df: df.assign(laneId=df["laneId"].mask(df.index == 3, "2.5")),
                       r"line 5, column 'laneId': 2\.5 is not an integer"),
    "NaN": ("tracks", lambda df: df.assign(y=df["y"].mask(df.index == 11, "")),
            r"01_tracks\.csv: line 13, column 'y': missing value \(NaN\)"),
    "infinite": ("tracks", lambda df: df.assign(dhw=df["dhw"].mask(df.index == 2, "inf")),
                 r"line 4, column 'dhw': non-finite value"),
    "duplicated (id, frame)": ("tracks", lambda df: pd.concat([df.iloc[:6], df.iloc[[5]], df.iloc[6:]]),
                               r"\(id \d+, frame \d+\) appears on lines 7 and 8"),
    "frame skip": ("tracks", lambda df: df.drop(index=4), r"track \d+ jumps from frame \d+ to frame \d+"),
    "unknown id": ("tracks", lambda df: df.assign(id=df["id"].mask(df.index == 0, "9999")),
                   r"line 2, column 'id': vehicle 9999 is not in 01_tracksMeta\.csv"),
    "lane outside markings": ("tracks", lambda df: df.assign(laneId=df["laneId"].mask(df.index == 0, "12")),
                              r"line 2, column 'laneId': lane 12 cannot hold vehicle"),
    "lane of the other direction": ("tracks", lambda df: df.assign(
        laneId=df["laneId"].mask(df.index == 0, "7" if df["laneId"].iloc[0] in ("2", "3", "4") else "3")),
        r"line 2, column 'laneId': lane \d cannot hold vehicle \d+ \(direction \d\)"),
    "bad markings": ("recordingMeta", lambda df: df.assign(upperLaneMarkings="6.0;x;9.0"),
                     r"column 'upperLaneMarkings': '6\.0;x;9\.0' is not a ';'-separated list"),
    "meta duplicate id": ("tracksMeta", lambda df: pd.concat([df, df.iloc[[0]]]), r"01_tracksMeta\.csv: id \d+ appears"),
    "meta count mismatch": ("tracksMeta", lambda df: df.assign(numFrames=df["numFrames"].mask(df.index == 0, "3")),
                            r"numFrames 3 / initialFrame \d+ disagree"),
    "bad direction": ("tracksMeta", lambda df: df.assign(drivingDirection=df["drivingDirection"].mask(df.index == 1, "3")),
                      r"line 3, column 'drivingDirection': 3 is not 1 or 2"),
    "recording id mismatch": ("recordingMeta", lambda df: df.assign(id="2"), r"does not match the file name"),
    "month as a number": ("recordingMeta", lambda df: df.assign(month="4.2005"),
                          r"line 2, column 'month': '4\.2005' is not MM\.YYYY"),
    "month 13": ("recordingMeta", lambda df: df.assign(month="13.2017"), r"column 'month': '13\.2017'"),
    "week day": ("recordingMeta", lambda df: df.assign(weekDay="Tuesday"), r"column 'weekDay': 'Tuesday' is not Mon"),
    "start time": ("recordingMeta", lambda df: df.assign(startTime="8h38"), r"column 'startTime': '8h38' is not HH:MM"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_malformed_input_is_refused_with_its_place(generated, tmp_path, case):
    kind, fn, pattern = CASES[case]
    folder = _copy(generated, tmp_path)
    _edit(folder, kind, fn)
    with pytest.raises(HighDFormatError, match=pattern):
        read_recording(folder, 1)


def test_missing_file_and_empty_folder(generated, tmp_path):
    folder = _copy(generated, tmp_path)
    (folder / "01_tracksMeta.csv").unlink()
    with pytest.raises(HighDFormatError, match=r"01_tracksMeta\.csv: file is missing"):
        read_recording(folder, 1)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(HighDFormatError, match="no NN_recordingMeta.csv"):
        recording_ids(empty)


def test_published_recording_meta_formats_load(generated, tmp_path):
    """month ``MM.YYYY``, weekDay ``Tue``, startTime ``08:38``, speedLimit -1: as HighD publishes them."""
    folder = _copy(generated, tmp_path)
    _edit(folder, "recordingMeta", lambda df: df.assign(month="09.2017", weekDay="Tue", startTime="08:38",
                                                        speedLimit="-1.00"))
    rec = read_recording(folder, 1)
    assert rec.meta["month"] == "09.2017" and rec.meta["startTime"] == "08:38"


def test_the_generator_writes_the_published_month_format(generated):
    assert read_recording(generated, 1).meta["month"] == "04.2026"


def test_the_real_i80_sample_replays():
    """Real traffic (NGSIM I-80 in HighD format, ../shared/data): 10 Hz, one carriageway, published meta."""

    from guardian.highd.replay import ReplayConfig, replay

    folder = SHARED_DATA / "i80_sample"
    if not folder.is_dir():
        pytest.fail(f"the real sample is missing: {folder}")
    rec = read_recording(folder, 1)
    assert rec.frame_rate == 10 and rec.meta["month"] == "04.2005" and rec.meta["weekDay"] == "Wed"
    result = replay(folder, ReplayConfig(seed=0))
    assert result["data_points"] > 50_000 and result["trajectories"] == 700
    assert set(result["override_rates"]) >= {"self_safety", "responsibility_trivial", "responsibility_ordered"}


@pytest.mark.parametrize("kind", ["recordingMeta", "tracksMeta", "tracks"])
def test_two_files_for_one_recording_are_refused_naming_both(generated, tmp_path, kind):
    folder = _copy(generated, tmp_path)
    shutil.copy(folder / f"01_{kind}.csv", folder / f"1_{kind}.csv")
    with pytest.raises(HighDFormatError, match=rf"01_{kind}\.csv and 1_{kind}\.csv are both recording 1's {kind}"):
        recording_ids(folder)


def test_a_recording_named_without_leading_zero_reads_and_is_listed(generated, tmp_path):
    from guardian.highd.replay import ReplayConfig, replay

    folder = _copy(generated, tmp_path)
    for p in list(folder.iterdir()):
        p.rename(folder / p.name.replace("01_", "1_"))
    assert recording_ids(folder) == [1]
    r = replay(folder, ReplayConfig(seed=0))
    assert len(r["recordings"]) == 1 and r["recordings"][0]["id"] == 1
    assert r["recordings"][0]["tracks"].endswith("1_tracks.csv")


def _write_bytes(folder, kind, fn):
    path = folder / f"01_{kind}.csv"
    path.write_bytes(fn(path.read_bytes()))
    return path


def _insert_after_line(data: bytes, n: int, extra: bytes) -> bytes:
    at = _nth_line_start(data, n + 1)
    return data[:at] + extra + data[at:]


def _set_first_field(data: bytes, n: int, value: bytes) -> bytes:
    """Physical line n's first field replaced by ``value``."""
    at = _nth_line_start(data, n)
    return data[:at] + value + data[data.index(b",", at):]


def _nth_line_start(data: bytes, n: int) -> int:
    pos = 0
    for _ in range(n - 1):
        pos = data.index(b"\n", pos) + 1
    return pos


BYTE_CASES = {
    "undecodable byte": ("tracks", lambda d: d[:_nth_line_start(d, 5)] + b"\xff" + d[_nth_line_start(d, 5) + 1:],
                         r"01_tracks\.csv: line 5, column 'frame': byte 0xff is not UTF-8"),
    "empty file": ("recordingMeta", lambda d: b"", r"01_recordingMeta\.csv: line 1: the file is empty"),
    "header only": ("tracksMeta", lambda d: d[:d.index(b"\n") + 1], r"01_tracksMeta\.csv: line 1: a header but no data"),
    "blank lines above a bad row": ("tracks", lambda d: _set_first_field(_insert_after_line(d, 1, b"\n\n"), 6, b"X"),
                                    r"01_tracks\.csv: line 6, column 'frame': 'X' is not an integer"),
    "a quoted newline above a bad row": ("tracksMeta", lambda d: _set_first_field(
        d.replace(b",Car,", b',"Ca\nr",', 1), 5, b"X"), r"01_tracksMeta\.csv: line 5, column 'id': 'X' is not an integer"),
    "an id too large for an integer": ("tracksMeta", lambda d: d[:_nth_line_start(d, 2)] + b"1e20" + d[
        _nth_line_start(d, 2) + len(d[_nth_line_start(d, 2):].split(b",", 1)[0]):],
        r"01_tracksMeta\.csv: line 2, column 'id': 1e\+20 is not an integer of at most"),
}


@pytest.mark.parametrize("case", sorted(BYTE_CASES))
def test_every_byte_is_accounted_for(generated, tmp_path, case):
    kind, fn, pattern = BYTE_CASES[case]
    folder = _copy(generated, tmp_path)
    _write_bytes(folder, kind, fn)
    with pytest.raises(HighDFormatError, match=pattern):
        read_recording(folder, 1)


def test_a_byte_order_mark_is_read_as_utf8(generated, tmp_path):
    folder = _copy(generated, tmp_path)
    for kind in ("recordingMeta", "tracksMeta", "tracks"):
        _write_bytes(folder, kind, lambda d: b"\xef\xbb\xbf" + d)
    assert read_recording(folder, 1).tracks.columns[0] == "frame"


PLAUSIBILITY_CASES = {
    "frame rate 1e12": ("recordingMeta", lambda df: df.assign(frameRate="1000000000000"),
                        r"01_recordingMeta\.csv: line 2, column 'frameRate': 1000000000000 Hz is outside \[1, 100\]"),
    "x and y headers swapped": ("tracks", lambda df: df.rename(columns={"x": "y", "y": "x"})[list(df.columns)],
                                r"01_tracks\.csv: line \d+, column 'y': the box centre .* lies outside direction"),
    "a speed of 300 m/s": ("tracks", lambda df: df.assign(xVelocity=df["xVelocity"].mask(df.index == 4, "300")),
                           r"line 6, column 'xVelocity': \|300\| m/s exceeds 70 m/s"),
    "an acceleration of 50 m/s^2": ("tracks", lambda df: df.assign(
        xAcceleration=df["xAcceleration"].mask(df.index == 2, "-50")), r"line 4, column 'xAcceleration'"),
}


@pytest.mark.parametrize("case", sorted(PLAUSIBILITY_CASES))
def test_implausible_recordings_are_refused_naming_the_rule(generated, tmp_path, case):
    kind, fn, pattern = PLAUSIBILITY_CASES[case]
    folder = _copy(generated, tmp_path)
    _edit(folder, kind, fn)
    with pytest.raises(HighDFormatError, match=pattern) as err:
        read_recording(folder, 1)
    assert "--no-plausibility" in str(err.value)
    if case != "x and y headers swapped":  # swapped axes also break the lanes' structure
        assert read_recording(folder, 1, plausibility=False).id == 1


def test_a_vehicle_without_frames_is_refused(generated, tmp_path):
    folder = _copy(generated, tmp_path)
    _edit(folder, "tracksMeta", lambda df: pd.concat([df, df.iloc[[0]].assign(id="9999", numFrames="0")]))
    with pytest.raises(HighDFormatError, match=r"01_tracksMeta\.csv: line \d+, column 'numFrames': 0; a vehicle has"):
        read_recording(folder, 1)


def test_no_plausibility_is_named_in_the_replay_output(generated, tmp_path, capsys):
    import json

    from guardian.cli import main

    folder = _copy(generated, tmp_path)
    _edit(folder, "tracks", lambda df: df.assign(xVelocity=df["xVelocity"].mask(df.index == 4, "300")))
    assert main(["replay", str(folder), "--json"]) == 2
    assert "exceeds 70 m/s" in capsys.readouterr().err
    assert main(["replay", str(folder), "--no-plausibility", "--v-max", "400", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["plausibility"] is False


def test_frames_may_start_anywhere(generated, tmp_path):
    folder = _copy(generated, tmp_path)
    _edit(folder, "tracks", lambda df: df.assign(frame=(df["frame"].astype(int) + 5000).astype(str)))
    _edit(folder, "tracksMeta", lambda df: df.assign(initialFrame=(df["initialFrame"].astype(int) + 5000).astype(str),
                                                     finalFrame=(df["finalFrame"].astype(int) + 5000).astype(str)))
    assert read_recording(folder, 1).tracks["frame"].min() > 5000


def test_a_folder_is_listed_once_while_it_does_not_change(generated, tmp_path, monkeypatch):
    """A replay asks for every recording's files: the folder is listed once, not once per recording (which made a
    replay of 1,000 recordings quadratic); a file added is seen at once."""
    import os
    from pathlib import Path

    from guardian.highd import files

    for name in os.listdir(generated):
        shutil.copy(generated / name, tmp_path / name)
    listed = []
    real = Path.iterdir
    monkeypatch.setattr(Path, "iterdir", lambda self: listed.append(self) or real(self))
    first = files.recording_files(tmp_path)
    assert all(files.recording_files(tmp_path) is first for _ in range(50)) and len(listed) == 1
    shutil.copy(tmp_path / "01_tracks.csv", tmp_path / "07_tracks.csv")
    os.utime(tmp_path, ns=(0, os.stat(tmp_path).st_mtime_ns + 1))   # whatever the clock's grain: the folder changed
    assert 7 in files.recording_files(tmp_path) and len(listed) == 2
