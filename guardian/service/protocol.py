"""uvicorn's h11 protocol with JSON framing errors and a read timeout on the request head.

uvicorn answers a request it cannot parse with a plain-text 400 and has no timeout for a request
head that never completes (a client that sends half a header holds its connection forever). This
subclass keeps uvicorn's framing (h11: chunked bodies, Content-Length validation, pipelining) and
changes three things:

- a framing error is answered in JSON with the status h11 hints (400, 414 for a request line over
  the head limit, 431 for a head over it), with ``Connection: close``;
- a request head not complete within ``read_timeout`` gets 408 (JSON) and the connection closes;
- a connection that never sends a byte is closed after the keep-alive timeout.
"""
from __future__ import annotations

import json

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from guardian.service.limits import Limits

_REASONS = {400: "Bad Request", 408: "Request Timeout", 414: "URI Too Long",
            431: "Request Header Fields Too Large", 501: "Not Implemented"}


class _Connection(h11.Connection):
    """An h11 connection that remembers the last protocol error (uvicorn drops it)."""

    last_error: h11.RemoteProtocolError | None = None

    def next_event(self):
        try:
            return super().next_event()
        except h11.RemoteProtocolError as exc:
            self.last_error = exc
            raise


class GuardedH11Protocol(H11Protocol):
    limits: Limits = Limits()  # set per server by ``guardian.service.server``

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.conn = _Connection(h11.SERVER, self.limits.max_header_bytes)
        self._head_timer = None
        self._head_has_line_end = False

    def connection_made(self, transport) -> None:
        super().connection_made(transport)
        self.timeout_keep_alive_task = self.loop.call_later(self.timeout_keep_alive,
                                                            self.timeout_keep_alive_handler)

    def connection_lost(self, exc) -> None:
        self._cancel_head_timer()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self.conn.their_state is h11.IDLE:
            if self._head_timer is None:
                self._head_has_line_end = False
                self._head_timer = self.loop.call_later(self.limits.read_timeout, self._head_timeout)
            self._head_has_line_end = self._head_has_line_end or b"\n" in data
        super().data_received(data)

    def handle_events(self) -> None:
        super().handle_events()
        if self.conn.their_state is not h11.IDLE:
            self._cancel_head_timer()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if self.conn.their_state is h11.IDLE and self.conn.trailing_data[0]:
            self._head_has_line_end = b"\n" in self.conn.trailing_data[0]
            if self._head_timer is None:
                self._head_timer = self.loop.call_later(self.limits.read_timeout, self._head_timeout)

    def _cancel_head_timer(self) -> None:
        if self._head_timer is not None:
            self._head_timer.cancel()
            self._head_timer = None

    def _head_timeout(self) -> None:
        self._head_timer = None
        if self.conn.their_state is h11.IDLE and not self.transport.is_closing():
            self._reply_and_close(408, f"request head not received within {self.limits.read_timeout:g} s")

    def send_400_response(self, msg: str) -> None:
        exc = self.conn.last_error
        status = getattr(exc, "error_status_hint", 400) if exc is not None else 400
        detail = str(exc) if exc is not None and str(exc) else msg
        if status == 431 and not self._head_has_line_end:
            status, detail = 414, f"request line longer than {self.limits.max_header_bytes} bytes"
        elif status == 431:
            detail = f"request head longer than {self.limits.max_header_bytes} bytes"
        self._reply_and_close(status if status in _REASONS else 400, f"invalid HTTP request: {detail}")

    def _reply_and_close(self, status: int, message: str) -> None:
        """Write a whole JSON response past h11 (its state may be ERROR) and close."""
        self._cancel_head_timer()
        body = json.dumps({"error": message}).encode()
        head = (f"HTTP/1.1 {status} {_REASONS[status]}\r\ncontent-type: application/json\r\n"
                f"content-length: {len(body)}\r\nconnection: close\r\n\r\n").encode()
        self.transport.write(head + body)
        self.transport.close()
