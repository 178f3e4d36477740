"""The optimizer's progress printer, shared by ``scratchfab optimize`` and the pipeline."""

from __future__ import annotations

import math
import re
from types import SimpleNamespace

import pytest

from scratchfab.console import clock
from scratchfab.optimize import progress as progress_mod
from scratchfab.optimize.progress import progress_printer
from scratchfab.optimize.stage import Progress

BAR = re.compile(r"\[(#*)(\.*)\] (\d+)/(\d+) loss (\S+)  elapsed (\S+)  eta (\S+)")
STEP = re.compile(r"(\d+)/(\d+) loss (\S+)  elapsed (\S+)  eta (\S+)")


@pytest.fixture
def fake_clock(monkeypatch):
    """Seconds on the printer's monotonic clock, set by the test."""
    now = [1000.0]
    monkeypatch.setattr(progress_mod, "time", SimpleNamespace(monotonic=lambda: now[0]))
    return now


def steps(total: int):
    for i in range(1, total + 1):
        yield Progress(i, total, 1.0 / i, float(i), float(total - i))


@pytest.mark.parametrize(
    ("seconds", "text"),
    [(math.nan, "--:--"), (math.inf, "--:--"), (0.4, "00:00"), (65, "01:05"), (3725, "1:02:05")],
)
def test_clock(seconds, text):
    assert clock(seconds) == text


def test_log_gets_a_line_per_tenth_and_each_message(fake_clock):
    lines: list[str] = []
    report = progress_printer(lines.append)
    report(Progress(0, 100, math.nan, 0.0, math.nan, "compiling kernels"))
    for p in steps(100):
        report(p)
    report(Progress(100, 100, math.nan, 100.0, 0.0, "writing outputs"))
    assert lines[0] == "compiling kernels..." and lines[-1] == "writing outputs..."
    bars = [BAR.fullmatch(line) for line in lines[1:-1]]
    assert all(bars)
    # The clock stood still: only a new tenth of the steps gives a line.
    assert [int(b[3]) for b in bars] == [1, *range(10, 101, 10)]
    for b in bars:
        i = int(b[3])
        assert len(b[1]) == round(30 * i / 100) and len(b[1]) + len(b[2]) == 30
        assert float(b[5]) == pytest.approx(1.0 / i, abs=5e-6)
        assert b[6] == f"{i // 60:02d}:{i % 60:02d}"


def test_log_gets_a_line_at_least_every_five_seconds(fake_clock):
    lines: list[str] = []
    report = progress_printer(lines.append)
    for p in steps(100):
        fake_clock[0] += 2.0
        report(p)
    shown = [int(BAR.fullmatch(line)[3]) for line in lines]
    # 2 s a step: a new tenth gives a line, and within one every third step is more
    # than 5 s after the last line.
    tenths = [10 * k + j for k in range(1, 10) for j in (0, 3, 6, 9)]
    assert shown == [1, 4, 7, *tenths, 100]


def test_terminal_redraws_every_step_and_keeps_the_last(fake_clock):
    drawn: list[tuple[str, bool]] = []
    said: list[str] = []
    fractions: list[float | None] = []

    def redraw(text: str, done: bool, fraction: float | None) -> None:
        drawn.append((text, done))
        fractions.append(fraction)

    report = progress_printer(said.append, redraw)
    report(Progress(0, 5, math.nan, 0.0, math.nan, "compiling kernels"))
    for p in steps(5):
        report(p)
    assert said == []
    assert drawn[0] == ("compiling kernels...", True)
    # the terminal draws the bar: the text is the log line's after its bar
    assert [STEP.fullmatch(text)[1] for text, _ in drawn[1:]] == ["1", "2", "3", "4", "5"]
    assert [done for _, done in drawn[1:]] == [False] * 4 + [True]
    assert fractions == [None, 0.2, 0.4, 0.6, 0.8, 1.0]


def whole_words(text: str, room: int) -> str:
    """The longest run of ``text``'s first words (as written, spaces between) in ``room``."""
    ends = [m.end() for m in re.finditer(r"\S+", text) if m.end() <= room]
    return text[: ends[-1]] if ends else text[:room]


def drawn_lines(err: str) -> list[str]:
    """The lines a terminal shows for each redraw of stderr (a carriage return each)."""
    assert err.startswith("\r")
    return [part.removesuffix("\n") for part in err[1:].split("\r")]


@pytest.mark.parametrize("columns", [0, 20, 40, 70, 200])
def test_terminal_line_stays_inside_the_terminals_width(columns, capsys, fake_clock):
    """The optimizer's redrawn line never wraps (a wrapped line scrolls at every redraw): the
    bar narrows to 8 characters, then goes, then the text keeps its first whole words."""
    from scratchfab.cli.options import RedrawnLine

    report = progress_printer(lambda text: None, RedrawnLine(columns=lambda: columns))
    report(Progress(0, 300, math.nan, 0.0, math.nan, "compiling kernels"))
    step = Progress(150, 300, 0.01234, 12.0, 12.0)
    report(step)
    report(Progress(300, 300, 0.01, 24.0, 0.0))
    lines = drawn_lines(capsys.readouterr().err)
    assert len(lines) == 3
    text = "150/300 loss 0.01234  elapsed 00:12  eta 00:12"
    for line in lines:
        assert "\n" not in line
        assert not columns or len(line) <= columns - 1
    room = columns - 1
    width = 28 if not columns else min(28, room - len(text) - 3)
    if width >= 8:  # 0 (a terminal that does not say), 70 and 200
        assert lines[0] == "compiling kernels..."
        found = re.fullmatch(r"\[(#*)(\.*)\] (.*)", lines[1])
        assert found and found[3] == text
        assert (len(found[1]), len(found[2])) == (width // 2, width - width // 2)
        assert lines[2].startswith(f"[{'#' * width}] 300/300 ")
    else:  # no bar, the words that fit
        assert lines[0] == whole_words("compiling kernels...", room)
        assert lines[1] == whole_words(text, room)
        assert lines[1] == {20: "150/300 loss", 40: "150/300 loss 0.01234  elapsed 00:12"}[columns]


def test_redrawn_line_blanks_the_last_within_the_width(capsys):
    """A shorter line is padded with spaces over the last one, never past the terminal's
    width (it may have narrowed since); a word longer than the line is cut where it ends."""
    from scratchfab.cli.options import RedrawnLine

    columns = [200]
    line = RedrawnLine(columns=lambda: columns[0])
    line("a" * 20 + " b", False)
    columns[0] = 12
    line("c" * 30, False)
    line("d d", False)
    line("e", True)
    line("f", False)
    assert drawn_lines(capsys.readouterr().err) == [
        "a" * 20 + " b",
        "c" * 11,
        "d d" + " " * 8,
        "e" + " " * 2,
        "f",
    ]
