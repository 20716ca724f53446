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
    assert set(data) == {"name", "paper_name", "state", "pieces", "params"} and data["paper_name"] == "C_c"
    assert main(["rcis", "export", "nope", "--out", str(out), "--cache-dir", str(cache_dir)]) == 2
    paper = tmp_path / "paper.json"
    assert main(["rcis", "export", "C_c", "--out", str(paper), "--cache-dir", str(cache_dir)]) == 0
    assert json.loads(paper.read_text()) == data  # the paper's name and the long one are the same set
    assert library.region("C_a") is library.region("aggressive")


def test_rollout_json(library, cache_dir, capsys):
    code, data = run_json(capsys, ["rollout", "--intention", "aggressive", "--agent", "bad", "--episodes", "2",
                                   "--seed", "4", "--env-config", "duration=6", "--json", "--cache-dir",
                                   str(cache_dir)])
    assert code == 0
    for key in ("episodes", "steps", "safety_violations", "override_steps",
                "mean_steps_to_identify_intention", "identified_fraction"):
        assert key in data
    assert data["episodes"] == 2 and data["safety_violations"] == 0


def test_rollout_rejects_zero_episodes(library, cache_dir, capsys):
    assert main(["rollout", "--episodes", "0", "--cache-dir", str(cache_dir)]) == 2
    assert "--episodes" in capsys.readouterr().err


def test_itha_highway_json(tmp_path, capsys):
    code, data = run_json(capsys, ["itha", "highway", "--runs", "2", "--steps", "40", "--seed", "1", "--json",
                                   "--cache-dir", str(tmp_path), "--rerun", str(tmp_path / "hw.rrd")])
    assert code == 0
    for oa in ("trivial", "ordered"):
        assert {"distance_mean", "unsafe_steps", "lane_changes"} <= set(data[oa])
        assert data[oa]["unsafe_steps"] == 0
    from guardian.recording.rerun import read_entities, read_texts
    ents = read_entities(tmp_path / "hw.rrd")
    for e in ("/road/lanes", "/road/cars", "/road/ego", "/ego/trigger", "/verdicts/left", "/verdicts/right"):
        assert ents.get(e, 0) > 0, (e, sorted(ents))
    assert set(read_texts(tmp_path / "hw.rrd", "/ego/trigger")) <= {"stay", "left", "right"}


def test_itha_processors_json(capsys):
    code, data = run_json(capsys, ["itha", "processors", "--runs", "3", "--steps", "20", "--json"])
    assert code == 0
    for est in ("trivial", "under", "ordered"):
        assert {"accepted_jobs_mean", "violations_mean"} <= set(data[est])


def test_itha_rejects_bad_counts(capsys):
    assert main(["itha", "processors", "--runs", "0"]) == 2
    assert "--runs" in capsys.readouterr().err


def test_rollout_highway_env_json(tmp_path, capsys):
    code, data = run_json(capsys, ["rollout", "--env", "highway-fast-v0", "--agent", "reckless", "--episodes", "1",
                                   "--seed", "2", "--json", "--rerun", str(tmp_path / "he.rrd")])
    assert code == 0
    assert {"episodes", "steps", "collisions", "ego_at_fault_collisions", "override_steps"} <= set(data)
    assert data["ego_at_fault_collisions"] == 0
    from guardian.recording.rerun import read_entities, read_texts
    ents = read_entities(tmp_path / "he.rrd")
    assert ents.get("/road/ego", 0) == data["steps"]
    overrides = read_texts(tmp_path / "he.rrd", "/events/override")
    assert overrides and all("episode 0" in t for t in overrides)


def test_rollout_env_errors(capsys):
    assert main(["rollout", "--env", "nope-v0"]) == 2
    assert "unknown environment 'nope-v0'" in capsys.readouterr().err
    assert main(["rollout", "--env", "highway-v0", "--intention", "aggressive"]) == 2
    assert "--intention applies to the overtake scenarios" in capsys.readouterr().err
    assert main(["rollout", "--traffic", "3"]) == 2  # the two-car env has no traffic
    assert "two cars alone" in capsys.readouterr().err
    assert main(["rollout", "--agent", "all", "--rerun", "x.rrd"]) == 2
    assert "--rerun records one run" in capsys.readouterr().err
    assert main(["rollout", "--env", "highway-v0", "--algo", "DQN"]) == 2
    assert "--algo" in capsys.readouterr().err


def test_highd_generate_and_replay_json(tmp_path, capsys):
    code, data = run_json(capsys, ["highd", "generate", "--out", str(tmp_path / "d"), "--recordings", "2",
                                   "--minutes", "0.3", "--seed", "1", "--json"])
    assert code == 0 and len(data["files"]) == 6
    code, data = run_json(capsys, ["replay", str(tmp_path / "d"), "--seed", "3", "--workers", "2", "--json",
                                   "--rerun", str(tmp_path / "r.rrd")])
    assert code == 0
    for key in ("data_points", "trajectories", "lane_changes", "disturbance_bounds", "override_rates"):
        assert key in data
    assert set(data["override_rates"]) == {"self_safety", "responsibility_trivial", "responsibility_ordered",
                                           "responsibility_trivial_no_input", "responsibility_ordered_no_input",
                                           "rss_longitudinal", "rss_longitudinal_calibrated", "rss_cut_in",
                                           "rss_cut_in_calibrated"}
    from guardian.recording.rerun import read_entities
    ents = read_entities(tmp_path / "r.rrd")
    assert ents.get("/road/vehicles", 0) > 100 and ents.get("/road/markings", 0) == 1


def test_replay_refuses_malformed_data_with_exit_2(tmp_path, capsys):
    assert main(["highd", "generate", "--out", str(tmp_path), "--minutes", "0.2"]) == 0
    capsys.readouterr()
    path = tmp_path / "01_tracks.csv"
    lines = path.read_text().splitlines()
    lines[5] = lines[5].replace(",", ",,", 1)
    path.write_text("\n".join(lines) + "\n")
    assert main(["replay", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "01_tracks.csv" in err and "line" in err
    assert main(["replay", str(tmp_path / "nowhere")]) == 2
    assert "no such file or folder" in capsys.readouterr().err


def test_rollout_highway_overtake_json_rerun_and_video(traffic_library, cache_dir, tmp_path, capsys):
    from guardian.recording.rerun import read_entities, read_texts

    rrd, video = tmp_path / "run.rrd", tmp_path / "video"
    code, data = run_json(capsys, ["rollout", "--env", "guardian/HighwayOvertake-v0", "--intention", "aggressive",
                                   "--agent", "random", "--episodes", "1", "--seed", "2", "--traffic", "3",
                                   "--rerun", str(rrd), "--video", str(video), "--json", "--iterations", "3",
                                   "--cache-dir", str(cache_dir)])
    assert code == 0
    for key in ("episodes", "steps", "collisions", "ego_at_fault_collisions", "override_steps", "safety_violations",
                "model_violation_steps", "conflict_steps", "wrong_identifications",
                "mean_steps_to_identify_intention", "traffic_model_worst"):
        assert key in data
    assert data["intention"] == "aggressive" and data["model_violation_steps"] == 0
    entities = read_entities(rrd)
    for e in ("/road/ego", "/road/lead", "/road/traffic", "/intention/valid_count", "/road/lanes"):
        assert entities.get(e, 0) > 0, e
    assert any("valid intentions" in t for t in read_texts(rrd, "/intention/log"))
    if data["override_steps"]:
        assert read_texts(rrd, "/events/override")
    assert list(video.rglob("*.mp4"))
    from rerun.chunk import RrdReader
    assert len(list(RrdReader(str(rrd)).blueprints())) == 1


def test_rollout_env_refuses_what_it_cannot_run(library, cache_dir, capsys):
    base = ["rollout", "--episodes", "1", "--cache-dir", str(cache_dir)]
    assert main(base + ["--env", "nowhere-v0"]) == 2
    road = ["rollout", "--episodes", "1", "--env", "highway-v0"]  # no set library there: --cache-dir is refused
    assert main(road + ["--agent", "nobody"]) == 2
    assert main(road + ["--agent", "mpc"]) == 2
    assert main(base + ["--env", "guardian/HighwayOvertake-v0", "--agent", "mpc", "--action", "meta"]) == 2
    assert main(base + ["--env", "guardian/HighwayOvertake-v0", "--traffic", "-1"]) == 2
    err = capsys.readouterr().err
    assert "nowhere-v0" in err and "nobody" in err and "continuous actions" in err and "--traffic" in err


def test_ego_speed_min_reaches_the_sets_and_the_env(tmp_path, capsys):
    import pytest

    code, data = run_json(capsys, ["rollout", "--env", "guardian/HighwayOvertake-v0", "--agent", "idle",
                                   "--episodes", "1", "--ego-speed-min", "0", "--iterations", "0",
                                   "--cache-dir", str(tmp_path), "--json"])
    assert code == 0 and data["safety_violations"] == 0
    from guardian.cli import build_parser
    from guardian.cli.common import load_library

    args = build_parser().parse_args(["rcis", "certify", "--ego-speed-min", "0", "--iterations", "0",
                                      "--cache-dir", str(tmp_path)])
    assert load_library(args).params.v_ex_bounds == (0.0, 36.0)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["rcis", "build", "--ego-speed-min", "40"])
    assert "--ego-speed-min must be in [0, 36)" in capsys.readouterr().err
