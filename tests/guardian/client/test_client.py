"""guardian.client against a real service on loopback: sessions over HTTP, the stream and asyncio give the same
records; a step whose answer is lost is sent again and applied once; errors carry the service's status."""
import asyncio
import socket
import struct
import threading
import time

import numpy as np
import pytest

from guardian.client import AsyncGuardianClient, GuardianClient, ServiceError, Session
from guardian.client.common import Answer, encode
from guardian.model.roads import Road, road_from_dict
from guardian.service import Limits, ServiceConfig, ServiceThread

ROAD = {"lanes": 3, "lane_width": 4.0}
VEHICLE = {"length": 5.0, "width": 2.0, "max_steering": 0.785, "max_acceleration": 6.0, "dt": 0.0667}
EGO = {"x": 0.0, "y": 4.0, "speed": 20.0}
TOKEN = "correct-horse-battery-staple"


@pytest.fixture(scope="module")
def service(library):
    with ServiceThread(library, ServiceConfig(port=0)) as svc:
        yield svc


@pytest.fixture
def client(service):
    with GuardianClient(service.url) as c:
        yield c


def two_car_steps(n: int, seed: int = 3) -> list[dict]:
    rng = np.random.default_rng(seed)
    return [{"state": rng.uniform([20, -0.5, -40, 15], [30, 2, 60, 30]), "input": rng.uniform([-3, -1.8], [3, 1.8])}
            for _ in range(n)]


def scene_steps(n: int) -> list[dict]:
    out = []
    for k in range(n):
        x = 20.0 * k * VEHICLE["dt"]
        out.append({"ego": {**EGO, "x": x},
                    "cars": [{"id": "a", "x": x + 15.0, "y": 4.0, "speed": 18.0, "length": 5, "width": 2},
                             {"id": "b", "x": x - 3.0, "y": 8.0, "speed": 21.0, "length": 5, "width": 2}],
                    "input": [1.5, 0.05 * (-1) ** k]})
    return out


def async_records(url: str, create, steps, stream: bool) -> tuple[list, dict]:
    """The records of ``steps`` on a new session of an AsyncGuardianClient, over HTTP or the stream."""
    async def run():
        async with AsyncGuardianClient(url) as client, await create(client) as session:
            if stream:
                async with session.stream() as s:
                    records = [await s.step(**body) for body in steps]
            else:
                records = [await session.step(**body) for body in steps]
            return records, await session.summary()
    return asyncio.run(run())


def test_two_car_sessions_give_the_same_records_over_http_the_stream_and_asyncio(client, service):
    steps = two_car_steps(12)
    with client.create_session(horizon=4) as over_http, client.create_session(horizon=4) as over_ws:
        assert over_http.kind == "two_car" and over_http.info["horizon"] == 4 and over_http.next_seq == 0
        expected = [over_http.step(**body) for body in steps]
        assert [r["t"] for r in expected] == list(range(12)) and over_http.next_seq == 12
        with over_ws.stream() as stream:
            got = [stream.step(**body) for body in steps[:6]]
            with pytest.raises(ServiceError) as refused:  # one writer: HTTP steps wait for the stream to close
                over_ws.step(**steps[6])
            assert refused.value.status == 409 and "stream" in refused.value.message
            got += [stream.step(**body) for body in steps[6:11]]
        got.append(over_ws.step(**steps[11]))  # the seq goes on over HTTP after the stream
        assert got == expected
        assert over_ws.summary()["steps"] == 12 and over_ws.summary()["last"] == expected[-1]
    for stream in (False, True):
        records, summary = async_records(service.url, lambda c: c.create_session(horizon=4), steps, stream)
        assert records == expected and summary["steps"] == 12


def test_scene_sessions_give_the_same_records_over_http_the_stream_and_asyncio(client, service):
    steps = scene_steps(10)
    with client.create_scene_session(ROAD, VEHICLE) as over_http, \
            client.create_scene_session(Road(3, 4.0), VEHICLE, {"h_min": 2.0}) as over_ws:
        assert over_http.kind == over_ws.kind == "scene"
        expected = [over_http.step(**body) for body in steps]
        assert [r["t"] for r in expected] == list(range(10)) and expected[0]["model"]["vehicle"]["length"] == 5.0
        with over_ws.stream() as stream:
            assert [stream.step(**body) for body in steps] == expected
        assert over_ws.summary()["steps"] == 10
        answer = over_http.lane_change(EGO, steps[0]["cars"], to=0)
        assert set(answer) == {"allowed", "reason"} and isinstance(answer["allowed"], bool)
        blocked = over_http.lane_change(EGO, [{"id": "c", "x": 0.0, "y": 8.0, "speed": 20.0, "length": 5, "width": 2}],
                                        to=2)
        assert blocked["allowed"] is False and blocked["reason"]
    for stream in (False, True):
        records, summary = async_records(service.url, lambda c: c.create_scene_session(ROAD, VEHICLE), steps, stream)
        assert records == expected and summary["steps"] == 10 and summary["kind"] == "scene"
    road_map = road_from_dict({"lanes": 3, "lane_width": 4.0, "spans": [[[None, None]], [[None, None]], [[None, 400.0]]],
                               "ends": [[2, 400.0]]})
    with client.create_scene_session(road_map, VEHICLE) as on_map:
        assert on_map.step(**steps[0])["t"] == 0


# ---- lost answers -------------------------------------------------------------------------------------

class CuttingProxy:
    """A TCP proxy in front of the service that, once ``cut(mode)``, swallows the next answer and ends the client's
    connection: ``close`` (FIN), ``reset`` (RST) or ``stall`` (held past the client's timeout, then closed). The
    request reached the service whole, so it was applied: only its answer is lost."""

    STALL = 1.0

    def __init__(self, address):
        self.upstream, self.lock, self.cuts, self.mode = address, threading.Lock(), 0, None
        self.accepted = 0  # connections the clients opened
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.listener.getsockname()[1]}"
        threading.Thread(target=self._accept, daemon=True).start()

    def cut(self, mode: str, times: int = 1) -> None:
        with self.lock:
            self.mode, self.cuts = mode, times

    def close(self) -> None:
        self.listener.close()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            self.accepted += 1
            pair = (client, socket.create_connection(self.upstream))
            for src, dst, answers in ((pair[0], pair[1], False), (pair[1], pair[0], True)):
                threading.Thread(target=self._pipe, args=(src, dst, answers, pair), daemon=True).start()

    def _take(self) -> str | None:
        with self.lock:
            if self.cuts:
                self.cuts -= 1
                return self.mode
        return None

    def _pipe(self, src, dst, answers: bool, pair) -> None:
        mode = None
        try:
            while data := src.recv(65536):
                mode = self._take() if answers else None
                if mode is not None:
                    break
                dst.sendall(data)
        except OSError:
            pass
        if mode == "stall":
            time.sleep(self.STALL)
        if mode == "reset":
            pair[0].setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        for s in pair:
            try:
                s.shutdown(socket.SHUT_RD if mode == "reset" else socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()


@pytest.fixture
def proxy(service):
    p = CuttingProxy(service.address)
    yield p
    p.close()


@pytest.mark.parametrize("mode", ["close", "reset", "stall"])
def test_a_step_whose_answer_is_lost_is_sent_again_and_applied_once(client, proxy, mode):
    steps = two_car_steps(3, seed=5)
    with client.create_session() as reference:
        expected = [reference.step(**body) for body in steps]
    with GuardianClient(proxy.url, timeout=0.5) as cut:
        session = cut.create_session()
        got = [session.step(**steps[0])]
        proxy.cut(mode)
        got.append(session.step(**steps[1]))  # applied, its answer lost: sent again, answered from the store
        got.append(session.step(**steps[2]))
        summary = session.summary()
    assert got == expected and session.next_seq == 3
    assert summary["steps"] == 3 and summary["last"] == expected[2]
    assert proxy.accepted == 2  # the lost answer's connection, and the one its retry opened


def test_the_async_client_sends_a_lost_step_again_and_it_is_applied_once(proxy):
    steps = scene_steps(3)

    async def run():
        async with AsyncGuardianClient(proxy.url, timeout=2.0) as client:
            session = await client.create_scene_session(ROAD, VEHICLE)
            records = [await session.step(**steps[0])]
            proxy.cut("close")
            records += [await session.step(**steps[1]), await session.step(**steps[2])]
            return records, await session.summary()

    records, summary = asyncio.run(run())
    assert [r["t"] for r in records] == [0, 1, 2] and summary["steps"] == 3 and summary["last"] == records[2]
    assert proxy.accepted == 2


def test_without_retries_the_same_step_sent_again_is_applied_once(proxy):
    body = two_car_steps(1)[0]
    with GuardianClient(proxy.url, retries=0) as client:
        session = client.create_session()
        proxy.cut("close")
        with pytest.raises(ConnectionError, match="no answer after 1 attempt"):
            session.step(**body)
        assert session.next_seq == 0  # not known to be applied: the caller sends it again
        assert session.step(**body)["t"] == 0 and session.summary()["steps"] == 1


def test_a_session_creation_whose_answer_is_lost_is_not_sent_again(client, proxy):
    created = client.health()["created"]
    with GuardianClient(proxy.url) as cut:
        proxy.cut("close")
        with pytest.raises(ConnectionError, match="not idempotent.*may have been created"):
            cut.create_session()
        assert client.health()["created"] == created + 1  # one session made, none more
        assert cut.create_session().next_seq == 0


def test_a_409_after_a_retry_for_the_next_step_means_the_first_attempt_was_applied(client):
    session = Session(client, "n0.0.x.0123456789abcdef", "secret", next_seq=7)
    conflict = encode({"error": "step 7 was already applied", "expected_seq": 8})
    with pytest.raises(ServiceError) as first:
        session.step_result(7, Answer(409, {}, conflict, retried=0))
    assert first.value.status == 409 and "applied" not in first.value.extra and session.next_seq == 7
    with pytest.raises(ServiceError) as after_retry:
        session.step_result(7, Answer(409, {}, conflict, retried=1))
    assert after_retry.value.extra["applied"] is True and after_retry.value.extra["expected_seq"] == 8
    assert session.next_seq == 8


# ---- errors -------------------------------------------------------------------------------------------

def test_errors_carry_the_status_and_the_message(client, service):
    assert client.health()["status"] == "ok" and client.ready()["ready"] is True
    with pytest.raises(ServiceError) as refused:
        client.create_scene_session(ROAD, {**VEHICLE, "model": "unicycle"})
    assert refused.value.status == 422 and "not supervised" in refused.value.message
    with pytest.raises(ServiceError) as bad:
        client.create_session(horizon=0)
    assert bad.value.status == 422 and "horizon" in bad.value.message
    session = client.create_session()
    with pytest.raises(ServiceError) as bad_step:
        session.step(state=[25.0, 0.0], input=[0.0, 0.0])
    assert bad_step.value.status == 422 and session.next_seq == 0
    with pytest.raises(ValueError, match="not JSON"):
        session.step(state=[float("nan"), 0, 40, 20], input=[0, 0])
    with pytest.raises(TypeError, match="seq"):
        session.step(seq=3, state=[25, 0, 40, 20], input=[0, 0])
    with pytest.raises(ServiceError) as wrong_secret:
        Session(client, session.id, "not-the-secret").summary()
    assert wrong_secret.value.status == 403
    with pytest.raises(ServiceError) as no_stream:
        Session(client, session.id, "not-the-secret").stream()
    assert no_stream.value.status == 403 and "secret" in no_stream.value.message
    with pytest.raises(ServiceError) as two_car:
        session.lane_change(EGO, [], to=0)
    assert two_car.value.status == 409
    assert session.close() == {"closed": session.id}
    for gone in (session, Session(client, "nope", "x")):
        with pytest.raises(ServiceError) as unknown:
            gone.step(state=[25, 0, 40, 20], input=[0, 0])
        assert unknown.value.status == 404 and "unknown session" in unknown.value.message
    with Session(client, "nope", "x").stream() as stream, pytest.raises(ServiceError) as unknown:
        stream.step(state=[25, 0, 40, 20], input=[0, 0])
    assert unknown.value.status == 404
    with pytest.raises(ServiceError) as misdirected:
        Session(client, "n9.0.1.0123456789abcdef", "x").step(state=[25, 0, 40, 20], input=[0, 0])
    assert misdirected.value.status == 421 and misdirected.value.extra["node"] == "n9"


def test_a_stream_error_reply_raises_and_the_stream_goes_on(client):
    steps = two_car_steps(2)
    with client.create_session() as session, session.stream() as stream:
        assert stream.step(**steps[0])["t"] == 0
        with pytest.raises(ServiceError) as bad:
            stream.step(state=[1.0, 2.0], input=[0.0, 0.0])
        assert bad.value.status == 422 and session.next_seq == 1
        assert stream.step(**steps[1])["t"] == 1


def test_a_wrong_token_is_401_and_the_right_one_opens_everything(library):
    with ServiceThread(library, ServiceConfig(port=0, token=TOKEN), warm=False) as svc:
        for token in (None, "wrong-token-of-some-length"):
            with GuardianClient(svc.url, token=token) as client:
                for _ in range(2):  # 401 closes the connection: the client opens another
                    with pytest.raises(ServiceError) as denied:
                        client.health()
                    assert denied.value.status == 401 and "token" in denied.value.message

            async def denied_async(token=token):
                async with AsyncGuardianClient(svc.url, token=token) as client:
                    for _ in range(2):
                        with pytest.raises(ServiceError) as denied:
                            await client.create_session()
                        assert denied.value.status == 401
            asyncio.run(denied_async())
        with GuardianClient(svc.url, token=TOKEN) as client, client.create_session() as session:
            with session.stream() as stream:
                assert stream.step(**two_car_steps(1)[0])["t"] == 0
            with pytest.raises(ServiceError) as denied:
                Session(GuardianClient(svc.url, token="wrong-token-of-some-length"), session.id,
                        session.secret).stream()
            assert denied.value.status == 401


def test_a_full_service_is_503_and_idle_connections_closed_by_the_server_are_reopened(library):
    config = ServiceConfig(port=0, max_sessions=1, session_ttl=30.0, limits=Limits(keepalive_timeout=0.1))
    with ServiceThread(library, config, warm=False) as svc, GuardianClient(svc.url, retries=0) as client:
        session = client.create_session()
        time.sleep(1.0)  # the server closes the idle connection: the client sees it and opens another (retries=0)
        assert session.step(**two_car_steps(1)[0])["t"] == 0
        time.sleep(1.0)  # so does POST /sessions, which is never sent twice
        with pytest.raises(ServiceError) as full:
            client.create_session()
        assert full.value.status == 503 and full.value.extra["retry_after_s"] == 30.0
        session.close()
        assert client.create_session().kind == "two_car"


def test_the_async_reader_skips_interim_answers_and_honours_connection_close():
    """A scripted server: ``100 Continue`` then the answer with ``Connection: close``, then it closes; the next
    request opens a new connection."""
    connections = []

    async def run():
        async def answer(reader, writer):
            connections.append(1)
            await reader.readuntil(b"\r\n\r\n")
            body = b'{"status": "ok"}'
            writer.write(b"HTTP/1.1 100 Continue\r\n\r\nHTTP/1.1 200 OK\r\nContent-Type: application/json\r\n"
                         b"Connection: close\r\nContent-Length: %d\r\n\r\n%s" % (len(body), body))
            await writer.drain()
            await asyncio.sleep(0.2)  # the client must not wait for the close to read the answer
            writer.close()

        server = await asyncio.start_server(answer, "127.0.0.1", 0)
        url = f"http://127.0.0.1:{server.sockets[0].getsockname()[1]}"
        async with server, AsyncGuardianClient(url, retries=0, timeout=1.0) as client:
            assert await client.health() == {"status": "ok"}
            assert await client.health() == {"status": "ok"}

    asyncio.run(run())
    assert len(connections) == 2
