"""``guardian serve --workers N``: sessions pinned to a worker, connections routed to it.

The row: "serve with two processes on one port: 145 of 300 steps answer 404, 21 of 50 streams close
4404". Here every request goes out on a fresh connection (as curl or a retrying client does), so the
kernel hands it to either worker and the routing has to work for every one.
"""
import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time

import pytest
from service_client import Raw, call, create, secret_header, step
from websockets.sync.client import connect as ws_connect

ADMIN = "an-admin-token-of-some-length"
GOOD_STATE, GOOD_INPUT = [25.0, 0.0, 40.0, 20.0], [0.5, 0.0]


def serve(cache_dir, *args):
    proc = subprocess.Popen([sys.executable, "-m", "guardian.cli", "serve", "--cache-dir", str(cache_dir), "--json",
                             "--port", "0", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = []
    while not lines or lines[-1] != "}":
        line = proc.stdout.readline()
        if not line:
            raise RuntimeError(proc.stderr.read())
        lines.append(line.rstrip("\n"))
    info = json.loads("\n".join(lines))
    host, port = info["url"].removeprefix("http://").split(":")
    address = (host, int(port))
    deadline = time.monotonic() + 30
    while call(address, "GET", "/ready")[0] != 200:
        assert time.monotonic() < deadline, "never ready"
        time.sleep(0.05)
    return proc, address, info


def children(pid: int) -> list:
    return [int(p) for p in open(f"/proc/{pid}/task/{pid}/children").read().split()]


@pytest.fixture(scope="module")
def two(cache_dir):
    proc, address, info = serve(cache_dir, "--workers", "2", "--admin-token", ADMIN)
    yield proc, address, info
    proc.terminate()
    proc.communicate(timeout=30)


def worker_of(sid: str) -> int:
    return int(sid.split(".")[1])


def test_every_step_on_a_fresh_connection_reaches_its_session(two):
    proc, address, info = two
    assert info["workers"] == 2 and len(children(proc.pid)) == 2
    sessions = [create(address) for _ in range(30)]
    assert {worker_of(s) for s, _ in sessions} == {0, 1}
    counts = [sum(worker_of(s) == w for s, _ in sessions) for w in (0, 1)]
    assert abs(counts[0] - counts[1]) <= 2, counts  # new sessions go to the worker with the fewest
    statuses = []
    for k in range(10):
        for sid, secret in sessions:  # 300 steps, each on its own connection
            status, _, rec = call(address, "POST", f"/sessions/{sid}/step", step(k, GOOD_STATE, GOOD_INPUT),
                                  secret_header(secret))
            statuses.append(status)
            assert status != 200 or rec["t"] == k
    assert statuses.count(200) == 300
    for sid, secret in sessions:
        assert call(address, "GET", f"/sessions/{sid}", None, secret_header(secret))[2]["steps"] == 10


def test_new_sessions_whose_requests_arrive_together_are_spread_over_the_workers():
    """Ten ``POST /sessions`` lines reach worker 0 before any of their sessions exists (a session is created
    when its request's task runs): the ones kept on worker 0 count as on their way there, like the ones sent
    to worker 1, so the two get five each (not counting them kept all ten on worker 0)."""
    from types import SimpleNamespace

    import numpy as np

    from guardian.service.protocol import GuardianHttpProtocol
    from guardian.service.workers import FIELDS, Cluster, Router

    stats, placed, arrived = np.zeros((2, len(FIELDS)), np.int64), np.zeros((2, 2), np.int64), np.zeros((2, 2), np.int64)
    stats[:, 0] = 1  # both workers alive, no session yet
    router = Router.__new__(Router)
    router.node, router.worker, router.workers = "n0", 0, 2
    router.cluster = Cluster(stats, placed, arrived, 0, router)
    router.send_connection = lambda worker, fd, data, placement=False: placed.__setitem__((0, worker),
                                                                                          placed[0, worker] + 1) or True
    class Connection(SimpleNamespace):
        __hash__ = object.__hash__

    kept = 0
    for _ in range(10):
        connection = Connection(
            pending=bytearray(b"POST /sessions HTTP/1.1\r\n"), placed_by=None, limits=None, handoff_tries=0,
            service=SimpleNamespace(router=router, handed_off=0), connections=set(), refused=False,
            transport=SimpleNamespace(get_write_buffer_size=lambda: 0, abort=lambda: None,
                                      get_extra_info=lambda name: SimpleNamespace(fileno=lambda: -1)),
            _stop_read_timer=lambda: None)
        kept += not GuardianHttpProtocol._handed_off(connection)
    assert kept == 5 and list(placed.sum(axis=0)) == [5, 5], placed


def test_one_connection_may_visit_sessions_of_every_worker(two):
    _, address, _ = two
    sessions = [create(address) for _ in range(8)]
    raw = Raw(address)  # keep-alive: the connection moves to each session's worker in turn, between requests
    for k in range(3):
        for sid, secret in sessions:
            status, _, rec = raw.request("POST", f"/sessions/{sid}/step", step(k, GOOD_STATE, GOOD_INPUT),
                                         secret_header(secret))
            assert status == 200 and rec["t"] == k
    pipelined = b"".join((f"GET /sessions/{sid} HTTP/1.1\r\nHost: localhost\r\nSession-Secret: {secret}\r\n\r\n")
                         .encode() for sid, secret in sessions)
    raw.send(pipelined)  # pipelined across workers: answered in order, another worker's session with 421
    answers = [raw.response() for _ in sessions]
    first = sessions[0][0].split(".")[1]
    for (sid, _), (status, _, body) in zip(sessions, answers):
        if sid.split(".")[1] == first:
            assert status == 200 and body["session"] == sid
        else:
            assert status == 421 and body["worker"] == int(sid.split(".")[1])
    raw.close()


def test_fifty_streams_all_reach_their_sessions(two):
    _, address, _ = two
    sessions = [create(address) for _ in range(50)]
    errors = []

    def stream(sid, secret):
        try:
            with ws_connect(f"ws://{address[0]}:{address[1]}/sessions/{sid}/stream",
                            additional_headers=secret_header(secret)) as ws:
                for k in range(5):
                    ws.send(json.dumps(step(k, GOOD_STATE, GOOD_INPUT)))
                    assert json.loads(ws.recv())["t"] == k
        except Exception as exc:  # noqa: BLE001 - counted
            errors.append(repr(exc))

    threads = [threading.Thread(target=stream, args=s) for s in sessions]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert errors == []


def test_health_ready_and_the_admin_listing_cover_every_worker(two):
    _, address, _ = two
    sessions = [create(address) for _ in range(6)]
    health = call(address, "GET", "/health")[2]
    assert health["workers"] == 2 and health["workers_alive"] == 2
    assert health["sessions"] >= 6 and health["created"] >= 6
    assert call(address, "GET", "/ready")[2] == {"ready": True, "workers_ready": 2, "workers": 2}
    listed = call(address, "GET", "/sessions", None, {"authorization": f"Bearer {ADMIN}"})[2]
    assert "workers_missing" not in listed
    ids = {s["session"] for s in listed["sessions"]}
    assert {sid for sid, _ in sessions} <= ids and {worker_of(i) for i in ids} == {0, 1}
    assert len(ids) == health["sessions"]


def test_a_dead_worker_is_started_again_and_its_sessions_say_410(cache_dir):
    proc, address, _ = serve(cache_dir, "--workers", "2")
    try:
        sessions = [create(address) for _ in range(10)]
        victim = children(proc.pid)[1]
        os.kill(victim, signal.SIGKILL)
        deadline = time.monotonic() + 30
        while victim in children(proc.pid) or len(children(proc.pid)) < 2 or call(address, "GET", "/ready")[0] != 200:
            assert time.monotonic() < deadline, "the worker was not started again"
            time.sleep(0.1)
        lost = {sid for sid, _ in sessions if worker_of(sid) == 1}
        assert lost and len(lost) < len(sessions)
        for sid, secret in sessions:
            status, _, body = call(address, "POST", f"/sessions/{sid}/step", step(0, GOOD_STATE, GOOD_INPUT),
                                   secret_header(secret))
            if sid in lost:
                assert status == 410 and body["restarted"] is True and "restarted" in body["error"]
            else:
                assert status == 200
        assert worker_of(create(address)[0]) in (0, 1)
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=30)
    assert "worker 1" in err and "starting it again" in err


def test_sigterm_with_workers_answers_in_flight_then_exits(cache_dir):
    proc, address, _ = serve(cache_dir, "--workers", "2")
    try:
        sid, secret = create(address)
        body = json.dumps(step(0, GOOD_STATE, GOOD_INPUT)).encode()
        head = (f"POST /sessions/{sid}/step HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
                f"Session-Secret: {secret}\r\nContent-Length: {len(body)}\r\n\r\n").encode()
        raw = Raw(address).send(head + body[:10])
        time.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        time.sleep(0.5)
        raw.send(body[10:])
        status, headers, record = raw.response()
        assert status == 200 and record["t"] == 0 and headers["connection"] == "close"
        assert proc.wait(timeout=30) == 0
    finally:
        proc.kill()
        proc.communicate()


# ---- several hosts behind a load balancer -------------------------------------------------------------

class PrefixRouter:
    """A stand-in for the load balancer of docs/service.md (nginx ``map $uri``): a request whose path
    names a session goes to the node in the id's first field; anything else round-robin. One request
    per upstream connection, like a proxy without keep-alive."""

    SESSION = re.compile(rb"^[A-Z]+ /sessions/([a-z0-9][a-z0-9-]*)\.")

    def __init__(self, nodes: dict):
        self.nodes, self.turn = nodes, 0
        self.loop = asyncio.new_event_loop()
        self.server = self.loop.run_until_complete(asyncio.start_server(self.handle, "127.0.0.1", 0))
        self.address = self.server.sockets[0].getsockname()[:2]
        threading.Thread(target=self.loop.run_forever, daemon=True).start()

    async def handle(self, reader, writer):
        try:
            while True:
                head = await reader.readuntil(b"\r\n\r\n")
                length = re.search(rb"(?i)content-length: *([0-9]+)", head)
                body = await reader.readexactly(int(length.group(1))) if length else b""
                m = self.SESSION.match(head)
                if m and m.group(1).decode() in self.nodes:
                    node = m.group(1).decode()
                else:
                    node = sorted(self.nodes)[self.turn % len(self.nodes)]
                    self.turn += 1
                up_r, up_w = await asyncio.open_connection(*self.nodes[node])
                up_w.write(head + body)
                answer = await up_r.readuntil(b"\r\n\r\n")
                n = re.search(rb"(?i)content-length: *([0-9]+)", answer)
                answer += await up_r.readexactly(int(n.group(1))) if n else b""
                up_w.close()
                writer.write(answer)
        except (asyncio.IncompleteReadError, ConnectionError):
            writer.close()

    def close(self):
        self.loop.call_soon_threadsafe(self.server.close)


def test_two_nodes_behind_a_prefix_routing_balancer(cache_dir):
    (pa, aa, _), (pb, ab, _) = serve(cache_dir, "--node", "alpha"), serve(cache_dir, "--node", "beta", "--workers", "2")
    router = PrefixRouter({"alpha": aa, "beta": ab})
    try:
        sessions = [create(router.address) for _ in range(8)]
        assert {sid.split(".")[0] for sid, _ in sessions} == {"alpha", "beta"}
        raw = Raw(router.address)
        for k in range(5):
            for sid, secret in sessions:
                status, _, rec = raw.request("POST", f"/sessions/{sid}/step", step(k, GOOD_STATE, GOOD_INPUT),
                                             secret_header(secret))
                assert status == 200 and rec["t"] == k
        raw.close()
        # a balancer that sends a session's request to the wrong node is told where it lives
        sid, secret = next(s for s in sessions if s[0].startswith("alpha."))
        status, _, err = call(ab, "POST", f"/sessions/{sid}/step", step(5, GOOD_STATE, GOOD_INPUT),
                              secret_header(secret))
        assert status == 421 and err["node"] == "alpha"
    finally:
        router.close()
        for p in (pa, pb):
            p.terminate()
            p.communicate(timeout=30)


def test_a_worker_that_takes_no_connections_gets_503_not_a_wrong_404(library):
    """When another worker's inbox stays full, a request for its session is retried, then answered 503;
    it is never served by the wrong worker (which would say 404)."""
    from guardian.service import Limits, ServiceConfig, ServiceThread

    class FullInbox:
        node, worker, workers = "n0", 0, 2
        tries = 0

        def start(self, server):
            pass

        def stop(self):
            pass

        def place(self):
            return 0

        def keep_placement(self):
            return None

        def send_connection(self, worker, fd, data, placement=False):
            FullInbox.tries += 1
            return False

    svc = ServiceThread(library, ServiceConfig(port=0, limits=Limits(read_timeout=0.3)))
    svc.server.router = FullInbox()
    with svc:
        other = f"n0.1.{svc.store.ids.new().split('.')[2]}.0123456789abcdef"
        status, headers, err = call(svc.address, "POST", f"/sessions/{other}/step", step(0, GOOD_STATE, GOOD_INPUT),
                                    secret_header("x"))
        assert status == 503 and "worker 1" in err["error"] and headers["retry-after"] == "1"
        assert FullInbox.tries > 10
        sid, secret = create(svc.address)  # this worker's own sessions are served as ever
        assert call(svc.address, "GET", f"/sessions/{sid}", None, secret_header(secret))[0] == 200
