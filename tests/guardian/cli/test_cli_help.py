"""The help a person reads: plain text, a version, every option explained with its default, a group
named without its command says which there are, and docs/cli.md's synopses show the code's defaults."""
import argparse
import importlib.metadata
import re

import pytest

from guardian.cli import build_parser, main
from project import ROOT

HELP_ELSEWHERE: set = set()


def _parsers(parser=None, path=("guardian",)):
    parser = parser or build_parser()
    yield " ".join(path), parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, (*path, name))


def test_help_is_plain_text_without_markup():
    for prog, parser in _parsers():
        text = parser.format_help()
        assert "``" not in text and ":class:" not in text and ":func:" not in text, (prog, text)
    assert build_parser().description.startswith("The guardian command line")


def test_every_option_and_argument_says_what_it_is():
    missing = {(prog, (a.option_strings or [a.dest])[0]) for prog, parser in _parsers() for a in parser._actions
               if not a.help and not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))}
    assert missing <= HELP_ELSEWHERE, missing - HELP_ELSEWHERE


@pytest.mark.parametrize("path,option,default", [
    (("itha", "highway"), "--runs", "25"), (("itha", "highway"), "--steps", "500"),
    (("itha", "highway"), "--seed", "0"), (("itha", "highway"), "--overapprox", "both"),
    (("itha", "processors"), "--runs", "25"), (("itha", "processors"), "--steps", "50"),
    (("highd", "generate"), "--recordings", "1"), (("highd", "generate"), "--minutes", "1.0"),
    (("highd", "generate"), "--seed", "0"), (("replay",), "--v-max", "60"),
    (("data", "convert", "ngsim"), "--recording-id", "1"),
])
def test_the_help_names_the_default(path, option, default, capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args([*path, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    start = text.index(f" {option} ")
    entry = text[start:start + 400]
    assert f"default {default})" in entry, entry


def test_certify_workers_says_it_certifies_in_parallel(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["rcis", "certify", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--workers WORKERS processes certifying the sets in parallel" in text
    assert "processes for the intention sets" not in text


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"guardian {importlib.metadata.version('guardian')}\n"


def test_version_without_installed_metadata(monkeypatch, capsys):
    import guardian

    def not_installed(name):
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "version", not_installed)
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"guardian {guardian.__version__}\n"


@pytest.mark.parametrize("argv,choices", [
    ([], "rcis, rollout, falsify, itha, highd, data, replay, serve, sumo"), (["rcis"], "build, certify, export, plot"),
    (["itha"], "highway, processors"), (["highd"], "generate"), (["data"], "convert"), (["data", "convert"], "ngsim, commonroad"),
])
def test_a_group_without_its_command_says_which_there_are(argv, choices, capsys):
    assert main(argv) == 2
    out, err = capsys.readouterr()
    prog = " ".join(["guardian", *argv])
    assert out == "" and err == f"{prog}: choose one of {choices} ({prog} --help says what each does)\n"
    assert "_command" not in err and "convert_format" not in err


def test_the_replay_synopsis_shows_the_defaults():
    """docs/cli.md's ``guardian replay [...]`` shows each option with the value it has when not given."""
    from guardian.highd.replay import ReplayConfig

    line = next(l for l in (ROOT / "docs" / "cli.md").read_text().splitlines() if l.startswith("`guardian replay ["))
    shown = dict(re.findall(r"\[(--[a-z-]+) ([^\]\s]+)\]", line))
    replay = dict(next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices)["replay"]
    defaults = {a.option_strings[0]: a.default for a in replay._actions if a.option_strings}
    effective = {"--workers": 1, "--u-min": ReplayConfig().u_min, "--u-max": ReplayConfig().u_max}  # None: unset
    shown.pop("--rerun")  # an example file name (no recording by default)
    assert shown.keys() >= {"--seed", "--workers", "--h-min", "--v-max"}
    for option, value in shown.items():
        default = effective.get(option, defaults[option])
        assert value == str(default) or float(value) == float(default), (option, value, default)
