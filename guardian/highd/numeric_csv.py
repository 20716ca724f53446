"""A compiled reader for CSV files whose every field is a plain decimal number (HighD's tracks files).

``read_numeric_csv(path, columns)`` returns ``{column: float64 array}`` in the file's column order,
or None when the file is anything but simple: then the caller reads it the general way (pyarrow,
and pandas for the message), so every error is still reported exactly as before.

Simple means: an ASCII header that is a permutation of ``columns`` (no quotes, no BOM), then rows
of exactly that many fields ending in ``\\n`` or ``\\r\\n`` (the last newline optional), every field
``[-]digits[.digits][(e|E)[+|-]digits]``. No blank line, no empty field, no space.

Exactness. A field's significant digits form an integer ``m`` and its decimal exponent ``k``. When
``m <= 2**53`` and ``|k| <= 22`` both ``m`` and ``10**|k|`` are exact doubles, so ``m * 10**k`` or
``m / 10**-k`` is rounded once by IEEE-754 and is the correctly rounded value of the decimal
(Clinger's fast path, W. D. Clinger, "How to read floating point numbers accurately", PLDI 1990):
the double every correctly rounding parser returns, pyarrow's among them (a test compares them
bit for bit). A field outside the fast path (more than 15-16 significant digits, a huge exponent)
makes the whole file go the general way: this reader never rounds differently, it declines.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from numba import njit

_POW10 = np.array([10.0 ** k for k in range(23)])  # each exact in binary64
_EXACT = 2 ** 53
_MINUS, _PLUS, _DOT, _COMMA, _CR, _LF, _ZERO, _NINE, _E, _e = 45, 43, 46, 44, 13, 10, 48, 57, 69, 101


def read_numeric_csv(path: Path, columns) -> tuple[dict[str, np.ndarray], set] | None:
    """The columns of a simple all-numeric CSV whose header is a permutation of ``columns``; else None.

    Returns ``({name: float64 values}, names)``, the names being the columns whose every field is a
    plain integer (digits with an optional minus: exactly an int64 after ``astype``).
    """
    buf = _read_with_sentinel(Path(path))
    newline = np.flatnonzero(buf[: 1 << 16] == _LF)
    if not len(newline):
        return None
    try:
        header = buf[: newline[0]].tobytes().decode("ascii")
    except UnicodeDecodeError:
        return None
    names = header[:-1].split(",") if header.endswith("\r") else header.split(",")
    if sorted(names) != sorted(columns) or len(set(names)) != len(names):
        return None
    start = int(newline[0]) + 1
    rows_at_most = (len(buf) - 1 - start) // (2 * len(names) - 1) + 1  # a row is >= 2 bytes per field, less one
    out = np.empty((len(names), rows_at_most))
    plain = np.ones(len(names), dtype=np.bool_)
    rows = _parse(buf, start, out, plain, _POW10)
    if rows <= 0:
        return None
    return {name: out[j, :rows] for j, name in enumerate(names)}, {n for n, p in zip(names, plain) if p}


def _read_with_sentinel(path: Path) -> np.ndarray:
    """The file's bytes and one 0 byte after them, so the kernel's digit loops need no bounds test."""
    size = path.stat().st_size
    buf = np.zeros(size + 1, dtype=np.uint8)
    view, done = memoryview(buf)[:size], 0
    with open(path, "rb", buffering=0) as fh:
        while done < size:
            got = fh.readinto(view[done:])
            if not got:
                break  # the file shrank while being read: what was read is parsed (or declined)
            done += got
    return buf[: done + 1]


@njit(cache=True)
def _parse(buf, i, out, plain, pow10):
    """Rows parsed into ``out[:, :rows]``, ``plain[col]`` cleared where a field has a point or an exponent;
    0 if any byte falls outside the simple form (or there is no row). ``buf[-1]`` is a 0 sentinel."""
    n, ncols, capacity = len(buf) - 1, out.shape[0], out.shape[1]
    row = 0
    while i < n:
        if row >= capacity:
            return 0
        for col in range(ncols):
            negative = buf[i] == _MINUS
            if negative:
                i += 1
            m, digits, point = 0, 0, -1  # point: the digits before the decimal point, -1 without one
            while True:  # the sentinel stops it
                c = buf[i]
                if _ZERO <= c <= _NINE:
                    m = m * 10 + (c - _ZERO)
                    if m > _EXACT:
                        return 0
                    digits += 1
                elif c == _DOT and point < 0 and digits > 0:
                    point = digits
                else:
                    break
                i += 1
            if digits == 0 or point == digits:  # no digit, or none after the point
                return 0
            k = 0
            if point >= 0:
                k = point - digits
                plain[col] = False
            if buf[i] == _E or buf[i] == _e:
                i += 1
                exp_negative = buf[i] == _MINUS
                if exp_negative or buf[i] == _PLUS:
                    i += 1
                e, start = 0, i
                while _ZERO <= buf[i] <= _NINE:
                    e = e * 10 + (buf[i] - _ZERO)
                    if e > 400:
                        return 0
                    i += 1
                if i == start:
                    return 0
                k += -e if exp_negative else e
                plain[col] = False
            if m == 0:
                value = 0.0
            elif 0 <= k <= 22:
                value = m * pow10[k]
            elif -22 <= k < 0:
                value = m / pow10[-k]
            else:
                return 0
            out[col, row] = -value if negative else value
            if col < ncols - 1:
                if buf[i] != _COMMA:
                    return 0
                i += 1
            elif i < n:
                if buf[i] == _CR:
                    i += 1
                if buf[i] != _LF:
                    return 0
                i += 1
        row += 1
    return row
