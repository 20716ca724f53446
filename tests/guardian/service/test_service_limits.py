"""Defects found by trying the service with stock tools, each kept fixed: the JSON-cost check is linear in the
body, any token byte is answered 401, a port out of range is refused in one line."""
import subprocess
import sys

import pytest
from service_client import Raw, call

from guardian.service import Limits, ServiceConfig, ServiceThread
from guardian.service.limits import json_cost_error, without_strings

TOKEN = "a-token-of-some-length-0123456789"
ADMIN = "an-admin-token-of-some-length-987"


class Counted(bytes):
    """Bytes that count what ``without_strings`` does to them: characters looked at by ``find`` and by index."""

    looked = 0

    def find(self, sub, start=0, *rest):
        found = bytes.find(self, sub, start, *rest)
        Counted.looked += (found if found >= 0 else len(self)) - start + 1
        return found

    def __getitem__(self, i):
        Counted.looked += 1
        return bytes.__getitem__(self, i)


EVIL = [b'"' + b'\\"' * 32_700,                         # a string of escaped quotes, never closed (issue 42: 19.5 s)
        b'["' + b'\\\\' * 16_000 + b'\\"' * 16_000 + b'"]',  # backslash runs before quotes
        b'"' * 65_000,                                   # empty strings back to back
        b'{"a": "' + b'\\' * 65_000]                     # one backslash run, unterminated


@pytest.mark.parametrize("body", EVIL, ids=["escaped-quotes", "backslash-runs", "quotes", "backslashes"])
def test_blanking_strings_looks_at_each_byte_a_bounded_number_of_times(body):
    Counted.looked = 0
    without_strings(Counted(body))
    assert Counted.looked <= 3 * len(body) + 10


def test_an_evil_body_is_answered_and_the_worker_keeps_serving(library):
    with ServiceThread(library, ServiceConfig(port=0)) as svc:
        for body in EVIL:
            raw = Raw(svc.address, timeout=10.0)  # the quadratic check held the worker for 57 s
            status, _, answer = raw.request("POST", "/sessions", body)
            assert status in (400, 422) and "error" in answer  # not JSON, or not a session's settings
            raw.close()
        assert call(svc.address, "GET", "/health")[0] == 200


def test_the_cost_check_still_refuses_depth_long_numbers_and_nan():
    limits = Limits()
    assert "nested 33 deep" in json_cost_error(b"[" * 33 + b"]" * 33, limits)
    assert json_cost_error(b'["' + b"[" * 100 + b'"]', limits) is None  # brackets inside a string do not count
    assert "41 characters" in json_cost_error(b"[" + b"1" * 41 + b"]", limits)
    assert "NaN" in json_cost_error(b"[NaN]", limits)
    assert json_cost_error(b'["NaN", "\\"[[["]', limits) is None


@pytest.mark.parametrize("given", [b"\xe9", b"\xff\xfe", b"caf\xc3\xa9", b"\x80" * 40, TOKEN.encode() + b"\xe9"])
def test_any_token_byte_is_answered_401_and_the_admin_listing_403(library, given):
    with ServiceThread(library, ServiceConfig(port=0, token=TOKEN, admin_token=ADMIN)) as svc:
        raw = Raw(svc.address)
        raw.send(b"GET /health HTTP/1.1\r\nHost: localhost\r\nAuthorization: Bearer " + given + b"\r\n\r\n")
        status, _, answer = raw.response()
        assert status == 401 and "token" in answer["error"]
        raw.close()
    with ServiceThread(library, ServiceConfig(port=0, admin_token=ADMIN)) as svc:
        raw = Raw(svc.address)
        raw.send(b"GET /sessions HTTP/1.1\r\nHost: localhost\r\nAuthorization: Bearer " + given + b"\r\n\r\n")
        status, _, answer = raw.response()
        assert status == 403 and "admin token" in answer["error"]
        raw.close()


@pytest.mark.parametrize("port", ["99999", "-1", "http", "65536"])
def test_a_port_out_of_range_is_refused_in_one_line(port):
    done = subprocess.run([sys.executable, "-m", "guardian.cli", "serve", "--port", port], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2
    last = done.stderr.strip().splitlines()[-1]
    assert "--port must be a TCP port, 0..65535" in last and "Traceback" not in done.stderr


def test_an_id_naming_a_worker_the_node_does_not_have_is_unknown_not_misrouted():
    from guardian.service.sessions import SessionIds, base36

    ids = SessionIds.starting_now("n0", 0, workers=2)
    here = f"n0.%d.{base36(ids.boot)}.0123456789abcdef"
    assert ids.unknown(here % 1).status == 421   # the other worker's: pipelined behind another request
    assert ids.unknown(here % 2).status == 404   # no worker 2 on this node
    assert ids.unknown(f"n0.5.{base36(ids.service_boot - 1)}.0123456789abcdef").status == 410  # a previous run's
