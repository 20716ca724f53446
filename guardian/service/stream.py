"""The step stream: one WebSocket per session (``GET /sessions/ID/stream``), on the server's own WebSocket support.

Each text (or binary) message is a step body (the session's kind's: ``guardian.service.api.StepRequest`` or
``guardian.service.scene.SceneStep``); each reply is its record, or ``{"error", "status", ...}`` with the
status HTTP would give. Replies come in message order.

- The handshake is refused with an HTTP JSON answer for the token (401), ``Host``/``Origin`` (403), a wrong
  ``Session-Secret`` (403), and a session that already has a stream (409: one writer per session). An unknown,
  expired, restarted or misrouted session is accepted, told ``{"error", "status"}`` and closed with code 4000 +
  status (4404, 4410, 4421).
- A browser cannot send headers with a WebSocket: a handshake from an allowed ``Origin`` without
  ``Session-Secret`` is accepted and its first message must be ``{"secret": S}`` (with ``"token": T`` when the
  service requires one); a wrong one is told why and closed with 4401 or 4403.
- While a stream is attached, HTTP steps on its session get 409 and the session does not expire.
- A message over ``--max-body`` gets a 413 reply and the stream stays open; one over ``stream_frame_factor``
  x ``--max-body`` (1 MiB by default) is not read: the server closes the stream with 1009 (message too big).
- A stream without a message for ``--stream-idle-timeout`` seconds is closed with 4408; a deleted session
  closes its stream with 4404 at once; a stopping service closes every stream with 1012 (service restart).
"""
from __future__ import annotations

import asyncio
import json
import logging

from guardian.service import api
from guardian.service.sessions import SECRET_HEADER, ServiceError

log = logging.getLogger("guardian.service")


class Stream:
    """One WebSocket of one session (see the module docstring)."""

    def __init__(self, app, scope, receive, send):
        from guardian.service.app import Request

        self.app, self.store, self.limits = app, app.store, app.limits
        self.scope, self.receive, self.send = scope, receive, send
        self.request = Request(scope)
        self.sid = api.route(self.request.path)[1] if api.route(self.request.path) else None
        self.secret = self.request.headers.get(SECRET_HEADER)
        self.session = None
        self.closed = False

    async def run(self) -> None:
        if (await self.receive())["type"] != "websocket.connect":
            return
        refusal = self.app.check(self.request, stream=True)
        if refusal is None and (self.sid is None or api.route(self.request.path)[0] != "stream"):
            refusal = api.error(404, f"no WebSocket at {self.request.path}; streams are /sessions/ID/stream")
        gone = None
        if refusal is None:
            try:
                self.store.get(self.sid)
            except ServiceError as exc:  # unknown, expired, restarted, misrouted: accepted, told, closed
                gone = exc
        browser = "origin" in self.request.headers
        if refusal is None and gone is None and (self.secret is not None or not browser):
            refusal = self._authorize(self.secret)
        if refusal is not None:
            await self._deny(refusal)
            return
        await self.send({"type": "websocket.accept"})
        try:
            if gone is not None:
                await self._reply({**gone.body(), "status": gone.status})
                await self.close(4000 + gone.status, gone.message)
                return
            if self.secret is None and not await self._first_message_credentials():
                return
            try:
                self.session = self.store.get(self.sid)
            except ServiceError as exc:  # gone while the credentials came
                await self._reply({**exc.body(), "status": exc.status})
                await self.close(4000 + exc.status, exc.message)
                return
            if self.session.stream is not None:
                await self._reply({"error": f"session {self.sid!r} already has a stream (one writer per session)",
                                   "status": 409})
                await self.close(4409, "one writer per session")
                return
            self.session.stream = self
            self.app.streams.add(self)
            await self._serve()
        finally:
            self.detach()
            self.app.streams.discard(self)

    async def _serve(self) -> None:
        while not self.closed:
            try:
                message = await asyncio.wait_for(self.receive(), self.limits.stream_idle_timeout)
            except asyncio.TimeoutError:
                await self.close(4408, f"no message for {self.limits.stream_idle_timeout:g} s")
                return
            if message["type"] == "websocket.disconnect":
                self.closed = True
                return
            raw = message.get("bytes") or (message.get("text") or "").encode()
            await self._message(raw)

    async def _message(self, raw: bytes) -> None:
        if len(raw) > self.limits.max_body:
            await self._reply({"error": f"message of {len(raw)} bytes exceeds {self.limits.max_body}", "status": 413})
            return
        try:
            request = api.parse_body(self.store.step_model(self.sid), raw, self.limits)
            await self._send_text(self.store.step(self.sid, self.secret, request, stream=self))
        except ServiceError as exc:
            await self._reply({**exc.body(), "status": exc.status})
            if exc.status in (404, 410):
                await self.close(4000 + exc.status, exc.message)
        except Exception:  # a bug answers in JSON and is logged; the stream stays
            log.exception("guardian service: unhandled error on the stream of %s", self.sid)
            await self._reply({"error": "internal error (logged by the service)", "status": 500})

    # ---- credentials ----------------------------------------------------------------------------------
    def _authorize(self, secret: str | None):
        """The refusal of ``secret`` for this session (403, or 409 when a stream is attached), else None; an
        unknown or gone session is accepted and told so."""
        try:
            session = self.store.authorized(self.sid, secret)
        except ServiceError as exc:
            return api.error(exc.status, exc.message, close=True) if exc.status == 403 else None
        if session.stream is not None:
            return api.error(409, f"session {self.sid!r} already has a stream (one writer per session)", close=True)
        return None

    async def _first_message_credentials(self) -> bool:
        """A browser's stream: its first message carries the secret (and the token); False when refused."""
        try:
            message = await asyncio.wait_for(self.receive(), self.limits.stream_idle_timeout)
        except asyncio.TimeoutError:
            await self.close(4408, "no credentials")
            return False
        if message["type"] == "websocket.disconnect":
            self.closed = True
            return False
        try:
            given = json.loads(message.get("text") or message.get("bytes") or b"")
        except ValueError:
            given = None
        if not isinstance(given, dict) or not isinstance(given.get("secret"), str):
            await self._reply({"error": "send {\"secret\": SECRET} first (a stream without the Session-Secret "
                                        "header)", "status": 403})
            await self.close(4403, "no secret")
            return False
        if self.app.token is not None:
            token = given.get("token")
            token = token.encode() if isinstance(token, str) else None
            if not (self.app._is_token(token, self.app.token) or self.app._is_token(token, self.app.admin_token)):
                await self._reply({"error": "missing or wrong token (send {\"secret\": S, \"token\": T} first)",
                                   "status": 401})
                await self.close(4401, "wrong token")
                return False
        refusal = self._authorize(given["secret"])
        if refusal is not None:
            await self._reply({**json.loads(refusal.body), "status": refusal.status})
            await self.close(4000 + refusal.status, "refused")
            return False
        self.secret = given["secret"]
        await self._reply({"authenticated": True, "session": self.sid})
        return True

    # ---- sending and ending ------------------------------------------------------------------------------
    async def _deny(self, resp) -> None:
        """Refuse the handshake with an HTTP answer (the ASGI WebSocket denial response)."""
        if "websocket.http.response" in self.scope.get("extensions", {}):
            headers = [(b"content-type", b"application/json"), (b"content-length", str(len(resp.body)).encode())]
            headers += [(k.encode("latin-1"), v.encode("latin-1")) for k, v in resp.headers]
            await self.send({"type": "websocket.http.response.start", "status": resp.status, "headers": headers})
            await self.send({"type": "websocket.http.response.body", "body": resp.body})
        else:
            await self.send({"type": "websocket.close", "code": 1008})

    async def _reply(self, body: dict) -> None:
        await self._send_text(json.dumps(body).encode())

    async def _send_text(self, body: bytes) -> None:
        if not self.closed:
            await self.send({"type": "websocket.send", "text": body.decode()})

    async def close(self, code: int, reason: str) -> None:
        if not self.closed:
            self.closed = True
            self.detach()
            await self.send({"type": "websocket.close", "code": code, "reason": reason[:120]})

    def session_closed(self) -> None:
        """The session was deleted: say so and close with 4404 (from another request, on this loop)."""
        async def tell():
            await self._reply({"error": f"session {self.sid!r} was deleted", "status": 404})
            await self.close(4404, "session deleted")
        asyncio.ensure_future(tell())

    def detach(self) -> None:
        if self.session is not None and self.session.stream is self:
            self.session.stream = None
            self.session.last_used = self.store.clock()
        self.session = None


