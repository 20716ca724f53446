"""One client connection: HTTP/1.1 requests answered in arrival order, or one WebSocket stream.

A request is read whole (head, then body) before anything runs, and answered in the same event-loop
turn its last byte arrived in: a client that leaves mid-request has nothing executed, and one that
half-closes its socket right after a request (``nc -N``) still gets its answer. Timeouts are checked
by the server's sweeper (``Connection.tick``):

- a request not received whole within ``read_timeout`` of its first byte: 408 (JSON), close;
- a connection idle between requests (or never sending a byte) for ``keepalive_timeout``: closed;
- a framing error: JSON with the status (400, 413, 414, 417, 431, 501, 505) and ``Connection: close``.

With several workers, a request naming another worker's session hands the whole connection to that
worker before its head is parsed (``workers.Router``): the socket's file descriptor and the bytes
read so far travel over a Unix socket, and the connection then talks to that worker directly. A
``POST /sessions`` goes the same way to the worker with the fewest sessions.
"""
from __future__ import annotations

import asyncio
import inspect
import logging

from guardian.service import api
from guardian.service.http import (REASONS, ChunkedReader, FramingError, find_head_end, parse_head,
                                   request_line_target, serialize)
from guardian.service.sessions import SECRET_HEADER, ServiceError, SessionIds

log = logging.getLogger("guardian.service")
REFUSED_DRAIN = 1.0  # seconds a connection refused at the limit is read (and discarded) before it closes
HANDOFF_RETRY = 0.002  # seconds between attempts to hand a connection to a worker whose inbox is full


class Connection(asyncio.BufferedProtocol):
    """HTTP/1.1 (keep-alive, pipelining, chunked bodies) on one socket; see the module docstring.

    A buffered protocol: the transport reads into one 64 KiB buffer per worker (``get_buffer``) and the
    bytes are copied out at once (``buffer_updated``); a plain protocol's reads allocate 256 KiB each
    (~11 us per request on Python 3.11).
    """

    def __init__(self, server, initial: bytes = b"", placed_by: int | None = None):
        self.server = server
        self.placed_by = placed_by  # a new session's connection another worker sent here
        self.app = server.app
        self.limits = server.limits
        self.buf = bytearray(initial)
        self.transport = None
        self.state = "idle"     # idle | body | busy | stream | gone
        self.head = None
        self.chunks = None
        self.started = None     # when the request being read began (its first byte)
        self.last_active = server.now()
        self.stream = None
        self.close_after = False   # answer what is running, then close (the client half-closed)
        self.write_paused = False
        self.task = None
        self.handoff_tries = 0

    def now(self) -> float:
        return self.server.now()

    # ---- asyncio.Protocol ---------------------------------------------------------------------------

    def connection_made(self, transport) -> None:
        self.transport = transport
        conns = self.server.connections
        if len(conns) >= self.server.connection_cap:
            # answer at once, half-close, and drain what the client still sends for a moment (closing
            # with unread input would reset the connection and could destroy the answer)
            self.server.refused += 1
            self.server.refusing.add(self)
            self.state, self.started = "refused", self.now()
            resp = api.error(503, f"connection limit {self.server.connection_cap} reached; try again later",
                             (("retry-after", "1"),), close=True)
            transport.write(serialize(resp.status, resp.body, resp.headers, True))
            if transport.can_write_eof():
                transport.write_eof()
            return
        conns.add(self)
        if self.buf:
            self._process()

    def get_buffer(self, sizehint: int):
        return self.server.read_buffer

    def buffer_updated(self, nbytes: int) -> None:
        self.data_received(bytes(self.server.read_buffer[:nbytes]))

    def data_received(self, data: bytes) -> None:
        if self.state == "stream":
            self.stream.data_received(data)
            return
        if self.state in ("gone", "refused"):
            return
        self.buf += data
        self.last_active = self.now()
        if self.state in ("idle", "body"):
            self._process()
        elif len(self.buf) > self.limits.max_body + self.limits.max_header_bytes:
            self.transport.pause_reading()  # busy: hold further pipelined input until the answer is out

    def eof_received(self):
        if self.state == "stream":
            self.stream.eof_received()
            return False
        if self.state == "busy":  # a whole request is running: answer it, then close
            self.close_after = True
            return True
        if self.state == "refused":
            self.server.refusing.discard(self)
        return False  # nothing complete is pending: close (written answers are flushed first)

    def connection_lost(self, exc) -> None:
        self.server.connections.discard(self)
        self.server.refusing.discard(self)
        self._placement_done()
        if self.stream is not None:
            self.stream.detach()
        self.state = "gone"

    def pause_writing(self) -> None:
        self.write_paused = True
        self.transport.pause_reading()

    def resume_writing(self) -> None:
        self.write_paused = False
        if self.state in ("idle", "body"):
            self.transport.resume_reading()
            self._process()

    # ---- requests -----------------------------------------------------------------------------------

    def _process(self) -> None:
        limits = self.limits
        while not self.write_paused and self.state in ("idle", "body"):
            if self.state == "idle":
                while self.buf[:1] in (b"\r", b"\n"):  # empty lines before a request line are ignored
                    del self.buf[:1]
                if not self.buf:
                    self.started = None
                    return
                if self.started is None:
                    self.started = self.now()
                if self.server.router is not None and self._handed_off():
                    return
                found = find_head_end(self.buf)
                if found is None:
                    if len(self.buf) > limits.max_header_bytes:
                        if b"\n" not in self.buf[:limits.max_header_bytes]:
                            self._fail(414, f"request line longer than {limits.max_header_bytes} bytes")
                        else:
                            self._fail(431, f"request head longer than {limits.max_header_bytes} bytes")
                    return
                end, body_start = found
                if end > limits.max_header_bytes:
                    line_end = self.buf.find(b"\n", 0, limits.max_header_bytes)
                    if line_end < 0:
                        self._fail(414, f"request line longer than {limits.max_header_bytes} bytes")
                    else:
                        self._fail(431, f"request head of {end} bytes is longer than {limits.max_header_bytes}")
                    return
                raw = bytes(self.buf[:end])
                del self.buf[:body_start]
                try:
                    head = parse_head(raw, limits)
                except FramingError as exc:
                    self._fail(exc.status, exc.message)
                    return
                if head.upgrade == "websocket" and api.route(head.path) is not None \
                        and api.route(head.path)[0] == "stream" and head.method == "GET":
                    self._upgrade(head)
                    return
                refusal = self.app.check_head(head)
                if refusal is not None:
                    self._answer(refusal, head)
                    if refusal.close:
                        return
                    continue
                self.head, self.state = head, "body"
                self.chunks = ChunkedReader(limits) if head.chunked else None
                if head.expect_continue and head.has_body and not self.buf:
                    self.transport.write(b"HTTP/1.1 100 Continue\r\n\r\n")
            head = self.head
            try:
                if self.chunks is not None:
                    if not self.chunks.feed(self.buf):
                        return
                    body = bytes(self.chunks.body)
                else:
                    n = head.content_length or 0
                    if len(self.buf) < n:
                        return
                    body = bytes(self.buf[:n])
                    del self.buf[:n]
            except FramingError as exc:
                self._fail(exc.status, exc.message)
                return
            self.state, self.head, self.chunks = "idle", None, None
            self.started = self.now() if self.buf else None
            self._run(head, body)

    def _placement_done(self) -> None:
        if self.placed_by is not None:
            self.server.cluster.answered_placement(self.placed_by)
            self.placed_by = None

    def _run(self, head, body: bytes) -> None:
        try:
            result = self.app.handle(head, body)
        except Exception:  # a bug must still answer in JSON, and be logged
            log.exception("guardian service: unhandled error on %s %s", head.method, head.path)
            result = api.error(500, "internal error (logged by the service)", close=True)
        self._placement_done()  # after the session exists: the load others read never misses it
        if inspect.isawaitable(result):
            self.state = "busy"
            self.task = asyncio.ensure_future(self._finish(head, result))
            self.server.tasks.add(self.task)
            self.task.add_done_callback(self.server.tasks.discard)
            return
        self._answer(result, head)

    async def _finish(self, head, awaitable) -> None:
        try:
            result = await awaitable
        except ServiceError as exc:
            result = api.service_error(exc)
        except Exception:
            log.exception("guardian service: unhandled error on %s %s", head.method, head.path)
            result = api.error(500, "internal error (logged by the service)", close=True)
        if self.state == "gone":
            return
        self.state = "idle"
        self._answer(result, head)
        if self.state == "idle":
            self.transport.resume_reading()
            self.started = self.now() if self.buf else None
            self._process()

    def _answer(self, resp: api.Response, head) -> None:
        close = resp.close or head.close or self.close_after or self.app.stopping
        self.transport.write(serialize(resp.status, resp.body, resp.headers, close, head.method == "HEAD",
                                       resp.content_type))
        self.last_active = self.now()
        if close:
            self.close_transport()

    def write(self, data: bytes) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(data)

    def respond_error(self, status: int, message: str, headers=()) -> None:
        """A JSON error and close (a refused WebSocket handshake)."""
        self._send_and_close(status, message, headers)

    def _fail(self, status: int, message: str) -> None:
        if status == 400 and not message.startswith("invalid HTTP request"):
            message = "invalid HTTP request: " + message
        self._send_and_close(status if status in REASONS else 400, message)

    def _send_and_close(self, status: int, message: str, headers=()) -> None:
        resp = api.error(status, message, headers, close=True)
        self.transport.write(serialize(resp.status, resp.body, resp.headers, True))
        self.close_transport()

    def close_transport(self) -> None:
        self.state = "gone" if self.state != "stream" else self.state
        if self.transport is not None and not self.transport.is_closing():
            self.transport.close()

    def abort(self) -> None:
        if self.transport is not None:
            self.transport.abort()

    # ---- the WebSocket stream -------------------------------------------------------------------------

    def _upgrade(self, head) -> None:
        from guardian.service.stream import Stream

        refusal = self.app.check_head(head)
        if refusal is not None:
            self._answer(api.Response(refusal.status, refusal.body, refusal.headers, True), head)
            return
        sid = api.route(head.path)[1]
        secret = head.headers.get(SECRET_HEADER)
        try:
            session = self.app.store.authorized(sid, secret)
            if session.stream is not None:
                self._send_and_close(409, f"session {sid!r} already has a stream (one writer per session)")
                return
        except ServiceError as exc:
            if exc.status == 403:
                self._send_and_close(403, exc.message)
                return
            # unknown, expired, restarted, misrouted: the stream says so once accepted
        extra, self.buf = bytes(self.buf), bytearray()
        stream = Stream(self, self.app.store, sid, secret, self.limits, self.now())
        self.state, self.stream = "stream", stream
        if not stream.accept(head, extra):
            self.state = "gone"

    # ---- timeouts (the server's sweeper calls this) ---------------------------------------------------

    def tick(self, now: float) -> None:
        if self.state == "refused":
            if now - self.started > REFUSED_DRAIN:
                self.abort()
        elif self.state == "stream":
            self.stream.tick(now)
        elif self.state in ("idle", "body"):
            if self.started is not None:
                if now - self.started > self.limits.read_timeout:
                    part = "head" if self.state == "idle" else "body"
                    self._send_and_close(408, f"request {part} not received within {self.limits.read_timeout:g} s")
            elif now - self.last_active > self.limits.keepalive_timeout:
                self.close_transport()

    def shutdown(self) -> None:
        """SIGTERM: idle connections close now; a request being read is answered with Connection: close."""
        if self.state == "stream":
            self.stream.close(1001, "the service is stopping")
        elif self.state == "idle" and not self.buf:
            self.close_transport()

    # ---- handing the connection to another worker ----------------------------------------------------

    def _handed_off(self) -> bool:
        """True when the request line names another worker's session and the connection went there."""
        target = request_line_target(self.buf)
        if target is None:
            return False
        router = self.server.router
        text = target.decode("latin-1")
        placement = text.split("?", 1)[0] == "/sessions" and self.buf.startswith(b"POST ")
        if placement:
            if self.placed_by is not None:
                return False  # placed here already: never passed on again
            worker = router.place()  # a new session goes to the worker with the fewest
            if worker == router.worker:
                return False
        else:
            sid = api.session_of(text)
            parsed = SessionIds.parse(sid) if sid else None
            if parsed is None or parsed[0] != router.node or parsed[1] == router.worker or parsed[1] >= router.workers:
                return False
            worker = parsed[1]
        if self.transport.get_write_buffer_size():
            # an earlier answer is still being written: wait for it, or it could arrive after the next one
            self.state = "busy"
            self.transport.pause_reading()
            asyncio.get_running_loop().call_later(HANDOFF_RETRY, self._retry_handoff)
            return True
        sock = self.transport.get_extra_info("socket")
        if not router.send_connection(worker, sock.fileno(), bytes(self.buf), placement=placement):
            # the worker's inbox is full (it is far behind, or restarting): try again shortly, then give up
            self.handoff_tries += 1
            if self.handoff_tries * HANDOFF_RETRY > self.limits.read_timeout:
                self._send_and_close(503, f"worker {worker} takes no connections now; try again later",
                                     (("retry-after", "1"),))
                return True
            self.state = "busy"
            self.transport.pause_reading()
            asyncio.get_running_loop().call_later(HANDOFF_RETRY, self._retry_handoff)
            return True
        self.server.connections.discard(self)
        self.server.handed_off += 1
        self.state = "gone"
        self.transport.abort()  # our descriptor closes; the socket lives on in the other worker
        return True

    def _retry_handoff(self) -> None:
        if self.state == "busy":
            self.state = "idle"
            self.transport.resume_reading()
            self._process()
