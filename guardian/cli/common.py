"""What every command shares: the parser, argument types, shared flags (argparse parents), output, progress.

Every expected failure is refused while the arguments are parsed, before any work starts: one line
naming the option and the value, exit 2 (``Parser.error``). Types check values (``count``,
``positive_number``), paths (``output_file``, ``output_folder``, ``existing_path``); a command refuses
options that do not apply with ``usage_error``.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path


COMMAND = "COMMAND"  # the metavar of every group's sub-commands
_REQUIRED = "the following arguments are required: "


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``guardian rcis build: argument --workers: ...``, exit 2).

    Every parser records its ``prog`` as the default ``_prog``, so a command knows its own name
    (the deepest sub-command's wins). A group named without its sub-command says which there are
    (``guardian rcis: choose one of build, certify, export, plot``), not the internal name of the slot.
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.set_defaults(_prog=self.prog)

    def add_commands(self, dest: str):
        """The required sub-commands of this group (``dest`` holds the name chosen; shown as COMMAND)."""
        return self.add_subparsers(dest=dest, required=True, metavar=COMMAND, title="commands")

    def error(self, message):
        self.exit(2, f"{self.prog}: {self._readable(message)}\n")

    def _readable(self, message: str) -> str:
        subs = [a for a in self._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or not message.startswith(_REQUIRED):
            return message
        missing = message[len(_REQUIRED):].split(", ")
        if COMMAND not in missing:
            return message
        rest = [m for m in missing if m != COMMAND]
        return (f"choose one of {', '.join(subs[0].choices)} ({self.prog} --help says what each does)"
                + (f"; {_REQUIRED}{', '.join(rest)}" if rest else ""))


def usage_error(args, message: str) -> int:
    """Refuse the command line with one line naming what is wrong; the exit code 2 to return."""
    print(f"{getattr(args, '_prog', 'guardian')}: {message}", file=sys.stderr)
    return 2


# ---- argument types ---------------------------------------------------------------------------------
def count(minimum: int):
    """A whole number at least ``minimum`` (``type=count(1)``)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be a whole number >= {minimum}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be a whole number >= {minimum}, got {text!r}")
        return value

    parse.__name__ = f"count>={minimum}"
    return parse


def number(text: str) -> float:
    """A finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def positive_number(text: str) -> float:
    """A finite number > 0."""
    value = number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def lag_seconds(text: str) -> float:
    """An actuator's lag: a time constant in (0, itha.actuator.LAG_MAX] seconds."""
    from itha.actuator import LAG_MAX

    value = positive_number(text)
    if value > LAG_MAX:
        raise argparse.ArgumentTypeError(f"must be at most {LAG_MAX:g} s (no vehicle's actuator lags longer), got "
                                         f"{text!r}")
    return value


def _writable_folder_error(folder: Path) -> str | None:
    """Why files cannot be created in ``folder`` or in the folders that would be made for it, or None."""
    existing = folder
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if not existing.is_dir():
        return f"{existing} is not a folder"
    try:  # the one reliable test (permissions, read-only file systems, root)
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as exc:
        return f"cannot write in {existing} ({exc.strerror or exc})"
    return None


def output_file(text: str) -> Path:
    """A file the command may write (created with its folders); refused if it is a folder or unwritable."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a folder, not a file")
    if path.exists():
        try:
            with open(path, "ab"):
                pass
        except OSError as exc:
            raise argparse.ArgumentTypeError(f"cannot write {path} ({exc.strerror or exc})") from None
        return path
    bad = _writable_folder_error(path.parent if str(path.parent) else Path("."))
    if bad:
        raise argparse.ArgumentTypeError(f"cannot write {path}: {bad}")
    return path


def output_folder(text: str) -> Path:
    """A folder the command may write into (created if missing); refused if it is a file or unwritable."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a file, not a folder")
    bad = _writable_folder_error(path)
    if bad:
        raise argparse.ArgumentTypeError(f"cannot write into {path}: {bad}")
    return path


def existing_path(text: str) -> Path:
    """A file or folder that exists."""
    path = Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f"no such file or folder: {path}")
    return path


# ---- shared flags (argparse parents) -----------------------------------------------------------------
def _add_json(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def json_option() -> argparse.ArgumentParser:
    """The parent of every command with a result: ``--json``."""
    parent = argparse.ArgumentParser(add_help=False)
    _add_json(parent)
    return parent


def _add_library(p, min_iterations: int) -> None:
    p.add_argument("--iterations", type=count(min_iterations), default=None,
                   help="inside-out iterations for the aggressive and cautious sets (default 5)")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="where computed sets are cached (default $GUARDIAN_CACHE_DIR or ~/.cache/guardian)")
    p.add_argument("--rebuild", action="store_true", help="ignore the cache and recompute")
    p.add_argument("--workers", type=count(1), default=2, help="processes for the intention sets (default 2)")
    p.add_argument("--ego-speed-min", type=ego_speed_min, default=None, metavar="V",
                   help="the safe set's lowest ego speed v_ex^min (default: the dissertation's 16 m/s; 0 lets the "
                        "ego wait behind the lead instead of having to overtake, and is the only value "
                        "guardian/HighwayOvertake-v0 with traffic takes)")


def library_options(min_iterations: int = 0) -> argparse.ArgumentParser:
    """The parent of every command that loads the RCIS library (``--iterations`` at least ``min_iterations``)."""
    parent = argparse.ArgumentParser(add_help=False)
    _add_library(parent, min_iterations)
    return parent


def add_library_options(p: argparse.ArgumentParser) -> None:
    """The library's flags and ``--json`` on ``p`` (the same declarations as the parents)."""
    _add_library(p, 0)
    _add_json(p)


# ---- output and work ---------------------------------------------------------------------------------
def emit(result: dict, as_json: bool, text: str) -> None:
    print(json.dumps(result, indent=2, ensure_ascii=False) if as_json else text)


def load_library(args):
    from intention.params import OvertakeParams
    from intention.library import LibrarySettings, build_library, replace_settings

    settings = replace_settings(LibrarySettings(), intention_max_iterations=args.iterations)
    params = OvertakeParams()
    if getattr(args, "ego_speed_min", None) is not None:
        params = OvertakeParams(v_ex_bounds=(args.ego_speed_min, params.v_ex_bounds[1]))
    return build_library(params=params, settings=settings, cache_dir=args.cache_dir, use_cache=not args.rebuild,
                         workers=args.workers)


def progress_bar(label: str):
    from guardian.cli.progress import ProgressBar

    return ProgressBar(label)


def intention_name(text: str) -> str:
    """``all``, or an intention set by either name (``C_a``/``aggressive``, ``C_c``/``cautious``)."""
    from intention.library import set_name

    try:
        name = "all" if text == "all" else set_name(text)
    except ValueError:
        name = None
    if name not in ("aggressive", "cautious", "all"):
        raise argparse.ArgumentTypeError(f"--intention must be aggressive, cautious, C_a, C_c or all, got {text!r}")
    return name


def ego_speed_min(text: str) -> float:
    value = float(text)
    if not 0.0 <= value < 36.0:
        raise argparse.ArgumentTypeError(f"--ego-speed-min must be in [0, 36) m/s, got {text}")
    return value
