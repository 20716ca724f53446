"""The set cache heals: corrupt, truncated, foreign or unreadable entries are refused and recomputed,
--rebuild replaces what is there, and a cache folder that cannot be written is warned about, never fatal."""
import pytest

from rcis.cache import entry_path, load_region, save_region, try_load, try_save
from rcis.errors import StaleCacheError
from intention.library import LibrarySettings, build_library, replace_settings
from rcis.polyhedron import Polyhedron
from rcis.region import Region

PAYLOAD = {"set": "test", "params": {"h_min": 10.0}}
FAST = replace_settings(LibrarySettings(), intention_max_iterations=0)


def _region():
    return Region([Polyhedron.from_box([0.0, 0.0], [1.0, 2.0]), Polyhedron.from_box([1.0, 0.0], [3.0, 1.0])], 2)


@pytest.fixture
def entry(tmp_path):
    path = entry_path(tmp_path, "test", PAYLOAD)
    save_region(path, _region(), PAYLOAD, {"iterations": 1})
    return path


def _damage(path, how):
    data = path.read_bytes()
    if how == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif how == "one byte flipped":  # inside an array's stored bytes: a flip in a zip header's spare
        import zipfile                  # fields (a local CRC copy, a timestamp) leaves the data intact

        with zipfile.ZipFile(path) as z:
            member = max(z.infolist(), key=lambda m: m.compress_size)
        h = member.header_offset  # the local header: 30 bytes, then its own name and extra lengths
        start = h + 30 + int.from_bytes(data[h + 26:h + 28], "little") + int.from_bytes(data[h + 28:h + 30], "little")
        i = start + member.compress_size // 2
        path.write_bytes(data[:i] + bytes([data[i] ^ 0xFF]) + data[i + 1:])
    elif how == "empty":
        path.write_bytes(b"")
    elif how == "a folder":
        path.unlink()
        path.mkdir()
    elif how == "not a zip":
        path.write_text("hello")


@pytest.mark.parametrize("how", ["truncated", "one byte flipped", "empty", "a folder", "not a zip"])
def test_a_damaged_entry_is_refused_with_its_name_never_a_traceback(entry, how):
    _damage(entry, how)
    with pytest.raises(StaleCacheError, match=entry.name):
        load_region(entry, PAYLOAD)
    messages = []
    assert try_load(entry, PAYLOAD, log=messages.append) is None
    assert len(messages) == 1 and entry.name in messages[0] and "recomputing" in messages[0]


def test_a_good_entry_round_trips_and_leaves_no_temporary_file(entry):
    region, info = load_region(entry, PAYLOAD)
    assert len(region) == 2 and info == {"iterations": 1}
    assert [p.name for p in entry.parent.iterdir()] == [entry.name]


def test_rebuild_replaces_a_corrupt_entry(tmp_path, capsys):
    lib = build_library(settings=FAST, cache_dir=tmp_path, quiet=True)
    path = entry_path(tmp_path, "bounded_velocity", lib.sets["bounded_velocity"].payload)
    _damage(path, "truncated")
    build_library(settings=FAST, cache_dir=tmp_path, quiet=True, use_cache=False)  # --rebuild
    region, _ = load_region(path, lib.sets["bounded_velocity"].payload)  # healed
    assert len(region) == len(lib.region("bounded_velocity"))
    _damage(path, "one byte flipped")
    again = build_library(settings=FAST, cache_dir=tmp_path, quiet=True)  # refused, recomputed, rewritten
    assert not again.sets["bounded_velocity"].from_cache
    assert "refusing cache entry" in capsys.readouterr().err
    assert build_library(settings=FAST, cache_dir=tmp_path, quiet=True).sets["bounded_velocity"].from_cache


@pytest.mark.parametrize("kind", ["a file", "below a file"])
def test_an_unwritable_cache_folder_warns_once_and_the_product_goes_on(tmp_path, kind):
    blocker = tmp_path / "cache"
    blocker.write_text("not a folder")
    folder = blocker if kind == "a file" else blocker / "sub"
    messages = []
    assert not try_save(entry_path(folder, "test", PAYLOAD), _region(), PAYLOAD, {}, log=messages.append)
    assert not try_save(entry_path(folder, "test2", PAYLOAD), _region(), PAYLOAD, {}, log=messages.append)
    assert len(messages) == 1 and str(folder) in messages[0]
    lib = build_library(settings=FAST, cache_dir=folder / "x", quiet=True)
    assert not lib.sets["bounded_velocity"].from_cache


def test_the_cli_builds_with_a_cache_dir_that_is_a_file(tmp_path, capsys):
    """A command that uses the sets computes them without a cache (one warning); ``rcis build``, whose only
    job is to fill the cache, refuses it before any work (one line, exit 2)."""
    import json

    from guardian.cli import main

    blocker = tmp_path / "f"
    blocker.write_text("x")
    assert main(["rcis", "build", "--iterations", "1", "--cache-dir", str(blocker), "--json"]) == 2
    out = capsys.readouterr()
    assert out.out == "" and out.err.count("\n") == 1 and f"--cache-dir: cannot write into {blocker}" in out.err

    code = main(["rcis", "export", "C_c", "--out", str(tmp_path / "c.json"), "--iterations", "1",
                 "--cache-dir", str(blocker), "--json"])
    out = capsys.readouterr()
    data = json.loads(out.out)  # a result, not a traceback
    assert code == 0 and data["name"] == "cautious" and data["pieces"] > 0
    assert out.err.count("cannot write the cache folder") == 1
