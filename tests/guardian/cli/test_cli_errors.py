"""A command line that never throws at the user.

Every expected failure (an invalid value, inverted bounds, an output path that cannot be written, a
missing file, an option that does not apply) is one line on stderr naming the option or the file,
exit 2, before any work starts (the work functions are replaced by ones that fail the test if called).
Ctrl-C (SIGINT to the process group, as a terminal sends it) and SIGTERM by PID stop ``rcis build``
and ``rcis certify`` at once, with one line, keeping the cache entries already computed and leaving no
half-written entry and no worker behind. Human output shows the figures the JSON has.
"""
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from guardian.cli import main

WORK = ["guardian.cli.sets.load_library", "guardian.highd.replay.replay", "guardian.highd.generate.generate",
        "guardian.highd.ngsim.convert_ngsim", "itha.highway_experiment.highway_experiment",
        "itha.processors.processors_experiment", "guardian.evaluation.episodes.run_episodes", "guardian.evaluation.campaign.run_campaign"]


@pytest.fixture
def no_work(monkeypatch):
    def started(*args, **kwargs):
        raise AssertionError("work started before the command line was checked")

    import guardian.evaluation.rollouts  # noqa: F401 (binds run_episodes when imported: first imported under the
    #                                       patch, it would keep the stub for every later test of this process)
    for target in WORK:
        monkeypatch.setattr(target, started)


@pytest.fixture
def paths(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    ngsim = tmp_path / "trajectories.csv"
    ngsim.write_text("Vehicle_ID\n")
    return {"FILE": str(a_file), "UNDER_FILE": str(a_file / "out"), "DIR": str(tmp_path),
            "NGSIM": str(ngsim), "MISSING": str(tmp_path / "missing"), "PROC": "/proc/guardian-test/out"}


# (argv, what the one line must name)
REFUSED = [
    # invalid values
    ("rcis build --workers 0", "--workers"), ("rcis build --workers -1", "--workers"),
    ("rcis certify --workers 0", "--workers"), ("rcis build --iterations 0", "--iterations"),
    ("rcis build --iterations -2", "--iterations"), ("rcis certify --samples 0", "--samples"),
    ("rcis export C_c --out {DIR}/c.json --workers -1", "--workers"),
    ("replay --u-min 3 --u-max -3", "--u-min"), ("replay --u-min 1", "--u-min"), ("replay --u-max -1", "--u-max"),
    ("replay --workers 0", "--workers"), ("replay --h-min -1", "--h-min"), ("replay --v-max nan", "--v-max"),
    ("itha processors --keep-jobs -1", "--keep-jobs"), ("itha processors --runs 0", "--runs"),
    ("itha highway --steps 0", "--steps"), ("highd generate --out {DIR} --minutes 0", "--minutes"),
    ("highd generate --out {DIR} --recordings 0", "--recordings"),
    ("highd generate --out {DIR} --frame-rate 0", "--frame-rate"),
    ("data convert ngsim {NGSIM} --out {DIR} --main-lanes 0", "--main-lanes"),
    # seeds are whole numbers >= 0 (numpy's generators refuse negative ones)
    ("rcis certify --samples 10 --seed -1", "argument --seed: must be a whole number >= 0"),
    ("itha highway --runs 1 --steps 1 --seed -1 --set closed-form", "argument --seed: must be a whole number >= 0"),
    ("itha processors --runs 1 --steps 1 --seed -1", "argument --seed: must be a whole number >= 0"),
    ("highd generate --out {DIR} --seed -1", "argument --seed: must be a whole number >= 0"),
    ("replay --seed -1", "argument --seed: must be a whole number >= 0"),
    ("falsify --only roads --seed -1", "argument --seed: must be a whole number >= 0"),
    ("itha processors --seed 1.5", "argument --seed: must be a whole number >= 0"),
    # output paths that cannot be written
    ("rcis export C_c --out {UNDER_FILE}", "--out"), ("rcis export C_c --out {DIR}", "--out"),
    ("rcis export C_c --out {PROC}", "--out"), ("rcis plot --out {FILE}", "--out"),
    ("rcis plot --out {UNDER_FILE}", "--out"), ("highd generate --out {UNDER_FILE}", "--out"),
    ("highd generate --out {PROC}", "--out"), ("data convert ngsim {NGSIM} --out {UNDER_FILE}", "--out"),
    ("replay --rerun {UNDER_FILE}", "--rerun"), ("replay --rerun {DIR}", "--rerun"),
    ("itha highway --rerun {PROC}", "--rerun"),
    # rcis build's only job is to fill the cache: a cache folder it cannot write is refused
    ("rcis build --cache-dir {PROC}", "--cache-dir: cannot write into /proc/guardian-test/out"),
    ("rcis build --cache-dir {FILE}", "--cache-dir"), ("rcis build --cache-dir {UNDER_FILE}", "--cache-dir"),
    ("rcis build --rebuild --cache-dir {PROC}", "--cache-dir"),
    # missing files
    ("replay {MISSING}", "missing"), ("data convert ngsim {MISSING} --out {DIR}", "missing"),
    # options that do not apply
    ("replay --input-bounds data --u-min -3", "--u-min"), ("replay --scheduler tcp://x:1 --workers 2", "--workers"),
    ("falsify --scheduler tcp://x:1 --workers 2", "--workers"), ("falsify --workers 0", "--workers"),
    ("falsify --episodes 0", "--episodes"), ("falsify --agent careful", "--agent"), ("falsify --agent line", "--agent"),
    ("itha highway --set closed-form --cache-dir {DIR}", "--cache-dir"),
    ("itha highway --set closed-form --rebuild", "--rebuild"),
    ("rollout --env merge-v0 --overapprox ordered", "--overapprox"),
    ("rollout --env merge-v0 --traffic 4", "--traffic"),
    ("rollout --env guardian/Merge-v0 --traffic 4", "--traffic"),
    ("rollout --env exit-v0 --controlled 2 --env-config controlled_vehicles=3", "--controlled"),
    ("rollout --env exit-v0 --action meta --env-config action={{\"type\":\"ContinuousAction\"}}", "--action"),
    ("rollout --env exit-v0 --controlled 2 --env-config action={{\"type\":\"ContinuousAction\"}}", "--controlled"),
    ("rollout --env exit-v0 --traffic 4 --env-config vehicles_count=3", "--traffic"),
    ("rollout --env guardian/HighwayOvertake-v0 --traffic 4 --env-config traffic_count=2", "--traffic"),
    ("rollout --env CartPole-v1", "CartPole-v1 is not a highway-env environment"),
    ("rollout --env highway-v0 --seed -1", "--seed"),
    ("rollout --env highway-v0 --rebuild", "--rebuild"), ("rollout --env highway-v0 --iterations 3", "--iterations"),
    ("rollout --env exit-v0 --cache-dir {DIR}", "--cache-dir"), ("rollout --env exit-v0 --workers 1", "--workers"),
    ("rollout --env highway-v0 --no-guardian --safe-start", "--safe-start changes the guardian; it does not"),
    ("rollout --env guardian/Overtake-v0 --jerk 5", "--jerk applies to highway-env's roads"),
    ("rollout --env highway-v0 --jerk 0", "--jerk"), ("rollout --env highway-v0 --jerk inf", "--jerk"),
    ("falsify --jerk 5", "--jerk applies to highway-env's roads"),
    ("rollout --env guardian/Overtake-v0 --lag 0.3", "--lag applies to highway-env's roads"),
    ("rollout --env guardian/Overtake-v0 --jerk 5 --lag 0.3", "--jerk and --lag apply to highway-env's roads"),
    ("rollout --env highway-v0 --lag 0", "--lag"), ("rollout --env highway-v0 --lag nan", "--lag"),
    ("rollout --env highway-v0 --lag 61", "at most 60 s"), ("falsify --only roads --lag 1e9", "at most 60 s"),
    ("falsify --lag 0.3", "--lag applies to highway-env's roads"),
    ("rollout --env guardian/HighwayOvertake-v0 --agent mpc --env-config intention=aggressive", "--intention"),
    ("rollout --env guardian/Overtake-v0 --env-config disturbance=adversarial", "--disturbance"),
    ("rollout --env guardian/HighwayOvertake-v0 --env-config params=1", "'params'"),
    ("rollout --env guardian/HighwayOvertake-v0 --ego-speed-min 16", "--ego-speed-min 0"),
    ("rollout --env guardian/HighwayOvertake-v0 --traffic 4 --env-config traffic_from_behind=6", "traffic_from_behind"),
    # env config values (the key named) and what an env cannot take (the env named)
    ("rollout --env merge-v0 --env-config policy_frequency=0", "policy_frequency"),
    ("rollout --env merge-v0 --env-config policy_frequency=-5", "policy_frequency"),
    ("rollout --env merge-v0 --env-config policy_frequency=abc", "policy_frequency"),
    ("rollout --env merge-v0 --env-config simulation_frequency=0", "simulation_frequency"),
    ("rollout --env exit-v0 --env-config duration=abc", "duration"),
    ("rollout --env exit-v0 --env-config duration=-1", "duration"),
    ("rollout --env exit-v0 --env-config vehicles_count=-1", "vehicles_count"),
    ("rollout --env exit-v0 --env-config lanes_count=0", "lanes_count"),
    ("rollout --env exit-v0 --env-config policy_frequency=10", "policy_frequency"),
    ("rollout --env guardian/Merge-v0 --env-config neighbour_vehicles_connected_lanes=maybe",
     "neighbour_vehicles_connected_lanes"),
    ("rollout --env merge-generic-v0 --controlled 2 --action meta", "merge-generic-v0 has one controlled car"),
    ("rollout --env merge-generic-v0 --action continuous", "merge-generic-v0 fails with ContinuousAction"),
    ("rollout --env merge-v0 --env-config action={{\"type\":\"ContinuousAction\"}}", "merge-v0 fails with"),
]


@pytest.mark.parametrize("argv,names", REFUSED, ids=[a for a, _ in REFUSED])
def test_refused_with_one_line_and_exit_2_before_any_work(argv, names, paths, no_work, capsys):
    code = main(argv.format(**paths).split())
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("guardian ") and names in err, err
    assert "Traceback" not in err


def test_an_unwritable_folder_is_refused_for_a_user_without_rights(tmp_path, no_work, capsys):
    if os.geteuid() == 0:
        pytest.skip("root writes everywhere; the /proc and file-in-the-way cases cover the refusal")
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    assert main(["highd", "generate", "--out", str(locked / "out")]) == 2
    assert "cannot write" in capsys.readouterr().err


def test_rcis_build_refuses_an_unwritable_default_cache_folder(monkeypatch, no_work, capsys):
    monkeypatch.setenv("GUARDIAN_CACHE_DIR", "/proc/guardian-test/cache")
    assert main(["rcis", "build"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "/proc/guardian-test/cache ($GUARDIAN_CACHE_DIR" in err, err


def test_commands_that_only_use_the_cache_go_on_without_a_writable_one(monkeypatch, tmp_path):
    """Only rcis build refuses: the others load the library and may compute it without a cache (one
    warning, docs/engine.md)."""
    class Reached(Exception):
        pass

    def reached(args):
        raise Reached(str(args.cache_dir))

    monkeypatch.setattr("guardian.cli.sets.load_library", reached)
    for argv in (["export", "C_c", "--out", str(tmp_path / "c.json")], ["certify"], ["plot", "--out", str(tmp_path)]):
        with pytest.raises(Reached, match="/proc/guardian-test/cache"):
            main(["rcis", *argv, "--cache-dir", "/proc/guardian-test/cache"])


def test_the_console_script_prints_one_line_too(tmp_path):
    """The installed entry point (not only main()) refuses with one line and exit 2."""
    r = subprocess.run([sys.executable, "-m", "guardian.cli", "rcis", "build", "--workers", "0"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr == "guardian rcis build: argument --workers: must be a whole number >= 1, got '0'\n"


# ---- interrupts ---------------------------------------------------------------------------------------
def _children(pid: int) -> set:
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.add(int(stat.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _interrupt(argv, cache, wait_for, how, signum, keep_stdout=False):
    env = {**os.environ, "GUARDIAN_CACHE_DIR": str(cache), "PYTHONUNBUFFERED": "1"}
    # SIGINT's default action, as at a terminal: a suite started in the background (``cmd &``) ignores SIGINT,
    # and Python then installs no Ctrl-C handler in the children it starts
    proc = subprocess.Popen([sys.executable, "-m", "guardian.cli", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        seen = []
        for line in proc.stderr:
            seen.append(line)
            if wait_for in line:
                break
        assert wait_for in "".join(seen), "".join(seen)
        workers = _children(proc.pid)
        (os.killpg if how == "group" else os.kill)(proc.pid, signum)
        t0 = time.perf_counter()
        out, err = proc.communicate(timeout=20)  # the work itself would take minutes
        stopped = time.perf_counter() - t0
        return proc.returncode, ((out, "".join(seen) + err) if keep_stdout else err), workers, stopped
    finally:
        if proc.poll() is None:  # the test failed: leave nothing running
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _entries_are_whole(cache: Path):
    from rcis.cache import load_region

    names = sorted(p.name for p in cache.iterdir())
    assert not [n for n in names if n.endswith(".tmp") or n.startswith(".")], names
    for path in cache.glob("*.npz"):
        with np.load(path) as z:
            payload = json.loads(str(z["meta"]))["payload"]
        load_region(path, payload)  # raises on a partial or corrupt entry
    return names


@pytest.mark.parametrize("how,signum,code", [("group", signal.SIGINT, 130), ("pid", signal.SIGTERM, 143)],
                         ids=["ctrl-c", "sigterm-by-pid"])
def test_rcis_build_stops_at_once_and_keeps_the_finished_sets(tmp_path, how, signum, code):
    cache = tmp_path / "cache"
    rc, err, workers, stopped = _interrupt(["rcis", "build", "--iterations", "9", "--workers", "2"], cache,
                                           "[rcis cautious] iteration 1:", how, signum)
    name = signal.Signals(signum).name
    assert rc == code and "Traceback" not in err
    assert err.strip().splitlines()[-1] == f"guardian rcis build: interrupted by {name}; finished sets are kept in the cache"
    assert stopped < 10, stopped  # generous: measured 0.1-0.2 s; the build would go on for minutes
    names = _entries_are_whole(cache)
    assert any(n.startswith("bounded_velocity-") for n in names)  # finished before the signal: kept
    assert workers and not any(_alive(w) for w in workers)  # the two workers are gone


@pytest.mark.parametrize("how,signum,code", [("group", signal.SIGINT, 130), ("pid", signal.SIGTERM, 143)],
                         ids=["ctrl-c", "sigterm-by-pid"])
def test_rcis_certify_stops_at_once(library, cache_dir, tmp_path, how, signum, code):
    rc, err, workers, stopped = _interrupt(["rcis", "certify", "--samples", "200000", "--cache-dir", str(cache_dir)],
                                           tmp_path, "[certify", how, signum)
    assert rc == code and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith(f"guardian rcis certify: interrupted by {signal.Signals(signum).name}")
    assert stopped < 10, stopped
    assert workers and not any(_alive(w) for w in workers)


def test_an_interrupted_campaign_prints_the_table_of_the_episodes_that_finished(tmp_path):
    """SIGTERM after the first episodes: the tables of what finished (with their failures) are printed, then the
    one line and exit 143; nothing of the finished work is thrown away."""
    rc, err, _, _ = _interrupt(["falsify", "--only", "roads", "--agent", "random", "--episodes", "2", "--workers", "1"],
                               tmp_path, "[falsify] 2/", "pid", signal.SIGTERM, keep_stdout=True)
    out, err = err
    assert rc == 143 and "Traceback" not in err
    assert err.strip().splitlines()[-1] == "guardian falsify: interrupted by SIGTERM"
    first = out.splitlines()[0]
    assert "(interrupted: the episodes that finished)" in first and not first.startswith("0 episodes"), out
    assert "campaign  episodes" in out


def _fail_cautious(name, params, settings, seed, quiet):
    """``_compute`` in the workers: the aggressive set is computed, the cautious one fails later."""
    from intention import library

    if name == "cautious":
        time.sleep(1.0)
        raise RuntimeError("the cautious set failed")
    return library._COMPUTE(name, params, settings, seed, quiet)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_set_is_stored_as_soon_as_it_is_computed(tmp_path, monkeypatch, workers):
    """If the build stops (interrupt, error) after one intention set is done, that set is in the cache."""
    from intention import library
    from intention.library import LibrarySettings, build_library, replace_settings

    monkeypatch.setattr(library, "_COMPUTE", library._compute, raising=False)
    monkeypatch.setattr(library, "_compute", _fail_cautious)
    with pytest.raises(RuntimeError, match="cautious"):
        build_library(settings=replace_settings(LibrarySettings(), intention_max_iterations=0), cache_dir=tmp_path,
                      quiet=True, workers=workers)
    names = _entries_are_whole(tmp_path)
    assert [n.split("-")[0] for n in names] == ["aggressive", "bounded_velocity"]


# ---- human output ----------------------------------------------------------------------------------------
def _figures(x):
    if isinstance(x, bool) or x is None:
        return
    if isinstance(x, (int, float)):
        yield x
    elif isinstance(x, dict):
        for v in x.values():
            yield from _figures(v)
    elif isinstance(x, list):
        for v in x:
            yield from _figures(v)


def _shown(v, text: str) -> bool:
    if isinstance(v, int):
        return str(v) in text
    if not math.isfinite(v):
        return True
    forms = {f"{v:g}", f"{v:.1f}", f"{v:.2f}", f"{v:.3f}", f"{100 * v:.2f}", str(v)}
    return any(f in text for f in forms)


def _human_and_json(argv, capsys):
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert main(argv + ["--json"]) == 0
    return text, json.loads(capsys.readouterr().out)


def test_replay_sensitivity_without_json_prints_every_rate(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("GUARDIAN_CACHE_DIR", str(tmp_path))
    text, data = _human_and_json(["replay", "--sensitivity", "--contexts", "--seed", "1"], capsys)
    assert "sensitivity" in text and "RSS" in text
    for row in data["sensitivity"]:
        assert row["variant"] in text
    data.pop("timings"), data.pop("seconds")  # differ between the two runs
    missing = [v for v in _figures(data) if not _shown(v, text)]
    assert missing == []


@pytest.mark.parametrize("argv", [["itha", "processors", "--runs", "2", "--steps", "10"],
                                  ["itha", "highway", "--runs", "2", "--steps", "20", "--set", "closed-form"]],
                         ids=["processors", "highway"])
def test_itha_human_output_shows_every_figure(argv, capsys):
    text, data = _human_and_json(argv, capsys)
    data.pop("seconds", None)
    assert [v for v in _figures(data) if not _shown(v, text)] == []


def test_rcis_build_human_output_shows_every_figure(library, cache_dir, capsys):
    text, data = _human_and_json(["rcis", "build", "--cache-dir", str(cache_dir)], capsys)
    data.pop("seconds")
    for s in data["sets"].values():
        s.pop("seconds")  # a cached set's build time is shown, but rounded to 0.1 s
    assert [v for v in _figures(data) if not _shown(v, text)] == []


@pytest.mark.parametrize("guard", [[], ["--no-guardian"]], ids=["guarded", "unguarded"])
def test_rollout_human_output_shows_every_figure_of_every_car_and_crash(guard, capsys):
    argv = ["rollout", "--env", "guardian/Merge-v0", "--agent", "reckless", "--action", "meta", "--controlled", "2",
            "--env-config", "traffic=hard", "--env-config", "duration=6", "--env-config", "policy_frequency=5",
            "--episodes", "2", "--seed", "3", *guard]
    text, data = _human_and_json(argv, capsys)
    assert len(data["agents"]) == 2 and all(f"car {i}: " in text for i in range(2))
    if guard:
        assert data["crashes"] and all(f"car {c['car']} " in text for c in data["crashes"])
    assert "action=meta" in text.splitlines()[0]
    assert [v for v in _figures(data) if not _shown(v, text)] == []


def test_falsify_human_output_shows_every_figure(monkeypatch, capsys):
    import guardian.evaluation.campaign

    counts = ("episodes", "steps", "collisions", "ego_at_fault_collisions", "starts_outside",
              "collisions_after_outside_starts", "ego_at_fault_after_outside_starts", "safety_violations",
              "failsafe_steps", "override_steps", "conflict_steps", "unchecked_entries", "reversing_steps",
              "unsupervised_steps", "traffic_reversing_uncovered_steps", "episodes_cut", "actuator_clipped_steps",
              "exceptions")
    row = lambda group, base: dict({k: base + 7 * i for i, k in enumerate(counts)}, group=group)
    result = {"episodes": 1001, "seconds": 12.5, "workers": 1, "scheduler": None, "cells": 3, "episodes_per_cell": 1,
              "totals": row("all", 1001), "by_env": [row("exit-v0 meta", 2001)], "by_agent": [row("hold", 3001)],
              "by_setting": [row("own config", 4001), row("density 2.5", 5001)],
              "failures": [{"kind": "unchecked_entries", "count": 6007, "cell": "own config",
                            "replay": {"env": "exit-v0", "agent": "hold", "action": "meta", "env_config": {},
                                       "episodes": 1, "seed": 8008}}]}
    monkeypatch.setattr(guardian.evaluation.campaign, "run_campaign", lambda *a, **k: result)
    argv = ["falsify", "--only", "roads", "--agent", "merge"]
    assert main(argv) == 1  # the counts above break the promise
    text = capsys.readouterr().out
    assert main(argv + ["--json"]) == 1
    data = json.loads(capsys.readouterr().out)
    data.pop("seconds")
    assert [v for v in _figures(data) if not _shown(v, text)] == []
    assert "density 2.5" in text and "count=6007" in text


def test_serve_refuses_a_busy_port_before_it_loads_the_sets(monkeypatch, capsys):
    """A port another process holds is refused in one line, at once: the sets (seconds to load, minutes to build)
    are never touched."""
    import socket

    import guardian.cli.serve

    def never(*_):
        raise AssertionError("the sets were loaded before the port was checked")

    monkeypatch.setattr(guardian.cli.serve, "load_library", never)
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen(1)
        port = held.getsockname()[1]
        assert main(["serve", "--port", str(port)]) == 2
    assert f"cannot listen on 127.0.0.1:{port}" in capsys.readouterr().err


def test_an_interrupted_rollout_leaves_at_once_and_its_recording_is_whole(tmp_path):
    """Ctrl-C during a rollout: the one line, exit 130, no traceback, out well before the interpreter would have
    torn down its modules (1-2 s under load), and the rerun recording written so far reads back."""
    from guardian.recording.rerun import read_texts

    rrd = tmp_path / "run.rrd"
    rc, err, _, stopped = _interrupt(["rollout", "--env", "highway-fast-v0", "--episodes", "20", "--rerun", str(rrd)],
                                     tmp_path / "cache", "[rollout highway-fast-v0 random] 2/", "group", signal.SIGINT)
    assert rc == 130 and "Traceback" not in err
    assert err.strip().splitlines()[-1] == "guardian rollout: interrupted by SIGINT"
    assert stopped < 10, stopped
    assert read_texts(rrd, "/events/episode")[:2] == ["episode 0 starts", "episode 1 starts"]
