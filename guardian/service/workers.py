"""``guardian serve --workers N``: N worker processes on one listening socket, sessions pinned to one each.

Design (docs/service.md has the picture):

- The parent binds the socket, loads and warms the library, then forks the workers (they share the
  library's memory copy-on-write and start warm). It only supervises: a worker that dies is started
  again (its sessions are lost: their ids then answer 410 "server restarted"); SIGTERM or SIGINT is
  passed on and the parent exits 0 once every worker has stopped.
- Every worker accepts on the shared socket; the kernel hands each new connection to a worker that
  is waiting in ``accept`` (an idle one), so new sessions spread over the workers by load.
- A session lives in the worker that created it; its id says which (``NODE.WORKER.BOOT.RANDOM``).
- Routing: when a request line names a session of another worker, the worker that holds the
  connection passes the socket itself (its file descriptor, SCM_RIGHTS) and the bytes read so far to
  that worker over a Unix socket, before parsing the request. From then on the connection talks to
  the session's worker directly: no proxy hop, no copy. A client that keeps one connection per
  session (the stream, or HTTP keep-alive) is handed over at most once.
- Each worker has an inbox: a ``SOCK_SEQPACKET`` socket pair (atomic messages from any process).
  Messages: ``C`` a connection (fd attached to the first part), ``Q`` a query (the admin listing),
  ``R`` a reply; long ones are cut into parts of ``PART`` bytes.
- ``/health`` and ``/ready`` read per-worker counters from shared memory (no messages).
"""
from __future__ import annotations

import asyncio
import gc
import itertools
import json
import logging
import mmap
import os
import signal
import socket
import struct
import sys
import time

import numpy as np

from guardian.service.server import Server, ServiceConfig, bind, warm_up
from guardian.service.sessions import SessionIds

log = logging.getLogger("guardian.service")
PART = 60_000             # payload bytes per inbox message
_HEADER = struct.Struct("!cBHQ")  # kind, flags (1: more parts follow), sender worker, message id
FIELDS = ("pid", "ready", "sessions", "expired", "closed", "created", "connections", "handed_off", "boot")
LISTING_TIMEOUT = 2.0     # seconds a worker waits for the others' session lists


class Router:
    """One worker's end of the inboxes: hands connections over, answers and asks queries."""

    def __init__(self, node: str, worker: int, workers: int, inboxes: list):
        self.node, self.worker, self.workers = node, worker, workers
        self.rx = inboxes[worker][0]
        self.tx = [pair[1] for pair in inboxes]
        self.ids = itertools.count(1)
        self.parts: dict = {}      # (kind, id) -> (bytearray, fds)
        self.pending: dict = {}    # query id -> (future, replies, expected)
        self.server = None
        self.cluster = None

    def place(self) -> int:
        """The worker a new session should live on: the fewest sessions, counting the placements on
        their way to each (sent by any worker, not yet answered there); ties stay here."""
        load = self.cluster.load()
        best = min(range(self.workers), key=lambda w: (load[w], w != self.worker))
        return best

    def keep_placement(self) -> int:
        """Count a new session kept on this worker as on its way here (until answered, like one sent to
        another worker): its session is created only when the request's task runs, and many request lines
        may arrive before that."""
        self.cluster.placed[self.worker, self.worker] += 1
        return self.worker

    def start(self, server) -> None:
        self.server = server
        self.rx.setblocking(False)
        for s in self.tx:
            s.setblocking(False)
        asyncio.get_running_loop().add_reader(self.rx.fileno(), self._drain)

    def stop(self) -> None:
        try:
            asyncio.get_running_loop().remove_reader(self.rx.fileno())
        except (RuntimeError, ValueError):
            pass

    def _send(self, worker: int, kind: bytes, payload: bytes, fds=()) -> bool:
        mid = next(self.ids)
        chunks = [payload[i:i + PART] for i in range(0, len(payload), PART)] or [b""]
        try:
            for k, chunk in enumerate(chunks):
                more = 1 if k < len(chunks) - 1 else 0
                msg = _HEADER.pack(kind, more, self.worker, mid) + chunk
                if k == 0 and fds:
                    socket.send_fds(self.tx[worker], [msg], list(fds))
                else:
                    self.tx[worker].send(msg)
        except (BlockingIOError, InterruptedError):
            return False
        return True

    def send_connection(self, worker: int, fd: int, data: bytes, placement: bool = False) -> bool:
        """Pass the socket ``fd`` and the bytes read from it to ``worker``; False if its inbox is full.

        ``placement``: the connection carries a new session's request (counted until it is answered)."""
        ok = self._send(worker, b"P" if placement else b"C", data, (fd,))
        if ok and placement:
            self.cluster.placed[self.worker, worker] += 1
        return ok

    def _drain(self) -> None:
        while True:
            try:
                msg, fds, _, _ = socket.recv_fds(self.rx, PART + 64, 4)
            except (BlockingIOError, InterruptedError):
                return
            if not msg:
                return
            kind, more, sender, mid = _HEADER.unpack_from(msg)
            key = (kind, sender, mid)
            buf, got = self.parts.pop(key, (bytearray(), []))
            buf += msg[_HEADER.size:]
            got += fds
            if more:
                self.parts[key] = (buf, got)
                continue
            try:
                self._deliver(kind, bytes(buf), got, sender)
            except Exception:  # noqa: BLE001 - a bad message must not stop the inbox
                log.exception("guardian service: worker %d could not handle an inbox message", self.worker)

    def _deliver(self, kind: bytes, data: bytes, fds: list, sender: int) -> None:
        if kind in (b"C", b"P"):
            sock = socket.socket(fileno=fds[0])
            for extra in fds[1:]:
                os.close(extra)
            sock.setblocking(False)
            self.server.adopt(sock, data, placed_by=sender if kind == b"P" else None)
        elif kind == b"Q":
            query = json.loads(data)
            if query["op"] == "list":
                reply = {"id": query["id"], "worker": self.worker, "sessions": self.server.store.listing()}
                self._send(query["from"], b"R", json.dumps(reply).encode())
        elif kind == b"R":
            reply = json.loads(data)
            entry = self.pending.get(reply["id"])
            if entry is not None:
                future, replies, expected = entry
                replies[reply["worker"]] = reply["sessions"]
                if len(replies) == expected and not future.done():
                    future.set_result(None)

    async def listing(self) -> tuple[list, list]:
        """Every worker's sessions (this one's at once), and the workers that did not answer in time."""
        qid = next(self.ids)
        others = [w for w in range(self.workers) if w != self.worker]
        future = asyncio.get_running_loop().create_future()
        replies: dict = {}
        self.pending[qid] = (future, replies, len(others))
        query = json.dumps({"op": "list", "id": qid, "from": self.worker}).encode()
        for w in others:
            self._send(w, b"Q", query)
        if others:
            try:
                await asyncio.wait_for(future, LISTING_TIMEOUT)
            except asyncio.TimeoutError:
                pass
        self.pending.pop(qid, None)
        out = list(self.server.store.listing())
        for w in others:
            out.extend(replies.get(w, []))
        return out, [w for w in others if w not in replies]


class Cluster:
    """This worker's view of all workers: counters in shared memory, the listing through the router."""

    def __init__(self, stats: np.ndarray, placed: np.ndarray, arrived: np.ndarray, worker: int, router: Router):
        self.stats, self.worker, self.router = stats, worker, router
        self.row = stats[worker]
        self.placed = placed      # [src, dst]: new-session connections src sent to dst (src writes its row)
        self.arrived = arrived    # [dst, src]: those dst has answered (dst writes its row)

    def answered_placement(self, src: int) -> None:
        self.arrived[self.worker, src] += 1

    def load(self) -> list:
        """Live sessions per worker plus the new sessions on their way to it (a dead worker counts as full)."""
        sessions = self.stats[:, FIELDS.index("sessions")]
        inflight = self.placed.sum(axis=0) - self.arrived.sum(axis=1)
        return [int(sessions[w] + inflight[w]) if self.stats[w, 0] > 0 else 1 << 40 for w in range(len(self.stats))]

    def set_ready(self, ready: bool) -> None:
        self.row[FIELDS.index("ready")] = int(ready)

    def publish(self, server) -> None:
        store, row = server.store, self.row
        row[2], row[3], row[4], row[5] = len(store.live), store.expired_total, store.closed_total, store.created_total
        row[6], row[7] = len(server.connections), server.handed_off

    def _alive(self) -> np.ndarray:
        return self.stats[self.stats[:, 0] > 0]

    def totals(self) -> dict:
        rows = self._alive()
        out = {name: int(rows[:, FIELDS.index(name)].sum()) for name in ("sessions", "expired", "closed", "created")}
        return {**out, "workers": len(self.stats), "workers_alive": len(rows)}

    def readiness(self) -> tuple[int, int]:
        return int(self._alive()[:, FIELDS.index("ready")].sum()), len(self.stats)

    async def listing(self):
        return await self.router.listing()


def _inboxes(n: int) -> list:
    pairs = []
    for _ in range(n):
        rx, tx = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        for s in (rx, tx):
            s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        pairs.append((rx, tx))
    return pairs


def _worker_main(library, config: ServiceConfig, sock, worker: int, boot: int, service_boot: int,
                 inboxes: list, stats: np.ndarray, placed: np.ndarray, arrived: np.ndarray) -> int:
    """The body of one forked worker process; returns its exit code."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    _die_with_parent()
    for k, (rx, _) in enumerate(inboxes):
        if k != worker:
            rx.close()
    router = Router(config.node, worker, config.workers, inboxes)
    cluster = Cluster(stats, placed, arrived, worker, router)
    router.cluster = cluster
    stats[worker, FIELDS.index("boot")] = boot
    ids = SessionIds(config.node, worker, boot, service_boot, config.workers)
    server = Server(library, config, ids=ids, router=router, cluster=cluster)
    server.store.on_change = lambda store: cluster.publish(server)
    asyncio.run(server.serve(sock))  # SIGTERM and SIGINT stop it gracefully
    return 0


class Supervisor:
    """The parent: forks the workers, starts a dead one again, passes SIGTERM/SIGINT on."""

    def __init__(self, library, config: ServiceConfig, sock: socket.socket):
        self.library, self.config, self.sock = library, config, sock
        n = config.workers
        self.inboxes = _inboxes(n)
        self._shm = mmap.mmap(-1, 8 * (len(FIELDS) * n + 2 * n * n))
        shared = np.frombuffer(self._shm, dtype=np.int64)
        self.stats = shared[:len(FIELDS) * n].reshape(n, len(FIELDS))
        self.placed = shared[len(FIELDS) * n:len(FIELDS) * n + n * n].reshape(n, n)
        self.arrived = shared[len(FIELDS) * n + n * n:].reshape(n, n)
        self.service_boot = time.time_ns() // 1_000_000
        self.boots = [self.service_boot] * n
        self.pids: dict[int, int] = {}   # pid -> worker
        self.stopping = False
        self.restarts = 0

    def _spawn(self, worker: int, boot: int) -> None:
        self.stats[worker] = 0
        # placements to a dead worker are lost with it: count them as answered
        self.arrived[worker] = self.placed[:, worker]
        pid = os.fork()
        if pid == 0:  # the worker
            code = 1
            try:
                code = _worker_main(self.library, self.config, self.sock, worker, boot, self.service_boot,
                                    self.inboxes, self.stats, self.placed, self.arrived)
            except BaseException:  # noqa: BLE001
                log.exception("guardian service: worker %d failed", worker)
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
                os._exit(code)
        self.stats[worker, 0] = pid
        self.pids[pid] = worker
        self.boots[worker] = boot

    def run(self) -> int:
        gc.collect()
        gc.freeze()  # the library's objects stay in shared pages (fewer copy-on-write faults)
        for k in range(self.config.workers):
            self._spawn(k, self.service_boot)

        def stop(signum, frame):
            self.stopping = True

        signal.signal(signal.SIGTERM, stop)
        signal.signal(signal.SIGINT, stop)
        forwarded_at = None
        while self.pids:
            if self.stopping and forwarded_at is None:
                forwarded_at = time.monotonic()
                for pid in list(self.pids):
                    _signal(pid, signal.SIGTERM)
            if forwarded_at is not None and time.monotonic() - forwarded_at > self.config.graceful_timeout + 5:
                for pid in list(self.pids):
                    _signal(pid, signal.SIGKILL)
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                break
            if pid == 0:
                time.sleep(0.05)
                continue
            worker = self.pids.pop(pid, None)
            if worker is None:
                continue
            self.stats[worker, 0] = 0
            if not self.stopping:
                code = os.waitstatus_to_exitcode(status)
                print(f"guardian serve: worker {worker} (pid {pid}) ended with {code}; starting it again "
                      "(its sessions are lost: their ids answer 410)", file=sys.stderr, flush=True)
                self.restarts += 1
                self._spawn(worker, max(time.time_ns() // 1_000_000, self.boots[worker] + 1))
        self.sock.close()
        return 0


def _die_with_parent() -> None:
    """Linux: SIGTERM this worker when the parent dies (a killed parent leaves no workers serving)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _signal(pid: int, sig) -> None:
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        pass


def serve_workers(library, config: ServiceConfig, sock: socket.socket | None = None) -> Supervisor:
    """The supervisor of ``config.workers`` workers on ``sock`` (bound from the config if None)."""
    config.check()
    warm_up(library)
    return Supervisor(library, config, sock or bind(config.host, config.port, config.backlog))
