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
    report = progress_printer(said.append, lambda text, done: drawn.append((text, done)))
    report(Progress(0, 5, math.nan, 0.0, math.nan, "compiling kernels"))
    for p in steps(5):
        report(p)
    assert said == []
    assert drawn[0] == ("compiling kernels...", True)
    assert [int(BAR.fullmatch(text)[3]) for text, _ in drawn[1:]] == [1, 2, 3, 4, 5]
    assert [done for _, done in drawn[1:]] == [False] * 4 + [True]
