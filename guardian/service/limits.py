"""What a request may cost before the service parses it, and the check that enforces it.

The gate runs before JSON parsing: a body's size, its nesting depth and the length of its number
literals are bounded on the raw bytes, so no body can make the parser allocate, recurse or convert
without bound. ``NaN`` and ``Infinity`` are not JSON (RFC 8259) and are refused here too.
"""
from __future__ import annotations

import re
import resource
from dataclasses import dataclass

import numpy as np

_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)
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


def json_cost_error(raw: bytes, limits: Limits) -> str | None:
    """Why ``raw`` may not be handed to a JSON parser, or None.

    Strings are blanked first so that brackets, digits or words inside them do not count.
    """
    bare = _STRING.sub(b'""', raw) if b'"' in raw else raw
    if bare.count(b"[") + bare.count(b"{") > limits.max_depth:  # else the depth cannot exceed it
        codes = np.frombuffer(bare, dtype=np.uint8)
        steps = (np.isin(codes, (ord("["), ord("{"))).astype(np.int32)
                 - np.isin(codes, (ord("]"), ord("}"))).astype(np.int32))
        depth = int(np.cumsum(steps).max())
        if depth > limits.max_depth:
            return f"JSON nested {depth} deep; at most {limits.max_depth} levels are accepted"
    long_number = re.search(rb"[-+0-9.eE]{%d,}" % (limits.max_number_chars + 1), bare)
    if long_number:
        return (f"a JSON number of {len(long_number.group())} characters; "
                f"at most {limits.max_number_chars} are accepted")
    not_json = _NOT_JSON.search(bare)
    if not_json:
        return f"malformed JSON body: {not_json.group().decode()} is not a number JSON allows"
    return None
