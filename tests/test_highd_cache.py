"""The columnar cache of parsed recordings and the fast CSV path: the same tables, or an honest miss."""
import json
import os
import shutil
from pathlib import Path

import pandas as pd
import pytest

from guardian.highd.cache import load_recording
from guardian.highd.reader import HighDFormatError, read_recording
from guardian.highd.replay import default_sample, replay

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "i80_sample"
SAMPLES = [default_sample()] + ([REAL] if REAL.is_dir() else [])


def same_recording(a, b) -> None:
    pd.testing.assert_frame_equal(a.tracks, b.tracks, check_exact=True)
    pd.testing.assert_frame_equal(a.tracks_meta, b.tracks_meta, check_exact=True)
    assert {k: str(v) for k, v in a.meta.items()} == {k: str(v) for k, v in b.meta.items()}
    assert (a.upper_markings, a.lower_markings) == (b.upper_markings, b.lower_markings)


@pytest.mark.parametrize("folder", SAMPLES, ids=[p.name for p in SAMPLES])
def test_the_fast_reader_and_the_cache_give_the_tables_pandas_gives(folder, tmp_path, monkeypatch):
    import guardian.highd.reader as reader
    from guardian.highd.schema import FILES

    for kind, schema in FILES.items():  # clean files take the fast path
        path = folder / f"01_{kind}.csv"
        assert reader._read_clean_csv(path, schema) is not None, kind
    fresh = read_recording(folder, 1)
    monkeypatch.setattr(reader, "_read_clean_csv", lambda *a: None)  # pandas only, as before
    same_recording(fresh, read_recording(folder, 1))
    monkeypatch.undo()
    first, hit1 = load_recording(folder, 1, cache_dir=tmp_path)
    second, hit2 = load_recording(folder, 1, cache_dir=tmp_path)
    assert (hit1, hit2) == (False, True)
    same_recording(first, fresh)
    same_recording(second, fresh)


def test_an_edited_file_misses_and_a_foreign_entry_is_refused(tmp_path, capsys):
    data = tmp_path / "data"
    shutil.copytree(default_sample(), data)
    cache = tmp_path / "cache"
    rec, _ = load_recording(data, 1, cache_dir=cache)
    tracks = data / "01_tracks.csv"
    lines = tracks.read_text().splitlines(keepends=True)
    header, row = lines[0].split(","), lines[1].split(",")
    col = header.index("xVelocity")
    row[col] = str(float(row[col]) + 0.5)
    tracks.write_text(lines[0] + ",".join(row) + "".join(lines[2:]))
    edited, hit = load_recording(data, 1, cache_dir=cache)
    assert not hit and edited.tracks["xVelocity"].iloc[0] == pytest.approx(rec.tracks["xVelocity"].iloc[0] + 0.5)
    (entry,) = [p for p in cache.iterdir() if json.loads((p / "entry.json").read_text())["request"]["sources"]
                ["tracks"]["mtime_ns"] == os.stat(tracks).st_mtime_ns]
    stored = json.loads((entry / "entry.json").read_text())
    stored["request"]["code"] = "someone else's"
    (entry / "entry.json").write_text(json.dumps(stored))
    again, hit = load_recording(data, 1, cache_dir=cache)
    assert not hit and "refusing the HighD cache entry" in capsys.readouterr().err
    same_recording(again, edited)


def test_a_bad_file_is_reported_as_before_and_never_cached(tmp_path):
    data = tmp_path / "data"
    shutil.copytree(default_sample(), data)
    tracks = data / "01_tracks.csv"
    lines = tracks.read_text().splitlines(keepends=True)
    row = lines[3].split(",")
    row[2] = "abc"
    tracks.write_text("".join(lines[:3]) + ",".join(row) + "".join(lines[4:]))
    with pytest.raises(HighDFormatError, match=r"line 4, column .*'abc' is not a number"):
        load_recording(data, 1, cache_dir=tmp_path / "cache")
    assert not any((tmp_path / "cache").glob("*/entry.json"))


def test_a_second_replay_reads_the_cache_and_says_the_same(tmp_path):
    first = replay(cache_dir=tmp_path)
    second = replay(cache_dir=tmp_path)
    assert (first["cache"]["hits"], second["cache"]["hits"]) == (0, 1)
    for r in (first, second):
        r.pop("cache"), r.pop("timings"), r.pop("seconds")
    assert first == second


@pytest.mark.parametrize("folder", SAMPLES, ids=[p.name for p in SAMPLES])
def test_the_cached_itha_view_is_the_converted_recording(folder, tmp_path):
    """A repeated replay skips conversion too: the stored view equals to_itha of a fresh read."""
    import numpy as np

    from guardian.highd.cache import load_itha_view
    from guardian.highd.convert import to_itha

    fresh = to_itha(read_recording(folder, 1))
    first, ids1, hit1 = load_itha_view(folder, 1, cache_dir=tmp_path)
    second, ids2, hit2 = load_itha_view(folder, 1, cache_dir=tmp_path)
    assert (hit1, hit2) == (False, True) and np.array_equal(ids1, ids2)
    for view in (first, second):
        assert view.frame_rate == fresh.frame_rate and view.recording == fresh.recording
        for k in ("vehicle", "frame", "direction", "lane", "v", "h", "vL", "u", "d"):
            a, b = getattr(view, k), getattr(fresh, k)
            assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), k
        assert len(view.lane_changes) == len(fresh.lane_changes) > 0
        for x, y in zip(view.lane_changes, fresh.lane_changes):
            for f in x.__dataclass_fields__:
                assert np.array_equal(np.asarray(getattr(x, f)), np.asarray(getattr(y, f))), f


def test_a_view_with_a_missing_array_is_refused_and_rebuilt(tmp_path, capsys):
    """The view is a folder of .npy files; one missing (a crash mid-copy, a hand edit) refuses the
    whole entry with a message and reads the CSV files again, never a partial view."""
    import numpy as np

    from guardian.highd.cache import load_itha_view

    folder = SAMPLES[0]
    load_itha_view(folder, 1, cache_dir=tmp_path)
    views = list(tmp_path.glob("*/itha-*"))
    assert len(views) == 1 and views[0].is_dir()
    (views[0] / "v.npy").unlink()
    data, _, hit = load_itha_view(folder, 1, cache_dir=tmp_path)
    assert not hit and "refusing the HighD cache entry" in capsys.readouterr().err
    again, _, hit = load_itha_view(folder, 1, cache_dir=tmp_path)
    assert hit and np.array_equal(again.v, data.v)
