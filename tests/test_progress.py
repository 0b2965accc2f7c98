"""The progress bar (fem_impact.app.progress, tqdm): only on a terminal and on rank 0, a label, the count
and the time left; its line is ended before a message."""

from __future__ import annotations

import io
from types import SimpleNamespace

from fem_impact.app.progress import Progress


class Terminal(io.StringIO):
    def isatty(self):
        return True


class Clock:
    """A clock the test moves: the bar redraws at most every 0.2 s of it."""

    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        return self.now


def test_a_bar_shows_the_label_the_count_and_the_time_left_and_ends_its_line():
    stream, clock = Terminal(), Clock()
    bar = Progress(SimpleNamespace(rank=0), label="time loop", stream=stream, clock=clock)
    bar(1, 4)
    clock.now += 0.5   # past the bar's minimum interval between redraws: 2 steps in 0.5 s, 2 left
    bar(2, 4)
    text = stream.getvalue()
    assert "time loop" in text and "step 2/4" in text and " 50.0%" in text and "eta 0.5 s" in text
    assert not text.endswith("\n")
    clock.now += 0.1   # within the interval: not drawn
    bar(3, 4)
    assert stream.getvalue() == text
    bar(4, 4)
    assert stream.getvalue().endswith("\n") and "step 4/4" in stream.getvalue()
    assert Progress.open_bar is None


def test_a_long_run_shows_its_time_left_as_a_person_reads_it():
    stream, clock = Terminal(), Clock()
    bar = Progress(None, stream=stream, clock=clock)
    bar(1, 10**9)
    clock.now += 0.25   # 2 steps in 0.25 s: 1e9 steps take 1.25e8 s
    bar(2, 10**9)
    assert "eta 4 years" in stream.getvalue()
    Progress.end_line()
    assert stream.getvalue().endswith("\n")


def test_no_bar_off_a_terminal_or_off_rank_0():
    stream = io.StringIO()
    Progress(None, stream=stream)(1, 2)
    terminal = Terminal()
    Progress(SimpleNamespace(rank=1), stream=terminal)(1, 2)
    Progress(None, stream=Terminal(), enabled=False)(1, 2)
    assert stream.getvalue() == "" and terminal.getvalue() == ""
    forced = io.StringIO()
    Progress(None, label="reading", unit="frame", stream=forced, enabled=True)(3, 3)
    assert "reading" in forced.getvalue() and "frame 3/3" in forced.getvalue()


def test_end_line_ends_only_an_unfinished_line():
    Progress.end_line()   # no bar: nothing to do
    stream = Terminal()
    bar = Progress(None, stream=stream)
    bar(1, 3)
    Progress.end_line()
    text = stream.getvalue()
    assert text.endswith("\n")
    Progress.end_line()
    bar(2, 3)   # a bar whose line was ended draws no more
    assert stream.getvalue() == text
