"""Running the service: uvicorn on one event loop, a listening socket we bind ourselves.

One process, one event loop: guardian steps are short CPU work (about half a millisecond), so they
run on the loop, which answers every connection's requests in the order they arrive and needs no
locks. The socket is bound before uvicorn starts, so ``--port 0`` knows its port and the listen
backlog is ours. SIGTERM and SIGINT stop accepting, answer the requests in flight, then exit.
"""
from __future__ import annotations

import ipaddress
import os
import socket
import threading
from dataclasses import dataclass, field

import uvicorn

from guardian.service.api import create_app
from guardian.service.limits import Limits
from guardian.service.protocol import GuardedH11Protocol
from guardian.service.sessions import SessionStore

TOKEN_ENV = "GUARDIAN_TOKEN"


@dataclass(frozen=True)
class ServiceConfig:
    """Every option of ``guardian serve``; the defaults are the documented ones."""

    host: str = "127.0.0.1"
    port: int = 8765
    token: str | None = None          # required on any address other than loopback
    session_ttl: float = 300.0        # seconds a session may idle before it expires
    max_sessions: int = 1000
    backlog: int = 2048               # listen queue (the kernel caps it at net.core.somaxconn)
    graceful_timeout: float = 10.0    # seconds in-flight requests get on shutdown
    limits: Limits = field(default_factory=Limits)

    def check(self) -> None:
        if self.token is None and not is_loopback(self.host):
            raise ValueError(f"refusing to serve on {self.host!r} without a token: pass --token or set "
                             f"{TOKEN_ENV} (loopback addresses need none)")
        if self.token is not None and len(self.token) < 16:
            raise ValueError("the token must be at least 16 characters")
        if self.session_ttl <= 0 or self.max_sessions < 1:
            raise ValueError(f"--session-ttl must be > 0 and --max-sessions >= 1, got "
                             f"{self.session_ttl}, {self.max_sessions}")


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def token_from_env(given: str | None) -> str | None:
    return given if given is not None else (os.environ.get(TOKEN_ENV) or None)


def bind(host: str, port: int, backlog: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    # proto must say TCP: asyncio sets TCP_NODELAY on accepted sockets only then, and without it
    # uvicorn's separate head and body writes meet the client's delayed ACK (40 ms per request).
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    sock.listen(backlog)
    sock.set_inheritable(True)
    return sock


def make_server(library, config: ServiceConfig = ServiceConfig()) -> tuple[uvicorn.Server, socket.socket]:
    """A uvicorn server for the guardian API and its bound socket.

    Parameters
    ----------
    library : intention.library.OvertakeLibrary
        The sets every session's guardian uses.
    config : ServiceConfig
        Address, token, session TTL and cap, and the request limits; checked first.

    Returns
    -------
    (uvicorn.Server, socket.socket)
        Call ``server.run(sockets=[sock])``.
    """
    config.check()
    store = SessionStore(library, ttl=config.session_ttl, max_sessions=config.max_sessions)
    app = create_app(library, store, config.limits, config.token)
    protocol = type("Protocol", (GuardedH11Protocol,), {"limits": config.limits})
    uv = uvicorn.Config(
        app, http=protocol, ws="websockets-sansio", lifespan="on", log_level="warning", access_log=False,
        timeout_keep_alive=int(max(1, config.limits.keepalive_timeout)), backlog=config.backlog,
        timeout_graceful_shutdown=int(max(1, config.graceful_timeout)), ws_max_size=config.limits.max_body,
        h11_max_incomplete_event_size=config.limits.max_header_bytes, server_header=False)
    sock = bind(config.host, config.port, config.backlog)
    server = uvicorn.Server(uv)
    server.store = store
    app.stopping = lambda: server.should_exit
    return server, sock


class ServiceThread:
    """The service on a background thread (tests, benchmarks): ``with ServiceThread(lib) as svc: svc.url``."""

    def __init__(self, library, config: ServiceConfig = ServiceConfig(port=0)):
        self.server, self.sock = make_server(library, config)
        self.address = self.sock.getsockname()[:2]
        self.url = f"http://{self.address[0]}:{self.address[1]}"
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)

    @property
    def store(self) -> SessionStore:
        return self.server.store

    def __enter__(self) -> "ServiceThread":
        self.thread.start()
        while not self.server.started:
            if not self.thread.is_alive():
                raise RuntimeError("the guardian service did not start")
            self.thread.join(0.01)
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(30)
        self.sock.close()
