"""What a request may cost before the service parses it, and the check that enforces it.

The gate runs before JSON parsing: a body's size, its nesting depth and the length of its number
literals are bounded on the raw bytes, so no body can make the parser allocate, recurse or convert
without bound. ``NaN`` and ``Infinity`` are not JSON (RFC 8259) and are refused here too.
"""
from __future__ import annotations

import re
import resource
from dataclasses import dataclass

_NOT_JSON = re.compile(rb"\b(NaN|Infinity)\b")
FD_RESERVE = 64  # file descriptors kept free below RLIMIT_NOFILE (logs, the library, handoffs, accept)


@dataclass(frozen=True)
class Limits:
    """Bounds on one request and on connections; every one is a service option (``guardian serve --help``)."""

    max_body: int = 64 * 1024           # bytes of a body or stream message (413)
    max_depth: int = 32                 # nesting of JSON arrays and objects (400)
    max_number_chars: int = 40          # characters of one JSON number literal (400)
    max_url: int = 8 * 1024             # bytes of the request target (414)
    max_headers: int = 100              # header fields (431)
    max_header_bytes: int = 16 * 1024   # bytes of the request head (431; 414 for a request line)
    read_timeout: float = 10.0          # seconds to receive a whole request once it began (408)
    keepalive_timeout: float = 5.0      # seconds an idle connection is kept open
    max_connections: int | None = None  # open connections per worker (503 beyond); None: from the fd limit
    stream_idle_timeout: float = 60.0   # seconds a stream may go without a message (closed 4408)
    stream_frame_factor: int = 16       # stream messages up to this x max_body get a 413 reply; longer close 1009

    @property
    def max_stream_frame(self) -> int:
        """The largest stream message read at all: longer ones close the stream (1009) unread."""
        return self.max_body * self.stream_frame_factor

    def connection_cap(self) -> int:
        """``max_connections``, never more than the process may open (RLIMIT_NOFILE less a reserve)."""
        soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
        room = max(1, soft - FD_RESERVE) if soft != resource.RLIM_INFINITY else 1 << 20
        return min(self.max_connections, room) if self.max_connections is not None else min(room, 10_000)

    def check(self) -> None:
        for name in ("max_body", "max_depth", "max_number_chars", "max_url", "max_headers", "max_header_bytes",
                     "stream_frame_factor"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("read_timeout", "keepalive_timeout", "stream_idle_timeout"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 seconds, got {getattr(self, name)}")
        if self.max_connections is not None and self.max_connections < 1:
            raise ValueError(f"max_connections must be >= 1, got {self.max_connections}")


# A JSON string: its quote, then characters or escaped pairs, up to its closing quote or the end of the body.
# Possessive, so it never backtracks: one pass over the body, however many quotes and backslashes it holds.
_STRING = re.compile(rb'"(?:[^"\\]++|\\.)*+(?:"|\\?\Z)', re.DOTALL)
_ALL_BYTES = bytes(range(256))
_NOT_BRACKETS = bytes(c for c in _ALL_BYTES if c not in b"[]{}")
_NUMBER_CHARS = b"-+0123456789.eE"
_NUMBERS_ONLY = bytes(c if c in _NUMBER_CHARS else 0x20 for c in _ALL_BYTES)  # runs of number characters


def without_strings(raw: bytes) -> bytes:
    """``raw`` with the contents of every JSON string removed (``"..."`` becomes ``""``; an unterminated string
    runs to the end). Without a backslash, every other quote ends a string: a split does it."""
    if b"\\" in raw:
        return _STRING.sub(b'""', raw)
    parts = raw.split(b'"')
    bare = b'""'.join(parts[0::2])
    return bare + b'""' if len(parts) % 2 == 0 else bare


def nesting_depth(bare: bytes) -> int:
    """The deepest nesting of arrays and objects in ``bare`` (a body without strings)."""
    depth = deepest = 0
    for c in bare.translate(None, _NOT_BRACKETS):
        depth += 1 if c in (0x5B, 0x7B) else -1
        deepest = max(deepest, depth)
    return deepest


def json_cost_error(raw: bytes, limits: Limits) -> str | None:
    """Why ``raw`` may not be handed to a JSON parser, or None.

    Strings are blanked first so that brackets, digits or words inside them do not count.
    """
    bare = without_strings(raw) if b'"' in raw else raw
    if bare.count(b"[") + bare.count(b"{") > limits.max_depth:  # else the depth cannot exceed it
        depth = nesting_depth(bare)
        if depth > limits.max_depth:
            return f"JSON nested {depth} deep; at most {limits.max_depth} levels are accepted"
    longest = max(map(len, bare.translate(_NUMBERS_ONLY).split()), default=0)
    if longest > limits.max_number_chars:
        return f"a JSON number of {longest} characters; at most {limits.max_number_chars} are accepted"
    not_json = (b"NaN" in bare or b"Infinity" in bare) and _NOT_JSON.search(bare)
    if not_json:
        return f"malformed JSON body: {not_json.group().decode()} is not a number JSON allows"
    return None
