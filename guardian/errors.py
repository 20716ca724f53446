"""Every exception type a guardian user can meet, importable from here.

Each subclasses a builtin, so ``except ValueError`` still catches a bad file or configuration:

* ``ConfigError`` (``ValueError``): an environment configuration that cannot be simulated or
  supervised as asked; ``ConfigClash``, one of them: a key given twice (by a rollout's setting and its
  env config);
* ``HighDFormatError`` (``ValueError``): a HighD-format file is malformed; the message says where;
* ``ServiceError`` (``Exception``): a refused service request, with the HTTP status a client sees;
* ``LPError``, ``StaleCacheError`` (``RuntimeError``), ``SchedulerError`` (``ConnectionError``: no Dask
  scheduler answers at a ``--scheduler`` address; the message names the address and the reason): the
  engine's (``rcis.errors``), re-exported;
* ``Terminated`` (``KeyboardInterrupt``): SIGTERM, raised by the command line's handler so that a
  job stops as it does on Ctrl-C (finished work kept, nothing half-written).
"""
from __future__ import annotations

from rcis.errors import LPError, SchedulerError, StaleCacheError


class ConfigError(ValueError):
    """An environment configuration that cannot be simulated or supervised as asked."""


class ConfigClash(ConfigError):
    """A config key given in an env config that a rollout's own setting (``setting``) also sets: one of the
    two would be dropped without a word."""

    def __init__(self, env_id: str, key: str, setting: str):
        super().__init__(f"{env_id}: config key {key!r} is set by the rollout's {setting}; give it there, not in "
                         "the env config")
        self.env_id, self.key, self.setting = env_id, key, setting

    def __reduce__(self):
        return type(self), (self.env_id, self.key, self.setting)


class HighDFormatError(ValueError):
    """A HighD-format file is malformed; the message says where."""


class ServiceError(Exception):
    """An error with the HTTP status a client should see."""

    def __init__(self, status: int, message: str, **extra):
        super().__init__(message)
        self.status = status
        self.message = message
        self.extra = extra

    def body(self) -> dict:
        return {"error": self.message, **self.extra}


class Terminated(KeyboardInterrupt):
    """The process received SIGTERM; handled like Ctrl-C."""


__all__ = ["ConfigClash", "ConfigError", "HighDFormatError", "LPError", "SchedulerError", "ServiceError",
           "StaleCacheError", "Terminated"]
