"""Progress bars go to a terminal only: a log or a pipe gets the result or the error line, no bar."""

import io
import sys

from bmctl.commands._args import progress_bar


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def _run_bar(monkeypatch, stream):
    monkeypatch.setattr(sys, "stderr", stream)
    bar = progress_bar(total=3, desc="milling", unit="h", mininterval=0)
    for _ in range(3):
        bar.update(1)
    bar.close()
    return stream.getvalue()


def test_no_bar_when_stderr_is_not_a_terminal(monkeypatch):
    assert _run_bar(monkeypatch, io.StringIO()) == ""


def test_a_bar_on_a_terminal_is_drawn_and_cleared(monkeypatch):
    text = _run_bar(monkeypatch, _Terminal())
    assert "milling" in text and text.endswith("\r")  # cleared at close (leave=False)
