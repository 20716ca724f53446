"""The falsification campaign: the matrix the promise is tested on, seeding, replay of a failure."""
import json
import shlex

import pytest

from guardian.cli.rollout import replay_command
from guardian.evaluation.campaign import COUNTED, OVERTAKE_ENV, Campaign, Cell, matrix, run_campaign, run_episode
from project import ROOT


def test_the_matrix_spans_what_the_promise_is_tested_on():
    cells = matrix()
    overtake = [c for c in cells if c.env == OVERTAKE_ENV]
    highway = [c for c in cells if c.env != OVERTAKE_ENV]
    assert {c.agent for c in cells} >= {"random", "reckless", "seek", "brake_check", "oscillate", "hold", "trap"}
    assert {"mpc", "bad"} <= {c.agent for c in overtake if c.action == "continuous"}
    assert {(c.intention, c.disturbance) for c in overtake} == {(i, d) for i in ("aggressive", "cautious")
                                                                for d in ("random", "adversarial")}
    assert {c.traffic for c in overtake} == {0, 4, 8, 12}
    assert {c.config.get("lanes_count", 2) for c in overtake} == {2, 3}
    assert {c.env for c in highway} == {"highway-v0", "highway-fast-v0"}
    assert {c.action for c in cells} == {"continuous", "meta"}
    assert max(c.config.get("vehicles_density", 1) for c in highway) == 2.5
    assert {c.config.get("policy_frequency", 1) for c in highway} == {1, 5, 15}
    assert all(c.guardian for c in cells) and not any(c.guardian for c in matrix(guardian=False))


def test_a_cells_command_replays_its_episode(capsys):
    from guardian.cli import main

    cell = next(c for c in matrix(only="highway") if c.env == "highway-fast-v0" and c.agent == "brake_check"
                and c.config.get("vehicles_density") == 2.5 and c.action == "continuous")
    seed = 7
    direct = run_episode(cell, seed)
    argv = shlex.split(replay_command(cell.replay(seed)))[2:]  # "guardian rollout ..." -> the sub-command's arguments
    assert main(["rollout", *argv]) == 0
    replayed = json.loads(capsys.readouterr().out)
    assert {k: replayed[k] for k in COUNTED} == {k: direct[k] for k in COUNTED}


@pytest.mark.slow
def test_results_do_not_depend_on_how_episodes_are_spread():
    cells = [c for c in matrix(only="highway") if c.env == "highway-fast-v0" and c.setting == "density 2.5"
             and c.agent in ("seek", "trap")]
    one = run_campaign(cells, 3, seed=11, workers=1)
    two = run_campaign(cells, 3, seed=11, workers=2)
    assert one["episodes"] == two["episodes"] == 3 * len(cells)
    for table in ("totals", "by_env", "by_agent", "failures"):
        assert one[table] == two[table]


def test_an_episode_that_raises_is_counted_with_its_command():
    bad = Cell("highway-fast-v0", "random", "continuous", "broken", env_config=(("lanes_count", "0"),))
    r = run_episode(bad, 0)
    assert "exception" in r
    camp = Campaign()
    camp.add(bad, 0, r)
    assert camp.table("all")[0]["exceptions"] == 1
    assert camp.failures[0]["kind"] == "exception" and camp.failures[0]["replay"]["env_config"] == {"lanes_count": 0}
    assert "--env-config lanes_count=0" in replay_command(camp.failures[0]["replay"])


@pytest.mark.parametrize("argv, message", [(["--episodes", "0"], "--episodes"), (["--workers", "0"], "--workers")])
def test_the_command_refuses_nonsense(argv, message, capsys):
    from guardian.cli import main

    assert main(["falsify", *argv]) == 2
    assert message in capsys.readouterr().err


# ---- the roads beyond one straight segment (--only roads) ------------------------------------------------
def test_the_roads_cells_are_apart_from_the_default_matrix():
    default, roads = matrix(), matrix(only="roads")
    assert not {c.env for c in default} & {"merge-v0", "merge-generic-v0", "exit-v0", "guardian/Merge-v0"}
    assert {c.env for c in roads} == {"merge-v0", "merge-generic-v0", "exit-v0", "guardian/Merge-v0"}
    multi = [c for c in roads if c.controlled is not None]
    assert {c.controlled for c in multi} == {2, 4} and {c.overapprox for c in multi} == {"trivial", "ordered"}
    assert {c.config["traffic"] for c in multi} == {"easy", "hard"}
    assert {c.action for c in roads if c.env == "exit-v0"} == {"continuous", "meta"}
    assert not any(c.guardian for c in matrix(guardian=False, only="roads"))


def test_a_multi_agent_cells_command_replays_its_episode(capsys):
    from guardian.cli import main

    cell = next(c for c in matrix(only="roads") if c.controlled == 2 and c.overapprox == "ordered"
                and c.agent == "merge" and c.action == "meta" and c.config["traffic"] == "hard")
    direct = run_episode(cell, 3)
    assert "exception" not in direct, direct.get("exception")
    argv = shlex.split(replay_command(cell.replay(3)))[2:]
    assert main(["rollout", *argv]) == 0
    replayed = json.loads(capsys.readouterr().out)
    assert {k: replayed[k] for k in COUNTED} == {k: direct[k] for k in COUNTED}
    assert replayed["guarded_cars"] == 2 and replayed["overapprox"] == "ordered"


def test_a_crash_between_two_guarded_cars_is_a_failure_whoever_the_judge_blames():
    """The judged car ("ego") was not at fault, its partner, another guarded car, was: still a guarded car's
    fault, so the campaign lists it."""
    cell = next(c for c in matrix(only="roads") if c.controlled == 2)
    r = {k: 0 for k in COUNTED}
    r["crashes"] = [{"fault": "other", "rule": "entry", "start_inside": True, "car": 0, "partner_car": 1}]
    camp = Campaign()
    camp.add(cell, 0, r)
    assert [f["kind"] for f in camp.failures] == ["at-fault collision"]
    r["crashes"] = [{"fault": "other", "rule": "entry", "start_inside": True, "car": 0, "partner_car": None}]
    camp = Campaign()
    camp.add(cell, 0, r)
    assert camp.failures == []


def test_a_safe_set_exit_says_whether_the_episode_started_outside():
    """An exit after a start inside breaks the promise; one after a start outside is listed apart."""
    cell = next(c for c in matrix(only="overtake"))
    r = {k: 0 for k in COUNTED}
    r.update(crashes=[], safety_violations=1)
    camp = Campaign()
    camp.add(cell, 0, r)
    r["starts_outside"] = 1
    camp.add(cell, 1, r)
    assert [f["kind"] for f in camp.failures] == ["safe-set exit", "safe-set exit after a start outside"]
    assert camp.rows[("all",)]["safety_violations"] == 2


def test_the_campaign_fails_on_an_exit_after_a_start_inside_not_on_one_after_a_start_outside():
    from guardian.cli.falsify import promise_broken

    clean = {"totals": {k: 0 for k in COUNTED}, "failures": []}
    assert not promise_broken(clean)
    outside = dict(clean, failures=[{"kind": "safe-set exit after a start outside"},
                                    {"kind": "collision after a start outside"}])
    assert not promise_broken(outside)
    assert promise_broken(dict(clean, failures=[{"kind": "safe-set exit"}]))
    for k in ("ego_at_fault_collisions", "unchecked_entries", "reversing_steps", "unsupervised_steps"):
        assert promise_broken({"totals": dict(clean["totals"], **{k: 1}), "failures": []}), k


def _falsify_agent_choices() -> set:
    import argparse

    from guardian.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return set(next(a for a in sub.choices["falsify"]._actions if "--agent" in a.option_strings).choices)


def test_agent_choices_are_exactly_the_agents_the_cells_drive():
    driven = {c.agent for only in (None, "overtake", "highway", "roads") for guarded in (True, False)
              for c in matrix(guardian=guarded, only=only)}
    assert _falsify_agent_choices() == driven


def test_the_docs_name_the_agent_choices_and_the_agents_refused():
    """docs/cli.md: "--agent ... takes the agents the campaign's cells drive: ...; the other agents ... are refused"."""
    import re

    from envs.agents import AGENTS

    text = " ".join((ROOT / "docs" / "cli.md").read_text().split())
    sentence = re.search(r"`--agent` \(repeatable\)[^.]*?takes the agents the campaign's cells drive: (.*?) drive no "
                         r"cell and are refused\.", text)
    assert sentence, "docs/cli.md no longer says which agents falsify --agent takes"
    driven, _, refused = sentence.group(1).partition("the other agents")
    named = lambda part: {w for w in re.findall(r"`([a-z_]+)`", part) if w in AGENTS}
    choices = _falsify_agent_choices()
    assert named(driven) == choices
    assert named(refused) == set(AGENTS) - choices - {"all"}


def test_an_episode_cut_at_the_time_cap_is_counted_and_listed_with_its_command():
    cell = Cell("merge-v0", "random", "meta", "own config")
    camp = Campaign()
    camp.add(cell, 7, {"crashes": [], "episodes_cut": 1, "steps": 300})
    assert camp.table("all")[0]["episodes_cut"] == 1
    assert [f["kind"] for f in camp.failures] == ["episodes_cut"]
    assert "--seed 7" in replay_command(camp.failures[0]["replay"])
