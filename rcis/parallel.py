"""Process pools that an interrupt stops at once, and their results as they finish.

A job interrupted in the parent (Ctrl-C, or SIGTERM that the caller turns into ``KeyboardInterrupt``)
must not wait for its workers: leaving ``worker_pool`` by an exception terminates them (SIGTERM,
the default action: they die without output). Workers ignore SIGINT, since a Ctrl-C in a terminal
signals the whole process group and the parent decides what happens; they restore SIGTERM's default
action, which a parent's Python handler would otherwise give them.
"""
from __future__ import annotations

import multiprocessing
import signal
from contextlib import contextmanager


def _init_worker(initializer, initargs) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if initializer is not None:
        initializer(*initargs)


@contextmanager
def worker_pool(processes: int, initializer=None, initargs=()):
    """A ``multiprocessing.Pool`` of ``processes`` workers: joined on success, terminated on any exception.

    Parameters
    ----------
    processes : int
        Worker processes.
    initializer, initargs : optional
        Run in each worker after its signals are set (e.g. to hand it a progress queue).

    Returns
    -------
    contextmanager of multiprocessing.pool.Pool
    """
    pool = multiprocessing.get_context().Pool(processes, _init_worker, (initializer, initargs))
    try:
        yield pool
    except BaseException:
        pool.terminate()
        raise
    pool.close()
    pool.join()


def as_completed(results: dict, poll: float = 0.1, idle=None):
    """``(key, value)`` of ``{key: AsyncResult}`` in the order they finish (a worker's error is re-raised).

    Waits in slices of ``poll`` seconds, so that an interrupt in the parent is seen at once, and calls
    ``idle()`` after each (e.g. to forward the workers' progress).
    """
    pending = dict(results)
    while pending:
        finished = [k for k, r in pending.items() if r.ready()]
        for key in finished:
            yield key, pending.pop(key).get()
        if pending and not finished:
            next(iter(pending.values())).wait(poll)
            if idle is not None:
                idle()


@contextmanager
def process_executor(max_workers: int, initializer=None, initargs=()):
    """A ``concurrent.futures.ProcessPoolExecutor`` with ``worker_pool``'s behaviour on interrupts.

    For callers that need the executor's ``submit``/``map``; leaving by an exception cancels what has
    not started and terminates the workers instead of waiting for them.

    Parameters
    ----------
    max_workers : int
    initializer, initargs : optional
        Run in each worker after its signals are set.

    Returns
    -------
    contextmanager of concurrent.futures.ProcessPoolExecutor
    """
    from concurrent.futures import ProcessPoolExecutor

    ex = ProcessPoolExecutor(max_workers=max_workers, initializer=_init_worker, initargs=(initializer, initargs))
    try:
        yield ex
    except BaseException:
        terminate = getattr(ex, "terminate_workers", None)  # Python >= 3.14
        if terminate is not None:
            terminate()
        else:
            processes = list((getattr(ex, "_processes", None) or {}).values())  # no public way before 3.14
            ex.shutdown(wait=False, cancel_futures=True)
            for proc in processes:
                proc.terminate()
            for proc in processes:
                proc.join(timeout=2)
        raise
    ex.shutdown(wait=True)
