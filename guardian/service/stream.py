"""The step stream: one WebSocket per session (``GET /sessions/ID/stream``), over websockets' sans-I/O protocol.

Each text (or binary) message is a step body ``{"seq", "state", "input"}``; each reply is its record,
or ``{"error", "status", ...}`` with the status HTTP would give. Replies come in message order.

- The handshake is refused with an HTTP JSON answer for the token (401), ``Host``/``Origin`` (403),
  a missing or wrong ``Session-Secret`` (403), and a session that already has a stream (409: one
  writer per session). An unknown, expired, restarted or misrouted session is accepted, told
  ``{"error", "status"}`` and closed with code 4000 + status (4404, 4410, 4421).
- While a stream is attached, HTTP steps on its session get 409 and the session does not expire.
- A message over ``--max-body`` gets a 413 reply and the stream stays open; one over
  ``stream_frame_factor`` x ``--max-body`` (1 MiB by default) is not read: the stream closes with
  1009 (message too big), as RFC 6455 says.
- A stream without a message for ``--stream-idle-timeout`` seconds is closed with 4408; a deleted
  session closes its stream with 4404 at once.
"""
from __future__ import annotations

import json
import logging

from websockets.frames import Opcode
from websockets.http11 import Request
from websockets.protocol import State
from websockets.server import ServerProtocol

from guardian.service.api import StepRequest, parse_body
from guardian.service.sessions import ServiceError

log = logging.getLogger("guardian.service")
_quiet = logging.getLogger("guardian.service.websockets")
_quiet.setLevel(logging.WARNING)
CLOSE_WAIT = 5.0  # seconds a closing stream waits for the client's close frame


class Stream:
    """One accepted WebSocket of one session, driven by its connection's bytes."""

    def __init__(self, conn, store, sid: str, secret: str | None, limits, now: float):
        self.conn = conn
        self.store = store
        self.sid = sid
        self.secret = secret
        self.limits = limits
        self.proto = ServerProtocol(max_size=limits.max_stream_frame, logger=_quiet)
        self.session = None
        self.last_message = now
        self.closing_since = None
        self._fragments = None

    # ---- the handshake ------------------------------------------------------------------------------

    def accept(self, head, extra: bytes) -> bool:
        """Answer the handshake of ``head``; False if it was refused (the connection then closes)."""
        # websockets' parser reads the handshake from the byte stream before any frame: give it the head
        lines = [f"GET {head.target} HTTP/1.1"] + [f"{name}: {value}" for name, value in head.raw_lines]
        self.proto.receive_data(("\r\n".join(lines) + "\r\n\r\n").encode("latin-1"))
        requests = [e for e in self.proto.events_received() if isinstance(e, Request)]
        if not requests:
            self.conn.respond_error(400, "malformed WebSocket handshake")
            return False
        response = self.proto.accept(requests[0])
        if response.status_code != 101:  # a malformed handshake: websockets says why
            reason = response.body.decode(errors="replace").strip() if response.body else response.reason_phrase
            extra_headers = tuple((k.lower(), v) for k, v in response.headers.raw_items()
                                  if k.lower() in ("upgrade", "allow", "sec-websocket-version"))
            self.conn.respond_error(response.status_code, reason, extra_headers)
            return False
        self.proto.send_response(response)
        self._flush()
        try:
            self.session = self.store.get(self.sid)
        except ServiceError as exc:  # accepted, told why, closed with 4000 + status
            self._reply(json.dumps({**exc.body(), "status": exc.status}).encode())
            self.close(4000 + exc.status, exc.message)
            return True
        self.session.stream = self
        if extra:
            self.data_received(extra)
        return True

    # ---- frames -------------------------------------------------------------------------------------

    def data_received(self, data: bytes) -> None:
        self.proto.receive_data(data)
        self._events()

    def eof_received(self) -> None:
        self.proto.receive_eof()
        self._events()

    def _events(self) -> None:
        for frame in self.proto.events_received():
            if frame.opcode in (Opcode.TEXT, Opcode.BINARY):
                if frame.fin:
                    self._message(bytes(frame.data))
                else:
                    self._fragments = bytearray(frame.data)
            elif frame.opcode is Opcode.CONT and self._fragments is not None:
                self._fragments += frame.data
                if frame.fin:
                    data, self._fragments = bytes(self._fragments), None
                    self._message(data)
        self._flush()

    def _message(self, raw: bytes) -> None:
        self.last_message = self.conn.now()
        if self.proto.state is not State.OPEN:
            return
        if len(raw) > self.limits.max_body:
            self._reply(json.dumps({"error": f"message of {len(raw)} bytes exceeds {self.limits.max_body}",
                                    "status": 413}).encode())
            return
        try:
            req = parse_body(StepRequest, raw, self.limits)
            self._reply(self.store.step(self.sid, self.secret, req.seq, req.state, req.input, stream=self))
        except ServiceError as exc:
            self._reply(json.dumps({**exc.body(), "status": exc.status}).encode())
            if exc.status in (404, 410):
                self.close(4000 + exc.status, exc.message)

    def _reply(self, body: bytes) -> None:
        if self.proto.state is State.OPEN:
            self.proto.send_text(body)

    def _flush(self) -> None:
        data = self.proto.data_to_send()
        if not data:
            return
        eof = any(chunk == b"" for chunk in data)
        self.conn.write(b"".join(data))
        if eof or self.proto.state is State.CLOSED:
            self.detach()
            self.conn.close_transport()

    # ---- ending -------------------------------------------------------------------------------------

    def close(self, code: int, reason: str) -> None:
        """Start the closing handshake (the connection closes when the client answers, or after CLOSE_WAIT)."""
        if self.proto.state is State.OPEN:
            self.proto.send_close(code, reason[:120])
            self.closing_since = self.conn.now()
        self.detach()
        self._flush()

    def session_closed(self) -> None:
        """The session was deleted: say so and close with 4404."""
        self._reply(json.dumps({"error": f"session {self.sid!r} was deleted", "status": 404}).encode())
        self.close(4404, "session deleted")

    def detach(self) -> None:
        if self.session is not None and self.session.stream is self:
            self.session.stream = None
            self.session.last_used = self.store.clock()
        self.session = None

    def tick(self, now: float) -> None:
        """Called by the server's sweeper: idle streams close (4408), unanswered closings end."""
        if self.proto.state is State.OPEN and now - self.last_message > self.limits.stream_idle_timeout:
            self.close(4408, f"no message for {self.limits.stream_idle_timeout:g} s")
        elif self.closing_since is not None and now - self.closing_since > CLOSE_WAIT:
            self.detach()
            self.conn.abort()
