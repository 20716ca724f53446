"""The service under hostile clients: fuzzed bodies and framing, a soak with aborts, 200 clients at once.

Loopback only, bounded in count and time. Each test states what it would catch: a 5xx, a dropped
connection, a request executed from a partial body, a leaked thread, socket or session, memory
that grows, or sessions that disturb one another.
"""
import json
import os
import random
import socket
import threading
import time
from collections import Counter, defaultdict

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from service_client import Raw, call, create, secret_header, step
from websockets.sync.client import connect as ws_connect

from guardian.service import Limits, ServiceConfig, ServiceThread

pytestmark = pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")


@pytest.fixture(scope="module")
def service(library):
    limits = Limits(read_timeout=0.3, keepalive_timeout=2.0)
    with ServiceThread(library, ServiceConfig(port=0, limits=limits, max_sessions=5000)) as svc:
        yield svc


FIGURES = defaultdict(Counter)  # test -> answers by status ("closed": none), printed at the end (-s)


@pytest.fixture(scope="module", autouse=True)
def hostile_figures():
    yield
    print("\nhostile clients, answers by status:")
    for test, counts in FIGURES.items():
        print(f"  {test}: {sum(counts.values())} cases: " + ", ".join(f"{k}: {n}" for k, n in sorted(counts.items(), key=str)))


def tally(test: str, answer) -> None:
    FIGURES[test][answer[0] if answer is not None else "closed"] += 1


def step_inputs(seed: int, n: int, first: int = 0) -> list:
    rng = np.random.default_rng(seed)
    return [step(first + k, [float(rng.uniform(18, 32)), float(rng.uniform(-0.8, 2.6)), float(rng.uniform(-60, 80)),
                             float(rng.uniform(10, 33))], [float(rng.uniform(-3, 3)), float(rng.uniform(-1.8, 1.8))])
            for k in range(n)]


def assert_answer_is_clean(answer) -> None:
    """A 4xx or 2xx in JSON, or a clean close; never a 5xx."""
    if answer is None:
        return
    status, headers, body = answer
    assert status < 500, body
    if body is not None:
        assert headers["content-type"] == "application/json" and isinstance(body, dict), body


# ---- fuzz: bodies --------------------------------------------------------------------------------

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(min_value=-10 ** 60, max_value=10 ** 60)
    | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=20),
    lambda children: st.lists(children, max_size=6) | st.dictionaries(
        st.sampled_from(["state", "input", "use_intention", "horizon", "priority", "x"]) | st.text(max_size=5),
        children, max_size=5),
    max_leaves=30)
bodies = (json_values.map(lambda v: json.dumps(v).encode())
          | st.binary(max_size=200)
          | st.builds(lambda s, u: json.dumps({"state": s, "input": u}).encode(),
                      st.lists(st.floats(allow_nan=False, allow_infinity=False) | st.integers(-10 ** 30, 10 ** 30),
                               min_size=3, max_size=5),
                      st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=1, max_size=3)))

FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)


@FUZZ
@given(body=bodies)
def test_fuzzed_step_bodies_get_a_json_answer_never_a_5xx(service, body):
    sid, secret = fuzz_session(service)
    answer = fuzz_request(service, "POST", f"/sessions/{sid}/step", body, secret_header(secret))
    tally("fuzzed step bodies", answer)
    assert answer is not None
    assert_answer_is_clean(answer)
    assert answer[0] in (200, 400, 409, 413, 422), answer  # 409: a valid body whose seq is not the next


@FUZZ
@given(body=bodies)
def test_fuzzed_session_bodies_get_a_json_answer_never_a_5xx(service, body):
    answer = fuzz_request(service, "POST", "/sessions", body)
    tally("fuzzed session bodies", answer)
    assert_answer_is_clean(answer)
    assert answer[0] in (201, 400, 413, 422), answer
    if answer[0] == 201:
        assert fuzz_request(service, "DELETE", f"/sessions/{answer[2]['session']}", None,
                            secret_header(answer[2]["secret"]))[0] == 200


_fuzz_state = {}


def fuzz_conn(service) -> Raw:
    """One keep-alive connection for all examples: a 4xx must leave it usable."""
    if "conn" not in _fuzz_state:
        _fuzz_state["conn"] = Raw(service.address)
    return _fuzz_state["conn"]


def fuzz_request(service, method, path, body=None, headers=None):
    """On the shared connection; a new one only after the server said ``Connection: close``."""
    answer = fuzz_conn(service).request(method, path, body, headers)
    if answer is not None and answer[1].get("connection") == "close":
        _fuzz_state.pop("conn").close()
    return answer


def fuzz_session(service) -> tuple[str, str]:
    if "sid" not in _fuzz_state:
        created = fuzz_request(service, "POST", "/sessions", {})[2]
        _fuzz_state["sid"] = (created["session"], created["secret"])
    return _fuzz_state["sid"]


# ---- fuzz: framing -------------------------------------------------------------------------------

def _framed(body: bytes, mode: str, length, chunk_sizes) -> bytes:
    head = b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
    if mode == "length":
        length = length if isinstance(length, bytes) else str(length).encode()
        return head + b"Content-Length: " + length + b"\r\n\r\n" + body
    chunks, pos = b"", 0
    for size in chunk_sizes:  # declared sizes may disagree with what follows
        piece = body[pos:pos + abs(size)]
        pos += abs(size)
        chunks += b"%x\r\n%s\r\n" % (size if size >= 0 else len(piece) + 3, piece)
    return head + b"Transfer-Encoding: chunked\r\n\r\n" + chunks + b"0\r\n\r\n"


framings = st.builds(
    _framed,
    st.sampled_from([b'{"horizon": 3}', b"{}", b'{"use_intention": false}', b"[" * 50]),
    st.sampled_from(["length", "chunked"]),
    st.one_of(st.integers(-10 ** 12, 10 ** 12), st.sampled_from([b"-1", b"1e3", b"0x10", b"", b"  7", b"1,2",
                                                                 b"99999999999999999999999"])),
    st.lists(st.integers(-2, 20), max_size=4))


@settings(max_examples=120, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(request=framings, cut=st.integers(0, 200), half_close=st.booleans())
def test_fuzzed_framing_is_answered_or_closed_cleanly_and_partial_requests_never_run(service, request, cut, half_close):
    """With a half-close after the bytes (``nc -N``) a whole request is answered and a partial one closed at once;
    without, a partial one gets a 408 after the read timeout."""
    before = live_sessions(service)
    request = request[:len(request) - cut] if cut < len(request) else request
    raw = Raw(service.address, timeout=5.0).send(request)
    if half_close:
        raw.half_close()
    try:
        answer = raw.response()
    except ConnectionResetError:
        pytest.fail("the connection was reset instead of answered or closed")
    tally("fuzzed framing", answer)
    assert_answer_is_clean(answer)
    created = answer is not None and answer[0] == 201
    if created:
        call(service.address, "DELETE", f"/sessions/{answer[2]['session']}", None, secret_header(answer[2]["secret"]))
    raw.close()
    assert live_sessions(service) == before  # nothing created that was not answered


def live_sessions(service) -> int:
    return len(service.store.live)


# ---- many clients --------------------------------------------------------------------------------

def test_200_concurrent_clients_are_all_served(service):
    barrier = threading.Barrier(200)
    errors, done = [], []

    def client(i):
        try:
            barrier.wait(10)
            raw = Raw(service.address, timeout=30)
            sid, secret = create(raw)
            for body in step_inputs(i, 5):
                assert raw.request("POST", f"/sessions/{sid}/step", body, secret_header(secret))[0] == 200
            assert raw.request("DELETE", f"/sessions/{sid}", None, secret_header(secret))[0] == 200
            raw.close()
            done.append(i)
        except Exception as exc:  # noqa: BLE001 - every failure is counted
            errors.append(repr(exc))

    threads = [threading.Thread(target=client, args=(i,)) for i in range(200)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert errors == [] and len(done) == 200


def _fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


def test_soak_no_leaks_and_sessions_do_not_disturb_each_other(service):
    """Create, step, abandon, abort and delete at random from 32 clients, twice; then count what is left."""
    url = f"ws://{service.address[0]}:{service.address[1]}"
    reference = {}
    for seed in range(8):  # the records of each input sequence, stepped alone
        sid, secret = create(service.address)
        reference[seed] = [call(service.address, "POST", f"/sessions/{sid}/step", b, secret_header(secret))[2]
                           for b in step_inputs(seed, 12)]
        call(service.address, "DELETE", f"/sessions/{sid}", None, secret_header(secret))

    def client(k, rnd, left, mismatches, errors):
        try:
            for _ in range(12):
                action = rnd.choice(["replay", "abandon", "abort-body", "abort-head", "stream"])
                raw = Raw(service.address, timeout=30)
                sid, secret = create(raw)
                auth = secret_header(secret)
                if action == "replay":
                    seed = rnd.randrange(8)
                    got = [raw.request("POST", f"/sessions/{sid}/step", b, auth)[2] for b in step_inputs(seed, 12)]
                    if got != reference[seed]:
                        mismatches.append(seed)
                    assert raw.request("DELETE", f"/sessions/{sid}", None, auth)[0] == 200
                elif action == "abandon":
                    raw.request("POST", f"/sessions/{sid}/step", step_inputs(k, 1)[0], auth)
                    left.append((sid, secret))
                elif action == "abort-body":
                    raw.send(f"POST /sessions/{sid}/step HTTP/1.1\r\nHost: localhost\r\nSession-Secret: {secret}\r\n"
                             "Content-Type: application/json\r\nContent-Length: 90\r\n\r\n"
                             '{"seq": 0, "state": [25'.encode())
                    left.append((sid, secret))
                elif action == "abort-head":
                    raw.send(b"POST /sessions HTTP/1.1\r\nHost: localhost\r\nContent-Len")
                    left.append((sid, secret))
                else:
                    with ws_connect(f"{url}/sessions/{sid}/stream", additional_headers=auth) as ws:
                        for b in step_inputs(k, rnd.randrange(1, 6)):
                            ws.send(json.dumps(b))
                            assert "applied" in json.loads(ws.recv())
                    left.append((sid, secret))
                if rnd.random() < 0.5:
                    raw.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
                raw.close()  # with SO_LINGER 0: a reset, not a close
        except Exception as exc:  # noqa: BLE001
            errors.append(repr(exc))

    def round_(seed):
        left, mismatches, errors = [], [], []
        threads = [threading.Thread(target=client, args=(k, random.Random(seed * 100 + k), left, mismatches, errors))
                   for k in range(32)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
        return left, mismatches, errors

    def settle():
        deadline = time.monotonic() + 10
        while service.server.connections and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not service.server.connections, "connections left open"
        assert not service.server.uvicorn.server_state.tasks, "requests left running"

    base_live = len(service.store.live)
    settle()
    threads0, fds0 = threading.active_count(), _fds()
    for seed in (1, 2):
        left, mismatches, errors = round_(seed)
        assert errors == [] and mismatches == []
        settle()
        assert len(service.store.live) == base_live + len(left)  # exactly the abandoned ones
        for sid, secret in left:
            assert call(service.address, "DELETE", f"/sessions/{sid}", None, secret_header(secret))[0] == 200
        settle()
        assert threading.active_count() == threads0
        assert _fds() <= fds0 + 2
        if seed == 1:
            rss1 = _rss_mb()
    assert _rss_mb() - rss1 < 40, f"memory grew from {rss1:.0f} to {_rss_mb():.0f} MB over a second round"
