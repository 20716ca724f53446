"""Long jobs show a bar on a terminal and plain lines elsewhere."""
import io

from guardian.cli.progress import ProgressBar


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_lines_when_stderr_is_not_a_terminal():
    out = io.StringIO()
    bar = ProgressBar("replay", out)
    for i in range(1, 4):
        bar(i, 3)
    bar("rec 01", 5, 10)
    assert out.getvalue().splitlines() == ["[replay] 1/3", "[replay] 2/3", "[replay] 3/3", "[replay rec 01] 5/10"]


def test_a_bar_on_a_terminal_one_per_key_closed_when_done():
    out = Terminal()
    bar = ProgressBar("certify", out)
    bar(50, 100)
    bar("b", 1, 4)
    assert set(bar._bars) == {None, "b"}
    bar(100, 100)
    assert set(bar._bars) == {"b"}
    bar.close()
    text = out.getvalue()
    assert "certify" in text and "100%" in text and "|" in text and "[certify]" not in text
