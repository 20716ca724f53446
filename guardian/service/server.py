"""Running the service: options, the listening socket, one worker's event loop, warm-up, shutdown.

A worker is one process with one asyncio event loop: guardian steps are short CPU work (~0.2 ms),
so they run on the loop, in arrival order, with no locks. ``guardian serve --workers N`` runs N
such processes on one listening socket (``workers.py``). The socket is bound before any worker
starts, so ``--port 0`` knows its port and the listen backlog is ours; nothing is accepted before the
library is loaded and warmed up (``warm_up``). SIGTERM and SIGINT stop accepting, answer the requests
in flight with ``Connection: close``, close the streams (1001), then exit 0.
"""
from __future__ import annotations

import asyncio
import ipaddress
import logging
import os
import socket
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from guardian.service.api import App, StepRequest, SessionSettings
from guardian.service.limits import Limits
from guardian.service.protocol import Connection
from guardian.service.sessions import NODE_NAME, SessionIds, SessionStore

TOKEN_ENV = "GUARDIAN_TOKEN"
ADMIN_TOKEN_ENV = "GUARDIAN_ADMIN_TOKEN"
log = logging.getLogger("guardian.service")
READ_BUFFER = 64 * 1024  # bytes per read (one buffer per worker: reads are copied out at once)


@dataclass(frozen=True)
class ServiceConfig:
    """Every option of ``guardian serve``; the defaults are the documented ones."""

    host: str = "127.0.0.1"
    port: int = 8765
    token: str | None = None          # required on any address other than loopback
    admin_token: str | None = None    # lists every session; may read or delete any
    allow_origins: tuple = ()         # browser origins allowed to call (none by default)
    session_ttl: float = 300.0        # seconds a session may idle before it expires
    max_sessions: int = 1000          # per worker
    backlog: int = 2048               # listen queue (the kernel caps it at net.core.somaxconn)
    graceful_timeout: float = 10.0    # seconds in-flight requests get on shutdown
    workers: int = 1
    node: str = "n0"                  # this host's name in session ids (several hosts behind a balancer)
    limits: Limits = field(default_factory=Limits)

    def check(self) -> None:
        if self.token is None and not is_loopback(self.host):
            raise ValueError(f"refusing to serve on {self.host!r} without a token: pass --token or set "
                             f"{TOKEN_ENV} (loopback addresses need none)")
        for name, value in (("token", self.token), ("admin token", self.admin_token)):
            if value is not None and len(value) < 16:
                raise ValueError(f"the {name} must be at least 16 characters")
        if self.token is not None and self.token == self.admin_token:
            raise ValueError("the admin token must differ from the token")
        if self.session_ttl <= 0 or self.max_sessions < 1:
            raise ValueError(f"--session-ttl must be > 0 and --max-sessions >= 1, got "
                             f"{self.session_ttl}, {self.max_sessions}")
        if not 1 <= self.workers <= 64:
            raise ValueError(f"--workers must be in 1..64, got {self.workers}")
        if not NODE_NAME.match(self.node):
            raise ValueError(f"--node {self.node!r}: 1-32 of a-z, 0-9 and '-', starting with a letter or digit")
        for origin in self.allow_origins:
            if not (origin.startswith(("http://", "https://")) and "/" not in origin.split("://", 1)[1]):
                raise ValueError(f"--allow-origin {origin!r}: an origin is scheme://host[:port], e.g. "
                                 "http://localhost:3000")
        self.limits.check()


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def token_from_env(given: str | None, env: str = TOKEN_ENV) -> str | None:
    return given if given is not None else (os.environ.get(env) or None)


def bind(host: str, port: int, backlog: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    # proto must say TCP: asyncio sets TCP_NODELAY on accepted sockets only then (and answers are one
    # write each, but a client's delayed ACK would still cost 40 ms per request without it)
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    sock.listen(backlog)
    sock.set_inheritable(True)
    return sock


def warm_up(library, steps: int = 40) -> None:
    """Everything a first step would otherwise pay for, before any connection is accepted.

    The admissible rows of every set (stacked lazily, ~1 s), the compiled kernels (loaded from numba's
    cache or compiled), pydantic's validators and the estimator's arrays: a guardian is driven through
    trajectories of both intentions, so the identified sets' supervisors run too.
    """
    from guardian.decide.lead import IntentionAwareGuardian
    from intention.library import SET_NAMES

    for name in SET_NAMES:
        library.admissible(name)
    rng = np.random.default_rng(0)
    for intention in ("cautious", "aggressive"):
        model = library.models[intention]
        guardian = IntentionAwareGuardian(library)
        x = np.array([25.0, 0.0, 30.0, 22.0])
        for _ in range(steps):
            u = rng.uniform([-3.0, -1.8], [3.0, 1.8])
            applied, record = guardian.step(x, u)
            record.as_dict()
            x = model.system.step(x, applied, np.zeros(4))
    StepRequest.model_validate_json(b'{"seq": 0, "state": [25, 0, 30, 22], "input": [0, 0]}')
    SessionSettings.model_validate_json(b"{}")


class _AcceptLog:
    """asyncio's exception handler, with accept errors (EMFILE...) logged at most once per ``period`` s."""

    def __init__(self, period: float = 10.0):
        self.period, self.last, self.suppressed = period, -1e9, 0

    def __call__(self, loop, context) -> None:
        message = context.get("message", "")
        if "accept" in message:
            now = time.monotonic()
            if now - self.last < self.period:
                self.suppressed += 1
                return
            exc = context.get("exception")
            log.error("guardian service: %s: %s%s", message, exc,
                      f" ({self.suppressed} more since the last report)" if self.suppressed else "")
            self.last, self.suppressed = now, 0
            return
        loop.default_exception_handler(context)


class Server:
    """One worker: the app, its sessions, its connections and their sweeper, on one event loop."""

    def __init__(self, library, config: ServiceConfig, ids: SessionIds | None = None, router=None, cluster=None):
        self.config = config
        self.limits = config.limits
        self.store = SessionStore(library, ttl=config.session_ttl, max_sessions=config.max_sessions,
                                  ids=ids or SessionIds.starting_now(config.node))
        self.app = App(self.store, config.limits, config.token, config.admin_token, config.allow_origins,
                       loopback=is_loopback(config.host), cluster=cluster)
        self.app.connections = lambda: len(self.connections)
        self.router = router
        self.cluster = cluster
        self.connections: set[Connection] = set()
        self.refusing: set[Connection] = set()  # over the connection cap: answered 503, being drained
        self.tasks: set = set()
        self.connection_cap = config.limits.connection_cap()
        self.refused = 0
        self.handed_off = 0
        self.read_buffer = memoryview(bytearray(READ_BUFFER))  # every connection reads into it (one loop)
        self.started = threading.Event()
        self._loop = None
        self._stop = None
        self._now = time.monotonic()

    def now(self) -> float:
        return self._now

    def adopt(self, sock: socket.socket, initial: bytes, placed_by: int | None = None) -> None:
        """Serve a connection another worker handed over (with the bytes it had read); ``placed_by``: the
        worker that sent a new session's request here (told when it is answered)."""
        asyncio.ensure_future(self._loop.connect_accepted_socket(
            lambda: Connection(self, initial, placed_by), sock))

    async def serve(self, sock: socket.socket) -> None:
        """Accept on ``sock`` until ``request_stop``; then shut down gracefully."""
        self._loop = asyncio.get_running_loop()
        self._loop.set_exception_handler(_AcceptLog())
        self._stop = asyncio.Event()
        server = await self._loop.create_server(lambda: Connection(self), sock=sock, backlog=self.config.backlog)
        sweeper = asyncio.ensure_future(self._sweep())
        if self.router is not None:
            self.router.start(self)
        self.app.ready = True
        if self.cluster is not None:
            self.cluster.set_ready(True)
        self.started.set()
        try:
            await self._stop.wait()
        finally:
            self.app.stopping = True
            if self.cluster is not None:
                self.cluster.set_ready(False)
            server.close()
            for conn in list(self.connections):
                conn.shutdown()
            deadline = time.monotonic() + self.config.graceful_timeout
            while (self.connections or self.tasks) and time.monotonic() < deadline:
                await asyncio.sleep(0.02)
            for conn in list(self.connections):
                conn.abort()
            sweeper.cancel()
            if self.router is not None:
                self.router.stop()

    def request_stop(self) -> None:
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)

    async def _sweep(self) -> None:
        limits = self.limits
        period = max(0.01, min(0.25, limits.read_timeout / 4, limits.keepalive_timeout / 4))
        last_store_sweep = 0.0
        while True:
            self._now = now = time.monotonic()
            for conn in list(self.connections) + list(self.refusing):
                conn.tick(now)
            if now - last_store_sweep > min(self.store.ttl / 4.0, 30.0):
                self.store.sweep()
                last_store_sweep = now
            if self.cluster is not None:
                self.cluster.publish(self)
            await asyncio.sleep(period)


def make_server(library, config: ServiceConfig = ServiceConfig(), warm: bool = True) -> tuple[Server, socket.socket]:
    """One worker of the guardian service and its bound socket (``--workers N`` is ``workers.serve_workers``).

    Parameters
    ----------
    library : intention.library.OvertakeLibrary
        The sets every session's guardian uses.
    config : ServiceConfig
        Address, tokens, origins, session TTL and cap, node name and the limits; checked first.
    warm : bool
        Warm the library up first (``warm_up``), so that the first step costs what the others do.

    Returns
    -------
    (Server, socket.socket)
        Run it with ``asyncio.run(server.serve(sock))``; ``server.request_stop()`` stops it gracefully.
    """
    config.check()
    if config.workers != 1:
        raise ValueError("make_server runs one worker; workers.serve_workers runs several")
    if warm:
        warm_up(library)
    server = Server(library, config, ids=SessionIds.starting_now(config.node))
    return server, bind(config.host, config.port, config.backlog)


class ServiceThread:
    """One worker on a background thread (tests, benchmarks): ``with ServiceThread(lib) as svc: svc.url``."""

    def __init__(self, library, config: ServiceConfig = ServiceConfig(port=0), warm: bool = True):
        self.server, self.sock = make_server(library, config, warm)
        self.address = self.sock.getsockname()[:2]
        self.url = f"http://{self.address[0]}:{self.address[1]}"
        self.thread = threading.Thread(target=lambda: asyncio.run(self.server.serve(self.sock)), daemon=True)

    @property
    def store(self) -> SessionStore:
        return self.server.store

    def __enter__(self) -> "ServiceThread":
        self.thread.start()
        while not self.server.started.wait(0.01):
            if not self.thread.is_alive():
                raise RuntimeError("the guardian service did not start")
        return self

    def __exit__(self, *exc) -> None:
        self.server.request_stop()
        self.thread.join(30)
        self.sock.close()
