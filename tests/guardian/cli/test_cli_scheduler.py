"""``--scheduler`` of ``guardian falsify`` and ``guardian replay``: an address where no Dask scheduler
answers is refused with one line naming the address and the reason (exit 2), before any work starts,
and ``--workers`` beside it is refused; a scheduler that answers runs the work.

The connect timeout is Dask's own ``distributed.comm.timeouts.connect`` (30 s by default); these tests
set it to 1 s (``DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT`` for a subprocess, ``dask.config.set`` here).
"""
import os
import socket
import subprocess
import sys

import dask
import pytest

from guardian.cli import main


@pytest.fixture
def nowhere():
    """A TCP address nothing listens on (a port the system just handed out, closed again)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"tcp://127.0.0.1:{port}"


@pytest.fixture
def short_timeout():
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        yield


COMMANDS = [["replay"], ["falsify", "--only", "roads", "--agent", "merge"]]


@pytest.mark.parametrize("argv", COMMANDS, ids=["replay", "falsify"])
def test_an_unreachable_scheduler_is_one_line_and_exit_2(argv, nowhere, tmp_path):
    env = {**os.environ, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "1s", "GUARDIAN_CACHE_DIR": str(tmp_path)}
    r = subprocess.run([sys.executable, "-m", "guardian.cli", *argv, "--scheduler", nowhere], capture_output=True,
                       text=True, env=env, timeout=60)
    assert r.returncode == 2 and r.stdout == "", r.stderr
    assert r.stderr == (f"guardian {argv[0]}: --scheduler: cannot reach the Dask scheduler at {nowhere} "
                        f"(Timed out trying to connect to {nowhere} after 1 s)\n")


@pytest.mark.parametrize("address", ["nonsense", "foo://127.0.0.1:1"])
@pytest.mark.parametrize("argv", COMMANDS, ids=["replay", "falsify"])
def test_a_malformed_scheduler_address_is_refused(argv, address, capsys):
    assert main([*argv, "--scheduler", address]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"cannot reach the Dask scheduler at {address} (" in err, err


def test_falsify_connects_before_it_builds_the_sets(nowhere, short_timeout, monkeypatch, capsys):
    """The overtake cells need the RCIS library (a minute when the cache is cold): not built for nothing."""
    import guardian.evaluation.campaign

    def started(*args, **kwargs):
        raise AssertionError("work started before the scheduler answered")

    monkeypatch.setattr(guardian.evaluation.campaign, "_library", started)
    monkeypatch.setattr(guardian.evaluation.campaign, "_chunk", started)
    assert main(["falsify", "--only", "overtake", "--agent", "seek", "--scheduler", nowhere]) == 2
    assert nowhere in capsys.readouterr().err


def test_replay_connects_before_it_reads_a_recording(nowhere, short_timeout, monkeypatch, capsys):
    import guardian.highd.replay

    def started(*args, **kwargs):
        raise AssertionError("work started before the scheduler answered")

    monkeypatch.setattr(guardian.highd.replay, "process_recording", started)
    assert main(["replay", "--scheduler", nowhere]) == 2
    assert nowhere in capsys.readouterr().err


def test_the_library_functions_raise_a_scheduler_error(nowhere, short_timeout):
    from guardian.errors import SchedulerError
    from guardian.evaluation.campaign import matrix, run_campaign
    from guardian.highd.replay import replay

    with pytest.raises(SchedulerError, match="cannot reach the Dask scheduler") as info:
        replay(scheduler=nowhere)
    assert info.value.address == nowhere and isinstance(info.value, ConnectionError)
    with pytest.raises(SchedulerError):
        run_campaign(matrix(only="roads")[:1], 1, scheduler=nowhere)


def test_falsify_runs_on_a_scheduler_that_answers():
    import distributed

    from guardian.evaluation.campaign import matrix, run_campaign

    cells = [c for c in matrix(only="roads") if c.env == "merge-v0" and c.agent in ("merge", "reckless")]
    local = run_campaign(cells, 1, seed=4, workers=1)
    with distributed.LocalCluster(n_workers=1, processes=False, dashboard_address=None) as cluster:
        dsk = run_campaign(cells, 1, seed=4, workers=None, scheduler=cluster.scheduler_address)
    assert dsk["scheduler"] == cluster.scheduler_address and dsk["workers"] is None
    for table in ("totals", "by_env", "by_agent", "failures"):
        assert dsk[table] == local[table]
