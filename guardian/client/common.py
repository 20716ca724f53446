"""What the synchronous and the asyncio clients share: the service's address, the requests they build, the
retry rule, and how an answer becomes a result or a ``ServiceError`` (no I/O here).
"""
from __future__ import annotations

import json
import time
import urllib.parse
from collections.abc import Mapping
from dataclasses import dataclass, field

from guardian.errors import ServiceError

SECRET_HEADER = "Session-Secret"
BACKOFF = 0.05          # seconds before the first retry; doubled at each retry
BACKOFF_MAX = 1.0       # seconds at most between two attempts
FRESH_AFTER = 1.0       # seconds idle after which a request that must not be retried gets a new connection
NOT_RETRIED = ("it is not sent again automatically: POST /sessions is not idempotent, and a session may have "
               "been created (it expires after the service's session time-to-live unless it is used)")


@dataclass(frozen=True)
class Target:
    """Where the service is: ``scheme`` (http or https), ``host``, ``port``, ``netloc`` (the ``Host`` header)
    and ``prefix`` (a path the routes are under, e.g. behind a reverse proxy; usually empty)."""

    scheme: str
    host: str
    port: int
    netloc: str
    prefix: str

    @classmethod
    def parse(cls, url: str) -> "Target":
        """The target of ``url`` (``http://HOST:PORT`` or ``https://HOST:PORT``, optionally with a path)."""
        u = urllib.parse.urlsplit(url)
        if u.scheme not in ("http", "https") or not u.hostname or u.query or u.fragment or u.username:
            raise ValueError(f"service URL {url!r}: give http://HOST:PORT or https://HOST:PORT (no query, no "
                             "user name)")
        port = u.port or (443 if u.scheme == "https" else 80)
        return cls(u.scheme, u.hostname, port, u.netloc, u.path.rstrip("/"))

    def ws_url(self, path: str) -> str:
        """The WebSocket URL of ``path`` on this service (``ws://`` or ``wss://``)."""
        return f"{'wss' if self.scheme == 'https' else 'ws'}://{self.netloc}{self.prefix}{path}"


def _plain(value):
    """JSON for numpy arrays and scalars (anything with ``tolist``)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serializable")


def encode(body) -> bytes:
    """``body`` as compact JSON bytes; NaN and infinities are refused here (they are not JSON)."""
    try:
        return json.dumps(body, allow_nan=False, default=_plain, separators=(",", ":")).encode()
    except ValueError as exc:
        raise ValueError(f"request body is not JSON: {exc}") from None


def road_dict(road) -> dict:
    """A scene session's ``road``: a dict as given, or a ``guardian.model.roads.Road``/``RoadMap`` converted with
    ``road_as_dict``."""
    if isinstance(road, Mapping):
        return dict(road)
    from guardian.model.roads import Road, RoadMap, road_as_dict

    if isinstance(road, (Road, RoadMap)):
        return road_as_dict(road)
    raise TypeError(f"road must be a dict, a Road or a RoadMap, not {type(road).__name__}")


@dataclass
class Request:
    """One request: ``idempotent`` says whether it may be sent again after it was sent whole and no answer
    came; ``what`` names it in messages."""

    method: str
    path: str
    body: bytes | None = None
    headers: dict = field(default_factory=dict)
    idempotent: bool = True
    what: str = ""


@dataclass
class Answer:
    """An HTTP answer: status, headers (lower-case names), body, and how many retries it took."""

    status: int
    headers: dict
    body: bytes
    retried: int = 0

    def json(self):
        try:
            return json.loads(self.body)
        except ValueError:
            text = self.body[:200].decode("utf-8", "replace")
            raise ServiceError(self.status, f"HTTP {self.status} answer is not JSON: {text!r}") from None


def error_of(answer: Answer) -> ServiceError:
    """The ``ServiceError`` of an error answer: its status, its ``"error"`` message, its other fields as
    ``extra`` (and ``retry_after_s`` from a ``Retry-After`` header)."""
    try:
        body = json.loads(answer.body)
    except ValueError:
        body = None
    if isinstance(body, dict) and isinstance(body.get("error"), str):
        message = body["error"]
        extra = {k: v for k, v in body.items() if k not in ("error", "status", "message")}
    else:
        text = answer.body[:200].decode("utf-8", "replace")
        message = f"HTTP {answer.status} without a JSON error body: {text!r}"
        extra = {}
    retry_after = answer.headers.get("retry-after")
    if retry_after is not None and "retry_after_s" not in extra:
        try:
            extra["retry_after_s"] = float(retry_after)
        except ValueError:
            pass
    return ServiceError(answer.status, message, **extra)


def result(answer: Answer, *ok: int):
    """The JSON body of ``answer`` when its status is one of ``ok``, else its ``ServiceError`` raised."""
    if answer.status in ok:
        return answer.json()
    raise error_of(answer)


class Attempts:
    """The retry rule of one request: after a connection failure (refused, reset, timed out, closed without an
    answer) it is sent again, at most ``retries`` times with a doubling backoff, unless it was sent whole and
    is not idempotent. Answers, whatever their status, are never retried."""

    def __init__(self, request: Request, retries: int):
        self.request, self.retries, self.tries = request, retries, 0

    def failed(self, exc: BaseException, sent: bool) -> float:
        """The delay before the next attempt, or the ``ConnectionError`` saying why there is none."""
        what = self.request.what or f"{self.request.method} {self.request.path}"
        if sent and not self.request.idempotent:
            raise ConnectionError(f"{what}: the request was sent but the connection failed before an answer "
                                  f"came ({type(exc).__name__}: {exc}); {NOT_RETRIED}") from exc
        if self.tries >= self.retries:
            hint = "; step() again with the same body is applied once" if self.request.path.endswith("/step") else ""
            raise ConnectionError(f"{what}: no answer after {self.tries + 1} attempt(s) ({type(exc).__name__}: "
                                  f"{exc}){hint}") from exc
        self.tries += 1
        return min(BACKOFF * 2 ** (self.tries - 1), BACKOFF_MAX)


class ClientBase:
    """The settings and request builders both clients share (see ``GuardianClient``)."""

    def __init__(self, url: str, token: str | None = None, timeout: float = 10.0, retries: int = 3):
        if not timeout > 0 or retries < 0:
            raise ValueError(f"timeout must be > 0 and retries >= 0, got {timeout}, {retries}")
        self.target = Target.parse(url)
        self.url, self.token, self.timeout, self.retries = url, token, float(timeout), int(retries)
        self._last_used = time.monotonic()

    def headers(self, secret: str | None = None, body: bool = False) -> dict:
        """The headers of a request: the token, the session's secret, the body's type."""
        out = {"Accept": "application/json"}
        if self.token is not None:
            out["Authorization"] = f"Bearer {self.token}"
        if secret is not None:
            out[SECRET_HEADER] = secret
        if body:
            out["Content-Type"] = "application/json"
        return out

    def must_be_fresh(self, request: Request) -> bool:
        """Should ``request`` go on a new connection (it may not be retried, and the kept one has idled long
        enough for the server to be closing it)?"""
        return not request.idempotent and time.monotonic() - self._last_used > FRESH_AFTER

    def create_request(self, settings: dict) -> Request:
        return Request("POST", "/sessions", encode(settings), self.headers(body=True), idempotent=False,
                       what="POST /sessions")

    def scene_request(self, road, vehicle: Mapping, guardian: Mapping | None) -> Request:
        body = {"kind": "scene", "road": road_dict(road), "vehicle": dict(vehicle)}
        if guardian is not None:
            body["guardian"] = dict(guardian)
        return self.create_request(body)

    @staticmethod
    def ready_result(answer: Answer) -> dict:
        """``/ready``'s body: 200, or 503 with ``"ready": false`` (warming up, stopping); other answers raise."""
        if answer.status == 503:
            body = answer.json() if answer.body.startswith(b"{") else None
            if isinstance(body, dict) and "ready" in body:
                return body
        return result(answer, 200)


class SessionBase:
    """What a session of either client holds, and the requests it builds (see ``Session``)."""

    def __init__(self, client, id: str, secret: str, kind: str = "two_car", next_seq: int = 0,
                 info: dict | None = None):
        self.client, self.id, self.secret, self.kind = client, id, secret, kind
        self.next_seq = int(next_seq)
        self.info = dict(info or {})
        self.closed = False
        self._path = "/sessions/" + urllib.parse.quote(id, safe="")

    @classmethod
    def created(cls, client, answer: Answer):
        """The session of a ``POST /sessions`` answer (201)."""
        body = result(answer, 201)
        info = {k: v for k, v in body.items() if k != "secret"}
        return cls(client, body["session"], body["secret"], body.get("kind", "two_car"), body.get("next_seq", 0),
                   info)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(id={self.id!r}, kind={self.kind!r}, next_seq={self.next_seq})"

    def step_body(self, body: dict) -> tuple[int, bytes]:
        """The next step's sequence number and its JSON body."""
        if "seq" in body:
            raise TypeError("step() keeps the sequence number itself: do not pass seq")
        return self.next_seq, encode({"seq": self.next_seq, **body})

    def step_request(self, body: dict) -> tuple[int, Request]:
        seq, raw = self.step_body(body)
        return seq, Request("POST", self._path + "/step", raw, self.client.headers(self.secret, body=True),
                            what=f"step {seq} of session {self.id}")

    def step_result(self, seq: int, answer: Answer) -> dict:
        """The record of step ``seq`` (the session then expects ``seq + 1``), or its error raised.

        A 409 saying the session expects ``seq + 1`` after a retry means the first attempt was applied and its
        answer lost: the session moves on to ``seq + 1`` and the 409 is raised with ``applied=True``.
        """
        if answer.status == 200:
            record = answer.json()
            self.next_seq = seq + 1
            return record
        err = error_of(answer)
        if answer.status == 409 and answer.retried and err.extra.get("expected_seq") == seq + 1:
            self.next_seq = seq + 1
            raise ServiceError(409, f"step {seq} of session {self.id} was applied by an attempt whose answer was "
                                    f"lost, and the retry was refused ({err.message}); the session goes on at step "
                                    f"{seq + 1}; summary()['last'] is the step's record",
                               **{**err.extra, "applied": True})
        raise err

    def lane_change_request(self, ego: Mapping, cars, to: int) -> Request:
        return Request("POST", self._path + "/lane_change", encode({"ego": ego, "cars": list(cars), "to": to}),
                       self.client.headers(self.secret, body=True), what=f"lane change of session {self.id}")

    def summary_request(self) -> Request:
        return Request("GET", self._path, None, self.client.headers(self.secret), what=f"summary of {self.id}")

    def close_request(self) -> Request:
        return Request("DELETE", self._path, None, self.client.headers(self.secret), what=f"closing {self.id}")

    def close_result(self, answer: Answer) -> dict:
        """``{"closed": ID}``; a 404 after a retry means the first attempt closed it."""
        if answer.status == 404 and answer.retried:
            answer = Answer(200, {}, encode({"closed": self.id}))
        body = result(answer, 200)
        self.closed = True
        return body
