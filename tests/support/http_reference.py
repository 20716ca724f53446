"""Request framing as two parsers this project did not write read it, and as the running service answers it.

- ``h11_first(data)``: the first request of ``data`` as h11 (pure Python, RFC 9112) reads it, or None;
- ``llhttp_first(data)``: the same with llhttp (Node.js's parser) through ``httptools.HttpRequestParser``,
  with none of its leniencies switched on, or None;
- ``probe(address, data, half_close)``: ``data`` sent on a fresh TCP connection to the service (then a
  half-close, or not), and the first answer classified: ``"accepted"`` (the application answered it as a
  request, whatever its status) or ``"refused"`` (a framing refusal of the server's HTTP layer, or a close
  with no answer).

A parser "accepts" when it reads a whole first request without an error up to its end; what follows it
(a pipelined request, garbage) is the next request's business. When it read a whole head but not the body
(cut short, or malformed), the head comes back with ``whole=False``: a server may answer from the head
alone (a 404, a missing ``Content-Type``) before any body.
"""
from __future__ import annotations

import socket
import time
from dataclasses import dataclass

import h11
import httptools


@dataclass(frozen=True)
class Parsed:
    """A request as a parser read it: header names lower-case, values as the parser gives them."""

    method: bytes
    target: bytes
    version: str
    headers: tuple  # ((name, value), ...)
    body: bytes
    whole: bool = True  # False: the head alone was read whole (the body is cut short or malformed)


def h11_first(data: bytes, eof: bool = True, max_head: int = 16 * 1024) -> Parsed | None:
    conn = h11.Connection(h11.SERVER, max_incomplete_event_size=max_head)
    conn.receive_data(data)
    if eof:
        conn.receive_data(b"")
    request, body = None, b""

    def parsed(whole: bool) -> Parsed | None:
        if request is None:
            return None
        return Parsed(request.method, request.target, request.http_version.decode(),
                      tuple((bytes(n), bytes(v)) for n, v in request.headers), body, whole)
    try:
        while True:
            event = conn.next_event()
            if isinstance(event, h11.Request):
                request = event
            elif isinstance(event, h11.Data):
                body += event.data
            elif isinstance(event, h11.EndOfMessage):
                return parsed(True)
            else:  # NEED_DATA, ConnectionClosed, PAUSED: no whole request
                return parsed(False)
    except h11.RemoteProtocolError:
        return parsed(False)


class _Callbacks:
    def __init__(self):
        self.url, self.headers, self.body, self.complete, self.head = b"", [], b"", False, False

    def on_url(self, url: bytes) -> None:
        self.url += url

    def on_header(self, name: bytes, value: bytes) -> None:
        self.headers.append((name.lower(), value))

    def on_headers_complete(self) -> None:
        self.head = True

    def on_body(self, body: bytes) -> None:
        self.body += body

    def on_message_complete(self) -> None:
        if not self.complete:
            self.complete = True
            raise _FirstDone  # stop at the first request: what follows it is not its business


class _FirstDone(Exception):
    pass


def llhttp_first(data: bytes) -> Parsed | None:
    cb = _Callbacks()
    parser = httptools.HttpRequestParser(cb)
    try:
        parser.feed_data(data)
    except httptools.HttpParserCallbackError as exc:
        if not isinstance(exc.__context__, _FirstDone):
            raise
    except httptools.HttpParserUpgrade:
        pass  # an upgrade (or CONNECT): llhttp stops after the head; the request counts if it was whole
    except httptools.HttpParserError:
        pass
    if not cb.head:
        return None
    return Parsed(parser.get_method(), cb.url, parser.get_http_version(), tuple(cb.headers), cb.body, cb.complete)


# ---- the service ---------------------------------------------------------------------------------

# the texts of guardian.service.protocol's refusals (each a JSON {"error": ...})
FRAMING_TEXTS = {400: ("invalid HTTP request", "invalid WebSocket handshake"), 408: ("not received within",),
                 413: ("exceeds",), 414: ("request target longer than", "invalid WebSocket handshake"),
                 417: ("is not supported (only 100-continue)",),
                 431: ("header fields", "request head longer than", "invalid WebSocket handshake"),
                 501: ("is not supported (only chunked)",), 503: ("connection limit",),
                 505: ("is not supported: this service speaks HTTP/1.1",)}
WEBSOCKETS_REFUSAL = b"Failed to open a WebSocket connection"  # the websockets library's own handshake refusals


@dataclass
class Answer:
    kind: str             # "accepted" | "refused"
    status: int | None    # None: closed (or reset, or silent) without an answer
    body: object = None   # parsed JSON, or bytes
    how: str = ""         # "answer" | "closed" | "reset" | "silent" | "broken"

    def __str__(self) -> str:
        return f"{self.kind} {self.status or self.how} {self.body!r:.160}"


def is_framing_refusal(status: int, body) -> bool:
    if isinstance(body, bytes) and body.startswith(WEBSOCKETS_REFUSAL):
        return True
    text = body.get("error", "") if isinstance(body, dict) else ""
    return any(fragment in text for fragment in FRAMING_TEXTS.get(status, ()))


def probe(address, data: bytes, half_close: bool, timeout: float = 5.0) -> Answer:
    """``data`` on a fresh connection, and the service's first answer to it."""
    import json

    sock = socket.create_connection(address, timeout=timeout)
    try:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            sock.sendall(data)
            if half_close:
                sock.shutdown(socket.SHUT_WR)
        except (BrokenPipeError, ConnectionResetError):
            pass  # refused before it was all sent: read what it said
        client = h11.Connection(h11.CLIENT)
        method = "HEAD" if data.lstrip(b"\r\n").startswith(b"HEAD ") else "GET"  # a HEAD answer has no body
        client.send(h11.Request(method=method, target="/", headers=[("host", "localhost")]))
        client.send(h11.EndOfMessage())
        status, body, deadline = None, b"", time.monotonic() + timeout
        while True:
            try:
                event = client.next_event()
            except h11.RemoteProtocolError as exc:  # an answer cut short, or not HTTP
                return Answer("refused", status, repr(exc), "broken")
            if event is h11.NEED_DATA:
                try:
                    sock.settimeout(max(0.01, deadline - time.monotonic()))
                    chunk = sock.recv(65536)
                except socket.timeout:
                    return Answer("refused", None, None, "silent")
                except ConnectionResetError:
                    return Answer("refused", None, None, "reset")
                if not chunk and status is None:
                    return Answer("refused", None, None, "closed")
                client.receive_data(chunk)
                continue
            if isinstance(event, h11.InformationalResponse):
                if event.status_code == 101:  # a WebSocket handshake accepted: the app has it
                    return Answer("accepted", 101, None, "answer")
            elif isinstance(event, h11.Response):
                status = event.status_code
            elif isinstance(event, h11.Data):
                body += event.data
            elif isinstance(event, (h11.EndOfMessage, h11.ConnectionClosed)):
                try:
                    parsed = json.loads(body) if body else None
                except ValueError:
                    parsed = body
                kind = "refused" if is_framing_refusal(status, parsed) else "accepted"
                return Answer(kind, status, parsed, "answer")
    finally:
        sock.close()


def exchange(address, data: bytes, half_close: bool, timeout: float = 5.0) -> bytes:
    """Every byte the service sends back to ``data`` until it closes (or ``timeout`` passes quietly)."""
    sock = socket.create_connection(address, timeout=timeout)
    try:
        sock.sendall(data)
        if half_close:
            sock.shutdown(socket.SHUT_WR)
        out = b""
        while True:
            try:
                chunk = sock.recv(65536)
            except (socket.timeout, ConnectionResetError):
                return out
            if not chunk:
                return out
            out += chunk
    finally:
        sock.close()


def statuses(answers: bytes) -> list[int]:
    """The status of each whole response in ``answers``, in order."""
    client = h11.Connection(h11.CLIENT)
    client.receive_data(answers)
    client.receive_data(b"")
    found = []
    while True:
        if client.our_state is h11.IDLE:
            client.send(h11.Request(method="GET", target="/", headers=[("host", "localhost")]))
            client.send(h11.EndOfMessage())
        event = client.next_event()
        if isinstance(event, h11.Response):
            found.append(event.status_code)
        elif isinstance(event, h11.EndOfMessage):
            if client.our_state is not h11.DONE or client.their_state is not h11.DONE:
                return found
            client.start_next_cycle()
        elif event is h11.NEED_DATA or isinstance(event, h11.ConnectionClosed):
            return found
