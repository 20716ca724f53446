"""The OpenAPI document describes every answer the service gives (a truthful contract).

Referees we did not write: openapi-spec-validator checks the document; openapi-core checks each response
(status listed for the operation, body valid against the schema, headers) of requests chosen to
produce every kind of answer, from the routes and from the checks and the reader before them.
"""
import json
import re
import socket
import time

import pytest
from openapi_core import OpenAPI
from openapi_core.testing import MockRequest, MockResponse
from openapi_spec_validator import validate as validate_spec
from service_client import Raw, call, create, secret_header, step
from websockets.sync.client import connect as ws_connect

from guardian.service import Limits, ServiceConfig, ServiceThread, openapi

ADMIN = "an-admin-token-of-some-length"
TOKEN = "the-service-token-of-some-length"
GOOD = step(0, [25.0, 0.0, 40.0, 20.0], [0.5, 0.0])
TEMPLATES = [(re.compile(r"^/sessions/[^/]+/step$"), "/sessions/{sid}/step"),
             (re.compile(r"^/sessions/[^/]+/stream$"), "/sessions/{sid}/stream"),
             (re.compile(r"^/sessions/[^/]+$"), "/sessions/{sid}")]


def template(path: str) -> str:
    path = path.split("?", 1)[0]
    for pattern, name in TEMPLATES:
        if pattern.match(path):
            return name
    return path


class Contract:
    """Validates each answer against the document and records which (path, method, status) were seen."""

    def __init__(self):
        self.doc = openapi.document()
        self.api = OpenAPI.from_dict(json.loads(json.dumps(self.doc)))
        self.seen = set()

    def check(self, method: str, path: str, answer) -> tuple:
        assert answer is not None, f"{method} {path}: no answer"
        status, headers, body = answer
        tpl = template(path)
        assert tpl in self.doc["paths"], f"{method} {path} answered {status} on a path the document lacks"
        ops = self.doc["paths"][tpl]
        # a method the path does not have (405) or HEAD is judged by the path's GET (or only) operation
        op_method = method.lower() if method.lower() in ops else ("get" if "get" in ops else next(
            m for m in ops if m != "parameters"))
        responses = ops[op_method]["responses"]
        assert str(status) in responses, f"{method} {path} answered {status}, not in {sorted(responses)}"
        self.seen.add((tpl, op_method, status))
        if method == "HEAD" or status == 101:
            return answer
        raw_body = body if isinstance(body, bytes) else json.dumps(body).encode()
        ctype = headers.get("content-type", "")
        self.api.validate_response(
            MockRequest("http://localhost", op_method, path.split("?", 1)[0]),
            MockResponse(raw_body, status, headers=headers, content_type=ctype.split(";")[0]))
        return answer


@pytest.fixture(scope="module")
def contract():
    return Contract()


@pytest.fixture(scope="module")
def service(library):
    limits = Limits(read_timeout=0.5, keepalive_timeout=2.0)
    with ServiceThread(library, ServiceConfig(port=0, limits=limits, admin_token=ADMIN, max_sessions=60,
                                              session_ttl=1.5)) as svc:
        yield svc


def test_the_document_is_valid_openapi_with_the_bearer_scheme():
    doc = openapi.document()
    validate_spec(doc)
    schemes = doc["components"]["securitySchemes"]
    assert schemes["bearer"] == {**schemes["bearer"], "type": "http", "scheme": "bearer"}
    assert schemes["sessionSecret"]["in"] == "header" and schemes["sessionSecret"]["name"] == "Session-Secret"
    assert doc["components"]["schemas"]["Error"]["required"] == ["error"]
    assert "detail" not in json.dumps(doc)  # FastAPI's {"detail": ...} is not what the service sends


def test_docs_work_offline(service):
    status, headers, page = call(service.address, "GET", "/docs")
    assert status == 200 and headers["content-type"].startswith("text/html")
    page = page.decode()
    assert "<script" not in page.lower() and not re.search(r"""(src|href)=["']?(https?:)?//""", page)
    for path, item in openapi.document()["paths"].items():
        for method, op in item.items():
            if method != "parameters":
                assert op["operationId"] in page and f"{method.upper()} {path}" in page


def _raw(svc, data: bytes, half_close: bool = False):
    raw = Raw(svc.address).send(data)
    if half_close:
        raw.half_close()
    try:
        return raw.response()
    finally:
        raw.close()


def test_every_answer_of_the_routes_matches_the_document(service, contract):
    a = service.address
    c = contract.check
    admin = {"authorization": f"Bearer {ADMIN}"}
    c("GET", "/health", call(a, "GET", "/health"))
    c("HEAD", "/health", call(a, "HEAD", "/health"))
    c("GET", "/ready", call(a, "GET", "/ready"))
    c("GET", "/openapi.json", call(a, "GET", "/openapi.json"))
    c("GET", "/docs", call(a, "GET", "/docs"))
    for path in ("/health", "/ready", "/sessions", "/openapi.json", "/docs"):
        c("PUT", path, call(a, "PUT", path, b"{}"))
    sid, secret = create(a)
    auth = secret_header(secret)
    c("POST", "/sessions", call(a, "POST", "/sessions", {"horizon": 4}))
    c("POST", "/sessions", call(a, "POST", "/sessions", {"horizon": 0}))                       # 422
    c("POST", "/sessions", call(a, "POST", "/sessions", b"{nope"))                             # 400
    c("POST", "/sessions", call(a, "POST", "/sessions", b"[" * 40 + b"]" * 40))                # 400 depth
    c("POST", "/sessions", call(a, "POST", "/sessions", {}, {"content-type": "text/plain"}))   # 415
    c("POST", "/sessions", call(a, "POST", "/sessions", b"x" * 70_000))                        # 413
    c("POST", "/sessions", _raw(service, b"POST /sessions HTTP/1.1\r\nHost: localhost\r\n"
                                         b"Content-Type: application/json\r\n\r\n"))          # 411
    c("GET", "/sessions", call(a, "GET", "/sessions"))                                         # 403
    c("GET", "/sessions", call(a, "GET", "/sessions", None, admin))                           # 200
    for body, headers in [(GOOD, auth), (step(5, [25, 0, 40, 20], [0, 0]), auth),             # 200, 409
                          (GOOD, auth),                                                        # 200 (a retry)
                          (step(1, [25, 0, 40, 99], [0, 0]), auth),                            # 422 domain
                          (b'{"seq": 1}', auth), (b"nope", auth),                              # 422, 400
                          (GOOD, {}), (GOOD, secret_header("wrong")),                          # 403, 403
                          (GOOD, {**auth, "content-type": "text/plain"})]:                     # 415
        c("POST", f"/sessions/{sid}/step", call(a, "POST", f"/sessions/{sid}/step", body, headers))
    c("POST", f"/sessions/{sid}/step", call(a, "POST", f"/sessions/{sid}/step", b"x" * 70_000, auth))  # 413
    for unknown in ("nope", "n0.0.zzzzzzzz.0123456789abcdef", "far.0.1.0123456789abcdef",      # 404, 404, 421
                    "n0.0.1.0123456789abcdef"):                                                # 410 restarted
        c("POST", f"/sessions/{unknown}/step", call(a, "POST", f"/sessions/{unknown}/step", GOOD, auth))
        c("GET", f"/sessions/{unknown}", call(a, "GET", f"/sessions/{unknown}", None, auth))
        c("DELETE", f"/sessions/{unknown}", call(a, "DELETE", f"/sessions/{unknown}", None, auth))
    c("GET", f"/sessions/{sid}", call(a, "GET", f"/sessions/{sid}", None, auth))
    c("GET", f"/sessions/{sid}", call(a, "GET", f"/sessions/{sid}", None, admin))
    c("GET", f"/sessions/{sid}", call(a, "GET", f"/sessions/{sid}", None))                    # 403
    c("HEAD", f"/sessions/{sid}", call(a, "HEAD", f"/sessions/{sid}", None, auth))
    c("PATCH", f"/sessions/{sid}", call(a, "PATCH", f"/sessions/{sid}", b"{}", auth))          # 405
    c("GET", f"/sessions/{sid}/step", call(a, "GET", f"/sessions/{sid}/step", None, auth))     # 405
    c("GET", f"/sessions/{sid}/stream", call(a, "GET", f"/sessions/{sid}/stream", None, auth))  # 426
    c("POST", f"/sessions/{sid}/stream", call(a, "POST", f"/sessions/{sid}/stream", {}, auth))  # 405
    url = f"ws://{a[0]}:{a[1]}/sessions/{sid}/stream"
    with ws_connect(url, additional_headers=auth):
        c("GET", f"/sessions/{sid}/stream", (101, {}, None))
        c("GET", f"/sessions/{sid}/stream", _raw(service, _handshake(sid, secret)))           # 409 second stream
        c("POST", f"/sessions/{sid}/step", call(a, "POST", f"/sessions/{sid}/step",
                                                 step(1, [25, 0, 40, 20], [0, 0]), auth))     # 409 streaming
    c("GET", f"/sessions/{sid}/stream", _raw(service, _handshake(sid, "wrong")))              # 403
    c("DELETE", f"/sessions/{sid}", call(a, "DELETE", f"/sessions/{sid}", None, secret_header("wrong")))  # 403
    c("DELETE", f"/sessions/{sid}", call(a, "DELETE", f"/sessions/{sid}", None, auth))        # 200
    old, old_secret = create(a)
    time.sleep(2.0)
    c("GET", f"/sessions/{old}", call(a, "GET", f"/sessions/{old}", None, secret_header(old_secret)))  # 410 expired
    full = [create(a) for _ in range(60 - len(service.store.live))]
    c("POST", "/sessions", call(a, "POST", "/sessions", {}))                                   # 503 session limit
    for s, sec in full:
        call(a, "DELETE", f"/sessions/{s}", None, secret_header(sec))


def _handshake(sid: str, secret: str, extra: bytes = b"") -> bytes:
    return (f"GET /sessions/{sid}/stream HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\nSession-Secret: {secret}\r\n"
            ).encode() + extra + b"\r\n"


def test_every_answer_of_the_reader_and_the_checks_matches_the_document(service, contract):
    """Answers given before any route runs: framing (400, 414, 417, 431, 501, 505), 408, 403 Host/Origin."""
    c = contract.check
    a = service.address
    c("GET", "/health", _raw(service, b"GET /health HTTP/1.1\r\nHost: a\r\nHost: b\r\n\r\n"))            # 400
    c("GET", "/health", _raw(service, b"GET /health HTTP/1.1\r\nHost: localhost\r\nExpect: x\r\n\r\n"))  # 417
    c("GET", "/health", _raw(service, b"GET /health HTTP/1.1\r\nHost: x\r\n"
                                      + b"".join(b"X-%d: y\r\n" % i for i in range(200)) + b"\r\n"))   # 431
    c("GET", "/health", _raw(service, b"GET /health HTTP/2.0\r\nHost: localhost\r\n\r\n"))              # 505
    c("GET", "/health", _raw(service, b"GET /health HTTP/1.1\r\nHost: localhost\r\n"))                  # 408
    c("POST", "/sessions", _raw(service, b"POST /sessions HTTP/1.1\r\nHost: localhost\r\n"
                                         b"Transfer-Encoding: gzip\r\n\r\n"))                          # 501
    c("GET", "/health?" + "a" * 9000, _raw(service, b"GET /health?" + b"a" * 9000 + b" HTTP/1.1\r\n\r\n"))  # 414
    c("GET", "/health", call(a, "GET", "/health", None, {"host": "attacker.example"}))                # 403
    c("POST", "/sessions", call(a, "POST", "/sessions", {}, {"origin": "http://attacker.example"}))    # 403


def test_the_token_and_the_connection_limit_and_a_bug_answer_as_documented(library, contract, monkeypatch):
    c = contract.check
    config = ServiceConfig(port=0, token=TOKEN, limits=Limits(max_connections=3, keepalive_timeout=5.0))
    with ServiceThread(library, config) as svc:
        a = svc.address
        c("GET", "/health", call(a, "GET", "/health"))                                             # 401
        c("POST", "/sessions", call(a, "POST", "/sessions", {}, {"authorization": "Bearer nope"}))  # 401
        held = [socket.create_connection(a) for _ in range(3)]
        time.sleep(0.2)
        c("GET", "/health", call(a, "GET", "/health", None, {"authorization": f"Bearer {TOKEN}"}))   # 503
        for s in held:
            s.close()
        time.sleep(0.2)
        monkeypatch.setattr(svc.server.app, "_health", lambda *a: 1 / 0)
        c("GET", "/health", call(a, "GET", "/health", None, {"authorization": f"Bearer {TOKEN}"}))   # 500
        svc.server.app.stopping = True
        c("GET", "/ready", call(a, "GET", "/ready", None, {"authorization": f"Bearer {TOKEN}"}))      # 503
        svc.server.app.stopping = False


def test_the_answers_seen_cover_the_document(contract):
    """Run last in this module: every status the document lists for the step and session routes was
    produced above (the document claims nothing the tests did not see), and every answer seen was listed."""
    want = {("/sessions/{sid}/step", "post", s) for s in (200, 400, 403, 404, 409, 410, 413, 415, 421, 422)}
    want |= {("/sessions", "post", s) for s in (201, 400, 411, 413, 415, 422, 503)}
    want |= {("/sessions/{sid}", "get", s) for s in (200, 403, 404, 405, 410, 421)}
    want |= {("/sessions/{sid}/stream", "get", s) for s in (101, 403, 405, 409, 426)}
    want |= {("/health", "get", s) for s in (200, 400, 401, 403, 405, 408, 414, 417, 431, 500, 503, 505)}
    assert want <= contract.seen, sorted(want - contract.seen)
