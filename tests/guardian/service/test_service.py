"""The guardian service over real loopback sockets: API, framing, limits, sessions, token, stream."""
import json
import threading
import time

import numpy as np
import pytest
from service_client import Raw, call, create, secret_header, step
from websockets.sync.client import connect as ws_connect

from guardian.service import Limits, ServiceConfig, ServiceThread

GOOD_STATE, GOOD_INPUT = [25.0, 0.0, 40.0, 20.0], [0.5, 0.0]
GOOD_STEP = step(0, GOOD_STATE, GOOD_INPUT)
ADMIN = "an-admin-token-of-some-length"
ADMIN_HEADER = {"authorization": f"Bearer {ADMIN}"}


@pytest.fixture(scope="module")
def service(library):
    limits = Limits(read_timeout=1.0, keepalive_timeout=1.0)
    with ServiceThread(library, ServiceConfig(port=0, limits=limits, admin_token=ADMIN)) as svc:
        yield svc


def new_session(address, settings=None) -> tuple[str, str]:
    return create(address, settings)


def raw_step(sid: str, secret: str, body: bytes, host: bytes = b"localhost") -> bytes:
    """One step request as bytes (for pipelining and cut-short requests)."""
    return (b"POST /sessions/%s/step HTTP/1.1\r\nHost: %s\r\nContent-Type: application/json\r\n"
            b"Session-Secret: %s\r\nContent-Length: %d\r\n\r\n" % (sid.encode(), host, secret.encode(), len(body))
            + body)


def live(svc) -> int:
    return call(svc.address, "GET", "/health")[2]["sessions"]


def test_session_lifecycle(service, library):
    sid, secret = new_session(service.address)
    x = np.array(GOOD_STATE)
    model = library.models["cautious"]
    raw = Raw(service.address)  # one keep-alive connection for the whole loop
    auth = secret_header(secret)
    for seq in range(40):
        status, _, rec = raw.request("POST", f"/sessions/{sid}/step", step(seq, x.tolist(), [0.5, 0.0]), auth)
        assert status == 200 and rec["t"] == seq
        assert -3 <= rec["applied"][0] <= 3 and -1.8 <= rec["applied"][1] <= 1.8
        assert rec["failsafe"] is (rec["changed"] == "failsafe")
        x = model.system.step(x, rec["applied"], np.zeros(4))
    status, _, summary = raw.request("GET", f"/sessions/{sid}", None, auth)
    assert status == 200 and summary["steps"] == 40 and summary["valid_intentions"] == ["cautious"]
    assert summary["next_seq"] == 40 and summary["last"]["t"] == 39
    assert summary["active_set"] == "cautious" and summary["idle_s"] >= 0
    listed = {s["session"]: s for s in raw.request("GET", "/sessions", None, ADMIN_HEADER)[2]["sessions"]}
    assert listed[sid]["steps"] == 40
    assert raw.request("DELETE", f"/sessions/{sid}", None, auth)[0] == 200
    status, _, err = raw.request("GET", f"/sessions/{sid}", None, auth)
    assert status == 404 and "unknown session" in err["error"]
    raw.close()


def test_write_bodies_must_be_json(service):
    """A form (``curl -d`` without -H) or text/plain POST is refused (415): a browser page can send
    those cross-site without asking; nothing is created or stepped."""
    before = live(service)
    for ctype in ("application/x-www-form-urlencoded", "text/plain", "multipart/form-data; boundary=x", None):
        status, headers, err = call(service.address, "POST", "/sessions", {"horizon": 4}, {"content-type": ctype})
        assert status == 415 and "application/json" in err["error"] and headers["accept-post"] == "application/json"
    assert live(service) == before
    sid, secret = new_session(service.address)
    for ctype in ("text/plain", "application/x-www-form-urlencoded"):
        status, _, _ = call(service.address, "POST", f"/sessions/{sid}/step", GOOD_STEP,
                            secret_header(secret, **{"content-type": ctype}))
        assert status == 415
    assert call(service.address, "GET", f"/sessions/{sid}", None, secret_header(secret))[2]["steps"] == 0
    status, _, s = call(service.address, "POST", "/sessions", {"use_intention": False, "horizon": 4},
                        {"content-type": "application/json; charset=utf-8"})
    assert status == 201 and s["use_intention"] is False and s["horizon"] == 4
    assert call(service.address, "POST", f"/sessions/{s['session']}/step", GOOD_STEP,
                secret_header(s["secret"]))[0] == 200
    assert call(service.address, "PATCH", "/health", None)[0] == 405


def test_session_settings_are_honoured_and_checked(service):
    sid, secret = new_session(service.address, {"use_intention": False, "horizon": 3, "priority": ["steering", "throttle"]})
    _, _, s = call(service.address, "GET", f"/sessions/{sid}", None, secret_header(secret))
    assert s["use_intention"] is False and s["horizon"] == 3 and s["priority"] == ["steering", "throttle"]
    for bad, fragment in [({"horizon": 0}, "horizon"), ({"horizon": True}, "horizon"),
                          ({"use_intention": 1}, "use_intention"), ({"priority": ["throttle", "throttle"]}, "priority"),
                          ({"colour": "red"}, "colour")]:
        status, _, err = call(service.address, "POST", "/sessions", bad)
        assert status == 422 and fragment in err["error"], (bad, err)


@pytest.mark.parametrize("raw,status,fragment", [
    (b"{not json", 400, "malformed JSON"),
    (b'{"seq": 1, "state": [NaN, 0, 40, 20], "input": [0, 0]}', 400, "NaN"),
    (b'{"seq": 1, "state": [Infinity, 0, 40, 20], "input": [0, 0]}', 400, "Infinity"),
    (b'{"seq": 1, "state": [25, 0, 40], "input": [0, 0]}', 422, "state"),
    (b'{"seq": 1, "state": [25, 0, 40, 20], "input": [0, "x"]}', 422, "input.1"),
    (b'{"seq": 1, "state": [25, 0, 40, 20], "input": [0, true]}', 422, "input.1"),
    (b'{"seq": 1, "state": [25, 0, 40, 20]}', 422, "input"),
    (b'{"seq": 1, "state": [25, 0, 40, 20], "input": [0, 0], "extra": 1}', 422, "extra"),
    (b'{"state": [25, 0, 40, 20], "input": [0, 0]}', 422, "seq"),
    (b'{"seq": -1, "state": [25, 0, 40, 20], "input": [0, 0]}', 422, "seq"),
    (b'{"seq": 1.0, "state": [25, 0, 40, 20], "input": [0, 0]}', 422, "seq"),
    (b'{"seq": 1, "state": [25, 0, 40, 99.0], "input": [0, 0]}', 422, "model domain"),
    (b'{"seq": 1, "state": [-500, 0, 40, 20], "input": [0, 0]}', 422, "model domain"),
    (b'{"seq": 3, "state": [25, 0, 40, 20], "input": [0, 0]}', 409, "expects step 1"),
    (b'{"seq": 0, "state": [25, 0, 40, 20], "input": [0, 0]}', 409, "different state or input"),
    (b"[1, 2]", 422, "object"),
    (b'{"seq": 1, "state": [1' + b"0" * 400 + b', 0, 40, 20], "input": [0, 0]}', 400, "number"),
    (b"[" * 20000 + b"]" * 20000, 400, "nested"),
    (b"\xff\xfe{}", 400, "malformed JSON"),
])
def test_bad_steps_get_a_4xx_and_leave_the_session_alone(service, raw, status, fragment):
    sid, secret = new_session(service.address)
    conn = Raw(service.address)
    auth = secret_header(secret)
    assert conn.request("POST", f"/sessions/{sid}/step", GOOD_STEP, auth)[0] == 200
    before = conn.request("GET", f"/sessions/{sid}", None, auth)[2]
    got, headers, err = conn.request("POST", f"/sessions/{sid}/step", raw, auth)
    assert got == status and fragment in err["error"], err
    assert headers["content-type"] == "application/json"
    after = conn.request("GET", f"/sessions/{sid}", None, auth)[2]  # same connection: a 4xx keeps it usable
    before.pop("idle_s"), after.pop("idle_s")
    assert after == before
    conn.close()


def test_one_sessions_bad_request_does_not_disturb_another(service):
    (a, sa), (b, sb) = new_session(service.address), new_session(service.address, {"use_intention": False})
    call(service.address, "POST", f"/sessions/{a}/step", GOOD_STEP, secret_header(sa))
    ref = call(service.address, "GET", f"/sessions/{a}", None, secret_header(sa))[2]
    assert call(service.address, "POST", f"/sessions/{b}/step", b"garbage", secret_header(sb))[0] == 400
    now = call(service.address, "GET", f"/sessions/{a}", None, secret_header(sa))[2]
    ref.pop("idle_s"), now.pop("idle_s")
    assert now == ref


def test_a_state_in_the_domain_but_outside_the_set_gets_the_failsafe_flagged(service):
    sid, secret = new_session(service.address)
    status, _, rec = call(service.address, "POST", f"/sessions/{sid}/step",
                          step(0, [10.0, 0.0, 11.0, 0.0], [3.0, 0.0]), secret_header(secret))
    assert status == 200 and rec["in_invariant_set"] is False
    assert rec["failsafe"] is (rec["changed"] == "failsafe")
    assert -3 <= rec["applied"][0] <= 3 and -1.8 <= rec["applied"][1] <= 1.8


def test_every_error_is_json_and_methods_are_checked(service):
    for method, path, status in [("PATCH", "/sessions", 405), ("OPTIONS", "/health", 405), ("PUT", "/health", 405),
                                 ("GET", "/nowhere", 404), ("DELETE", "/sessions/nope", 404)]:
        got, headers, body = call(service.address, method, path)
        assert got == status and headers["content-type"] == "application/json" and "error" in body
    got, headers, body = call(service.address, "HEAD", "/health")
    assert got == 200 and body is None and int(headers["content-length"]) > 0
    assert call(service.address, "GET", "/openapi.json")[2]["paths"]["/sessions/{sid}/step"]["post"]["requestBody"]


def test_allow_headers_list_exactly_the_methods_of_each_path(service):
    """Issue 25: ``PUT /sessions`` said ``Allow: GET`` although POST exists."""
    sid, _ = new_session(service.address)
    expected = {"/health": "GET, HEAD", "/ready": "GET, HEAD", "/sessions": "GET, HEAD, POST",
                f"/sessions/{sid}": "GET, HEAD, DELETE", f"/sessions/{sid}/step": "POST",
                f"/sessions/{sid}/stream": "GET", "/openapi.json": "GET, HEAD", "/docs": "GET, HEAD"}
    for path, allow in expected.items():
        for method in ("PUT", "PATCH", "OPTIONS", "TRACE", "POST", "DELETE", "GET"):
            if method in allow.split(", "):
                continue
            status, headers, body = call(service.address, method, path, b"{}" if method in ("PUT", "PATCH") else None)
            assert status == 405 and headers["allow"] == allow, (method, path, headers)
            assert f"{method} is not allowed" in body["error"]


# ---- framing: what the fuzzing review did, byte for byte --------------------------------

def test_chunked_bodies_are_read_and_nothing_inside_them_runs_as_a_request(service):
    victim, victim_secret = new_session(service.address)
    body = json.dumps({"use_intention": False, "horizon": 3}).encode()
    smuggled = (f"DELETE /sessions/{victim} HTTP/1.1\r\nHost: localhost\r\nSession-Secret: {victim_secret}\r\n"
                "Content-Length: 0\r\n\r\n").encode()
    chunks = b"".join(b"%x\r\n%s\r\n" % (len(c), c) for c in (body[:7], body[7:]))
    head = b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
    raw = Raw(service.address).send(head + chunks + b"0\r\n\r\n")
    status, _, created = raw.response()
    assert status == 201 and created["use_intention"] is False
    assert call(service.address, "GET", f"/sessions/{created['session']}", None,
                secret_header(created["secret"]))[2]["horizon"] == 3
    # a chunked body holding a request is a body (malformed JSON), not a request
    raw.send(head + b"%x\r\n%s\r\n0\r\n\r\n" % (len(smuggled), smuggled))
    assert raw.response()[0] == 400
    assert call(service.address, "GET", f"/sessions/{victim}", None, secret_header(victim_secret))[0] == 200
    raw.close()


@pytest.mark.parametrize("partial", [
    b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Le",
    b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\nContent-Length: 30\r\n\r\n",
    b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\nContent-Length: 30\r\n\r\n"
    b"{\"horizon\": 3",
    b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n"
    b"\r\n5\r\n{\"hor",
])
def test_a_request_cut_short_executes_nothing(service, partial):
    before = live(service)
    for _ in range(20):
        raw = Raw(service.address).send(partial).half_close()
        assert raw.response() is None  # a clean close, no answer to a request that never arrived
        raw.close()
    assert live(service) == before


def test_a_whole_request_then_a_half_close_is_answered(service):
    """Issue 25: ``nc -N`` (the request, then FIN) ran the request but sent no answer."""
    before = live(service)
    body = b"{}"
    raw = Raw(service.address).send(b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
                                    b"Content-Length: 2\r\n\r\n" + body).half_close()
    status, _, created = raw.response()
    assert status == 201 and created["session"]
    raw.close()
    assert live(service) == before + 1
    sid, secret = created["session"], created["secret"]
    piped = b"".join(raw_step(sid, secret, json.dumps(step(k, GOOD_STATE, GOOD_INPUT)).encode()) for k in range(3))
    raw = Raw(service.address).send(piped).half_close()  # three pipelined steps, then FIN: three answers
    assert [raw.response()[2]["t"] for _ in range(3)] == [0, 1, 2]
    assert raw.closed()
    raw.close()


@pytest.mark.parametrize("head,status,fragment", [
    (b"POST /sessions HTTP/1.1\r\nHost: x\r\nContent-Length: -1\r\n\r\n", 400, "invalid HTTP request"),
    (b"POST /sessions HTTP/1.1\r\nHost: x\r\nContent-Length: -5\r\n\r\n", 400, "invalid HTTP request"),
    (b"POST /sessions HTTP/1.1\r\nHost: x\r\nContent-Length: 1x\r\n\r\n", 400, "invalid HTTP request"),
    (b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\nContent-Length: 209715200\r\n\r\n",
     413, "exceeds"),
    (b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n\r\n", 411, "Content-Length"),
    (b"GET /" + b"a" * 70_000 + b" HTTP/1.1\r\nHost: x\r\n\r\n", 414, "bytes"),
    (b"GET /" + b"a" * 9_000 + b" HTTP/1.1\r\nHost: x\r\n\r\n", 414, "request target"),
    (b"GET /health HTTP/1.1\r\nHost: x\r\n" + b"".join(b"X-%d: y\r\n" % i for i in range(200)) + b"\r\n",
     431, "header fields"),
    (b"GET /health HTTP/1.1\r\nHost: x\r\nX-Big: " + b"y" * 20_000 + b"\r\n\r\n", 431, "longer than"),
    (b"GARBAGE\r\n\r\n", 400, "invalid HTTP request"),
    (b"GET /health HTTP/1.1\r\n\r\n", 400, "Host"),
    (b"GET /health HTTP/1.1\r\nHost: a\r\nHost: b\r\n\r\n", 400, "host given more than once"),
    (b"GET /health HTTP/1.1\r\nHost: localhost\r\nX: a\r\n b\r\n\r\n", 400, "whitespace"),  # obs-fold
    (b"GET /health HTTP/1.1\r\nHost : localhost\r\n\r\n", 400, "Invalid header token"),
    (b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Length: 2\r\nTransfer-Encoding: chunked\r\n\r\n", 400,
     "Transfer-Encoding can't be present with Content-Length"),
    (b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Length: 2\r\nContent-Length: 3\r\n\r\n", 400,
     "Duplicate Content-Length"),
    (b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nTransfer-Encoding: gzip, chunked\r\n\r\n", 501, "chunked"),
    (b"GET /health HTTP/2.0\r\nHost: localhost\r\n\r\n", 505, "HTTP/2.0 is not supported"),
    (b"GET /health HTTP/1.1\r\nHost: localhost\r\nExpect: the-unexpected\r\n\r\n", 417, "Expect"),
    (b"GET /he\x01alth HTTP/1.1\r\nHost: localhost\r\n\r\n", 400, "Invalid char in url"),
])
def test_framing_errors_get_json_and_connection_close(service, head, status, fragment):
    raw = Raw(service.address).send(head)
    got, headers, body = raw.response()
    assert got == status and fragment in body["error"], body
    assert headers["content-type"] == "application/json" and headers["connection"] == "close"
    assert raw.closed()
    raw.close()


def test_a_200_mb_body_is_refused_before_it_is_read(service):
    raw = Raw(service.address).send(b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Length: -1\r\n\r\n")
    assert raw.response()[0] == 400
    raw.close()
    raw = Raw(service.address).send(b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
                                    b"Transfer-Encoding: chunked\r\n\r\n")
    sent = 0
    with pytest.raises((BrokenPipeError, ConnectionResetError)):
        while sent < 200 * 2 ** 20:
            raw.send(b"100000\r\n" + b" " * 0x100000 + b"\r\n")
            sent += 0x100000
    assert sent <= 8 * 2 ** 20  # refused after the first 64 KiB, not after 200 MB
    raw.close()


def test_pipelined_requests_are_answered_in_order(service):
    sid, secret = new_session(service.address)
    one = b"".join(raw_step(sid, secret, json.dumps(step(k, GOOD_STATE, GOOD_INPUT)).encode()) for k in range(5))
    raw = Raw(service.address).send(one + f"GET /sessions/{sid} HTTP/1.1\r\nHost: localhost\r\n"
                                           f"Session-Secret: {secret}\r\n\r\n".encode())
    ts = [raw.response()[2]["t"] for _ in range(5)]
    assert ts == [0, 1, 2, 3, 4] and raw.response()[2]["steps"] == 5
    raw.close()


def test_slow_and_idle_clients_are_timed_out(service):
    half = Raw(service.address).send(b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-")
    slow_body = Raw(service.address).send(b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json"
                                          b"\r\nContent-Length: 10\r\n\r\n{")
    idle = Raw(service.address)
    t0 = time.monotonic()
    status, headers, body = half.response()
    assert status == 408 and "head" in body["error"] and headers["connection"] == "close"
    status, headers, body = slow_body.response()
    assert status == 408 and "body" in body["error"] and headers["connection"] == "close"
    assert idle.closed(timeout=5.0)
    assert time.monotonic() - t0 < 4.0
    for r in (half, slow_body, idle):
        r.close()


# ---- sessions expire ------------------------------------------------------------------------------

def test_abandoned_sessions_expire_and_new_ones_are_served(library):
    config = ServiceConfig(port=0, session_ttl=4.0, max_sessions=1000)
    with ServiceThread(library, config) as svc:
        raw = Raw(svc.address)
        first = [create(raw) for _ in range(1000)]
        status, headers, err = raw.request("POST", "/sessions", {})
        assert status == 503 and "session limit 1000" in err["error"] and headers["retry-after"] == "4"
        time.sleep(4.3)
        sid, secret = create(raw)
        status, _, err = raw.request("GET", f"/sessions/{first[0][0]}", None, secret_header(first[0][1]))
        assert status == 410 and err["expired"] is True and "expired" in err["error"]
        assert raw.request("POST", f"/sessions/{first[1][0]}/step", GOOD_STEP, secret_header(first[1][1]))[0] == 410
        health = raw.request("GET", "/health")[2]
        assert health["sessions"] == 1 and health["expired"] == 1000
        assert health["max_sessions"] == 1000 and health["session_ttl_s"] == 4.0
        # a session in use does not expire
        for seq in range(6):
            assert raw.request("POST", f"/sessions/{sid}/step", step(seq, GOOD_STATE, GOOD_INPUT),
                               secret_header(secret))[0] == 200
            time.sleep(1.0)
        assert raw.request("GET", f"/sessions/{sid}", None, secret_header(secret))[0] == 200
        raw.close()


# ---- the token -----------------------------------------------------------------------------------

def test_a_public_address_without_a_token_is_refused():
    with pytest.raises(ValueError, match="without a token"):
        ServiceConfig(host="0.0.0.0").check()
    with pytest.raises(ValueError, match="at least 16"):
        ServiceConfig(host="0.0.0.0", token="short").check()
    with pytest.raises(ValueError, match="at least 16"):
        ServiceConfig(admin_token="short").check()
    with pytest.raises(ValueError, match="differ"):
        ServiceConfig(host="0.0.0.0", token="a-long-enough-secret", admin_token="a-long-enough-secret").check()
    ServiceConfig(host="0.0.0.0", token="a-long-enough-secret").check()
    ServiceConfig(host="::1").check()


def test_the_token_is_checked_on_every_request_and_on_the_stream(library):
    token = "correct-horse-battery-staple"
    with ServiceThread(library, ServiceConfig(port=0, token=token)) as svc:
        for headers in ({}, {"authorization": "Bearer wrong-token-of-some-length"}, {"authorization": token}):
            for method, path in [("GET", "/health"), ("POST", "/sessions"), ("GET", "/docs")]:
                status, h, body = call(svc.address, method, path, {} if method == "POST" else None, headers)
                assert status == 401 and "token" in body["error"] and h["www-authenticate"].startswith("Bearer")
        good = {"authorization": f"Bearer {token}"}
        sid, secret = create(svc.address, {}, good)
        url = f"ws://{svc.address[0]}:{svc.address[1]}/sessions/{sid}/stream"
        with pytest.raises(Exception, match="401"):
            ws_connect(url, additional_headers=secret_header(secret)).close()
        with ws_connect(url, additional_headers={**good, **secret_header(secret)}) as ws:
            ws.send(json.dumps(GOOD_STEP))
            assert json.loads(ws.recv())["t"] == 0


# ---- the stream ----------------------------------------------------------------------------------

def test_the_stream_answers_each_message_in_order_like_http(service, library):
    (over_http, sh), (over_ws, sw) = new_session(service.address), new_session(service.address)
    rng = np.random.default_rng(3)
    steps = [step(k, [float(rng.uniform(20, 30)), float(rng.uniform(-0.5, 2)), float(rng.uniform(-40, 60)),
                      float(rng.uniform(15, 30))], [float(rng.uniform(-3, 3)), float(rng.uniform(-1.8, 1.8))])
             for k in range(30)]
    conn = Raw(service.address)
    expected = [conn.request("POST", f"/sessions/{over_http}/step", s, secret_header(sh))[2] for s in steps]
    with ws_connect(f"ws://{service.address[0]}:{service.address[1]}/sessions/{over_ws}/stream",
                    additional_headers=secret_header(sw)) as ws:
        for s in steps[:10]:  # pipelined: ten messages, then ten replies
            ws.send(json.dumps(s))
        got = [json.loads(ws.recv()) for _ in range(10)]
        ws.send("not json")
        assert json.loads(ws.recv())["status"] == 400
        ws.send(json.dumps({"seq": 10, "state": [1, 2], "input": [0, 0]}))
        assert json.loads(ws.recv())["status"] == 422
        for s in steps[10:]:
            ws.send(json.dumps(s))
            got.append(json.loads(ws.recv()))
    assert got == expected
    assert call(service.address, "GET", f"/sessions/{over_ws}", None, secret_header(sw))[2]["steps"] == 30
    conn.close()


def test_the_stream_of_an_unknown_or_deleted_session_says_so_and_closes(service):
    with ws_connect(f"ws://{service.address[0]}:{service.address[1]}/sessions/nope/stream") as ws:
        assert json.loads(ws.recv())["status"] == 404
        with pytest.raises(Exception):
            ws.recv()
    assert ws.close_code == 4404
    sid, secret = new_session(service.address)
    with ws_connect(f"ws://{service.address[0]}:{service.address[1]}/sessions/{sid}/stream",
                    additional_headers=secret_header(secret)) as ws:
        ws.send(json.dumps(GOOD_STEP))
        assert json.loads(ws.recv())["t"] == 0
        assert call(service.address, "DELETE", f"/sessions/{sid}", None, secret_header(secret))[0] == 200
        assert json.loads(ws.recv())["status"] == 404  # told at once, without sending anything
        with pytest.raises(Exception):
            ws.recv()
    assert ws.close_code == 4404


# ---- the process: refusal to start, graceful shutdown ---------------------------------------------

def _serve(cache_dir, *args, env=None):
    import os
    import subprocess
    import sys

    return subprocess.Popen([sys.executable, "-m", "guardian.cli", "serve", "--cache-dir", str(cache_dir), "--json",
                             *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, **(env or {})})


def read_info(proc) -> dict:
    lines = []
    while not lines or lines[-1] != "}":
        line = proc.stdout.readline()
        if not line:
            raise RuntimeError("guardian serve ended: " + proc.stderr.read())
        lines.append(line.rstrip("\n"))
    return json.loads("\n".join(lines))


def address_of(info) -> tuple:
    host, port = info["url"].removeprefix("http://").split(":")
    return host, int(port)


def test_serve_refuses_a_public_address_without_a_token(cache_dir):
    proc = _serve(cache_dir, "--host", "0.0.0.0", "--port", "0", env={"GUARDIAN_TOKEN": ""})
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "without a token" in err


def test_sigterm_answers_the_request_in_flight_then_exits(library, cache_dir):
    import signal

    proc = _serve(cache_dir, "--port", "0")
    try:
        address = address_of(read_info(proc))
        sid, secret = create(address)
        body = json.dumps(GOOD_STEP).encode()
        raw = Raw(address).send(raw_step(sid, secret, body)[:-len(body) + 10])
        time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        time.sleep(0.5)
        raw.send(body[10:])  # the rest of the request in flight arrives after the signal
        status, headers, record = raw.response()
        assert status == 200 and record["t"] == 0 and headers["connection"] == "close"
        assert proc.wait(timeout=20) == 0
        with pytest.raises(OSError):
            call(address, "GET", "/health")
    finally:
        proc.kill()
        proc.communicate()


def test_sigterm_tells_back_to_back_keep_alive_clients_to_close_rather_than_resetting_them(library, cache_dir):
    """Clients sending request after request on keep-alive connections as the server stops: each request sent
    is answered, the last with ``Connection: close``; none is met by a reset or a close without an answer."""
    import signal

    proc = _serve(cache_dir, "--port", "0")
    outcomes = []

    def client(address, started):
        raw, answered = Raw(address), 0
        started.release()
        while True:
            try:
                got = raw.send(b"GET /health HTTP/1.1\r\nHost: localhost\r\n\r\n").response()
            except OSError as exc:
                got = exc
            if not isinstance(got, tuple) or got[0] != 200:
                outcomes.append(f"request {answered + 1} unanswered: {got!r}")
                return
            answered += 1
            if got[1].get("connection") == "close":
                outcomes.append("told to close")
                return

    try:
        address = address_of(read_info(proc))
        started = threading.Semaphore(0)
        threads = [threading.Thread(target=client, args=(address, started)) for _ in range(4)]
        for t in threads:
            t.start()
        for _ in threads:
            started.acquire()
        time.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        for t in threads:
            t.join(timeout=30)
        assert outcomes == ["told to close"] * 4, outcomes
        assert proc.wait(timeout=20) == 0
    finally:
        proc.kill()
        proc.communicate()
