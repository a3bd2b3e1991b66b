"""Progress off a terminal is plain lines, not carriage-return frames."""

from __future__ import annotations

import io

from kitbench.progress import PlainProgress, progress


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_off_a_terminal_progress_is_plain_lines():
    stream = io.StringIO()
    bar = progress(5, "record T", stream=stream)
    assert isinstance(bar, PlainProgress)
    bar.interval = 0.0  # a line per update, to see them
    for _ in range(5):
        bar.update(1)
        bar.set_postfix(success="100%")
    bar.close()
    bar.close()  # closing twice prints the last line once
    text = stream.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert len(lines) == 6 and lines[-1].startswith("record T: 5/5 (100%)") and lines[-1].endswith("success=100%")


def test_a_quiet_interval_prints_only_the_last_line():
    stream = io.StringIO()
    bar = progress(100, "eval T", stream=stream)
    for _ in range(100):
        bar.update(1)
    bar.close()
    assert stream.getvalue().count("\n") == 1


def test_on_a_terminal_it_is_a_tqdm_bar():
    from tqdm import tqdm

    bar = progress(3, "x", stream=_Terminal())
    assert isinstance(bar, tqdm)
    bar.close()
