"""The CLI by command: one module per group, the same commands and options as before the split."""
import argparse

from guardian.cli import build_parser

COMMANDS = {  # every command and its options, as the README documents them
    ("rcis", "build"): {"--iterations", "--cache-dir", "--rebuild", "--workers", "--ego-speed-min", "--json"},
    ("rcis", "certify"): {"--samples", "--seed", "--json"},
    ("rcis", "export"): {"--out", "--json"},
    ("rcis", "plot"): {"--out"},
    ("rollout",): {"--env", "--agent", "--policy", "--algo", "--action", "--intention", "--episodes", "--seed",
                   "--disturbance", "--traffic", "--env-config", "--horizon", "--no-guardian", "--no-intention",
                   "--safe-start", "--rerun", "--video", "--controlled", "--overapprox", "--json"},
    ("falsify",): {"--episodes", "--seed", "--only", "--agent", "--no-guardian", "--workers", "--scheduler",
                   "--cache-dir", "--json"},
    ("itha", "highway"): {"--runs", "--steps", "--seed", "--overapprox", "--set", "--rerun", "--json"},
    ("itha", "processors"): {"--runs", "--steps", "--seed", "--keep-jobs", "--json"},
    ("highd", "generate"): {"--out", "--recordings", "--minutes", "--seed", "--lanes", "--first-id", "--json"},
    ("data", "convert", "ngsim"): {"--out", "--main-lanes", "--recording-id", "--json"},
    ("replay",): {"--seed", "--contexts", "--workers", "--scheduler", "--sensitivity", "--h-min", "--u-min",
                  "--u-max", "--input-bounds", "--v-max", "--no-plausibility", "--no-cache", "--rerun", "--json"},
    ("serve",): {"--host", "--port", "--token", "--session-ttl", "--max-sessions", "--json"},
}


def _subparser(parser, path):
    for name in path:
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[name]
    return parser


def test_every_documented_command_and_option_exists():
    parser = build_parser()
    for path, options in COMMANDS.items():
        sub = _subparser(parser, path)
        known = {s for a in sub._actions for s in a.option_strings}
        assert options <= known, (path, options - known)


def test_each_group_lives_in_its_own_module():
    parser = build_parser()
    modules = {path: _subparser(parser, path).get_default("func").__module__ for path in COMMANDS}
    assert modules[("rcis", "build")] == "guardian.cli.sets" and modules[("serve",)] == "guardian.cli.serve"
    assert modules[("replay",)] == "guardian.cli.data" and modules[("itha", "highway")] == "guardian.cli.itha"
    assert modules[("rollout",)] == "guardian.cli.rollout"


def test_the_agent_help_names_every_agent_there_is():
    from envs.agents import AGENTS

    rollout = _subparser(build_parser(), ("rollout",))
    text = next(a.help for a in rollout._actions if "--agent" in a.option_strings)
    named = {word.strip(" ,") for word in text.split("|")} | set(text.replace(",", " ").split())
    assert set(AGENTS) <= named, set(AGENTS) - named
