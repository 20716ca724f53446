"""The command-line contract: sub-commands and the JSON keys scripts depend on."""
import json

from guardian.cli import main


def run_json(capsys, argv):
    code = main(argv)
    out = capsys.readouterr().out
    return code, json.loads(out)


def test_rcis_build_json(library, cache_dir, capsys):
    code, data = run_json(capsys, ["rcis", "build", "--json", "--cache-dir", str(cache_dir)])
    assert code == 0
    assert set(data["sets"]) == {"bounded_velocity", "aggressive", "cautious"}
    for s in data["sets"].values():
        assert {"iterations", "converged", "pieces", "seconds"} <= set(s)
        assert s["from_cache"]


def test_rcis_certify_json(library, cache_dir, capsys):
    code, data = run_json(capsys, ["rcis", "certify", "--samples", "50", "--json", "--cache-dir", str(cache_dir)])
    assert code == 0
    for s in data["sets"].values():
        assert s["samples"] == 50 and s["counterexamples"] == 0


def test_rcis_export_writes_the_documented_shape(library, cache_dir, tmp_path, capsys):
    out = tmp_path / "c.json"
    assert main(["rcis", "export", "cautious", "--out", str(out), "--cache-dir", str(cache_dir)]) == 0
    data = json.loads(out.read_text())
    assert set(data) == {"name", "state", "pieces", "params"}
    assert main(["rcis", "export", "nope", "--out", str(out), "--cache-dir", str(cache_dir)]) == 2


def test_rollout_json(library, cache_dir, capsys):
    code, data = run_json(capsys, ["rollout", "--scenario", "overtake", "--intention", "aggressive",
                                   "--driver", "bad", "--episodes", "2", "--seed", "4", "--max-steps", "60",
                                   "--json", "--cache-dir", str(cache_dir)])
    assert code == 0
    for key in ("episodes", "steps", "safety_violations", "override_steps",
                "mean_steps_to_identify_intention", "identified_fraction"):
        assert key in data
    assert data["episodes"] == 2 and data["safety_violations"] == 0


def test_rollout_rejects_zero_episodes(library, cache_dir, capsys):
    assert main(["rollout", "--episodes", "0", "--cache-dir", str(cache_dir)]) == 2
    assert "--episodes" in capsys.readouterr().err
