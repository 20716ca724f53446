"""The multi-agent table adds up runs in pieces by seed: every count summed, none dropped."""
import pytest


@pytest.fixture(scope="module")
def bench(benchmark_module):
    return benchmark_module("bench_multiagent")


def _row(episodes, distance, collisions, at_fault, crashes=()):
    return {"n": 2, "density": "easy", "overapprox": "ordered", "episodes": episodes, "distance_per_car": distance,
            "lane_changes": 1, "merges": 1, "on_ramp": 2, "override_steps": 10, "collisions": collisions,
            "at_fault": at_fault, "guarded_pairs": 0, "starts_outside": 0, "failsafe_steps": 3,
            "unchecked_entries": 0, "reversing_uncovered": 0, "crashes": list(crashes), "seconds": 1.0}


def test_pieces_add_up_and_each_crash_keeps_the_seed_that_replays_it(bench):
    a = {"agent": "merge", "action": "meta", "seed": 0, "rows": [_row(2, 100.0, 0, 0)]}
    b = {"agent": "merge", "action": "meta", "seed": 2, "rows": [_row(6, 200.0, 1, 1, [{"episode": 4}])]}
    (row,) = bench.merge([a, b])["rows"]
    assert row["episodes"] == 8 and row["collisions"] == 1 and row["at_fault"] == 1
    assert row["distance_per_car"] == pytest.approx((2 * 100 + 6 * 200) / 8)
    assert row["override_steps"] == 20 and row["failsafe_steps"] == 6 and row["seeds"] == [0, 2]
    assert row["crashes"] == [{"episode": 4, "seed": 2}]


def test_pieces_of_other_runs_or_the_same_seed_are_refused(bench):
    a = {"agent": "merge", "action": "meta", "seed": 0, "rows": [_row(2, 100.0, 0, 0)]}
    with pytest.raises(SystemExit, match="different agents"):
        bench.merge([a, dict(a, agent="random", seed=2)])
    with pytest.raises(SystemExit, match="its own --seed"):
        bench.merge([a, dict(a)])
    other_n = {"agent": "merge", "action": "meta", "seed": 0, "rows": [dict(_row(2, 100.0, 0, 0), n=4)]}
    assert len(bench.merge([a, other_n])["rows"]) == 2  # the same seed in another setting is another piece


@pytest.mark.parametrize("argv, says", [
    (["--n", "1"], "whole number >= 2"), (["--density", "jam"], "invalid choice: 'jam'"),
    (["--agent", "mpc"], "invalid choice: 'mpc'"), (["--episodes", "0"], "whole number >= 1"),
    (["--seed", "-1"], "whole number >= 0")])
def test_options_that_cannot_run_are_refused_before_any_episode(bench, argv, says, capsys):
    with pytest.raises(SystemExit) as stop:
        bench.main(argv)
    assert stop.value.code == 2 and says in capsys.readouterr().err
