"""The guardian service's HTTP API: who may ask what, and the routes (no I/O; see ``protocol``).

    GET    /health                -> 200 liveness and counts
    GET    /ready                 -> 200 when every worker is warmed up and none is stopping, else 503
    GET    /sessions              -> 200 every live session (admin token only)
    POST   /sessions              {"use_intention": true, "horizon": 10, "priority": ["throttle", "steering"]}
                                  -> 201 {"session": ID, "secret": SECRET, "next_seq": 0, ...}
    POST   /sessions/ID/step      {"seq": N, "state": [v_ex, y_e, h, v_Lx], "input": [a_ex, v_ey]}
                                  -> 200 the step record ("t" is N)
    GET    /sessions/ID           -> 200 {"session", "steps", "next_seq", "active_set", "valid_intentions", ...}
    DELETE /sessions/ID           -> 200 {"closed": ID}
    GET    /sessions/ID/stream    WebSocket: each text message a step body, each reply its record, in order
    GET    /openapi.json, /docs   the contract (OpenAPI 3.1) and its reference page, served from the package

A session's requests carry its secret (``Session-Secret``). Every answer is JSON; every error is
``{"error": message, ...}`` with the status the OpenAPI document lists for it (``openapi.py``).
"""
from __future__ import annotations

import hmac
import ipaddress
import json
import logging
from dataclasses import dataclass
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictInt, ValidationError, field_validator

from guardian.service.http import RequestHead
from guardian.service.limits import Limits, json_cost_error
from guardian.service.sessions import SECRET_HEADER, ServiceError, SessionStore

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
    """Body of one step: its sequence number, the state ``x = (v_ex, y_e, h, v_Lx)`` and the driver's
    input ``(a_ex, v_ey)``."""

    model_config = ConfigDict(extra="forbid")
    seq: StrictInt = Field(ge=0, le=2 ** 62)
    state: tuple[Finite, Finite, Finite, Finite]
    input: tuple[Finite, Finite]


@dataclass
class Response:
    status: int
    body: bytes
    headers: tuple = ()
    close: bool = False
    content_type: bytes = b"application/json"


def json_response(status: int, body: dict, headers=(), close: bool = False) -> Response:
    return Response(status, json.dumps(body).encode(), tuple(headers), close)


def error(status: int, message: str, headers=(), close: bool = False, **extra) -> Response:
    return json_response(status, {"error": message, **extra}, headers, close)


def service_error(exc: ServiceError) -> Response:
    headers = (("retry-after", str(int(exc.extra["retry_after_s"]))),) if "retry_after_s" in exc.extra else ()
    return json_response(exc.status, exc.body(), headers)


def _validation_message(errors) -> str:
    parts = []
    for e in errors:
        loc = [str(p) for p in e.get("loc", ())]
        parts.append((f"field {'.'.join(loc)!r}: " if loc else "") + e.get("msg", "invalid"))
    return "; ".join(parts)


def parse_body(model, raw: bytes, limits: Limits):
    """``raw`` checked for cost, then validated as ``model`` by pydantic's own JSON parser.

    Errors: 400 (too deep, a number too long, not JSON) or 422 (not the schema).
    """
    problem = json_cost_error(raw, limits)
    if problem:
        raise ServiceError(400, problem)
    try:
        return model.model_validate_json(raw)
    except ValidationError as exc:
        errors = exc.errors()
        if any(e.get("type") == "json_invalid" for e in errors):
            raise ServiceError(400, "malformed JSON body: " + _validation_message(errors)) from None
        raise ServiceError(422, _validation_message(errors)) from None


# ---- routes ----------------------------------------------------------------------------------------

ALLOWED = {"health": ("GET", "HEAD"), "ready": ("GET", "HEAD"), "sessions": ("GET", "HEAD", "POST"),
           "session": ("GET", "HEAD", "DELETE"), "step": ("POST",), "stream": ("GET",),
           "openapi": ("GET", "HEAD"), "docs": ("GET", "HEAD")}
_FIXED = {"/health": "health", "/ready": "ready", "/sessions": "sessions", "/openapi.json": "openapi",
          "/docs": "docs"}


def route(path: str) -> tuple[str, str | None] | None:
    """``(route name, session id)`` of a path, or None."""
    name = _FIXED.get(path)
    if name is not None:
        return name, None
    parts = path.split("/")
    if len(parts) >= 3 and parts[0] == "" and parts[1] == "sessions" and parts[2]:
        if len(parts) == 3:
            return "session", parts[2]
        if len(parts) == 4 and parts[3] in ("step", "stream"):
            return parts[3], parts[2]
    return None


def session_of(target: str) -> str | None:
    """The session id a request target names, if any (for routing a connection to its worker)."""
    if not target.startswith("/sessions/"):
        return None
    sid = target[10:].split("/", 1)[0].split("?", 1)[0]
    return sid or None


def is_loopback_host(value: str) -> bool:
    """Is a ``Host`` header's host a loopback name (``localhost``, 127.0.0.0/8, ``[::1]``)?"""
    host = value.strip().lower()
    if host.startswith("["):
        host = host[1:host.find("]")] if "]" in host else host
    elif host.count(":") == 1:
        host = host.split(":", 1)[0]
    if host in ("localhost", "localhost.") or host.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class App:
    """The routes and the checks before them; one per worker.

    Parameters
    ----------
    store : SessionStore
    limits : Limits
    token : str, optional
        Every request must send ``Authorization: Bearer TOKEN`` (or the admin token).
    admin_token : str, optional
        ``Authorization: Bearer ADMIN`` lists every session and may read or delete any.
    allow_origins : tuple of str
        Browser origins allowed to call (a request with another ``Origin`` gets 403).
    loopback : bool
        The service listens on loopback only: ``Host`` must then be a loopback name (DNS rebinding).
    cluster : object, optional
        The other workers (``workers.Cluster``): totals for /health and /ready, the admin listing.
    """

    def __init__(self, store: SessionStore, limits: Limits = Limits(), token: str | None = None,
                 admin_token: str | None = None, allow_origins=(), loopback: bool = True, cluster=None):
        self.store = store
        self.limits = limits
        self.token = token
        self.admin_token = admin_token
        self.allow_origins = {o.lower().rstrip("/") for o in allow_origins}
        self.loopback = loopback
        self.cluster = cluster
        self.ready = False       # set once the worker is warmed up
        self.stopping = False    # set when SIGTERM arrived
        self.connections = lambda: 0
        from guardian.service import openapi
        self._openapi_json = json.dumps(openapi.document()).encode()
        self._docs_page = openapi.docs_html().encode()

    # ---- checks on the head, before any body is read ----------------------------------------------

    def _bearer(self, headers: dict) -> str | None:
        value = headers.get("authorization")
        if value is None:
            return None
        scheme, _, given = value.partition(" ")
        return given.strip() if scheme.lower() == "bearer" else ""

    def is_admin(self, head: RequestHead) -> bool:
        given = self._bearer(head.headers)
        return bool(self.admin_token and given and hmac.compare_digest(given, self.admin_token))

    def check_head(self, head: RequestHead) -> Response | None:
        """The refusal of a request from its head alone (then its body is not read), or None."""
        h = head.headers
        if self.token is not None:
            given = self._bearer(h)
            if not given or not (hmac.compare_digest(given, self.token) or self.is_admin(head)):
                return error(401, "missing or wrong token (send 'Authorization: Bearer TOKEN')",
                             (("www-authenticate", 'Bearer realm="guardian"'),), close=True)
        if self.loopback and "host" in h and not is_loopback_host(h["host"]):
            return error(403, f"Host {h['host']!r} is not a loopback name: this service listens on loopback "
                              "only (a browser page reaching it under another name is DNS rebinding)", close=True)
        origin = h.get("origin")
        if origin is not None and origin.strip().lower().rstrip("/") not in self.allow_origins:
            return error(403, f"Origin {origin!r} is not allowed (guardian serve --allow-origin ORIGIN)", close=True)
        found = route(head.path)
        if found is None:
            return error(404, f"no such path {head.path}", close=head.has_body)
        allowed = ALLOWED[found[0]]
        if head.method not in allowed:
            return error(405, f"{head.method} is not allowed on {head.path}", (("allow", ", ".join(allowed)),),
                         close=head.has_body)
        if head.method == "POST":
            ctype = h.get("content-type", "").split(";", 1)[0].strip().lower()
            if ctype != "application/json":
                return error(415, "POST bodies must be JSON: send 'Content-Type: application/json'"
                                  + (f" (got {h['content-type']!r})" if "content-type" in h else ""),
                             (("accept-post", "application/json"),), close=True)
            if head.content_length is None and not head.chunked:
                return error(411, "a POST needs Content-Length or chunked Transfer-Encoding "
                                  "(send Content-Length: 0 for an empty body)", close=True)
        if head.content_length is not None and head.content_length > self.limits.max_body:
            return error(413, f"body of {head.content_length} bytes exceeds {self.limits.max_body}", close=True)
        return None

    # ---- the routes ---------------------------------------------------------------------------------

    def handle(self, head: RequestHead, body: bytes):
        """The response to a whole request that passed ``check_head`` (or an awaitable of it)."""
        name, sid = route(head.path)
        try:
            return getattr(self, "_" + name)(head, sid, body)
        except ServiceError as exc:
            return service_error(exc)

    def _health(self, head, sid, body) -> Response:
        counts = (self.cluster.totals() if self.cluster is not None
                  else {**self.store.counts(), "workers": 1, "workers_alive": 1})
        return json_response(200, {"status": "ok", "node": self.store.ids.node, "worker": self.store.ids.worker,
                                   **counts, "max_sessions": self.store.max_sessions,
                                   "session_ttl_s": self.store.ttl})

    def _ready(self, head, sid, body) -> Response:
        ready, workers = (self.cluster.readiness() if self.cluster is not None else (int(self.ready), 1))
        if self.stopping:
            return error(503, "stopping: no new sessions (SIGTERM received)", ready=False,
                         workers_ready=ready, workers=workers)
        if ready < workers:
            return error(503, f"{ready} of {workers} workers ready (warming up or restarting)", ready=False,
                         workers_ready=ready, workers=workers)
        return json_response(200, {"ready": True, "workers_ready": ready, "workers": workers})

    def _sessions(self, head, sid, body):
        if head.method == "POST":
            s = parse_body(SessionSettings, body or b"{}", self.limits)
            return json_response(201, self.store.create(s.use_intention, s.horizon, s.priority))
        if not self.is_admin(head):
            why = ("send the admin token ('Authorization: Bearer ADMIN_TOKEN')" if self.admin_token else
                   "start the service with --admin-token (or GUARDIAN_ADMIN_TOKEN) and send it")
            return error(403, f"listing every session needs the admin token: {why}")
        if self.cluster is None:
            return json_response(200, {"sessions": self.store.listing()})
        return self._cluster_listing()

    async def _cluster_listing(self) -> Response:
        listing, missing = await self.cluster.listing()
        return json_response(200, {"sessions": listing, **({"workers_missing": missing} if missing else {})})

    def _session(self, head, sid, body) -> Response:
        secret, admin = head.headers.get(SECRET_HEADER), self.is_admin(head)
        if head.method == "DELETE":
            return json_response(200, self.store.close(sid, secret, admin))
        return json_response(200, self.store.summary(sid, secret, admin))

    def _step(self, head, sid, body) -> Response:
        self.store.get(sid)  # 404/410/421 before the body is judged
        req = parse_body(StepRequest, body, self.limits)
        reply = self.store.step(sid, head.headers.get(SECRET_HEADER), req.seq, req.state, req.input)
        return Response(200, reply)

    def _stream(self, head, sid, body) -> Response:
        return error(426, "this path is a WebSocket stream: send a WebSocket handshake",
                     (("upgrade", "websocket"), ("connection", "Upgrade")))

    def _openapi(self, head, sid, body) -> Response:
        return Response(200, self._openapi_json)

    def _docs(self, head, sid, body) -> Response:
        return Response(200, self._docs_page, content_type=b"text/html; charset=utf-8")
