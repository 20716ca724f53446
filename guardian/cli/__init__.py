"""The ``guardian`` command line: one entry point, one module per command group.

``sets`` (rcis build|certify|export|plot), ``rollout``, ``falsify``, ``itha`` (highway|processors), ``data``
(highd generate, data convert ngsim, replay), ``serve``; ``common`` holds what they share.
"""
from __future__ import annotations

import argparse
import sys

from guardian.cli import data, falsify, itha, rollout, serve, sets


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="guardian", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for group in (sets, rollout, falsify, itha, data, serve):
        group.add_commands(sub)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "samples", 1) < 1:
        print("guardian: --samples must be at least 1", file=sys.stderr)
        return 2
    if getattr(args, "iterations", None) is not None and args.iterations < 0:
        print("guardian: --iterations must be >= 0", file=sys.stderr)
        return 2
    return args.func(args)
