"""Running the service: options, the listening socket, one worker's event loop, warm-up, shutdown.

A worker is one process serving the ASGI application (``guardian.service.app``) with uvicorn (httptools)
on one asyncio event loop: guardian steps are short CPU work (~0.2 ms), so they run on the loop, in arrival
order, with no locks. ``guardian serve --workers N`` runs N such processes on one listening socket
(``workers.py``). The socket is bound before any worker starts, so ``--port 0`` knows its port and the listen
backlog is ours; nothing is accepted before the library is loaded and warmed up (``warm_up``). SIGTERM and
SIGINT stop accepting, answer the requests in flight with ``Connection: close``, close the streams (1012),
then exit 0.
"""
from __future__ import annotations

import asyncio
import functools
import ipaddress
import logging
import os
import signal
import socket
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import uvicorn

from guardian.service.api import SessionSettings, StepRequest
from guardian.service.app import ServiceApp
from guardian.service.limits import Limits
from guardian.service.protocol import GuardianHttpProtocol
from guardian.service.sessions import NODE_NAME, SessionIds, SessionStore

TOKEN_ENV = "GUARDIAN_TOKEN"
ADMIN_TOKEN_ENV = "GUARDIAN_ADMIN_TOKEN"
log = logging.getLogger("guardian.service")


class _DeniedHandshakes(logging.Filter):
    """uvicorn's sans-I/O WebSocket protocol logs "returned without completing handshake" after a handshake
    the app refused with an HTTP answer (the ASGI denial response), which it did send: not an error here."""

    def filter(self, record) -> bool:
        return "without completing handshake" not in record.getMessage()


logging.getLogger("uvicorn.error").addFilter(_DeniedHandshakes())
SWEEP_PERIOD = 0.25  # seconds between the sweeper's rounds (expired sessions, the workers' counters)


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
    _warm_scene(library, steps)


def _warm_scene(library, steps: int) -> None:
    """A scene session driven along a three-lane road beside a car: the bicycle guardian's kernels."""
    from guardian.service.scene import SceneGuardian, SceneSettings, SceneStep

    settings = SceneSettings.model_validate_json(
        b'{"kind": "scene", "road": {"lanes": 3, "lane_width": 4}, "vehicle": {"length": 5, "width": 2, '
        b'"max_steering": 0.785, "max_acceleration": 6, "dt": 0.0667}}')
    guardian = SceneGuardian(settings, library)
    for k in range(steps):
        x = 20.0 * k * 0.0667
        guardian.step(SceneStep.model_validate({"seq": k, "ego": {"x": x, "y": 4.0, "speed": 20.0},
                                                "cars": [{"id": "a", "x": x + 15.0, "y": 4.0, "speed": 18.0,
                                                          "length": 5, "width": 2},
                                                         {"id": "b", "x": x - 3.0, "y": 8.0, "speed": 21.0,
                                                          "length": 5, "width": 2}],
                                                "input": [1.0, 0.02]}))


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
    """One worker: the app and its sessions, served by uvicorn on one event loop."""

    def __init__(self, library, config: ServiceConfig, ids: SessionIds | None = None, router=None, cluster=None):
        self.config = config
        self.limits = config.limits
        self.store = SessionStore(library, ttl=config.session_ttl, max_sessions=config.max_sessions,
                                  ids=ids or SessionIds.starting_now(config.node))
        self.app = ServiceApp(self.store, config.limits, config.token, config.admin_token, config.allow_origins,
                              loopback=is_loopback(config.host), cluster=cluster)
        self.router = router
        self.cluster = cluster
        self.connection_cap = config.limits.connection_cap()
        self.refused = 0
        self.handed_off = 0
        self.started = threading.Event()
        self.uvicorn = uvicorn.Server(uvicorn.Config(
            self.app, http=functools.partial(GuardianHttpProtocol, service=self), ws="websockets-sansio", lifespan="off",
            log_level="warning", access_log=False, proxy_headers=False, server_header=False,
            timeout_keep_alive=config.limits.keepalive_timeout, ws_max_size=config.limits.max_stream_frame,
            ws_ping_interval=None, ws_per_message_deflate=False, timeout_graceful_shutdown=config.graceful_timeout,
            backlog=config.backlog))
        self.uvicorn.config.load()
        self.app.connections = lambda: len(self.uvicorn.server_state.connections)
        self._loop = None

    @property
    def connections(self) -> set:
        return self.uvicorn.server_state.connections

    def adopt(self, sock: socket.socket, initial: bytes, placed_by: int | None = None) -> None:
        """Serve a connection another worker handed over (with the bytes it had read); ``placed_by``: the
        worker that sent a new session's request here (told when it is answered)."""
        config, state = self.uvicorn.config, self.uvicorn.server_state

        def protocol():
            return GuardianHttpProtocol(config, state, {}, service=self, initial=initial, placed_by=placed_by)
        asyncio.ensure_future(self._loop.connect_accepted_socket(protocol, sock))

    async def serve(self, sock: socket.socket) -> None:
        """Accept on ``sock`` until ``request_stop``; then shut down gracefully."""
        self._loop = asyncio.get_running_loop()
        self._loop.set_exception_handler(_AcceptLog())
        main = threading.current_thread() is threading.main_thread()
        # uvicorn catches SIGINT/SIGTERM while it serves and raises them again once it has shut down: give it
        # handlers that do nothing then (our stop is the graceful shutdown itself)
        previous = {sig: signal.signal(sig, lambda *a: None) for sig in (signal.SIGINT, signal.SIGTERM)} if main else {}
        sweeper = asyncio.ensure_future(self._sweep())
        if self.router is not None:
            self.router.start(self)
        try:
            await self.uvicorn.serve(sockets=[sock])
        finally:
            sweeper.cancel()
            if self.router is not None:
                self.router.stop()
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def request_stop(self) -> None:
        self.app.stopping = True
        if self.cluster is not None:
            self.cluster.set_ready(False)
        self.uvicorn.should_exit = True

    async def _sweep(self) -> None:
        while not self.uvicorn.started:
            await asyncio.sleep(0.01)
        self.app.ready = True
        if self.cluster is not None:
            self.cluster.set_ready(True)
        self.started.set()
        last_store_sweep = 0.0
        while True:
            now = time.monotonic()
            if self.uvicorn.should_exit and not self.app.stopping:
                self.request_stop()   # uvicorn's own signal handling asked to stop
            if now - last_store_sweep > min(self.store.ttl / 4.0, 30.0):
                self.store.sweep()
                last_store_sweep = now
            if self.cluster is not None:
                self.cluster.publish(self)
            await asyncio.sleep(SWEEP_PERIOD)


def make_server(library, config: ServiceConfig = ServiceConfig(), warm: bool = True,
                sock: socket.socket | None = None) -> tuple[Server, socket.socket]:
    """One worker of the guardian service and its bound socket (``--workers N`` is ``workers.serve_workers``).

    Parameters
    ----------
    library : intention.library.OvertakeLibrary
        The sets every session's guardian uses.
    config : ServiceConfig
        Address, tokens, origins, session TTL and cap, node name and the limits; checked first.
    warm : bool
        Warm the library up first (``warm_up``), so that the first step costs what the others do.
    sock : socket.socket, optional
        A socket already bound to the address (``bind``: a command binds first, so that a busy port is refused
        before the sets load); by default one is bound here.

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
    return server, sock if sock is not None else bind(config.host, config.port, config.backlog)


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
