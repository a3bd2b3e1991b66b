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


def test_a_line_says_the_time_left_at_the_rate_so_far():
    stream = io.StringIO()
    bar = PlainProgress(2500, "train T", unit="step", stream=stream, interval=0.0)
    bar.start -= 600.0  # 500 steps in ten minutes: 2,000 left take forty
    bar.update(500)
    bar.start -= 3000.0
    bar.update(1999)  # a step left at 0.69 step/s
    bar.update(1)
    first, second, last = stream.getvalue().splitlines()
    assert first.startswith("train T: 500/2500 (20%) [600 s, 0.83 step/s, 40 min left]"), first
    assert second.endswith(", 1 s left]"), second
    assert "left" not in last  # done: nothing left to say


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


def test_the_video_pass_of_an_evaluation_has_its_own_progress(needs_vulkan, tmp_path, capsys):
    from pathlib import Path

    from kitbench.evaluation.config import EvalConfig
    from kitbench.evaluation.runner import run_eval
    from kitbench.evaluation.suite import load_suite

    suite = load_suite(Path(__file__).resolve().parents[1] / "eval/suites/lift_peg_upright_short.toml").first(2)
    run_eval(EvalConfig.of(suite, "zero", tmp_path / "report", videos=2), progress=True)
    lines = capsys.readouterr().err.splitlines()
    assert any(line.startswith("eval LiftPegUpright-v1: 2/2") for line in lines)
    assert lines[-1].startswith("videos: 2/2 (100%)")  # off a terminal: its last line, after scoring's
