"""The guardian as an HTTP JSON service (``guardian serve``).

One intention-aware guardian, hence one intention estimator, per session.

    POST   /sessions                 {"use_intention": true, "horizon": 10, "priority": ["throttle", "steering"]}
                                     -> 201 {"session": ID, ...}
    POST   /sessions/ID/step         {"state": [v_ex, y_e, h, v_Lx], "input": [a_ex, v_ey]}
                                     -> 200 the step record (applied input, override, admissible set, ...)
    GET    /sessions/ID              -> 200 {"session", "steps", "active_set", "valid_intentions", "last"}
    DELETE /sessions/ID              -> 200 {"closed": ID}
    GET    /health                   -> 200 {"status": "ok", "sessions": N}

Errors are JSON ``{"error": message}``: 400 (malformed JSON, NaN or infinity,
wrong shapes, unknown fields, states outside the model domain), 404 (unknown
session or path), 405 (method), 413 (body over 64 KiB), 503 (session limit).
A request is validated before it touches its session, and sessions share no
state, so one session's bad request never disturbs another.
"""
from __future__ import annotations

import json
import threading
import uuid
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

from guardian.supervisor import IntentionAwareGuardian

MAX_BODY = 64 * 1024
MAX_SESSIONS = 1000
PRIORITY_NAMES = {"throttle": 0, "steering": 1}


class RequestError(Exception):
    def __init__(self, status: HTTPStatus, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


def _reject_constant(name):
    raise ValueError(f"{name} is not a number JSON allows")


def _parse_json(raw: bytes) -> dict:
    try:
        data = json.loads(raw or b"{}", parse_constant=_reject_constant)
    except (ValueError, UnicodeDecodeError) as exc:
        raise RequestError(HTTPStatus.BAD_REQUEST, f"malformed JSON body: {exc}") from exc
    if not isinstance(data, dict):
        raise RequestError(HTTPStatus.BAD_REQUEST, "the JSON body must be an object")
    return data


def _number_list(data: dict, key: str, n: int) -> list:
    if key not in data:
        raise RequestError(HTTPStatus.BAD_REQUEST, f"missing field {key!r}")
    v = data[key]
    if not isinstance(v, list) or len(v) != n or not all(
            isinstance(e, (int, float)) and not isinstance(e, bool) for e in v):
        raise RequestError(HTTPStatus.BAD_REQUEST, f"field {key!r} must be a list of {n} numbers, got {v!r}")
    return [float(e) for e in v]


class Session:
    def __init__(self, library, use_intention: bool, horizon: int, priority):
        self.id = uuid.uuid4().hex[:16]
        self.guardian = IntentionAwareGuardian(library, use_intention=use_intention, horizon=horizon,
                                               priority=priority)
        self.lock = threading.Lock()
        self.steps = 0
        self.last = None

    def summary(self) -> dict:
        g = self.guardian
        return {"session": self.id, "steps": self.steps, "active_set": g.active_set,
                "valid_intentions": list(g.estimator.valid), "use_intention": g.use_intention,
                "last": self.last}


class GuardianService:
    """Session bookkeeping, independent of HTTP (the handler only translates)."""

    def __init__(self, library):
        self.library = library
        self.sessions: dict[str, Session] = {}
        self.lock = threading.Lock()

    def create(self, data: dict) -> dict:
        unknown = set(data) - {"use_intention", "horizon", "priority"}
        if unknown:
            raise RequestError(HTTPStatus.BAD_REQUEST, f"unknown fields {sorted(unknown)}")
        use_intention = data.get("use_intention", True)
        horizon = data.get("horizon", 10)
        priority = data.get("priority", ["throttle", "steering"])
        if not isinstance(use_intention, bool):
            raise RequestError(HTTPStatus.BAD_REQUEST, "use_intention must be true or false")
        if not isinstance(horizon, int) or isinstance(horizon, bool) or not 1 <= horizon <= 1000:
            raise RequestError(HTTPStatus.BAD_REQUEST, f"horizon must be an integer in [1, 1000], got {horizon!r}")
        if not isinstance(priority, list) or sorted(map(str, priority)) != ["steering", "throttle"]:
            raise RequestError(HTTPStatus.BAD_REQUEST,
                               f"priority must order 'throttle' and 'steering', got {priority!r}")
        session = Session(self.library, use_intention, horizon, tuple(PRIORITY_NAMES[p] for p in priority))
        with self.lock:
            if len(self.sessions) >= MAX_SESSIONS:
                raise RequestError(HTTPStatus.SERVICE_UNAVAILABLE, f"session limit {MAX_SESSIONS} reached")
            self.sessions[session.id] = session
        return session.summary()

    def get(self, sid: str) -> Session:
        with self.lock:
            session = self.sessions.get(sid)
        if session is None:
            raise RequestError(HTTPStatus.NOT_FOUND, f"unknown session {sid!r}")
        return session

    def step(self, sid: str, data: dict) -> dict:
        unknown = set(data) - {"state", "input"}
        if unknown:
            raise RequestError(HTTPStatus.BAD_REQUEST, f"unknown fields {sorted(unknown)}")
        state = _number_list(data, "state", 4)
        u = _number_list(data, "input", 2)
        session = self.get(sid)
        with session.lock:
            try:
                _, record = session.guardian.step(state, u)
            except ValueError as exc:
                raise RequestError(HTTPStatus.BAD_REQUEST, str(exc)) from exc
            session.steps += 1
            session.last = record.as_dict()
            return session.last

    def close(self, sid: str) -> dict:
        with self.lock:
            if self.sessions.pop(sid, None) is None:
                raise RequestError(HTTPStatus.NOT_FOUND, f"unknown session {sid!r}")
        return {"closed": sid}


def make_handler(service: GuardianService):
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"
        disable_nagle_algorithm = True  # headers and body are separate writes: avoid 40 ms stalls

        def log_message(self, fmt, *args):  # quiet: one line per request is noise for a control loop
            pass

        def _reply(self, status: HTTPStatus, body: dict) -> None:
            data = json.dumps(body).encode()
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def _body(self) -> dict:
            length = self.headers.get("Content-Length")
            try:
                n = int(length) if length is not None else 0
            except ValueError:
                raise RequestError(HTTPStatus.BAD_REQUEST, f"bad Content-Length {length!r}") from None
            if n > MAX_BODY:
                raise RequestError(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, f"body of {n} bytes exceeds {MAX_BODY}")
            return _parse_json(self.rfile.read(n) if n else b"")

        def _route(self, method: str):
            parts = [p for p in self.path.split("?")[0].split("/") if p]
            try:
                if parts == ["health"] and method == "GET":
                    return self._reply(HTTPStatus.OK, {"status": "ok", "sessions": len(service.sessions)})
                if parts == ["sessions"] and method == "POST":
                    return self._reply(HTTPStatus.CREATED, service.create(self._body()))
                if len(parts) == 3 and parts[0] == "sessions" and parts[2] == "step" and method == "POST":
                    return self._reply(HTTPStatus.OK, service.step(parts[1], self._body()))
                if len(parts) == 2 and parts[0] == "sessions" and method == "GET":
                    return self._reply(HTTPStatus.OK, service.get(parts[1]).summary())
                if len(parts) == 2 and parts[0] == "sessions" and method == "DELETE":
                    return self._reply(HTTPStatus.OK, service.close(parts[1]))
                known = parts in (["health"], ["sessions"]) or (parts[:1] == ["sessions"] and len(parts) in (2, 3))
                if known:
                    raise RequestError(HTTPStatus.METHOD_NOT_ALLOWED, f"{method} is not allowed on {self.path}")
                raise RequestError(HTTPStatus.NOT_FOUND, f"no such path {self.path}")
            except RequestError as exc:
                self.close_connection = True  # the body may be unread: never reuse this connection
                return self._reply(exc.status, {"error": exc.message})

        def do_GET(self):
            self._route("GET")

        def do_POST(self):
            self._route("POST")

        def do_DELETE(self):
            self._route("DELETE")

        def do_PUT(self):
            self._route("PUT")

    return Handler


def make_server(library, host: str = "127.0.0.1", port: int = 8765) -> ThreadingHTTPServer:
    server = ThreadingHTTPServer((host, port), make_handler(GuardianService(library)))
    server.daemon_threads = True
    return server
