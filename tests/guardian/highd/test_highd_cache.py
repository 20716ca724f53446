"""The cached ITHA view of validated recordings and the fast CSV paths: the same data, or an honest miss."""
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from guardian.highd.cache import load_itha_view
from guardian.highd.convert import to_itha
from guardian.errors import HighDFormatError
from guardian.highd.reader import read_recording
from guardian.highd.replay import default_sample, replay
from project import SHARED_DATA

REAL = SHARED_DATA / "i80_sample"
SAMPLES = [default_sample()] + ([REAL] if REAL.is_dir() else [])


def same_recording(a, b) -> None:
    pd.testing.assert_frame_equal(a.tracks, b.tracks, check_exact=True)
    pd.testing.assert_frame_equal(a.tracks_meta, b.tracks_meta, check_exact=True)
    assert {k: str(v) for k, v in a.meta.items()} == {k: str(v) for k, v in b.meta.items()}
    assert (a.upper_markings, a.lower_markings) == (b.upper_markings, b.lower_markings)


@pytest.mark.parametrize("folder", SAMPLES, ids=[p.name for p in SAMPLES])
def test_the_fast_readers_give_the_tables_pandas_gives(folder, monkeypatch):
    import guardian.highd.reader as reader
    from guardian.highd.schema import FILES

    for kind, schema in FILES.items():  # clean files take the fast path
        path = folder / f"01_{kind}.csv"
        assert reader._read_clean_csv(path, schema) is not None, kind
    assert reader.read_numeric_csv(folder / "01_tracks.csv", list(FILES["tracks"])) is not None  # the compiled one
    fresh = read_recording(folder, 1)
    monkeypatch.setattr(reader, "read_numeric_csv", lambda *a: None)  # pyarrow for every file
    same_recording(fresh, read_recording(folder, 1))
    monkeypatch.setattr(reader, "_read_clean_csv", lambda *a: None)  # pandas only, as before
    same_recording(fresh, read_recording(folder, 1))


def same_view(a, b) -> None:
    assert a.frame_rate == b.frame_rate and a.recording == b.recording
    for k in ("vehicle", "frame", "direction", "lane", "v", "h", "vL", "u", "d"):
        x, y = getattr(a, k), getattr(b, k)
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), k
    assert len(a.lane_changes) == len(b.lane_changes)
    for x, y in zip(a.lane_changes, b.lane_changes):
        for f in x.__dataclass_fields__:
            assert np.array_equal(np.asarray(getattr(x, f)), np.asarray(getattr(y, f))), f


def test_an_edited_file_misses_and_a_foreign_entry_is_refused(tmp_path, capsys):
    data = tmp_path / "data"
    shutil.copytree(default_sample(), data)
    cache = tmp_path / "cache"
    view, _, _ = load_itha_view(data, 1, cache_dir=cache)
    tracks = data / "01_tracks.csv"
    lines = tracks.read_text().splitlines(keepends=True)
    header, row = lines[0].split(","), lines[1].split(",")
    col = header.index("xVelocity")
    row[col] = str(float(row[col]) + 0.5)
    tracks.write_text(lines[0] + ",".join(row) + "".join(lines[2:]))
    edited, _, hit = load_itha_view(data, 1, cache_dir=cache)
    assert not hit and abs(edited.v[0]) == pytest.approx(abs(view.v[0]) + 0.5 * np.sign(float(row[col])))
    same_view(edited, to_itha(read_recording(data, 1)))
    (entry,) = [p for p in cache.iterdir() if json.loads((p / "entry.json").read_text())["request"]["sources"]
                ["tracks"]["mtime_ns"] == os.stat(tracks).st_mtime_ns]
    stored = json.loads((entry / "entry.json").read_text())
    stored["request"]["code"] = "someone else's"
    (entry / "entry.json").write_text(json.dumps(stored))
    again, _, hit = load_itha_view(data, 1, cache_dir=cache)
    assert not hit and "refusing the HighD cache entry" in capsys.readouterr().err
    same_view(again, edited)


def test_a_bad_file_is_reported_as_before_and_never_cached(tmp_path):
    data = tmp_path / "data"
    shutil.copytree(default_sample(), data)
    tracks = data / "01_tracks.csv"
    lines = tracks.read_text().splitlines(keepends=True)
    row = lines[3].split(",")
    row[2] = "abc"
    tracks.write_text("".join(lines[:3]) + ",".join(row) + "".join(lines[4:]))
    with pytest.raises(HighDFormatError, match=r"line 4, column .*'abc' is not a number"):
        load_itha_view(data, 1, cache_dir=tmp_path / "cache")
    assert not any((tmp_path / "cache").glob("*/entry.json"))


@pytest.mark.parametrize("module", ["reader.py", "numeric_csv.py", "schema.py", "convert.py", "cache.py"])
def test_the_cache_key_covers_every_module_that_shapes_the_view(module, monkeypatch):
    """Editing the parser, the checks or the conversion must miss the cache, never serve the old view."""
    from guardian.highd import cache

    before = cache.code_version()
    read_bytes = Path.read_bytes
    monkeypatch.setattr(Path, "read_bytes", lambda p: read_bytes(p) + (b"# edited" if p.name == module else b""))
    assert cache.code_version() != before


def test_a_second_replay_reads_the_cache_and_says_the_same(tmp_path):
    first = replay(cache_dir=tmp_path)
    second = replay(cache_dir=tmp_path)
    assert (first["cache"]["hits"], second["cache"]["hits"]) == (0, 1)
    for r in (first, second):
        r.pop("cache"), r.pop("timings"), r.pop("seconds")
    assert first == second


@pytest.mark.parametrize("folder", SAMPLES, ids=[p.name for p in SAMPLES])
def test_the_cached_itha_view_is_the_converted_recording(folder, tmp_path):
    """A repeated replay skips parsing and conversion: the stored view equals to_itha of a fresh read."""
    fresh = to_itha(read_recording(folder, 1))
    first, ids1, hit1 = load_itha_view(folder, 1, cache_dir=tmp_path)
    second, ids2, hit2 = load_itha_view(folder, 1, cache_dir=tmp_path)
    assert (hit1, hit2) == (False, True) and np.array_equal(ids1, ids2)
    assert len(fresh.lane_changes) > 0
    same_view(first, fresh)
    same_view(second, fresh)


def test_a_view_with_a_missing_array_is_refused_and_rebuilt(tmp_path, capsys):
    """The view is a folder of .npy files; one missing (a crash mid-copy, a hand edit) refuses the
    whole entry with a message and reads the CSV files again, never a partial view."""
    folder = SAMPLES[0]
    load_itha_view(folder, 1, cache_dir=tmp_path)
    arrays = list(tmp_path.glob("*/v.npy"))
    assert len(arrays) == 1
    arrays[0].unlink()
    data, _, hit = load_itha_view(folder, 1, cache_dir=tmp_path)
    assert not hit and "refusing the HighD cache entry" in capsys.readouterr().err
    again, _, hit = load_itha_view(folder, 1, cache_dir=tmp_path)
    assert hit and np.array_equal(again.v, data.v)
