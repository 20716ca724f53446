"""Progress of long jobs on stderr: a tqdm bar on a terminal, one line per update otherwise.

Every long job takes a ``progress(*what, done, total)`` callback; ``ProgressBar(label)`` is the one
the command line passes. Logs and CI (stderr not a terminal) get plain lines they can grep.
"""
from __future__ import annotations

import sys


class ProgressBar:
    """``progress(done, total)`` or ``progress(key, done, total)`` (one bar per key, e.g. per recording)."""

    def __init__(self, label: str, stream=None):
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._bars: dict = {}

    def _name(self, key) -> str:
        return self.label if key is None else f"{self.label} {key}"

    def __call__(self, *args) -> None:
        *what, done, total = args
        key = what[0] if what else None
        if not self.tty:
            print(f"[{self._name(key)}] {done}/{total}", file=self.stream, flush=True)
            return
        bar = self._bars.get(key)
        if bar is None:
            from tqdm import tqdm

            bar = self._bars[key] = tqdm(total=total, desc=self._name(key), file=self.stream, dynamic_ncols=True)
        bar.total = total
        bar.n = done
        bar.refresh()
        if done >= total:
            bar.close()
            del self._bars[key]

    def close(self) -> None:
        for bar in self._bars.values():
            bar.close()
        self._bars.clear()
