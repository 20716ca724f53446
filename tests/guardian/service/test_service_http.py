"""The running service's request framing against two parsers this project did not write: h11 and llhttp.

Each case's bytes go to a real service (one worker on loopback) on a fresh TCP connection, then a half-close
or not, and the service's first answer is classified (``http_reference.probe``): *accepted* (the application
answered it as a request: 201, 200, 404, 405, 415, a 400 about its JSON...) or *refused* (a framing refusal
of the HTTP layer, ``guardian.service.protocol``: 400 "invalid HTTP request", 408, 413, 414, 417, 431, 501,
505, or a close without an answer). The same bytes go to h11 (pure Python) and to llhttp (through httptools,
no leniency) for their reading of the first request.

Properties:

1. no request the service accepts is refused by both h11 and llhttp (no framing only we would read); the one
   allowance: a 4xx the application gives from a head both parsers read whole, before a body whose framing
   is bad or cut short (a 404, a missing ``Content-Type``: the body is never read, nothing runs), counted;
2. what the service answered to an accepted request is what the service's own application answers to the
   request as h11 or llhttp read it (method, target, header fields, body): a reference copy of the app, run
   in-process on each parser's reading, must give the same status and the same error text or created
   session (``POST /sessions`` echoes ``horizon``; chunks split inside the JSON's key and number, so a byte of
   framing read into the body makes it malformed JSON, a 400 instead of a 201);
3. nothing runs that is refused or closed unanswered, not even a whole request pipelined before the refused
   bytes (no session is created): its answer must come first, then the refusal;
4. every probe is answered or closed within 5 s (the read timeout is 0.25 s), and every answer is whole HTTP.

Inputs: a hand-written list of request-smuggling shapes (CL.TE, TE.CL, TE.TE obfuscations, obs-fold,
conflicting Content-Length, NUL/CR/LF in names, values and targets, bare LF and bare CR line endings in heads
and in chunked framing, chunk-size overflow, odd versions and targets, bodies on GET, Expect variants, huge
heads...), then seeded random mutations of valid requests (byte insert/delete/replace, line-ending swaps,
header duplication, chunk-line edits). The tallies are printed (``-s``) and put in any failure's message.
"""
from __future__ import annotations

import asyncio
import json
import random
import time
import urllib.parse
from collections import Counter

import h11
import httptools
import pytest
from http_reference import exchange, h11_first, llhttp_first, probe, statuses
from service_client import call

from guardian.service import Limits, ServiceConfig, ServiceThread
from guardian.service.app import ServiceApp
from guardian.service.sessions import SessionStore

LIMITS = Limits(read_timeout=0.25, keepalive_timeout=1.0)
H11_STRICT_CHUNKS = tuple(int(x) for x in h11.__version__.split(".")[:2]) >= (0, 16)


@pytest.fixture(scope="module")
def service(library):
    config = ServiceConfig(port=0, limits=LIMITS, max_sessions=100_000, session_ttl=2.0)
    with ServiceThread(library, config) as svc:
        yield svc


class ReferenceApp:
    """The service's application, in-process, given a request as a reference parser read it: the answer the
    service would give had its HTTP layer read the request that way. Answers are cached by request."""

    def __init__(self, library):
        self.store = SessionStore(library, ttl=60.0, max_sessions=1_000_000)
        self.app = ServiceApp(self.store, LIMITS)
        self.app.ready = True
        self.loop = asyncio.new_event_loop()
        self.cache = {}

    def answer(self, parsed):
        if parsed not in self.cache:
            self.cache[parsed] = self._answer(parsed)
        return self.cache[parsed]

    def _answer(self, parsed):
        try:  # the target as uvicorn makes it a path (httptools.parse_url, then percent-decoded)
            path = httptools.parse_url(parsed.target).path.decode("ascii")
            method = parsed.method.decode("ascii")
        except (httptools.HttpParserInvalidURLError, UnicodeDecodeError):
            return None  # a request the server cannot hand to an application at all
        if "%" in path:
            path = urllib.parse.unquote(path)
        scope = {"type": "http", "method": method, "http_version": parsed.version, "path": path,
                 "headers": [(n.lower(), v) for n, v in parsed.headers]}
        sent = []

        async def receive():  # a head alone: the request ends there (the app must answer without a body)
            if not parsed.whole:
                return {"type": "http.disconnect"}
            return {"type": "http.request", "body": parsed.body, "more_body": False}

        async def send(message):
            sent.append(message)

        self.loop.run_until_complete(self.app(scope, receive, send))
        self.store.live.clear()
        if not sent:
            return None
        body = sent[1]["body"] if len(sent) > 1 else b""
        try:
            body = json.loads(body) if body else None
        except ValueError:
            pass
        return signature(sent[0]["status"], body)

    def close(self):
        self.loop.close()


@pytest.fixture(scope="module")
def reference(library):
    ref = ReferenceApp(library)
    yield ref
    ref.close()


def signature(status, body) -> tuple:
    """What identifies an answer: its status, and its error text, or the created session's settings, or the
    health status (ids, secrets and counts differ between the service and the reference)."""
    if isinstance(body, dict):
        if status == 201:
            return status, body.get("kind"), body.get("horizon"), body.get("use_intention"), tuple(body.get("priority", ()))
        if "error" in body:
            return status, body["error"]
        if "status" in body:
            return status, body["status"]
    return (status,)


# ---- the cases -----------------------------------------------------------------------------------

CRLF = b"\r\n"
LINE = b"POST /sessions HTTP/1.1"
JSON_HEADERS = [b"Host: localhost", b"Content-Type: application/json"]
BODY = b'{"horizon":123}'                                          # 15 bytes; 201 with horizon 123
CHUNKED = b'5\r\n{"hor\r\n7\r\nizon":1\r\n3\r\n23}\r\n0\r\n\r\n'  # BODY in chunks split inside key and number
SMUGGLED = b"GET /health HTTP/1.1\r\nHost: localhost\r\n\r\n"      # a request hidden in a body, or after it


def post(headers=(), body=b"", line=LINE, eol=CRLF, base=JSON_HEADERS) -> bytes:
    return line + eol + eol.join([*base, *headers]) + eol + eol + body


def chunked(body: bytes, headers=(), **kw) -> bytes:
    return post([b"Transfer-Encoding: chunked", *headers], body, **kw)


def length(body: bytes = BODY, value: bytes | None = None, headers=(), **kw) -> bytes:
    return post([b"Content-Length: " + (value if value is not None else str(len(body)).encode()), *headers], body, **kw)


TE_VALUES = [b"chunked", b"Chunked", b"CHUNKED", b"cHuNkEd", b" chunked", b"chunked ", b"\tchunked", b"chunked\t",
             b"xchunked", b"chunkedx", b"chunk", b"chunked, identity", b"identity, chunked", b"gzip, chunked",
             b"chunked, gzip", b"chunked,chunked", b"chunked, chunked", b"identity", b"gzip", b"", b"\x0bchunked",
             b"chunked\x0b", b"\x0cchunked", b"\xa0chunked", b"chunked\x00", b"chu\x00nked", b'"chunked"',
             b"chunked;q=1", b"x,chunked", b",chunked", b"chunked,", b"chunked\r", b"\x00chunked",
             b"chunked \r\n", b"ch\runked", b"chunked, ,"]
TE_LINES = [b"Transfer-Encoding : chunked", b"Transfer-Encoding\t: chunked", b"Transfer_Encoding: chunked",
            b" Transfer-Encoding: chunked", b"\tTransfer-Encoding: chunked", b"Transfer-Encoding:\r\n chunked",
            b"Transfer-Encoding:\r\n\tchunked", b"X: y\nTransfer-Encoding: chunked", b"X: y\rTransfer-Encoding: chunked",
            b"Transfer-Encoding\x00: chunked", b"\x00Transfer-Encoding: chunked", b"Transfer\rEncoding: chunked",
            b"Transfer-Encoding:chunked", b"Transfer-Encoding: chunked\r\nTransfer-Encoding: x",
            b"Transfer-Encoding: x\r\nTransfer-Encoding: chunked", b"Transfer-Encoding: chunked\r\nTransfer-Encoding: chunked",
            b"Transfer-Encoding: identity\r\nTransfer-Encoding: chunked", b"Transfer-Encoding:\x0bchunked",
            b"Transfer-Encoding: chunked\n", b"Transfer-Encoding\n: chunked", b"Transfer-Encoding: \n chunked",
            b"TRANSFER-ENCODING: chunked", b"Transfer-Encoding:: chunked", b"Transfer-Encoding :chunked"]
CL_VALUES = [b"15", b"15, 15", b"15,15", b"15,16", b"16,15", b"+15", b"-15", b"0x0f", b"0xf", b"15.0", b"1_5", b"015",
             b"0015", b" 15", b"15 ", b"\t15", b"15\t", b"1 5", b"15\x00", b"\x0015", b"", b" ", b"99999999999999999999",
             b"18446744073709551616", b"18446744073709551631", b"4294967311", b"1e1", b"\xd9\xa1\xd9\xa5", b"15\r",
             b"15;", b"1\r\n 5", b"15\x0b", b"0", b"4", b"16", b"200"]
CL_LINES = [b"Content-Length : 15", b"Content-Length\t: 15", b"Content_Length: 15", b"Content-Length:\r\n 15",
            b" Content-Length: 15", b"Content-Length: 15\r\nContent-Length: 15", b"Content-Length: 15\r\nContent-Length: 16",
            b"Content-Length: 16\r\nContent-Length: 15", b"Content-Length: 15\r\nContent-Length: 0",
            b"Content-Length: 0\r\nContent-Length: 15", b"Content-Length\x00: 15", b"Content-Length: 15\nX: y",
            b"Content-Length: 15\rX: y", b"Content-Length:15", b"content-length: 15", b"Content-Length:\t15\t",
            b"Content-Length: 15\r\n\tX", b"X: y\r\n Content-Length: 15"]
CHUNK_BODIES = [  # each after "Transfer-Encoding: chunked"
    b"f\r\n" + BODY + b"\r\n0\r\n\r\n", CHUNKED, CHUNKED + SMUGGLED,
    b"5\r\nhell\r\n0\r\n\r\n",                    # the shape: data "hell\r", then a bare LF ending it
    b'f\r\n{"horizon":123\r\n0\r\n\r\n',          # the same on JSON: body '{"horizon":123\r' if read
    b'f\r\n{"horizon":123}\n0\r\n\r\n', b'f\r\n{"horizon":123}\r0\r\n\r\n', b'f\r\n{"horizon":123}0\r\n\r\n',
    b'f\r\n{"horizon":123}\r\r\n0\r\n\r\n', b'f\r\n{"horizon":123}\n\r\n0\r\n\r\n',
    b'f\n{"horizon":123}\r\n0\r\n\r\n', b'f\r{"horizon":123}\r\n0\r\n\r\n', b'f\r\r\n{"horizon":123}\r\n0\r\n\r\n',
    b'f\r\n{"horizon":123}\r\n0\n\n', b'f\r\n{"horizon":123}\r\n0\r\n\n', b'f\r\n{"horizon":123}\r\n0\n\r\n',
    b'f\r\n{"horizon":123}\r\n0\r\r\n\r\n', b'f\r\n{"horizon":123}\r\n0\r\n\r', b'f\r\n{"horizon":123}\r\n0\r\n',
    b'f\r\n{"horizon":123}\r\n0\r\nX: y\n\r\n', b'f\r\n{"horizon":123}\r\n0\r\nX: y\r\r\n',
    b'f\r\n{"horizon":123}\r\n0\r\nX: y\r\n\n', b'f\r\n{"horizon":123}\r\n0\r\nX: y\r\n\r\n',
    b'f\r\n{"horizon":123}\r\n0\r\nContent-Length: 99\r\n\r\n', b'f\r\n{"horizon":123}\r\n0\r\nX: y\r\n z\r\n\r\n',
    b'f\r\n{"horizon":123}\r\n0\r\nnocolon\r\n\r\n', b'f\r\n{"horizon":123}\r\n0\r\nTransfer-Encoding: chunked\r\n\r\n',
    b'2;\n{"\r\nd\r\nhorizon":123}\r\n0\r\n\r\n',   # the bare LF inside a chunk extension ("2;\nxx")
    b"2;\nxx\r\n0\r\n\r\n", b'2;a\n{"\r\nd\r\nhorizon":123}\r\n0\r\n\r\n',
    b'2;a=b\n{"\r\nd\r\nhorizon":123}\r\n0\r\n\r\n', b'2;a\r{"\r\nd\r\nhorizon":123}\r\n0\r\n\r\n',
    b'2;a=b\r\n{"\r\nd;c=d\r\nhorizon":123}\r\n0;e\r\n\r\n', b'2;a="x\r\ny"\r\n{"\r\nd\r\nhorizon":123}\r\n0\r\n\r\n',
    b'2;a="x\ny"\r\n{"\r\nd\r\nhorizon":123}\r\n0\r\n\r\n', b'2;a\x00\r\n{"\r\nd\r\nhorizon":123}\r\n0\r\n\r\n',
    b'2 ;a=b\r\n{"\r\nd\r\nhorizon":123}\r\n0\r\n\r\n', b'2\t;a\r\n{"\r\nd\r\nhorizon":123}\r\n0\r\n\r\n',
    b'2;' + b"a" * 5000 + b'\r\n{"\r\nd\r\nhorizon":123}\r\n0\r\n\r\n',
    b' f\r\n{"horizon":123}\r\n0\r\n\r\n', b'f \r\n{"horizon":123}\r\n0\r\n\r\n', b'f\t\r\n{"horizon":123}\r\n0\r\n\r\n',
    b'+f\r\n{"horizon":123}\r\n0\r\n\r\n', b'-f\r\n{"horizon":123}\r\n0\r\n\r\n', b'0xf\r\n{"horizon":123}\r\n0\r\n\r\n',
    b'0f\r\n{"horizon":123}\r\n0\r\n\r\n', b'00000000000000000000f\r\n{"horizon":123}\r\n0\r\n\r\n',
    b'F\r\n{"horizon":123}\r\n0\r\n\r\n', b'1_0\r\n{"horizon":123}\r\n0\r\n\r\n',
    b'1000000000000000f\r\n{"horizon":123}\r\n0\r\n\r\n', b'ffffffffffffffffff\r\n{"horizon":123}\r\n0\r\n\r\n',
    b'fffffffffffffffff\r\n{"horizon":123}\r\n0\r\n\r\n', b'-1\r\n{"horizon":123}\r\n0\r\n\r\n',
    b'e\r\n{"horizon":123}\r\n0\r\n\r\n', b'10\r\n{"horizon":123}\r\n0\r\n\r\n', b'f\r\n{"horizon":123}\r\n',
    b'f\r\n{"horizon":123}\r\n\r\n', b'f\r\n{"horizon":123}\r\n00\r\n\r\n', b'f\r\n{"horizon":123}\r\n0;x\r\n\r\n',
    b'f\r\n{"horizon":123}\r\n0 \r\n\r\n', b'5\r\nhello\r\n0\r\n\r\n', b'\r\nf\r\n{"horizon":123}\r\n0\r\n\r\n',
    b'f\x00\r\n{"horizon":123}\r\n0\r\n\r\n', b'\x00f\r\n{"horizon":123}\r\n0\r\n\r\n',
    b"".join(b"1\r\n%c\r\n" % c for c in BODY) + b"0\r\n\r\n",
]
VERSIONS = [b"HTTP/1.0", b"HTTP/0.9", b"HTTP/2.0", b"HTTP/1.2", b"HTTP/1.10", b"HTTP/01.1", b"HTTP/1.1 ", b"http/1.1",
            b"HTTP/1", b"HTTP/1.1x", b"HTTP/3.0", b"HTTP/9.9", b"HTTP /1.1", b"HTTP/1.1\x00", b"HTTPS/1.1"]
TARGETS = [b"http://localhost/sessions", b"https://evil.example/sessions", b"http://localhost:80/sessions?x=1",
           b"//sessions", b"*", b"sessions", b"/sessions#frag", b"/sessions?a=b", b"%2Fsessions", b"/%73essions",
           b"/sessions/../sessions", b"/sess\x00ions", b"/sessions\r", b"/ses sions", b"/sessions\x7f", b"/s\xc3\xa9",
           b"/sessions\t", b"/sessions?\x00", b"/" + b"a" * 9000, b"localhost:80"]


WS = b"GET /sessions/n0.0.x.0123456789abcdef/stream HTTP/1.1\r\nHost: localhost\r\nConnection: Upgrade\r\nUpgrade: websocket\r\n"
WS_KEY = b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
WEBSOCKET_SHAPES = [  # handshakes websockets refuses while parsing them (uvicorn once held these open for good)
    ("with a body", WS + WS_KEY + b"Content-Length: 15\r\n\r\n" + BODY),
    ("with a chunked body", WS + WS_KEY + b"Transfer-Encoding: chunked\r\n\r\n" + CHUNKED),
    ("with a header line over 8 KB", WS + WS_KEY + b"X: " + b"a" * 9000 + b"\r\n\r\n"),
    ("POST with a body", length(headers=[b"Connection: Upgrade", b"Upgrade: websocket"])),
    ("POST with a key and a body", length(headers=[b"Connection: Upgrade", b"Upgrade: websocket", WS_KEY[:-2]])),
    ("without a key", WS + b"\r\n"),
]


def hand_written_cases() -> list[tuple[str, bytes]]:
    cases = [("plain length", length()), ("plain chunked", chunked(CHUNKED)),
             ("length then smuggled", length(BODY + SMUGGLED))]
    for first in ("CL", "TE"):  # CL.TE and TE.CL: both framings announced, in either order
        for cl in (b"15", str(len(CHUNKED)).encode(), b"4", b"0", b"200"):
            hs = [b"Content-Length: " + cl, b"Transfer-Encoding: chunked"]
            hs = hs if first == "CL" else hs[::-1]
            cases.append((f"{first} first, CL {cl.decode()}, chunked body + smuggled", post(hs, CHUNKED + SMUGGLED)))
            cases.append((f"{first} first, CL {cl.decode()}, plain body + smuggled", post(hs, BODY + SMUGGLED)))
    for te in TE_VALUES:  # TE.TE: the value obfuscated
        cases.append((f"TE {te!r}", post([b"Transfer-Encoding: " + te], CHUNKED)))
        cases.append((f"TE {te!r} + CL 15", post([b"Transfer-Encoding: " + te, b"Content-Length: 15"], BODY + SMUGGLED)))
        cases.append((f"CL 4 + TE {te!r}", post([b"Content-Length: 4", b"Transfer-Encoding: " + te], CHUNKED + SMUGGLED)))
    for line in TE_LINES:  # TE.TE: the name or the line obfuscated
        cases.append((f"TE line {line!r}", post([line], CHUNKED)))
        cases.append((f"TE line {line!r} + CL 15", post([line, b"Content-Length: 15"], BODY + SMUGGLED)))
    for cl in CL_VALUES:
        cases.append((f"CL {cl!r}", length(BODY + SMUGGLED, cl)))
    for line in CL_LINES:
        cases.append((f"CL line {line!r}", post([line], BODY + SMUGGLED)))
    for body in CHUNK_BODIES:
        cases.append((f"chunked {body[:40]!r}", chunked(body)))
    for eol in (b"\n", b"\r", b"\r\r\n", b"\n\r"):  # whole heads with other line endings
        cases.append((f"head eol {eol!r}, length", length(eol=eol)))
        cases.append((f"head eol {eol!r}, chunked", chunked(CHUNKED, eol=eol)))
    crlf_head = length(BODY).split(b"\r\n\r\n")[0].split(b"\r\n")
    for i in range(len(crlf_head)):  # one line ending swapped
        for eol in (b"\n", b"\r", b"\r\r\n"):
            cases.append((f"line {i} ends {eol!r}",
                          b"".join(ln + (eol if j == i else CRLF) for j, ln in enumerate(crlf_head)) + CRLF + BODY))
    for end in (b"\n\n", b"\r\n\n", b"\n\r\n", b"\r\r\n\r\n", b"\r\n\r", b"\r\n\r\r\n"):
        cases.append((f"head ends {end!r}", length(BODY).replace(b"\r\n\r\n", end, 1)))
    for field in (b"X\x00: a", b"X: a\x00b", b"X: a\rb", b"X: a\x01b", b"X: a\x7fb", b"X: \xff", b"X\r: a", b"X\x7f: a",
                  b"X Y: a", b"(X): a", b": a", b"X", b"X:", b"\x00: a", b"X: a\r\r\n", b"Host: local\x00host",
                  b"Content-Type: application/json\x00", b"X: a\x0bb", b"X\xff: a", b"Session-Secret: a\rb"):
        cases.append((f"field {field!r}", length(headers=[field])))
    for version in VERSIONS:
        cases.append((f"version {version!r}", length(line=b"POST /sessions " + version)))
    cases.append(("HTTP/0.9 simple request", b"GET /health\r\n\r\n"))
    cases.append(("HTTP/0.9 no blank line", b"GET /health\r\n"))
    cases.append(("HTTP/2 preface", b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n"))
    cases.append(("HTTP/1.0 chunked", chunked(CHUNKED, line=b"POST /sessions HTTP/1.0")))
    cases.append(("HTTP/1.0 no host", length(line=b"POST /sessions HTTP/1.0", base=[b"Content-Type: application/json"])))
    for target in TARGETS:
        cases.append((f"target {target[:40]!r}", length(line=b"POST " + target + b" HTTP/1.1")))
    for line in (b"POST  /sessions HTTP/1.1", b"POST /sessions  HTTP/1.1", b"POST\t/sessions\tHTTP/1.1",
                 b" POST /sessions HTTP/1.1", b"post /sessions HTTP/1.1", b"P\x00ST /sessions HTTP/1.1",
                 b"POST\x00 /sessions HTTP/1.1", b"POST /sessions HTTP/1.1 extra", b"POST /sessions", b"POST",
                 b"POSTX /sessions HTTP/1.1", b"PO ST /sessions HTTP/1.1", b"POST /sessions HTTP/1.1\x00"):
        cases.append((f"request line {line!r}", length(line=line)))
    for lead in (b"\r\n", b"\n", b"\r", b"\r\n\r\n", b" ", b"\x00", b"\r\n" * 50):
        cases.append((f"leading {lead[:8]!r}", lead + length()))
    for method, target in ((b"GET", b"/health"), (b"HEAD", b"/health"), (b"DELETE", b"/sessions/n0.0.x.0123456789abcdef"),
                           (b"OPTIONS", b"/health"), (b"GET", b"/sessions")):
        line = method + b" " + target + b" HTTP/1.1"
        cases.append((f"{method.decode()} with a length body", length(BODY + SMUGGLED, line=line)))
        cases.append((f"{method.decode()} with a chunked body", chunked(CHUNKED + SMUGGLED, line=line)))
    for expect in (b"100-continue", b"100-Continue", b"100-continue ", b"102-processing", b"100-continue, x", b"",
                   b"100-continue\r\nExpect: 100-continue", b"\x00", b"100-continue\x00"):
        cases.append((f"Expect {expect!r}", length(headers=[b"Expect: " + expect])))
    for fold in (b"Content-Type: application/\r\n json", b"Host: localhost\r\n folded", b"X: a\r\n\tb",
                 b"X: a\r\n \r\n", b"Content-Length: 1\r\n 5", b"X: a\n b"):
        cases.append((f"obs-fold {fold!r}", length(headers=[fold])))
    for ws in (b"Host : localhost", b"Content-Type : application/json", b"Host\t: localhost", b"X  : a"):
        cases.append((f"space before colon {ws!r}", length(headers=[ws])))
    cases += [("huge value", length(headers=[b"X: " + b"a" * 17000])), ("101 fields", length(headers=[b"X: a"] * 101)),
              ("100 fields", length(headers=[b"X%d: a" % i for i in range(98)])), ("huge name", length(headers=[b"X" * 17000 + b": a"])),
              ("long method", length(line=b"P" * 9000 + b" /sessions HTTP/1.1")), ("huge chunk size line", chunked(b"0" * 20000 + b"f\r\n" + BODY + b"\r\n0\r\n\r\n")),
              ("body over max", length(b"{" + b" " * 70000 + b"}")), ("chunked over max", chunked(b"10000\r\n" + b" " * 65536 + b"\r\n0\r\n\r\n")),
              ("announced over max", length(BODY, b"70000"))]
    for name, shape in WEBSOCKET_SHAPES:
        cases.append((f"websocket handshake {name}", shape))
    cases += [("upgrade h2c", length(headers=[b"Connection: Upgrade", b"Upgrade: h2c"])),
              ("CONNECT", b"CONNECT localhost:80 HTTP/1.1\r\nHost: localhost\r\n\r\n" + SMUGGLED),
              ("close then garbage", length(BODY + b"\x00garbage", headers=[b"Connection: close"])),
              ("close then smuggled", length(BODY + SMUGGLED, headers=[b"Connection: close"])),
              ("keep-alive 1.0 then smuggled", length(BODY + SMUGGLED, line=b"POST /sessions HTTP/1.0", headers=[b"Connection: keep-alive"])),
              ("pipelined then bad", length(BODY + b"{\"horizon\": 3}")),
              ("pipelined then bad chunked", length(BODY + post([b"Transfer-Encoding: chunked"], b"5\r\nhell\r\n0\r\n\r\n")))]
    return cases


# ---- seeded mutations of valid requests ----------------------------------------------------------

INTERESTING = b"\r\n\x00 \t:;,\"=0123456789abcdefABCDEFxX-+\x0b\x0c\x7f\x80\xff"
EOL_SWAPS = (b"\n", b"\r", b"\r\r\n", b"\n\r", b"", b"\r\n\r\n", b"\r\n ")


def valid_requests(rng: random.Random) -> list[bytes]:
    body = b'{"horizon":%d}' % rng.randint(100, 999)
    cut = rng.randint(3, len(body) - 2)  # a chunk boundary inside the JSON
    chunks = b"%x\r\n%s\r\n%x;ext=v\r\n%s\r\n0\r\n" % (cut, body[:cut], len(body) - cut, body[cut:])
    trailer = rng.choice((b"", b"T: v\r\n"))
    return [length(body), length(body, line=b"POST /sessions HTTP/1.0"), chunked(chunks + trailer + CRLF),
            length(body) + SMUGGLED, chunked(chunks + CRLF) + length(body),
            b"GET /health HTTP/1.1\r\nHost: localhost\r\nAccept: */*\r\n\r\n",
            length(body, headers=[b"Expect: 100-continue"]), chunked(b"".join(b"1\r\n%c\r\n" % c for c in body) + b"0\r\n\r\n")]


def mutate(rng: random.Random, data: bytes) -> bytes:
    data = bytearray(data)
    for _ in range(rng.choice((1, 1, 1, 2, 2, 3))):
        op = rng.choice(("insert", "delete", "replace", "eol", "eol", "duplicate", "chunk"))
        pos = rng.randrange(len(data) + 1)
        byte = rng.choice(INTERESTING) if rng.random() < 0.8 else rng.randrange(256)
        if op == "insert":
            data[pos:pos] = bytes([byte])
        elif op == "delete" and data:
            del data[pos:pos + rng.choice((1, 1, 2, 3))]
        elif op == "replace" and pos < len(data):
            data[pos] = byte
        elif op == "eol":
            ends = [i for i in range(len(data) - 1) if data[i:i + 2] == CRLF]
            if ends:
                i = rng.choice(ends)
                data[i:i + 2] = rng.choice(EOL_SWAPS)
        elif op == "duplicate":
            head_end = data.find(b"\r\n\r\n")
            lines = bytes(data[:head_end]).split(CRLF) if head_end > 0 else []
            if len(lines) > 1:
                line = rng.choice(lines[1:])
                name, _, value = line.partition(b":")
                if rng.random() < 0.5 and value.strip().isdigit():
                    line = name + b": " + str(int(value) + rng.choice((-1, 1, 100))).encode()
                elif rng.random() < 0.3:
                    line = name + b": " + rng.choice((b"chunked", b"identity", b"0", b"x"))
                at = rng.choice((head_end, data.find(CRLF) if data.find(CRLF) > 0 else head_end))
                data[at:at] = CRLF + line
        elif op == "chunk":
            head_end = data.find(b"\r\n\r\n")
            sizes = [i + 2 for i in range(max(head_end, 0), len(data) - 2) if data[i:i + 2] == CRLF
                     and chr(data[i + 2]) in "0123456789abcdef"]
            if sizes:
                i = rng.choice(sizes)
                data[i:i] = rng.choice((b"0", b"00000000000000000", b"1", b"f", b"-", b"+", b" ", b"ffffffffffffffff",
                                        b";", b";a=b;", b"\t", b"\n"))
    return bytes(data)


# ---- the check -----------------------------------------------------------------------------------

class Tally:
    def __init__(self, name: str):
        self.name, self.cases = name, 0
        self.counts = Counter()       # (who, verdict)
        self.answers = Counter()      # the service's answers by kind and status
        self.violations = []          # accepted by the service, refused by both
        self.mismatches = []          # accepted by the service, read differently from both
        self.broken = []              # an answer that is not HTTP, or cut short, or silence (no close either)
        self.ran = []                 # refused (or closed unanswered), yet a request of it ran
        self.early = 0                # a 4xx from the app on the head alone, the framing of the body bad
        self.seconds = Counter()      # waiting for the service, with and without a half-close

    def add(self, label, data, half_close, answer, h11_read, llhttp_read, reference) -> None:
        self.cases += 1
        reads = [p for p in (h11_read, llhttp_read) if p is not None]
        self.counts["h11", "accepted" if h11_read and h11_read.whole else "refused"] += 1
        self.counts["llhttp", "accepted" if llhttp_read and llhttp_read.whole else "refused"] += 1
        self.counts["service", answer.kind] += 1
        self.answers[answer.kind, answer.status or answer.how] += 1
        if answer.how in ("broken", "silent"):  # an answer cut short or not HTTP; or none, nor a close, in 5 s
            self.broken.append(f"{label}: {data!r:.300} -> {answer}")
        if answer.kind != "accepted":
            return
        mode = "half-close" if half_close else "open"
        got = signature(answer.status, answer.body)
        # what the app answers to each parser's reading; to a head alone (its body cut short or malformed),
        # only an error the app gives from the head (it never reads that body, nothing runs)
        expected = {reference.answer(p) for p in reads if p.whole or answer.status >= 400}
        if not any(p.whole for p in reads):
            if got in expected:
                self.early += 1  # a 4xx from the head: the request is refused before its body, nothing ran
            else:
                self.violations.append(f"{label} [{mode}]: {data!r:.300} -> {answer}")
        elif got not in expected:
            self.mismatches.append(f"{label} [{mode}]: {data!r:.300} -> service {got}, parsers {expected}")

    def summary(self) -> str:
        both = sum(1 for _ in self.violations)
        lines = [f"{self.name}: {self.cases} probes",
                 "  accepted/refused: " + ", ".join(f"{who} {self.counts[who, 'accepted']}/{self.counts[who, 'refused']}"
                                                    for who in ("service", "h11", "llhttp")),
                 f"  service accepted what both refuse: {both}; read differently from both: {len(self.mismatches)}; "
                 f"refused by the app from the head alone (4xx, its body's framing bad, nothing ran): {self.early}",
                 f"  answers cut short, not HTTP, or never sent (nor a close) within 5 s: {len(self.broken)}; "
                 f"refused or unanswered, yet a session was created: {len(self.ran)}",
                 "  service answers: " + ", ".join(f"{k} {s}: {n}" for (k, s), n in sorted(self.answers.items(), key=str)),
                 f"  waited {self.seconds[True]:.1f} s on half-closed probes, {self.seconds[False]:.1f} s on open ones"]
        return "\n".join(lines)

    def check(self) -> None:
        print("\n" + self.summary())
        problems = self.violations[:20] + self.mismatches[:20] + self.broken[:20] + self.ran[:20]
        assert not (self.violations or self.mismatches or self.broken or self.ran), \
            self.summary() + "\n" + "\n".join(problems)


def settle(service, timeout: float = 1.0) -> None:
    """Until no request is running (one pipelined behind the probe's first may still be)."""
    tasks, deadline = service.server.uvicorn.server_state.tasks, time.monotonic() + timeout
    while tasks and time.monotonic() < deadline:
        time.sleep(0.001)


def run(service, reference, tally: Tally, label: str, data: bytes, half_close: bool) -> None:
    settle(service)
    created = service.store.created_total
    t0 = time.perf_counter()
    answer = probe(service.address, data, half_close)
    tally.seconds[half_close] += time.perf_counter() - t0
    tally.add(label, data, half_close, answer, h11_first(data, eof=half_close), llhttp_first(data), reference)
    if answer.kind == "refused":  # refused or closed unanswered: then nothing ran, not even a request before it
        settle(service)
        if service.store.created_total != created:
            tally.ran.append(f"{label}: {data!r:.300} -> {answer}, yet {service.store.created_total - created} "
                             "session(s) created")


def assert_service_healthy(service) -> None:
    status, _, body = call(service.address, "GET", "/health")
    assert status == 200 and body["status"] == "ok"


def test_hand_written_smuggling_shapes(service, reference):
    cases = hand_written_cases()
    assert len(cases) >= 200, len(cases)
    tally = Tally(f"hand-written shapes ({len(cases)} cases, each sent with and without a half-close)")
    for label, data in cases:
        for half_close in (True, False):
            run(service, reference, tally, label, data, half_close)
    assert_service_healthy(service)
    tally.check()


@pytest.mark.parametrize("tail", [b"5\r\nhell\r\n0\r\n\r\n", b'f\r\n{"horizon":123\r\n0\r\n\r\n', b"2;\nxx\r\n0\r\n\r\n",
                                  b'2;\n{"\r\nd\r\nhorizon":123}\r\n0\r\n\r\n', b'f\n{"horizon":123}\r\n0\r\n\r\n',
                                  b'f\r\n{"horizon":123}\n0\r\n\r\n', b'f\r\n{"horizon":123}\r\n0\n\n'])
def test_bare_line_ends_in_chunked_framing_are_refused(service, tail):
    """The shapes the hand-written reader once accepted (a bare LF ending chunk data, so ``hell\\r`` was read as
    the body; a bare LF inside a chunk extension): both parsers refuse them, and so does the service, at once,
    with or without a half-close, and nothing is created."""
    data = chunked(tail)
    assert not llhttp_first(data).whole
    if H11_STRICT_CHUNKS:  # h11 before 0.16 read the bytes after chunk data loosely (CVE-2025-43859)
        assert not h11_first(data).whole
    before = len(service.store.live)
    for half_close in (True, False):
        answer = probe(service.address, data, half_close)
        assert answer.kind == "refused" and answer.status == 400, answer
        assert "invalid HTTP request" in answer.body["error"], answer
    assert len(service.store.live) == before


def test_a_pipelined_request_is_answered_before_the_refusal_of_what_follows_it(service):
    """A whole request followed by bytes that are no request: the request's answer, then the 400, in that
    order (a refusal written first would leave the request run but unanswered)."""
    for tail in (b'{"horizon": 3}', b"5\r\nhell\r\n0\r\n\r\n",
                 b"GET /health HTTP/1.1\r\nHost: localhost\r\nContent-Length: 99999999\r\n\r\n"):
        for half_close in (True, False):
            before = service.store.created_total
            got = statuses(exchange(service.address, length() + tail, half_close))
            assert got[:1] == [201] and got[1:] in ([400], [413]), (tail, half_close, got)
            assert service.store.created_total == before + 1


@pytest.mark.parametrize("name,shape", WEBSOCKET_SHAPES, ids=[name for name, _ in WEBSOCKET_SHAPES])
def test_refused_websocket_handshakes_are_answered_not_held_open(service, name, shape):
    """A handshake the websockets library refuses while parsing it (a body, a header line over its 8 KB) was
    neither answered nor closed, with no timer left running: any client could hold connections for good."""
    answer = probe(service.address, shape, half_close=False, timeout=2.0)
    assert answer.how == "answer" and answer.kind == "refused" and 400 <= answer.status < 500, answer


def run_mutations(service, reference, seed: int, count: int) -> Tally:
    rng = random.Random(seed)
    tally = Tally(f"mutations (seed {seed}, {count} cases)")
    for k in range(count):
        base = rng.choice(valid_requests(rng))
        data = mutate(rng, base)
        run(service, reference, tally, f"mutation {k}", data, half_close=k % 8 != 7)
    assert_service_healthy(service)
    return tally


def test_mutated_requests(service, reference):
    run_mutations(service, reference, seed=20240601, count=1000).check()


@pytest.mark.slow
def test_many_mutated_requests(service, reference):
    run_mutations(service, reference, seed=7, count=20_000).check()
