"""The engine's exception types, in one place; each subclasses a builtin so a caller may catch either.

The product's errors (and these, re-exported) are in ``guardian.errors``.
"""
from __future__ import annotations


class LPError(RuntimeError):
    """HiGHS ended in a status that is neither optimal, infeasible nor unbounded."""


class StaleCacheError(RuntimeError):
    """A cache file exists but was built from other parameters or code."""


class SchedulerError(ConnectionError):
    """No Dask scheduler answers at ``address`` (malformed, nothing listening, timed out): ``reason`` says which."""

    def __init__(self, address: str, reason: str):
        super().__init__(f"cannot reach the Dask scheduler at {address} ({reason})")
        self.address = address
        self.reason = reason

    def __reduce__(self):
        return type(self), (self.address, self.reason)


__all__ = ["LPError", "SchedulerError", "StaleCacheError"]
