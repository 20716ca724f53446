"""A strict HTTP/1.1 request reader and the response writer (RFC 9110/9112), without I/O.

The service reads requests itself rather than through a server framework: it must decide, from the
request line alone, which worker process a request belongs to (and hand the connection over before
anything is parsed), answer a request in the same event-loop turn its last byte arrived in (so a
client that half-closes its socket after a request still gets the answer), and stay cheap (the
parse is a few microseconds; a step is ~0.2 ms).

What it accepts is a strict subset of what h11 accepts (``tests/guardian/service/test_service_http.py`` runs both on
the same fuzzed bytes): one request line ``METHOD SP TARGET SP HTTP/1.x``, header fields
``name: value`` (no space before the colon, no obsolete line folding, no control characters), lines
ending in CRLF or LF, one ``Host`` on HTTP/1.1, ``Content-Length`` (digits; repeated only with the
same value) or ``Transfer-Encoding: chunked`` (not both; other codings are 501), ``Expect:
100-continue``. Anything else is a :class:`FramingError` with the status to answer (400, 413, 414,
417, 431, 501, 505), after which the connection closes.
"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from email.utils import formatdate

from guardian.service.limits import Limits
from guardian.errors import FramingError  # noqa: F401 (re-exported for the protocol)

REASONS = {100: "Continue", 101: "Switching Protocols", 200: "OK", 201: "Created", 400: "Bad Request",
           401: "Unauthorized", 403: "Forbidden", 404: "Not Found", 405: "Method Not Allowed",
           408: "Request Timeout", 409: "Conflict", 410: "Gone", 411: "Length Required",
           413: "Content Too Large", 414: "URI Too Long", 415: "Unsupported Media Type",
           417: "Expectation Failed", 421: "Misdirected Request", 422: "Unprocessable Content",
           426: "Upgrade Required", 431: "Request Header Fields Too Large", 500: "Internal Server Error",
           501: "Not Implemented", 503: "Service Unavailable", 505: "HTTP Version Not Supported"}

_HEAD_END = re.compile(rb"\r?\n\r?\n")
_TOKEN = re.compile(rb"^[!#$%&'*+\-.^_`|~0-9A-Za-z]+$")
_TARGET = re.compile(rb"^[\x21-\x7e]+$")
_VALUE_BAD = re.compile(rb"[\x00-\x08\x0a-\x1f\x7f]")
_DIGITS = re.compile(rb"^[0-9]+$")
_HEX = re.compile(rb"^[0-9A-Fa-f]{1,16}$")
MAX_CHUNK_LINE = 1024  # bytes of a chunk-size line with its extensions


@dataclass
class RequestHead:
    method: str
    target: str
    path: str
    query: str
    version: str
    headers: dict                 # lower-case name -> value (repeated fields joined with ", ")
    count: int                    # header fields
    head_bytes: int
    content_length: int | None = None
    chunked: bool = False
    close: bool = False           # the client asked to close after this request (or HTTP/1.0)
    upgrade: str | None = None    # the Upgrade protocol when Connection lists "upgrade"
    expect_continue: bool = False
    raw_lines: list = field(default_factory=list)  # (name, value) as sent, for the WebSocket handshake

    @property
    def has_body(self) -> bool:
        return self.chunked or bool(self.content_length)


def find_head_end(buf: bytearray, start: int = 0) -> tuple[int, int] | None:
    """``(end of the head, start of the body)`` in ``buf``, or None while the head is incomplete."""
    m = _HEAD_END.search(buf, start)
    if m is None:
        return None
    return m.start(), m.end()


def request_line_target(buf: bytearray) -> bytes | None:
    """The request target, once the request line has arrived (for routing before parsing)."""
    end = buf.find(b"\n")
    if end < 0:
        return None
    parts = bytes(buf[:end]).rstrip(b"\r").split(b" ")
    return parts[1] if len(parts) == 3 else None


def parse_head(raw: bytes, limits: Limits) -> RequestHead:
    """The request head (request line and fields, without the empty line), or a FramingError."""
    lines = raw.split(b"\n")
    lines = [ln[:-1] if ln.endswith(b"\r") else ln for ln in lines]
    parts = lines[0].split(b" ")
    if len(parts) != 3 or not parts[0] or not parts[1]:
        raise FramingError(400, "invalid HTTP request: the request line must be 'METHOD TARGET HTTP/1.1'")
    method, target, version = parts
    if not _TOKEN.match(method):
        raise FramingError(400, "invalid HTTP request: the method is not a token")
    if len(target) > limits.max_url:
        raise FramingError(414, f"request target of {len(target)} bytes exceeds {limits.max_url}")
    if not _TARGET.match(target):
        raise FramingError(400, "invalid HTTP request: the request target has a space, a control or a non-ASCII byte")
    if version not in (b"HTTP/1.1", b"HTTP/1.0"):
        if re.match(rb"^HTTP/[0-9]\.[0-9]$", version):
            raise FramingError(505, f"HTTP version {version.decode()} is not supported (1.1 and 1.0 are)")
        raise FramingError(400, "invalid HTTP request: the request line does not end in an HTTP version")
    if len(lines) - 1 > limits.max_headers:
        raise FramingError(431, f"{len(lines) - 1} header fields; at most {limits.max_headers} are accepted")
    headers: dict[str, str] = {}
    raw_lines = []
    for line in lines[1:]:
        if line[:1] in (b" ", b"\t"):
            raise FramingError(400, "invalid HTTP request: obsolete line folding in a header field")
        name, colon, value = line.partition(b":")
        if not colon or not _TOKEN.match(name):
            raise FramingError(400, "invalid HTTP request: a header field is not 'name: value'")
        value = value.strip(b" \t")
        if _VALUE_BAD.search(value):
            raise FramingError(400, f"invalid HTTP request: a control character in header {name.decode()!r}")
        key = name.decode("ascii").lower()
        text = value.decode("latin-1")
        raw_lines.append((name.decode("ascii"), text))
        if key in headers:
            if key == "host":
                raise FramingError(400, "invalid HTTP request: more than one Host header")
            headers[key] = headers[key] + ", " + text
        else:
            headers[key] = text
    t = target.decode("ascii")
    path, _, query = t.partition("?")
    head = RequestHead(method.decode("ascii"), t, path, query, version.decode("ascii")[5:], headers,
                       len(lines) - 1, len(raw), raw_lines=raw_lines)
    if head.version == "1.1" and "host" not in headers:
        raise FramingError(400, "invalid HTTP request: HTTP/1.1 needs a Host header")
    _framing(head, headers)
    connection = {t.strip().lower() for t in headers.get("connection", "").split(",")}
    head.close = "close" in connection or (head.version == "1.0" and "keep-alive" not in connection)
    if "upgrade" in connection and "upgrade" in headers:
        head.upgrade = headers["upgrade"].strip().lower()
    expect = headers.get("expect")
    if expect is not None:
        if expect.strip().lower() != "100-continue":
            raise FramingError(417, f"Expect: {expect} is not supported (100-continue is)")
        head.expect_continue = head.version == "1.1"
    return head


def _framing(head: RequestHead, headers: dict) -> None:
    te, cl = headers.get("transfer-encoding"), headers.get("content-length")
    if te is not None:
        if head.version == "1.0":
            raise FramingError(400, "invalid HTTP request: Transfer-Encoding in an HTTP/1.0 request")
        if cl is not None:
            raise FramingError(400, "invalid HTTP request: both Content-Length and Transfer-Encoding")
        if te.strip().lower() != "chunked":
            raise FramingError(501, f"Transfer-Encoding {te!r} is not supported (only 'chunked')")
        head.chunked = True
    elif cl is not None:
        values = {v.strip() for v in cl.split(",")}
        if len(values) != 1:
            raise FramingError(400, "invalid HTTP request: conflicting Content-Length values")
        value = values.pop().encode()
        if not _DIGITS.match(value):
            raise FramingError(400, f"invalid HTTP request: Content-Length {cl!r} is not a number of bytes")
        head.content_length = int(value) if len(value) <= 18 else 10 ** 18


class ChunkedReader:
    """Decodes a chunked body from a buffer, incrementally; ``feed`` says when it is complete."""

    def __init__(self, limits: Limits):
        self.limits = limits
        self.body = bytearray()
        self.remaining = 0        # bytes of the current chunk still to come
        self.state = "size"       # size | data | data-end | trailer | done
        self.trailer_bytes = 0

    def feed(self, buf: bytearray) -> bool:
        """Consume what it can from ``buf`` (in place); True once the last chunk and trailers are read."""
        while True:
            if self.state == "size":
                end = buf.find(b"\n")
                if end < 0:
                    if len(buf) > MAX_CHUNK_LINE:
                        raise FramingError(400, "invalid HTTP request: a chunk-size line is too long")
                    return False
                line = bytes(buf[:end]).rstrip(b"\r")
                del buf[:end + 1]
                size = line.split(b";", 1)[0]
                if not _HEX.match(size):
                    raise FramingError(400, "invalid HTTP request: a chunk size is not hexadecimal")
                self.remaining = int(size, 16)
                if len(self.body) + self.remaining > self.limits.max_body:
                    raise FramingError(413, f"body exceeds {self.limits.max_body} bytes")
                self.state = "data" if self.remaining else "trailer"
            elif self.state == "data":
                take = min(self.remaining, len(buf))
                self.body += buf[:take]
                del buf[:take]
                self.remaining -= take
                if self.remaining:
                    return False
                self.state = "data-end"
            elif self.state == "data-end":
                if len(buf) < 2 and buf[:1] != b"\n":
                    return False
                if buf[:2] == b"\r\n":
                    del buf[:2]
                elif buf[:1] == b"\n":
                    del buf[:1]
                else:
                    raise FramingError(400, "invalid HTTP request: a chunk is longer than its size says")
                self.state = "size"
            elif self.state == "trailer":
                end = buf.find(b"\n")
                if end < 0:
                    if self.trailer_bytes + len(buf) > self.limits.max_header_bytes:
                        raise FramingError(431, f"trailer longer than {self.limits.max_header_bytes} bytes")
                    return False
                line = bytes(buf[:end]).rstrip(b"\r")
                del buf[:end + 1]
                self.trailer_bytes += end + 1
                if self.trailer_bytes > self.limits.max_header_bytes:
                    raise FramingError(431, f"trailer longer than {self.limits.max_header_bytes} bytes")
                if not line:
                    self.state = "done"
                    return True
                name, colon, _ = line.partition(b":")
                if not colon or not _TOKEN.match(name):
                    raise FramingError(400, "invalid HTTP request: a trailer field is not 'name: value'")
            else:
                return True


_date = [0, b""]


def http_date() -> bytes:
    """The Date header's value, formatted once per second."""
    now = int(time.time())
    if _date[0] != now:
        _date[0], _date[1] = now, formatdate(now, usegmt=True).encode()
    return _date[1]


def serialize(status: int, body: bytes, headers=(), close: bool = False, head_only: bool = False,
              content_type: bytes = b"application/json") -> bytes:
    """One whole response: status line, Date, Content-Type, Content-Length, ``headers``, body."""
    parts = [b"HTTP/1.1 %d %s\r\ndate: %s\r\n" % (status, REASONS.get(status, "Unknown").encode(), http_date())]
    if body or status not in (101, 204, 304):
        parts.append(b"content-type: %s\r\ncontent-length: %d\r\n" % (content_type, len(body)))
    for name, value in headers:
        parts.append(b"%s: %s\r\n" % (name.encode() if isinstance(name, str) else name,
                                      value.encode("latin-1") if isinstance(value, str) else value))
    if close:
        parts.append(b"connection: close\r\n")
    parts.append(b"\r\n")
    if not head_only:
        parts.append(body)
    return b"".join(parts)
