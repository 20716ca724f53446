"""The guardian service over a real loopback socket."""
import http.client
import json
import threading

import numpy as np
import pytest

from guardian.service import make_server


@pytest.fixture(scope="module")
def server(library):
    srv = make_server(library, "127.0.0.1", 0)
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    yield srv.server_address
    srv.shutdown()
    srv.server_close()


def call(addr, method, path, body=None, raw=None):
    conn = http.client.HTTPConnection(*addr, timeout=10)
    data = raw if raw is not None else (json.dumps(body).encode() if body is not None else None)
    conn.request(method, path, body=data, headers={"Content-Type": "application/json"})
    resp = conn.getresponse()
    payload = json.loads(resp.read() or b"{}")
    conn.close()
    return resp.status, payload


def test_session_lifecycle(server, library):
    status, s = call(server, "POST", "/sessions", {})
    assert status == 201 and s["active_set"] == "bounded_velocity"
    sid = s["session"]
    x = np.array([25.0, 0.0, 40.0, 20.0])
    model = library.models["cautious"]
    for _ in range(40):
        status, rec = call(server, "POST", f"/sessions/{sid}/step", {"state": x.tolist(), "input": [0.5, 0.0]})
        assert status == 200
        assert -3 <= rec["applied"][0] <= 3 and -1.8 <= rec["applied"][1] <= 1.8
        x = model.system.step(x, rec["applied"], np.zeros(4))
    status, summary = call(server, "GET", f"/sessions/{sid}")
    assert status == 200 and summary["steps"] == 40 and summary["valid_intentions"] == ["cautious"]
    assert summary["active_set"] == "cautious"
    assert call(server, "DELETE", f"/sessions/{sid}")[0] == 200
    assert call(server, "GET", f"/sessions/{sid}")[0] == 404


@pytest.mark.parametrize("body,raw,fragment", [
    (None, b"{not json", "malformed JSON"),
    (None, b'{"state": [NaN, 0, 40, 20], "input": [0, 0]}', "NaN"),
    ({"state": [25, 0, 40], "input": [0, 0]}, None, "4 numbers"),
    ({"state": [25, 0, 40, 20], "input": [0, "x"]}, None, "2 numbers"),
    ({"state": [25, 0, 40, 20]}, None, "missing field 'input'"),
    ({"state": [25, 0, 40, 20], "input": [0, 0], "extra": 1}, None, "unknown fields"),
    ({"state": [25, 0, 40, 99.0], "input": [0, 0]}, None, "no piece"),
    (None, b"[1, 2]", "object"),
])
def test_bad_requests_get_a_400_and_leave_the_session_alone(server, body, raw, fragment):
    _, s = call(server, "POST", "/sessions", {})
    sid = s["session"]
    good = {"state": [25.0, 0.0, 40.0, 20.0], "input": [0.0, 0.0]}
    call(server, "POST", f"/sessions/{sid}/step", good)
    before = call(server, "GET", f"/sessions/{sid}")[1]
    status, err = call(server, "POST", f"/sessions/{sid}/step", body, raw)
    assert status == 400 and fragment in err["error"]
    after = call(server, "GET", f"/sessions/{sid}")[1]
    assert after == before


def test_one_sessions_bad_request_does_not_disturb_another(server, library):
    _, a = call(server, "POST", "/sessions", {})
    _, b = call(server, "POST", "/sessions", {"use_intention": False})
    x = [25.0, 0.0, 40.0, 20.0]
    call(server, "POST", f"/sessions/{a['session']}/step", {"state": x, "input": [0, 0]})
    ref = call(server, "GET", f"/sessions/{a['session']}")[1]
    assert call(server, "POST", f"/sessions/{b['session']}/step", raw=b"garbage")[0] == 400
    assert call(server, "GET", f"/sessions/{a['session']}")[1] == ref
    assert call(server, "GET", f"/sessions/{b['session']}")[1]["active_set"] == "bounded_velocity"


def test_unknown_routes_methods_and_oversized_bodies(server):
    assert call(server, "POST", "/sessions/nope/step", {"state": [25, 0, 40, 20], "input": [0, 0]})[0] == 404
    assert call(server, "GET", "/nowhere")[0] == 404
    assert call(server, "PUT", "/sessions")[0] == 405
    assert call(server, "POST", "/sessions", raw=b"{" + b" " * 70000 + b"}")[0] == 413
    status, err = call(server, "POST", "/sessions", {"horizon": 0})
    assert status == 400 and "horizon" in err["error"]
    assert call(server, "GET", "/health")[1]["status"] == "ok"
