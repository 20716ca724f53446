"""Independent jobs in this process, in local worker processes or on a Dask cluster: one helper.

``Jobs`` is how the certification, the set library, the falsification campaign and the HighD replay spread
their work::

    with Jobs(workers=2) as jobs:                      # or Jobs(scheduler="tcp://host:8786"), or Jobs()
        running = {key: jobs.submit(fn, *args) for key, args in work.items()}
        for key, value in jobs.as_completed(running):  # as each finishes (in order when run here)
            ...

* ``workers <= 1`` and no scheduler: each job runs in this process when its result is asked for;
* ``workers > 1``: local processes. A job interrupted in the parent (Ctrl-C, or SIGTERM that the caller
  turns into ``KeyboardInterrupt``) does not wait for its workers: leaving ``Jobs`` by an exception
  terminates them. Workers ignore SIGINT (a Ctrl-C in a terminal signals the whole process group and the
  parent decides what happens) and restore SIGTERM's default action, which a parent's Python handler
  would otherwise give them; ``initializer(*initargs)`` then runs in each;
* ``scheduler``: an existing Dask scheduler's address. It is connected to first: an address that is
  malformed or where no scheduler answers raises ``SchedulerError`` naming the address and the reason
  before any work starts (``check_scheduler``). The wait is Dask's connect timeout,
  ``distributed.comm.timeouts.connect`` (30 s by default; ``DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=5s``).
  The initializer does not run on the cluster's workers.

Results never depend on how jobs are spread: each job is a pure function of its arguments.
"""
from __future__ import annotations

import signal
from concurrent.futures import FIRST_COMPLETED, wait

from rcis.errors import SchedulerError


def _init_worker(initializer, initargs) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if initializer is not None:
        initializer(*initargs)


class _Here:
    """A job run in this process when its result is asked for."""

    def __init__(self, fn, args):
        self.fn, self.args = fn, args

    def result(self):
        return self.fn(*self.args)


class Jobs:
    """Run independent jobs here, on ``workers`` local processes or on the Dask scheduler at ``scheduler``
    (see the module docstring); a context manager.

    Parameters
    ----------
    workers : int
        Local processes (1: in this process); not used with ``scheduler``.
    scheduler : str, optional
        A Dask scheduler's address (``tcp://host:8786``).
    initializer, initargs : optional
        Run in each local worker process after its signals are set (e.g. to hand it a progress queue).
    """

    def __init__(self, workers: int = 1, scheduler: str | None = None, initializer=None, initargs=()):
        self.workers, self.scheduler = workers, scheduler
        self.initializer, self.initargs = initializer, initargs
        self._executor = self._client = None

    @property
    def parallel(self) -> bool:
        """Do jobs run beside this process (so that submitting early overlaps them with work here)?"""
        return self._executor is not None or self._client is not None

    def __enter__(self) -> "Jobs":
        if self.scheduler:
            self._client = dask_client(self.scheduler)
        elif self.workers > 1:
            from concurrent.futures import ProcessPoolExecutor

            self._executor = ProcessPoolExecutor(max_workers=self.workers, initializer=_init_worker,
                                                 initargs=(self.initializer, self.initargs))
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if self._client is not None:
            self._client.close()
        if self._executor is not None:
            if kind is None:
                self._executor.shutdown(wait=True)
            else:
                _terminate(self._executor)
        self._executor = self._client = None

    def submit(self, fn, *args):
        """Start ``fn(*args)``; the returned future's ``result()`` is its value (or raises its error)."""
        if self._client is not None:
            return self._client.submit(fn, *args, pure=False)
        if self._executor is not None:
            return self._executor.submit(fn, *args)
        return _Here(fn, args)

    def as_completed(self, futures: dict, poll: float = 0.1, idle=None):
        """``(key, value)`` of ``{key: future}`` as they finish (in the dict's order when run here).

        Local processes are waited for in slices of ``poll`` seconds, so that an interrupt in the parent is
        seen at once, and ``idle()`` is called after each slice (e.g. to forward the workers' progress)."""
        if self._client is not None:
            from dask.distributed import as_completed

            keys = {id(f): k for k, f in futures.items()}
            for fut in as_completed(list(futures.values())):
                yield keys[id(fut)], fut.result()
            return
        if self._executor is None:
            for key, fut in futures.items():
                yield key, fut.result()
            return
        pending = dict(futures)
        while pending:
            done, _ = wait(list(pending.values()), timeout=poll, return_when=FIRST_COMPLETED)
            for key in [k for k, f in pending.items() if f in done]:
                yield key, pending.pop(key).result()
            if idle is not None:
                idle()

    def map(self, fn, *iterables) -> list:
        """``[fn(*args) for args in zip(*iterables)]``, the jobs spread as ``submit`` spreads them."""
        futures = {k: self.submit(fn, *args) for k, args in enumerate(zip(*iterables))}
        values = dict(self.as_completed(futures))
        return [values[k] for k in range(len(futures))]


def _terminate(executor) -> None:
    """Cancel what has not started and end the workers without waiting for them."""
    terminate = getattr(executor, "terminate_workers", None)  # Python >= 3.14
    if terminate is not None:
        terminate()
        return
    processes = list((getattr(executor, "_processes", None) or {}).values())  # no public way before 3.14
    manager = getattr(executor, "_executor_manager_thread", None)
    executor.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        proc.terminate()
    for proc in processes:
        proc.join(timeout=2)
    if manager is not None:
        # The manager thread closes its wake-up pipe when it sees the workers gone; at exit the
        # interpreter writes to that pipe, and a close racing that write raises EBADF (CPython < 3.14).
        manager.join(timeout=2)


def check_scheduler(address: str, timeout: float | str | None = None) -> None:
    """Raise ``SchedulerError`` unless a Dask scheduler answers at ``address`` within ``timeout``.

    One connection is opened and closed, without the ``dask.distributed.Client`` that a failed connection
    leaves behind (whose clean-up prints a second traceback when it is collected). ``timeout``: seconds or
    a Dask duration (``"5s"``); default ``distributed.comm.timeouts.connect``. An ``inproc://`` address (a
    scheduler in this process's own event loop) is not probed.
    """
    import asyncio

    import dask
    from distributed.comm import connect
    from distributed.security import Security

    if address.startswith("inproc://"):
        return
    if timeout is None:
        timeout = dask.config.get("distributed.comm.timeouts.connect")
    seconds = dask.utils.parse_timedelta(timeout, default="seconds")

    async def once():
        comm = await connect(address, timeout=seconds, **Security().get_connection_args("client"))
        await comm.close()

    try:
        asyncio.run(once())
    except (OSError, ValueError, TypeError) as exc:
        raise SchedulerError(address, str(exc) or type(exc).__name__) from None


def dask_client(address: str, timeout: float | str | None = None):
    """A ``dask.distributed.Client`` of the scheduler at ``address`` (``SchedulerError`` if none answers)."""
    from dask.distributed import Client

    check_scheduler(address, timeout)
    try:
        return Client(address, timeout=timeout) if timeout is not None else Client(address)
    except (OSError, ValueError, TypeError) as exc:  # went away since the probe
        raise SchedulerError(address, str(exc) or type(exc).__name__) from None
