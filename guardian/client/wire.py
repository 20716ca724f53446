"""The minimal HTTP/1.1 of the asyncio client: a request's head (its body goes with ``Content-Length``), and the
reading of one answer from an asyncio stream: the status line, the header fields, a body framed by
``Content-Length`` (as the service frames every answer) or by the connection's end; interim 1xx answers are
skipped, a chunked answer is refused, and ``Connection: close`` (or HTTP/1.0 without keep-alive) says the
connection ends with the answer."""
from __future__ import annotations

import asyncio
import re

from guardian.client.common import Answer, Request, Target

MAX_HEAD_LINES = 200         # header fields of one answer
MAX_BODY = 64 * 1024 * 1024  # bytes of one answer
_UNSAFE = re.compile(r"[\r\n\x00]")


def _malformed(why: str) -> ConnectionError:
    return ConnectionError(f"malformed HTTP answer: {why}")


def head(request: Request, target: Target) -> bytes:
    """The request line and header fields of ``request`` to ``target``, with ``Host`` and ``Content-Length``.

    Parameters
    ----------
    request : Request
    target : Target

    Returns
    -------
    bytes
        Up to and including the empty line; the body follows it.
    """
    lines = [f"{request.method} {target.prefix}{request.path} HTTP/1.1", f"Host: {target.netloc}"]
    for name, value in request.headers.items():
        if _UNSAFE.search(f"{name}{value}"):
            raise ValueError(f"header {name!r}: a line break or NUL cannot be sent in a header field")
        lines.append(f"{name}: {value}")
    if request.body is not None or request.method in ("POST", "PUT", "PATCH"):
        lines.append(f"Content-Length: {len(request.body or b'')}")
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")


async def _head_fields(reader: asyncio.StreamReader) -> dict:
    headers: dict = {}
    for _ in range(MAX_HEAD_LINES):
        line = await reader.readline()
        if not line.endswith(b"\n"):
            raise ConnectionError("the connection was closed in the middle of an answer's head")
        if line in (b"\r\n", b"\n"):
            return headers
        name, sep, value = line.decode("latin-1").partition(":")
        if not sep or not name or name != name.strip():
            raise _malformed(f"header line {line[:100]!r}")
        name, value = name.lower(), value.strip()
        headers[name] = f"{headers[name]}, {value}" if name in headers else value
    raise _malformed(f"more than {MAX_HEAD_LINES} header fields")


async def read_answer(reader: asyncio.StreamReader, method: str) -> tuple[Answer, bool]:
    """The next answer on ``reader`` to a ``method`` request.

    Parameters
    ----------
    reader : asyncio.StreamReader
    method : str
        The request's method (an answer to ``HEAD`` has no body).

    Returns
    -------
    (Answer, bool)
        The answer, and whether the connection ends with it. A connection closed before the answer is whole,
        or an answer this reader does not take, raises ``ConnectionError``.
    """
    while True:
        line = await reader.readline()
        if not line.endswith(b"\n"):
            raise ConnectionError("the connection was closed without an answer")
        parts = line.decode("latin-1").rstrip("\r\n").split(" ", 2)
        if len(parts) < 2 or not parts[0].startswith("HTTP/1.") or not (parts[1].isdigit() and len(parts[1]) == 3):
            raise _malformed(f"status line {line[:100]!r}")
        version, status = parts[0], int(parts[1])
        headers = await _head_fields(reader)
        if not 100 <= status < 200:
            break
    tokens = {t.strip().lower() for t in headers.get("connection", "").split(",")}
    close = "close" in tokens or (version == "HTTP/1.0" and "keep-alive" not in tokens)
    if method == "HEAD" or status in (204, 304):
        return Answer(status, headers, b""), close
    if "transfer-encoding" in headers:
        raise _malformed(f"Transfer-Encoding {headers['transfer-encoding']!r} (only Content-Length is read)")
    length = headers.get("content-length")
    if length is None:  # the body runs to the connection's end
        body = bytearray()
        while chunk := await reader.read(65536):
            body += chunk
            if len(body) > MAX_BODY:
                raise _malformed(f"a body over {MAX_BODY} bytes")
        return Answer(status, headers, bytes(body)), True
    if not length.isdigit() or int(length) > MAX_BODY:
        raise _malformed(f"Content-Length {length!r}")
    return Answer(status, headers, await reader.readexactly(int(length))), close
