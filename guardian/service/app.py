"""The guardian service as an ASGI application: the routes, the checks before them, and the step stream.

Served by uvicorn (httptools) in each worker (``guardian.service.server``); the HTTP framing, its limits and
timeouts are the server's (``guardian.service.protocol``). Routes (``guardian.service.api`` lists them):
``/health``, ``/ready``, ``/sessions`` (list, create a two-car or a scene session), ``/sessions/ID`` (read,
delete), ``/sessions/ID/step``, ``/sessions/ID/lane_change`` (scene sessions), ``/sessions/ID/stream`` (a
WebSocket), ``/openapi.json``, ``/docs``.

A request's body is read whole before anything runs: a client that leaves mid-request has nothing executed.
Every answer is JSON; every error ``{"error": message, ...}`` with the status the OpenAPI document lists.

**Browsers.** A request with an ``Origin`` header is served only when the origin was allowed
(``--allow-origin``), and its answers then carry ``Access-Control-Allow-Origin``; a preflight (``OPTIONS`` with
``Access-Control-Request-Method``) is answered with the methods and headers allowed. A browser's WebSocket
cannot send headers: its stream may open without ``Session-Secret`` (and, when a token is required, without
``Authorization``) and send ``{"secret": ..., "token": ...}`` as its first message instead.
"""
from __future__ import annotations

import asyncio
import hmac
import json
import logging

from guardian.service import api
from guardian.service.api import Response, error, json_response
from guardian.service.sessions import SECRET_HEADER, ServiceError

log = logging.getLogger("guardian.service")
CORS_HEADERS = "authorization, content-type, session-secret"


class Request:
    """An HTTP request as the routes read it: method, path, headers (lower-case names, one value each: the
    last; names given twice are refused), the body."""

    __slots__ = ("method", "path", "version", "headers", "body", "repeated")

    def __init__(self, scope):
        self.method = scope.get("method", "GET")
        self.version = scope.get("http_version", "1.1")
        self.path = scope["path"]
        self.headers, self.repeated = {}, set()
        for name, value in scope["headers"]:
            key = name.decode("latin-1")
            if key in self.headers:
                self.repeated.add(key)
            self.headers[key] = value.decode("latin-1")
        self.body = b""

    def raw_header(self, name: str) -> bytes | None:
        value = self.headers.get(name)
        return None if value is None else value.encode("latin-1")


class ServiceApp:
    """The routes and the checks before them; one per worker (see the module docstring).

    Parameters
    ----------
    store : SessionStore
    limits : Limits
    token, admin_token : str, optional
        Every request must send ``Authorization: Bearer TOKEN`` (or the admin token); the admin token lists
        every session and may read or delete any.
    allow_origins : tuple of str
        Browser origins allowed to call (a request with another ``Origin`` gets 403).
    loopback : bool
        The service listens on loopback only: ``Host`` must then be a loopback name (DNS rebinding).
    cluster : object, optional
        The other workers (``workers.Cluster``): totals for /health and /ready, the admin listing.
    """

    def __init__(self, store, limits, token: str | None = None, admin_token: str | None = None, allow_origins=(),
                 loopback: bool = True, cluster=None):
        self.store, self.limits, self.cluster = store, limits, cluster
        self.token = token.encode() if token is not None else None
        self.admin_token = admin_token.encode() if admin_token is not None else None
        self.allow_origins = {o.lower().rstrip("/") for o in allow_origins}
        self.loopback = loopback
        self.ready = False       # set once the worker is warmed up
        self.stopping = False    # set when SIGTERM arrived
        self.streams: set = set()
        self.connections = lambda: 0
        from guardian.service import openapi
        self._openapi_json = json.dumps(openapi.document()).encode()
        self._docs_page = openapi.docs_html().encode()

    # ---- ASGI -------------------------------------------------------------------------------------------
    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] == "http":
            await self._http(scope, receive, send)
        elif scope["type"] == "websocket":
            await self._websocket(scope, receive, send)
        elif scope["type"] == "lifespan":
            while (await receive())["type"] != "lifespan.shutdown":
                await send({"type": "lifespan.startup.complete"})
            await send({"type": "lifespan.shutdown.complete"})

    async def _http(self, scope, receive, send) -> None:
        req = Request(scope)
        resp = self.check(req)
        if resp is None:
            while True:  # the whole body first: a client that leaves mid-request has nothing executed
                message = await receive()
                if message["type"] == "http.disconnect":
                    return
                req.body += message.get("body", b"")
                if len(req.body) > self.limits.max_body:
                    resp = error(413, f"body exceeds {self.limits.max_body} bytes", close=True)
                    break
                if not message.get("more_body", False):
                    break
            if resp is None:
                resp = await self.handle(req)
        await self._send(req, resp, send)

    async def _send(self, req: Request, resp: Response, send) -> None:
        headers = [] if resp.status == 204 else [(b"content-type", resp.content_type),
                                                 (b"content-length", str(len(resp.body)).encode())]
        headers += [(k.encode("latin-1"), v.encode("latin-1")) for k, v in resp.headers]
        origin = req.headers.get("origin")
        if origin is not None and self._origin_allowed(origin):
            headers.append((b"access-control-allow-origin", origin.encode("latin-1")))
        if self.allow_origins:  # the answer depends on the Origin: no shared cache may give it to another
            headers.append((b"vary", b"Origin"))
        if resp.close or self.stopping:
            headers.append((b"connection", b"close"))
        await send({"type": "http.response.start", "status": resp.status, "headers": headers})
        await send({"type": "http.response.body", "body": b"" if req.method == "HEAD" else resp.body})

    # ---- checks before any body is read -------------------------------------------------------------------
    def _bearer(self, headers: dict) -> bytes | None:
        value = headers.get("authorization")
        if value is None:
            return None
        scheme, _, given = value.partition(" ")
        return given.strip().encode("latin-1") if scheme.lower() == "bearer" else b""

    def _is_token(self, given: bytes | None, token: bytes | None) -> bool:
        return bool(token and given and hmac.compare_digest(given, token))  # bytes: any byte is compared

    def is_admin(self, headers: dict) -> bool:
        return self._is_token(self._bearer(headers), self.admin_token)

    def _origin_allowed(self, origin: str) -> bool:
        return origin.strip().lower().rstrip("/") in self.allow_origins

    def check(self, req: Request, stream: bool = False) -> Response | None:
        """The refusal of a request (or a stream's handshake) from its head alone, or None."""
        h = req.headers
        if req.version == "1.1" and "host" not in h:
            return error(400, "an HTTP/1.1 request needs a Host header", close=True)
        if req.repeated & {"authorization", SECRET_HEADER, "host", "origin", "content-type", "content-length"}:
            names = ", ".join(sorted(req.repeated))
            return error(400, f"header {names} given more than once", close=True)
        if self.loopback and "host" in h and not api.is_loopback_host(h["host"]):
            return error(403, f"Host {h['host']!r} is not a loopback name: this service listens on loopback "
                              "only (a browser page reaching it under another name is DNS rebinding)", close=True)
        origin = h.get("origin")
        if origin is not None and not self._origin_allowed(origin):
            return error(403, f"Origin {origin!r} is not allowed (guardian serve --allow-origin ORIGIN)", close=True)
        if req.method == "OPTIONS" and origin is not None and "access-control-request-method" in h:
            return self._preflight(req)
        browser_stream = stream and origin is not None
        if self.token is not None and not browser_stream:
            given = self._bearer(h)
            if not (self._is_token(given, self.token) or self._is_token(given, self.admin_token)):
                return error(401, "missing or wrong token (send 'Authorization: Bearer TOKEN')",
                             (("www-authenticate", 'Bearer realm="guardian"'),), close=True)
        found = api.route(req.path)
        if found is None:
            return error(404, f"no such path {req.path}")
        allowed = api.ALLOWED[found[0]]
        if req.method not in allowed:
            return error(405, f"{req.method} is not allowed on {req.path}", (("allow", ", ".join(allowed)),))
        if req.method == "POST":
            ctype = h.get("content-type", "").split(";", 1)[0].strip().lower()
            if ctype != "application/json":
                return error(415, "POST bodies must be JSON: send 'Content-Type: application/json'"
                                  + (f" (got {h['content-type']!r})" if "content-type" in h else ""),
                             (("accept-post", "application/json"),), close=True)
            if "content-length" not in h and "chunked" not in h.get("transfer-encoding", "").lower():
                return error(411, "a POST needs Content-Length or chunked Transfer-Encoding "
                                  "(send Content-Length: 0 for an empty body)", close=True)
        return None

    def _preflight(self, req: Request) -> Response:
        found = api.route(req.path)
        if found is None:
            return error(404, f"no such path {req.path}")
        methods = ", ".join(m for m in api.ALLOWED[found[0]] if m != "HEAD")
        return Response(204, b"", (("access-control-allow-methods", methods),
                                   ("access-control-allow-headers", CORS_HEADERS),
                                   ("access-control-max-age", "600")))

    # ---- the routes -------------------------------------------------------------------------------------
    async def handle(self, req: Request) -> Response:
        name, sid = api.route(req.path)
        try:
            result = getattr(self, "_" + name)(req, sid)
            if asyncio.iscoroutine(result):
                result = await result
            return result
        except ServiceError as exc:
            return api.service_error(exc)
        except Exception:  # a bug must still answer in JSON, and be logged
            log.exception("guardian service: unhandled error on %s %s", req.method, req.path)
            return error(500, "internal error (logged by the service)", close=True)

    def _health(self, req, sid) -> Response:
        counts = (self.cluster.totals() if self.cluster is not None
                  else {**self.store.counts(), "workers": 1, "workers_alive": 1})
        return json_response(200, {"status": "ok", "node": self.store.ids.node, "worker": self.store.ids.worker,
                                   **counts, "max_sessions": self.store.max_sessions,
                                   "session_ttl_s": self.store.ttl})

    def _ready(self, req, sid) -> Response:
        ready, workers = (self.cluster.readiness() if self.cluster is not None else (int(self.ready), 1))
        if self.stopping:
            return error(503, "stopping: no new sessions (SIGTERM received)", ready=False,
                         workers_ready=ready, workers=workers)
        if ready < workers:
            return error(503, f"{ready} of {workers} workers ready (warming up or restarting)", ready=False,
                         workers_ready=ready, workers=workers)
        return json_response(200, {"ready": True, "workers_ready": ready, "workers": workers})

    def _sessions(self, req, sid):
        if req.method == "POST":
            body = req.body or b"{}"
            if api.is_scene(body, self.limits):
                from guardian.service.scene import SceneSettings

                return json_response(201, self.store.create_scene(api.parse_body(SceneSettings, body, self.limits)))
            s = api.parse_body(api.SessionSettings, body, self.limits)
            return json_response(201, self.store.create(s.use_intention, s.horizon, s.priority))
        if not self.is_admin(req.headers):
            why = ("send the admin token ('Authorization: Bearer ADMIN_TOKEN')" if self.admin_token else
                   "start the service with --admin-token (or GUARDIAN_ADMIN_TOKEN) and send it")
            return error(403, f"listing every session needs the admin token: {why}")
        if self.cluster is None:
            return json_response(200, {"sessions": self.store.listing()})
        return self._cluster_listing()

    async def _cluster_listing(self) -> Response:
        listing, missing = await self.cluster.listing()
        return json_response(200, {"sessions": listing, **({"workers_missing": missing} if missing else {})})

    def _session(self, req, sid) -> Response:
        secret, admin = req.headers.get(SECRET_HEADER), self.is_admin(req.headers)
        if req.method == "DELETE":
            return json_response(200, self.store.close(sid, secret, admin))
        return json_response(200, self.store.summary(sid, secret, admin))

    def _step(self, req, sid) -> Response:
        secret = req.headers.get(SECRET_HEADER)
        self.store.authorized(sid, secret)  # 404/410/421, then 403, before the body is judged
        request = api.parse_body(self.store.step_model(sid), req.body, self.limits)
        return Response(200, self.store.step(sid, secret, request))

    def _lane_change(self, req, sid) -> Response:
        from guardian.service.scene import LaneChangeQuery

        secret = req.headers.get(SECRET_HEADER)
        self.store.authorized(sid, secret)
        query = api.parse_body(LaneChangeQuery, req.body, self.limits)
        return json_response(200, self.store.lane_change(sid, secret, query))

    def _stream(self, req, sid) -> Response:
        return error(426, "this path is a WebSocket stream: send a WebSocket handshake",
                     (("upgrade", "websocket"), ("connection", "Upgrade")))

    def _openapi(self, req, sid) -> Response:
        return Response(200, self._openapi_json)

    def _docs(self, req, sid) -> Response:
        return Response(200, self._docs_page, content_type=b"text/html; charset=utf-8")

    # ---- the step stream ----------------------------------------------------------------------------------
    async def _websocket(self, scope, receive, send) -> None:
        from guardian.service.stream import Stream

        await Stream(self, scope, receive, send).run()
