"""Raw-socket HTTP for the service tests: send exact bytes, read exact responses (h11 client side)."""
from __future__ import annotations

import json
import socket

import h11


class Raw:
    """One TCP connection to the service; ``send`` bytes, ``responses`` parsed until the server stops."""

    def __init__(self, address, timeout: float = 10.0):
        self.sock = socket.create_connection(address, timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.conn = h11.Connection(h11.CLIENT)

    def send(self, data: bytes) -> "Raw":
        self.sock.sendall(data)
        return self

    def half_close(self) -> "Raw":
        self.sock.shutdown(socket.SHUT_WR)
        return self

    def response(self):
        """The next response as (status, headers dict, parsed JSON or raw bytes), or None on a clean close."""
        status, headers, body = None, {}, b""
        if self.conn.our_state is h11.IDLE:  # the request went out as raw bytes: tell h11 one was sent
            self.conn.send(h11.Request(method="GET", target="/", headers=[("host", "localhost")]))
            self.conn.send(h11.EndOfMessage())
        while True:
            event = self.conn.next_event()
            if event is h11.NEED_DATA:
                try:
                    data = self.sock.recv(65536)
                except ConnectionResetError:
                    data = b""
                self.conn.receive_data(data)
                if not data and status is None:
                    return None
                continue
            if isinstance(event, h11.Response):
                status = event.status_code
                headers = {k.decode().lower(): v.decode() for k, v in event.headers}
            elif isinstance(event, h11.Data):
                body += event.data
            elif isinstance(event, (h11.EndOfMessage, h11.ConnectionClosed)):
                if self.conn.our_state is h11.DONE and self.conn.their_state is h11.DONE:
                    self.conn.start_next_cycle()
                try:
                    parsed = json.loads(body) if body else None
                except ValueError:
                    parsed = body
                return status, headers, parsed

    def request(self, method: str, path: str, body=None, headers: dict | None = None):
        """Send one well-formed request through h11 and read its response.

        ``Host: localhost`` (the service refuses other names on loopback) and, with a body,
        ``Content-Type: application/json`` unless ``headers`` says otherwise (a None value drops a field).
        """
        data = b"" if body is None else (body if isinstance(body, bytes) else json.dumps(body).encode())
        given = {k.lower(): v for k, v in (headers or {}).items()}
        base = {"host": "localhost", "content-length": str(len(data))}
        if body is not None:
            base["content-type"] = "application/json"
        h = [(k, v) for k, v in {**base, **given}.items() if v is not None]
        try:
            self.sock.sendall(self.conn.send(h11.Request(method=method, target=path, headers=h)))
            self.sock.sendall(self.conn.send(h11.Data(data=data)) + self.conn.send(h11.EndOfMessage()))
        except BrokenPipeError:  # the server answered and closed before reading it all: read the answer
            pass
        return self.response()

    def closed(self, timeout: float = 5.0) -> bool:
        """True when the server closed this connection (reads EOF) within ``timeout``."""
        self.sock.settimeout(timeout)
        try:
            return self.sock.recv(1) == b""
        except (ConnectionResetError, BrokenPipeError):
            return True
        except socket.timeout:
            return False

    def close(self) -> None:
        self.sock.close()


def call(address, method: str, path: str, body=None, headers: dict | None = None):
    raw = Raw(address)
    try:
        return raw.request(method, path, body, headers)
    finally:
        raw.close()


JSON = {"content-type": "application/json"}


def create(target, settings=None, headers: dict | None = None) -> tuple[str, str]:
    """A new session on ``target`` (an address or a Raw connection): ``(id, secret)``."""
    status, _, body = (target.request if isinstance(target, Raw) else
                       lambda *a: call(target, *a))("POST", "/sessions", settings or {}, headers or {})
    assert status == 201, body
    return body["session"], body["secret"]


def secret_header(secret: str, **more) -> dict:
    return {"session-secret": secret, **more}


def step(seq: int, state, u) -> dict:
    return {"seq": seq, "state": list(state), "input": list(u)}
