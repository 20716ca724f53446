"""The compiled numeric CSV reader: pyarrow's doubles bit for bit, or it declines.

Two referees it did not write: pyarrow's CSV reader (what the clean path used before) and Python's
``float`` (correctly rounded). Declining is always safe (the file goes the general way); accepting a
file and rounding one value differently is the failure these tests exist to catch.
"""
import io

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv
import pytest

from guardian.highd.numeric_csv import read_numeric_csv


def pyarrow_columns(text: bytes, names) -> dict:
    table = pcsv.read_csv(io.BytesIO(text), convert_options=pcsv.ConvertOptions(
        column_types={n: pa.float64() for n in names}))
    return {n: table.column(n).to_numpy() for n in table.column_names}


def write(tmp_path, text: str | bytes):
    path = tmp_path / "t.csv"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def magnitudes(rng, n):
    return (rng.standard_normal(n) * 10.0 ** rng.integers(-8, 9, n)).tolist()


SHORT = [lambda v: f"{v:.2f}", lambda v: f"{v:.6g}", lambda v: f"{v:e}", lambda v: f"{v:.9e}",
         lambda v: str(int(v)), lambda v: f"{v:.0f}", lambda v: f"{v:.4f}"]  # at most 15 significant digits
EDGES = ["-0", "-0.0", "0", "007", "00.5", "1e0022", "5e-0", "-1E-22", "1E+05", "9007199254740992",
         "900719925474099.2", "0.9007199254740992", "1234567890123456e-22"]


def test_every_value_of_a_plain_file_is_pyarrows_and_correctly_rounded(tmp_path):
    rng = np.random.default_rng(7)
    values = [SHORT[rng.integers(len(SHORT))](v) for v in magnitudes(rng, 60_000)] + EDGES
    values += values[: (-len(values)) % 3]  # whole rows of three
    rows = np.array(values).reshape(-1, 3)
    text = "a,b,c\n" + "\n".join(",".join(r) for r in rows) + "\n"
    ours, _ = read_numeric_csv(write(tmp_path, text), ["a", "b", "c"])
    theirs = pyarrow_columns(text.encode(), ["a", "b", "c"])
    for j, name in enumerate("abc"):
        assert ours[name].tobytes() == theirs[name].tobytes(), name
        assert ours[name].tobytes() == np.array([float(s) for s in rows[:, j]]).tobytes(), name


def test_long_decimals_are_read_exactly_or_declined(tmp_path):
    """17 significant digits (repr, %.17g) straddle the fast path: each value alone is either the
    correctly rounded double or a declined file, never a near miss."""
    rng = np.random.default_rng(8)
    accepted = 0
    for v in magnitudes(rng, 1500):
        for text in (repr(v), f"{v:.17g}", f"{v:.16e}", f"{v:.18f}"):
            got = read_numeric_csv(write(tmp_path, f"a\n{text}\n"), ["a"])
            if got is not None:
                accepted += 1
                assert got[0]["a"][0].tobytes() == np.float64(float(text)).tobytes(), text
    assert accepted > 1000  # the fast path does take most of them


@pytest.mark.parametrize("value", ["9007199254740993", "12345678901234567890", "0.12345678901234567890",
                                   "1e23", "1e-23", "123456789e-30", "1e401"])
def test_outside_the_fast_path_it_declines_rather_than_round(tmp_path, value):
    assert read_numeric_csv(write(tmp_path, f"a,b\n1,{value}\n"), ["a", "b"]) is None


@pytest.mark.parametrize("text", [
    "a,b\n1,\n",              # an empty field
    "a,b\n1,2\n\n3,4\n",      # a blank line
    "a,b\n1,2,3\n",           # a long row
    "a,b\n1\n",               # a short row
    "a,b\n1, 2\n",            # a space
    'a,b\n1,"2"\n',           # a quote
    "a,b\n1,nan\n", "a,b\n1,inf\n", "a,b\n1,+2\n", "a,b\n1,.5\n", "a,b\n1,5.\n", "a,b\n1,1e\n",
    "a,b\n1,--2\n", "a,b\n1,2\r\r\n", "a,b\n1,0x10\n",
    "\ufeffa,b\n1,2\n",       # a byte order mark
    '"a",b\n1,2\n',           # a quoted header
    "a,c\n1,2\n",             # a foreign column
    "a,a\n1,2\n",             # a repeated column
    "a,b\n",                  # no rows
    "",                       # empty
])
def test_anything_but_a_simple_numeric_file_is_declined(tmp_path, text):
    assert read_numeric_csv(write(tmp_path, text), ["a", "b"]) is None


def test_line_endings_and_column_order_are_kept(tmp_path):
    got, plain = read_numeric_csv(write(tmp_path, "b,a,c\r\n1.5,-2,7\r\n3,4e1,-0"), ["a", "b", "c"])
    assert list(got) == ["b", "a", "c"]
    assert got["b"].tolist() == [1.5, 3.0] and got["a"].tolist() == [-2.0, 40.0] and got["c"].tolist() == [7, 0]
    assert plain == {"c"}  # digits only: an exact int64; a point or an exponent leaves the check to the caller
