"""One client connection: uvicorn's httptools (llhttp) protocol, with the service's limits, timeouts and routing.

uvicorn parses and frames HTTP/1.1 (keep-alive, pipelining, chunked bodies, the WebSocket upgrade); this
subclass adds what a public service needs and uvicorn leaves out, each answered in JSON with
``Connection: close``:

- a request not received whole within ``read_timeout`` of its first byte: 408;
- a request target over ``max_url`` bytes: 414; over ``max_headers`` header fields, or a head over
  ``max_header_bytes`` bytes: 431; a body over ``max_body`` bytes (announced, or chunked): 413, not read;
  an ``Expect`` other than ``100-continue``: 417; anything llhttp refuses: 400 with llhttp's reason;
- a connection idle between requests, or never sending a byte, for ``keepalive_timeout``: closed;
- more open connections than the worker's cap: 503 and closed (read and discarded for a moment first, so
  that closing with unread input does not reset the connection and destroy the answer).

With several workers, a request whose line names another worker's session (or a new session, placed on the
worker with the fewest) hands the whole connection to that worker before it is parsed (``workers.Router``):
the socket's file descriptor and the bytes read so far travel over a Unix socket, and the connection then
talks to that worker directly. Only the request line is read for this, and only between requests.
"""
from __future__ import annotations

import json
from http import HTTPStatus

import httptools
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from guardian.service import api
from guardian.service.sessions import SessionIds

REFUSED_DRAIN = 1.0    # seconds a connection refused at the cap is read (and discarded) before it closes
HANDOFF_RETRY = 0.002  # seconds between attempts to hand a connection to a worker whose inbox is full
SHUTDOWN_GRACE = 0.5   # seconds an idle keep-alive connection stays open after a stop, for a request on its way


class _Refused(Exception):
    """A request the limits refuse, raised from a parser callback."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status, self.message = status, message


def json_refusal(status: int, message: str, headers=()) -> bytes:
    """A whole JSON error answer with ``Connection: close``."""
    body = json.dumps({"error": message}).encode()
    lines = [f"HTTP/1.1 {status} {HTTPStatus(status).phrase}", "content-type: application/json",
             f"content-length: {len(body)}", "connection: close", *(f"{k}: {v}" for k, v in headers)]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1") + body


def request_line(buf: bytes) -> bytes | None:
    """The request line at the start of ``buf`` (empty lines before it skipped) once it is complete, or None."""
    start = 0
    while buf[start:start + 1] in (b"\r", b"\n"):
        start += 1
    end = buf.find(b"\n", start)
    return None if end < 0 else bytes(buf[start:end]).rstrip(b"\r")


def request_line_target(buf: bytes) -> bytes | None:
    """The target of a complete, well-formed request line at the start of ``buf``, or None."""
    line = request_line(buf)
    parts = line.split(b" ") if line is not None else ()
    return parts[1] if len(parts) == 3 else None


class GuardianHttpProtocol(HttpToolsProtocol):
    """uvicorn's ``HttpToolsProtocol`` for one worker of the service (``service``: its ``Server``)."""

    def __init__(self, config, server_state, app_state, _loop=None, service=None, initial: bytes = b"",
                 placed_by: int | None = None):
        super().__init__(config, server_state, app_state, _loop)
        self.service, self.limits = service, service.limits
        self.initial, self.placed_by = initial, placed_by
        self.refused = False
        self.pending = bytearray()    # bytes of a new request held until its line says where it goes
        self.in_message = False       # the parser is inside a request
        self.in_head = False
        self.head_bytes = self.body_bytes = self.header_count = self.head_size = 0
        self.read_timer = None
        self.handoff_tries = 0
        self.eof = False              # the client half-closed: answer what came, then close
        self.body_cycle = None        # the cycle of the request whose body is being read
        self.refusal = None           # a refusal written once the whole requests before it are answered
        self.stopping = False         # the server stops: the next answer says Connection: close

    # ---- the connection -----------------------------------------------------------------------------------
    def connection_made(self, transport) -> None:
        if len(self.server_state.connections) >= self.service.connection_cap:
            self.refused, self.transport = True, transport
            self.service.refused += 1
            transport.write(json_refusal(503, f"connection limit {self.service.connection_cap} reached; try "
                                              "again later", (("retry-after", "1"),)))
            if transport.can_write_eof():
                transport.write_eof()
            self.loop.call_later(REFUSED_DRAIN, transport.abort)
            return
        super().connection_made(transport)
        self.timeout_keep_alive_task = self.loop.call_later(self.timeout_keep_alive, self.timeout_keep_alive_handler)
        if self.initial:
            initial, self.initial = self.initial, b""
            self.data_received(initial)

    def connection_lost(self, exc) -> None:
        self._placement_done()
        if self.refused:
            return
        self._stop_read_timer()
        super().connection_lost(exc)

    def eof_received(self):
        """A half-close: whole requests are answered, then the connection closes (``nc -N``); a request cut short
        by it never arrived and gets no answer (nothing of it ran: the app reads a body whole first)."""
        self.eof = True
        if self.refusal is not None:
            return True  # the requests before a refused one are answered, then the refusal, then close
        if self.refused or (self.in_message and not self.in_head):
            return None  # refused, or a body that will never come (its cycle sees a disconnect): close
        if (self.cycle is not None and not self.cycle.response_complete) or self.pipeline:
            return True  # answer the whole requests, then close (on_response_complete)
        return None      # idle, or a head cut short: close

    def data_received(self, data: bytes) -> None:
        if self.refused or self.refusal is not None:
            return  # drained, never read (after a refusal, nothing more is parsed)
        self._unset_keepalive_if_required()
        if not self.in_message and self._idle():
            self.pending += data
            if self.read_timer is None:
                self.read_timer = self.loop.call_later(self.limits.read_timeout, self._read_timed_out)
            if self.service.router is not None and self._handed_off():
                return
            if request_line(self.pending) is None and len(self.pending) <= self.limits.max_url + 16:
                return  # the request line is not complete yet
            data, self.pending = bytes(self.pending), bytearray()
        self._feed(data)

    def _feed(self, data: bytes) -> None:
        try:
            self.parser.feed_data(data)
            if self.in_head:
                self.head_bytes += len(data)
                if self.head_bytes > self.limits.max_header_bytes:
                    raise _Refused(431, f"request head longer than {self.limits.max_header_bytes} bytes")
        except _Refused as exc:
            self.refuse(exc.status, exc.message)
        except httptools.HttpParserCallbackError as exc:
            cause = exc.__context__
            if isinstance(cause, _Refused):
                self.refuse(cause.status, cause.message)
            else:
                self.refuse(400, f"invalid HTTP request: {exc}")
        except httptools.HttpParserError as exc:
            self.refuse(400, f"invalid HTTP request: {exc}")
        except httptools.HttpParserUpgrade:
            if self._should_upgrade():
                self._stop_read_timer()
                self.handle_websocket_upgrade()
                self._handshake_unanswered()
            else:
                self._unsupported_upgrade_warning()

    def _handshake_unanswered(self) -> None:
        """A WebSocket handshake that websockets refused while parsing it (a body announced, a header line over its
        8 KB, a path that is not ASCII...) is neither answered nor closed by uvicorn's WebSocket protocol, and no
        timer runs there: the connection would be held open for good. Answer it in JSON and close."""
        ws = self.transport.get_protocol()
        exc = getattr(getattr(ws, "conn", None), "handshake_exc", None)
        if ws is self or exc is None or getattr(ws, "handshake_initiated", True) or self.transport.is_closing():
            return
        cause = exc.__cause__ or exc
        status = {"RequestLineTooLong": 414, "HeaderLineTooLong": 431, "TooManyHeaders": 431}.get(type(cause).__name__, 400)
        self.transport.write(json_refusal(status, f"invalid WebSocket handshake: {cause}"))
        self.transport.close()

    def shutdown(self) -> None:
        """The server stops. A request in flight is answered with ``Connection: close``; an idle connection
        stays open ``SHUTDOWN_GRACE`` seconds, so a request a keep-alive client sent as the signal came is
        answered (and told to close) rather than reset."""
        self.stopping = True
        if self._idle() and not self.in_message and not self.pending:
            self.loop.call_later(SHUTDOWN_GRACE, self._close_if_idle)
        elif self.cycle is not None and not self.cycle.response_complete:
            self.cycle.keep_alive = False

    def _close_if_idle(self) -> None:
        if self.transport.is_closing():
            return
        if self._idle() and not self.in_message and not self.pending:
            self.transport.close()
        elif self.cycle is not None:
            self.cycle.keep_alive = False

    def _idle(self) -> bool:
        """Between requests: nothing being answered, nothing queued behind."""
        return (self.cycle is None or self.cycle.response_complete) and not self.pipeline

    def refuse(self, status: int, message: str, headers=()) -> None:
        """Answer ``status`` in JSON and close (the request, if it reached the app, sees a disconnect).

        Answers go out in request order: whole requests pipelined before the refused one (received in the same
        read, say) are answered first, then the refusal; until then nothing more is parsed. The refused request
        itself never runs: queued behind others, it is dropped; running, it sees the disconnect."""
        self._stop_read_timer()
        if self.transport.is_closing() or self.refusal is not None:
            return
        answer = json_refusal(status, message, headers)
        refused, self.body_cycle = self.body_cycle, None
        queued = False
        for entry in list(self.pipeline):
            if entry[0] is refused:
                self.pipeline.remove(entry)
                queued = True  # an earlier request is still being answered
        ahead = queued or bool(self.pipeline) or (
            self.cycle is not None and self.cycle is not refused and not self.cycle.response_complete)
        if ahead:
            self.refusal = answer
            return
        self.transport.write(answer)
        self.transport.close()

    def send_400_response(self, msg: str) -> None:
        self.refuse(400, msg)

    def _read_timed_out(self) -> None:
        self.read_timer = None
        if self.handoff_tries:
            return  # waiting for another worker to take the connection: that wait has its own deadline
        if self.in_message or self.pending:
            part = "body" if self.in_message and not self.in_head else "head"
            self.refuse(408, f"request {part} not received within {self.limits.read_timeout:g} s")

    def _stop_read_timer(self) -> None:
        if self.read_timer is not None:
            self.read_timer.cancel()
            self.read_timer = None

    # ---- the parser's callbacks: the limits ---------------------------------------------------------------
    def on_message_begin(self) -> None:
        self.in_message = self.in_head = True
        self.body_cycle = None
        self.head_bytes = self.body_bytes = self.header_count = self.head_size = 0
        if self.read_timer is None:
            self.read_timer = self.loop.call_later(self.limits.read_timeout, self._read_timed_out)
        super().on_message_begin()

    def on_url(self, url: bytes) -> None:
        super().on_url(url)
        if len(self.url) > self.limits.max_url:
            raise _Refused(414, f"request target longer than {self.limits.max_url} bytes")

    def on_header(self, name: bytes, value: bytes) -> None:
        self.header_count += 1
        if self.header_count > self.limits.max_headers:
            raise _Refused(431, f"more than {self.limits.max_headers} header fields")
        self.head_size += len(name) + len(value) + 4
        if self.head_size > self.limits.max_header_bytes:
            raise _Refused(431, f"request head longer than {self.limits.max_header_bytes} bytes")
        super().on_header(name, value)

    def on_headers_complete(self) -> None:
        self.in_head = False
        version = self.parser.get_http_version()
        if version not in ("1.0", "1.1"):
            raise _Refused(505, f"HTTP/{version} is not supported: this service speaks HTTP/1.1")
        for name, value in self.headers:
            if name == b"content-length" and value.isdigit() and int(value) > self.limits.max_body:
                raise _Refused(413, f"body of {int(value)} bytes exceeds {self.limits.max_body}")
            if name == b"expect" and value.lower() != b"100-continue":
                raise _Refused(417, f"Expect {value.decode('latin-1')!r} is not supported (only 100-continue)")
            if name == b"transfer-encoding" and value.strip().lower() != b"chunked":
                raise _Refused(501, f"Transfer-Encoding {value.decode('latin-1')!r} is not supported (only chunked)")
        before = self.cycle
        super().on_headers_complete()
        if self.cycle is not before:
            self.body_cycle = self.cycle
            if self.stopping:
                self.cycle.keep_alive = False

    def on_body(self, body: bytes) -> None:
        self.body_bytes += len(body)
        if self.body_bytes > self.limits.max_body:
            raise _Refused(413, f"body exceeds {self.limits.max_body} bytes")
        super().on_body(body)

    def on_message_complete(self) -> None:
        self.in_message = False
        self.body_cycle = None
        self._stop_read_timer()
        super().on_message_complete()

    def on_response_complete(self) -> None:
        self._placement_done()
        last = not self.pipeline  # the request just answered was the last one queued
        super().on_response_complete()
        if self.refusal is not None and last and not self.transport.is_closing():
            self.transport.write(self.refusal)
            self.transport.close()
        if self.eof and not self.pipeline and not self.transport.is_closing():
            self.transport.close()

    # ---- handing the connection to another worker ----------------------------------------------------------
    def _placement_done(self) -> None:
        if self.placed_by is not None:
            self.service.cluster.answered_placement(self.placed_by)
            self.placed_by = None

    def _handed_off(self) -> bool:
        """True when the pending request line names another worker's session (or a new session the router
        places elsewhere) and the connection went there."""
        target = request_line_target(self.pending)
        if target is None:
            return False
        router = self.service.router
        text = target.decode("latin-1")
        placement = text.split("?", 1)[0] == "/sessions" and self.pending.lstrip(b"\r\n").startswith(b"POST ")
        if placement:
            if self.placed_by is not None:
                return False  # placed here already: never passed on again
            worker = router.place()
            if worker == router.worker:
                self.placed_by = router.keep_placement()
                return False
        else:
            sid = api.session_of(text)
            parsed = SessionIds.parse(sid) if sid else None
            if parsed is None or parsed[0] != router.node or parsed[1] == router.worker or parsed[1] >= router.workers:
                return False
            worker = parsed[1]
        if self.transport.get_write_buffer_size() or not router.send_connection(
                worker, self.transport.get_extra_info("socket").fileno(), bytes(self.pending), placement=placement):
            # an answer is still being written, or the worker's inbox is full: try again shortly, then give up
            self.handoff_tries += 1
            if self.handoff_tries * HANDOFF_RETRY > self.limits.read_timeout:
                self.refuse(503, f"worker {worker} takes no connections now; try again later", (("retry-after", "1"),))
                return True
            self.transport.pause_reading()
            self.loop.call_later(HANDOFF_RETRY, self._retry_handoff)
            return True
        self._stop_read_timer()
        self.connections.discard(self)
        self.service.handed_off += 1
        self.refused = True   # nothing more is read here
        self.transport.abort()  # our descriptor closes; the socket lives on in the other worker
        return True

    def _retry_handoff(self) -> None:
        if self.transport.is_closing():
            return
        self.transport.resume_reading()
        if not self._handed_off():
            data, self.pending = bytes(self.pending), bytearray()
            self._feed(data)
