"""The guardian service's HTTP and WebSocket API (FastAPI), behind a gate that bounds each request.

    GET    /health                   -> 200 {"status", "sessions", "expired", "closed", "max_sessions", "session_ttl_s"}
    GET    /sessions                 -> 200 {"sessions": [{"session", "steps", "idle_s", "active_set"}, ...]}
    POST   /sessions                 {"use_intention": true, "horizon": 10, "priority": ["throttle", "steering"]}
                                     -> 201 {"session": ID, ...}
    POST   /sessions/ID/step         {"state": [v_ex, y_e, h, v_Lx], "input": [a_ex, v_ey]}
                                     -> 200 the step record (applied input, override, admissible set, failsafe, ...)
    GET    /sessions/ID              -> 200 {"session", "steps", "active_set", "valid_intentions", "idle_s", "last"}
    DELETE /sessions/ID              -> 200 {"closed": ID}
    WS     /sessions/ID/stream       each text message a step body, each reply its record, in order
    GET    /docs, /openapi.json      the schema

Every error is JSON ``{"error": message, ...}``: 400 malformed JSON or framing, or a body over the
depth / number-length bounds; 401 missing or wrong token; 404 unknown session or path; 405 method;
408 request not received within the read timeout; 410 expired session; 411 POST without a length;
413 body too large; 414 target too long; 422 a body that does not match the schema, or a state
outside the model domain (:class:`~guardian.service.sessions.ModelDomain`); 431 too many or too
large headers; 503 session limit. A request is validated before it touches its session.
"""
from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
from typing import Annotated, Literal

from fastapi import FastAPI, Request, WebSocket
from fastapi.exceptions import RequestValidationError
from fastapi.responses import Response
from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictInt, ValidationError, field_validator
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.websockets import WebSocketDisconnect

from guardian.service.limits import Limits, json_cost_error
from guardian.service.sessions import ServiceError, SessionStore

log = logging.getLogger("guardian.service")

Finite = Annotated[float, Field(strict=True, allow_inf_nan=False)]


class SessionSettings(BaseModel):
    """Body of ``POST /sessions``; every field optional."""

    model_config = ConfigDict(extra="forbid")
    use_intention: StrictBool = True
    horizon: StrictInt = Field(10, ge=1, le=1000)
    priority: tuple[Literal["throttle", "steering"], Literal["throttle", "steering"]] = ("throttle", "steering")

    @field_validator("priority")
    @classmethod
    def _both_inputs(cls, v):
        if v[0] == v[1]:
            raise ValueError("priority must order 'throttle' and 'steering', each once")
        return v


class StepRequest(BaseModel):
    """Body of one step: the state ``x = (v_ex, y_e, h, v_Lx)`` and the driver's input ``(a_ex, v_ey)``."""

    model_config = ConfigDict(extra="forbid")
    state: tuple[Finite, Finite, Finite, Finite]
    input: tuple[Finite, Finite]


def _body_schema(model, required: bool = True) -> dict:
    return {"requestBody": {"required": required, "content": {"application/json": {
        "schema": model.model_json_schema()}}}}


def _parse_body(model, raw: bytes):
    """``raw`` validated as ``model`` by pydantic's own JSON parser, whatever the Content-Type says
    (``curl -d`` sends form-encoded); errors become 400 (not JSON) or 422 (not the schema)."""
    try:
        return model.model_validate_json(raw)
    except ValidationError as exc:
        errors = exc.errors()
        if any(e.get("type") == "json_invalid" for e in errors):
            raise ServiceError(400, "malformed JSON body: " + _validation_message(errors)) from None
        raise ServiceError(422, _validation_message(errors)) from None


def json_response(status: int, body: dict, close: bool = False, headers: dict | None = None) -> Response:
    h = dict(headers or {})
    if close:
        h["connection"] = "close"
    return Response(json.dumps(body).encode(), status_code=status, media_type="application/json", headers=h)


def _validation_message(errors) -> str:
    parts = []
    for e in errors:
        loc = [str(p) for p in e.get("loc", ()) if p != "body"]
        parts.append((f"field {'.'.join(loc)!r}: " if loc else "") + e.get("msg", "invalid"))
    return "; ".join(parts)


def create_app(library, store: SessionStore | None = None, limits: Limits = Limits(),
               token: str | None = None) -> "Gate":
    """The ASGI application: the FastAPI routes wrapped in :class:`Gate`."""
    store = store or SessionStore(library)

    @contextlib.asynccontextmanager
    async def lifespan(app):
        sweeper = asyncio.create_task(_sweep_forever(store))
        try:
            yield
        finally:
            sweeper.cancel()

    app = FastAPI(title="guardian", version="2", lifespan=lifespan, strict_content_type=False,
                  description="Intention-aware safety supervisor (Chapter 6): one guardian per session.")
    app.state.store = store

    @app.exception_handler(ServiceError)
    async def _service_error(request, exc: ServiceError):
        return json_response(exc.status, exc.body())

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request, exc: StarletteHTTPException):
        message = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        if exc.status_code == 404:
            message = f"no such path {request.url.path}"
        elif exc.status_code == 405:
            message = f"{request.method} is not allowed on {request.url.path}"
        return json_response(exc.status_code, {"error": message}, headers=exc.headers)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request, exc: RequestValidationError):
        errors = exc.errors()
        if any(e.get("type") == "json_invalid" for e in errors):
            return json_response(400, {"error": "malformed JSON body: " + _validation_message(errors)})
        return json_response(422, {"error": _validation_message(errors)})

    @app.head("/health", include_in_schema=False)
    @app.get("/health")
    async def health():
        return json_response(200, store.health())

    @app.get("/sessions")
    async def list_sessions():
        return json_response(200, {"sessions": store.listing()})

    @app.post("/sessions", status_code=201, openapi_extra=_body_schema(SessionSettings, required=False))
    async def create_session(request: Request):
        s = _parse_body(SessionSettings, await request.body() or b"{}")
        return json_response(201, store.create(s.use_intention, s.horizon, s.priority))

    @app.post("/sessions/{sid}/step", openapi_extra=_body_schema(StepRequest))
    async def step(sid: str, request: Request):
        req = _parse_body(StepRequest, await request.body())  # half the cost of FastAPI's body handling
        return json_response(200, store.step(sid, req.state, req.input))

    @app.get("/sessions/{sid}")
    async def session_summary(sid: str):
        return json_response(200, store.summary(sid))

    @app.delete("/sessions/{sid}")
    async def close_session(sid: str):
        return json_response(200, store.close(sid))

    @app.websocket("/sessions/{sid}/stream")
    async def stream(ws: WebSocket, sid: str):
        await ws.accept()
        await _stream_steps(ws, store, sid, limits)

    return Gate(app, limits, token)


async def _sweep_forever(store: SessionStore) -> None:
    period = min(store.ttl / 4.0, 30.0)
    while True:
        await asyncio.sleep(period)
        store.sweep()


def _stream_reply(store: SessionStore, sid: str, raw: bytes, limits: Limits) -> tuple[dict, bool]:
    """The reply to one stream message, and whether the stream must end (session gone)."""
    if len(raw) > limits.max_body:
        return {"error": f"message of {len(raw)} bytes exceeds {limits.max_body}", "status": 413}, False
    problem = json_cost_error(raw, limits)
    if problem:
        return {"error": problem, "status": 400}, False
    try:
        req = _parse_body(StepRequest, raw)
        return store.step(sid, req.state, req.input), False
    except ServiceError as exc:
        return {**exc.body(), "status": exc.status}, exc.status in (404, 410)


async def _stream_steps(ws: WebSocket, store: SessionStore, sid: str, limits: Limits) -> None:
    """One reply per message, in order; the session's ttl also bounds how long the stream may idle."""
    try:
        store.get(sid)
    except ServiceError as exc:
        await ws.send_text(json.dumps({**exc.body(), "status": exc.status}))
        await ws.close(code=4000 + exc.status, reason=exc.message[:120])
        return
    while True:
        try:
            message = await asyncio.wait_for(ws.receive(), timeout=store.ttl + 1.0)
        except asyncio.TimeoutError:
            message = None
        if message is None or message["type"] == "websocket.disconnect":
            if message is None:
                with contextlib.suppress(Exception):
                    await ws.close(code=4410, reason="idle longer than the session ttl")
            return
        raw = message.get("bytes") or (message.get("text") or "").encode()
        reply, end = _stream_reply(store, sid, raw, limits)
        try:
            await ws.send_text(json.dumps(reply))
        except (WebSocketDisconnect, RuntimeError):
            return
        if end:
            await ws.close(code=4000 + reply["status"], reason=reply["error"][:120])
            return


class Gate:
    """ASGI middleware: bounds, token and whole-body reading before any route runs.

    A request reaches the routes only once its whole body has arrived within the read timeout; a
    client that disconnects mid-body has nothing executed.
    """

    def __init__(self, app, limits: Limits, token: str | None):
        self.app = app
        self.limits = limits
        self.token = token
        self.stopping = lambda: False  # the server sets this: answers during shutdown say Connection: close

    @property
    def store(self) -> SessionStore:
        return self.app.state.store

    def _authorized(self, headers: list) -> bool:
        if self.token is None:
            return True
        for name, value in headers:
            if name == b"authorization":
                scheme, _, given = value.decode("latin-1").partition(" ")
                return scheme.lower() == "bearer" and hmac.compare_digest(given.strip(), self.token)
        return False

    def _refusal(self, scope) -> tuple[int, str, dict] | None:
        target = len(scope.get("raw_path", b"")) + len(scope.get("query_string", b""))
        if target > self.limits.max_url:
            return 414, f"request target of {target} bytes exceeds {self.limits.max_url}", {}
        headers = scope.get("headers", [])
        if len(headers) > self.limits.max_headers:
            return 431, f"{len(headers)} header fields; at most {self.limits.max_headers} are accepted", {}
        head = sum(len(k) + len(v) + 4 for k, v in headers)
        if head > self.limits.max_header_bytes:  # the parser bounds only heads that arrive in pieces
            return 431, f"request head of {head} bytes is longer than {self.limits.max_header_bytes}", {}
        if not self._authorized(headers):
            return 401, "missing or wrong token (send 'Authorization: Bearer TOKEN')", {
                "www-authenticate": "Bearer"}
        return None

    async def __call__(self, scope, receive, send):
        if scope["type"] == "lifespan":
            return await self.app(scope, receive, send)
        refusal = self._refusal(scope)
        if scope["type"] == "websocket":
            if refusal:
                return await self._deny_websocket(scope, send, *refusal)
            return await self.app(scope, receive, send)
        if refusal:
            return await json_response(refusal[0], {"error": refusal[1]}, close=True,
                                       headers=refusal[2])(scope, receive, send)
        try:
            body = await self._read_body(scope, receive)
        except ServiceError as exc:
            return await json_response(exc.status, exc.body(), close=True)(scope, receive, send)
        if body is None:  # the client left before its request was complete: execute nothing
            return
        if body:
            problem = json_cost_error(body, self.limits)
            if problem:
                return await json_response(400, {"error": problem})(scope, receive, send)
        await self._run(scope, self._replay(body, receive), send)

    async def _run(self, scope, receive, send) -> None:
        started = False

        async def tracking_send(message):
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                if self.stopping():
                    message = {**message, "headers": [*message.get("headers", []), (b"connection", b"close")]}
            await send(message)

        try:
            await self.app(scope, receive, tracking_send)
        except Exception:  # a bug must still answer in JSON, and be logged
            log.exception("guardian service: unhandled error on %s %s", scope.get("method"), scope.get("path"))
            if not started:
                await json_response(500, {"error": "internal error (logged by the service)"},
                                    close=True)(scope, receive, send)

    async def _read_body(self, scope, receive) -> bytes | None:
        headers = dict(scope.get("headers", []))
        length = headers.get(b"content-length")
        chunked = b"transfer-encoding" in headers
        if length is not None and int(length) > self.limits.max_body:  # the parser validated the digits
            raise ServiceError(413, f"body of {int(length)} bytes exceeds {self.limits.max_body}")
        if scope["method"] == "POST" and length is None and not chunked:
            raise ServiceError(411, "a POST needs Content-Length or chunked Transfer-Encoding "
                                    "(send Content-Length: 0 for an empty body)")
        body = bytearray()
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.limits.read_timeout
        while True:
            try:
                message = await asyncio.wait_for(receive(), timeout=max(deadline - loop.time(), 0.0))
            except asyncio.TimeoutError:
                raise ServiceError(408, f"request body not received within {self.limits.read_timeout:g} s") from None
            if message["type"] == "http.disconnect":
                return None
            body += message.get("body", b"")
            if len(body) > self.limits.max_body:
                raise ServiceError(413, f"body exceeds {self.limits.max_body} bytes")
            if not message.get("more_body", False):
                return bytes(body)

    @staticmethod
    def _replay(body: bytes, receive):
        sent = False

        async def replay():
            nonlocal sent
            if not sent:
                sent = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        return replay

    @staticmethod
    async def _deny_websocket(scope, send, status: int, message: str, headers: dict) -> None:
        body = json.dumps({"error": message}).encode()
        if "websocket.http.response" in scope.get("extensions", {}):
            await send({"type": "websocket.http.response.start", "status": status,
                        "headers": [(b"content-type", b"application/json"),
                                    (b"content-length", str(len(body)).encode()),
                                    *[(k.encode(), v.encode()) for k, v in headers.items()]]})
            await send({"type": "websocket.http.response.body", "body": body})
        else:
            await send({"type": "websocket.close", "code": 4000 + status, "reason": message[:120]})
