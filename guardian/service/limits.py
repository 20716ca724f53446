"""What a request may cost before the service parses it, and the check that enforces it.

The gate runs before JSON parsing: a body's size, its nesting depth and the length of its number
literals are bounded on the raw bytes, so no body can make the parser allocate, recurse or convert
without bound. ``NaN`` and ``Infinity`` are not JSON (RFC 8259) and are refused here too.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)
_NOT_JSON = re.compile(rb"\b(NaN|Infinity)\b")


@dataclass(frozen=True)
class Limits:
    """Bounds on one request; every one is a service option (``guardian serve --help``)."""

    max_body: int = 64 * 1024           # bytes of a body or WebSocket message (413)
    max_depth: int = 32                 # nesting of JSON arrays and objects (400)
    max_number_chars: int = 40          # characters of one JSON number literal (400)
    max_url: int = 8 * 1024             # bytes of the request target (414)
    max_headers: int = 100              # header fields (431)
    max_header_bytes: int = 16 * 1024   # bytes of the request head (431; the parser's buffer)
    read_timeout: float = 10.0          # seconds to receive a whole request once it began (408)
    keepalive_timeout: float = 5.0      # seconds an idle connection is kept open


def json_cost_error(raw: bytes, limits: Limits) -> str | None:
    """Why ``raw`` may not be handed to a JSON parser, or None.

    Strings are blanked first so that brackets, digits or words inside them do not count.
    """
    bare = _STRING.sub(b'""', raw)
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
