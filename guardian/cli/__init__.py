"""The ``guardian`` command line: one entry point, one module per command group.

``sets`` (rcis build|certify|export|plot), ``rollout``, ``falsify``, ``itha`` (highway|processors), ``data``
(highd generate, data convert ngsim, replay), ``serve``, ``sumo``; ``common`` holds what they share.
"""
from __future__ import annotations

import argparse
import atexit
import os
import signal
import sys
import threading

from guardian.cli import data, falsify, itha, rollout, serve, sets, sumo
from guardian.cli.common import Parser
from guardian.errors import Terminated


DESCRIPTION = ("The guardian command line: a correct-by-construction safety supervisor for highway driving "
               "(robust controlled invariant sets, intention estimation, inter-triggering hybrid automata).")


def version() -> str:
    """The installed distribution's version, else the package's ``__version__``."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        return installed("guardian")
    except PackageNotFoundError:
        import guardian

        return getattr(guardian, "__version__", "unknown")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="guardian", description=DESCRIPTION)
    parser.add_argument("--version", action="version", version=f"guardian {version()}",
                        help="print guardian's version and exit")
    sub = parser.add_commands("command")
    for group in (sets, rollout, falsify, itha, data, serve, sumo):
        group.add_commands(sub)
    return parser


def _terminate(signum, frame):
    raise Terminated()


def _leave_now(code: int):
    """Exit an interrupted command at once: the exit handlers run and the streams are flushed, but the interpreter's
    teardown of every loaded module (1-2 s on a loaded machine, after the line was printed) is skipped. Everything a
    command keeps is written and closed by then (its own ``finally`` blocks ran on the way out)."""
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def main(argv=None) -> int:
    """Run one command; Ctrl-C (SIGINT) and SIGTERM stop it with one line, exit 130 and 143.

    SIGTERM raises ``Terminated`` (a ``KeyboardInterrupt``), so both signals take the same path:
    worker pools are terminated, finished work stays (cache entries are written atomically), and
    what a command keeps is named by its ``on_interrupt`` default. Run as the command line (``argv`` None), an
    interrupted command then leaves at once (``_leave_now``).
    """
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help, or a refused command line (one line on stderr, exit 2)
        return exc.code
    in_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminate) if in_main_thread else None
    try:
        return args.func(args)
    except KeyboardInterrupt as exc:
        name, code = ("SIGTERM", 143) if isinstance(exc, Terminated) else ("SIGINT", 130)
        kept = getattr(args, "on_interrupt", None)
        print(f"{args._prog}: interrupted by {name}" + (f"; {kept}" if kept else ""), file=sys.stderr, flush=True)
        if argv is None and in_main_thread:
            _leave_now(code)
        return code
    finally:
        if in_main_thread:
            signal.signal(signal.SIGTERM, previous)
