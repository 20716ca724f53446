"""A client of an existing Dask scheduler (``--scheduler`` of ``guardian falsify`` and ``guardian replay``).

``client(address)`` first opens one connection to the scheduler and closes it: an address that is
malformed or where no scheduler answers raises ``SchedulerError`` naming the address and the reason,
before any work starts, and without the ``dask.distributed.Client`` that a failed connection leaves
behind (whose clean-up prints a second traceback when it is collected). The wait for an answer is
Dask's connect timeout, ``distributed.comm.timeouts.connect`` (30 s by default; set it with
``DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=5s`` in the environment, or ``dask.config.set``), or the
``timeout`` passed.
"""
from __future__ import annotations

import asyncio
from contextlib import contextmanager

from guardian.errors import SchedulerError


def _probe(address: str, timeout) -> None:
    from distributed.comm import connect
    from distributed.security import Security

    async def once():
        comm = await connect(address, timeout=timeout, **Security().get_connection_args("client"))
        await comm.close()

    asyncio.run(once())


def check(address: str, timeout: float | str | None = None) -> None:
    """Raise ``SchedulerError`` unless a Dask scheduler answers at ``address`` within ``timeout``.

    ``timeout``: seconds or a Dask duration (``"5s"``); default ``distributed.comm.timeouts.connect``.
    An ``inproc://`` address (a scheduler in this process's own event loop) is not probed.
    """
    import dask

    if address.startswith("inproc://"):
        return
    if timeout is None:
        timeout = dask.config.get("distributed.comm.timeouts.connect")
    seconds = dask.utils.parse_timedelta(timeout, default="seconds")
    try:
        _probe(address, seconds)
    except (OSError, ValueError, TypeError) as exc:
        raise SchedulerError(address, str(exc) or type(exc).__name__) from None


@contextmanager
def client(address: str, timeout: float | str | None = None):
    """A ``dask.distributed.Client`` of the scheduler at ``address``, closed on exit.

    Raises ``SchedulerError`` (a ``ConnectionError``) if no scheduler answers there (see ``check``).
    """
    from dask.distributed import Client

    check(address, timeout)
    try:
        c = Client(address, timeout=timeout) if timeout is not None else Client(address)
    except (OSError, ValueError, TypeError) as exc:  # went away since the probe
        raise SchedulerError(address, str(exc) or type(exc).__name__) from None
    with c:
        yield c
