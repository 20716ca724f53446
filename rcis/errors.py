"""The engine's exception types, in one place; each subclasses a builtin so a caller may catch either.

The product's errors (and these, re-exported) are in ``guardian.errors``.
"""
from __future__ import annotations


class LPError(RuntimeError):
    """HiGHS ended in a status that is neither optimal, infeasible nor unbounded."""


class StaleCacheError(RuntimeError):
    """A cache file exists but was built from other parameters or code."""


__all__ = ["LPError", "StaleCacheError"]
