"""The stream's progress line: one formatter and one pacing, for ``stream`` and the pipeline."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
from test_stream import write_job

from scratchfab.cli import main, options
from scratchfab.cli.stream_cmd import _ProgressLine
from scratchfab.machine import stream_job
from scratchfab.machine.sender import StreamProgress
from scratchfab.machine.stream_job import (
    ProgressLines,
    StreamCallbacks,
    StreamRequest,
    progress_text,
    run_stream_job,
)
from scratchfab.model.job import JobLayout

# (acked, total, eta_s, state, wpos, final[, ran]), elapsed_s, the line as a person should
# read it
TABLE = [
    # every line acknowledged, 125 of them still queued in GRBL's planner: not 100 %
    (
        (1000, 1000, 5.2, "Run", (1.0, 2.0, -0.1), False, 875),
        65.2,
        " 87.5% 875/1000 lines  elapsed 01:05  ETA 00:06  Run X1.00 Y2.00 Z-0.10",
    ),
    ((8, 8, 0.0, "Idle", None, True, 8), 6.0, "100.0% 8/8 lines  elapsed 00:06  ETA 00:00  Idle"),
    (
        (420, 1000, 184.4, "Run", (1.0, 2.0, -0.1), False),
        65.2,
        " 42.0% 420/1000 lines  elapsed 01:05  ETA 03:05  Run X1.00 Y2.00 Z-0.10",
    ),
    (
        (0, 80000, math.inf, "Idle", None, False),
        0.0,
        "  0.0% 0/80000 lines  elapsed 00:00  ETA --:--  Idle",
    ),
    (
        (80000, 80000, 0.0, "Idle", (-0.001, 0.004, 5.0), True),
        3723.4,
        "100.0% 80000/80000 lines  elapsed 1:02:03  ETA 00:00  Idle X0.00 Y0.00 Z5.00",
    ),
    ((0, 0, 0.0, "Idle", None, True), 0.2, "100.0% 0/0 lines  elapsed 00:00  ETA 00:00  Idle"),
    (
        (999, 1000, 0.4, "Hold:0", (-12.346, 100.0, -0.004), False),
        59.6,
        " 99.9% 999/1000 lines  elapsed 01:00  ETA 00:01  Hold:0 X-12.35 Y100.00 Z0.00",
    ),
    # cut, not rounded: 99.99 % is not done, 2/3 is not yet 66.7 %
    (
        (79999, 80000, 0.8, "Run", (0.0, 0.0, -0.05), False),
        3600.0,
        " 99.9% 79999/80000 lines  elapsed 1:00:00  ETA 00:01  Run X0.00 Y0.00 Z-0.05",
    ),
    ((2, 3, 1.0, "Run", None, False), 2.0, " 66.6% 2/3 lines  elapsed 00:02  ETA 00:01  Run"),
    (
        (5, 7, 7322.0, "Door:1", (0.0, 0.0, 2.0), False),
        3599.6,
        " 71.4% 5/7 lines  elapsed 1:00:00  ETA 2:02:02  Door:1 X0.00 Y0.00 Z2.00",
    ),
]


@pytest.mark.parametrize(("report", "elapsed", "want"), TABLE)
def test_progress_text(report, elapsed, want):
    assert progress_text(StreamProgress(*report), elapsed) == want


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _paced(reports):
    """The lines :meth:`ProgressLines.line` lets through for (time, report) pairs."""
    clock = FakeClock()
    lines = ProgressLines(now=clock)
    out = []
    for t, report in reports:
        clock.t = t
        text = lines.line(report)
        if text is not None:
            out.append((t, text))
    return out


def _linear_job(seconds: float, total: int, hz: int = 5):
    """Reports at ``hz`` of a job acknowledging ``total`` lines evenly over ``seconds``."""
    n = int(seconds * hz)
    for k in range(n + 1):
        acked = k * total // n
        eta = seconds - k / hz
        yield k / hz, StreamProgress(acked, total, eta, "Run", (0.0, 0.0, 0.0))
    yield seconds + 0.3, StreamProgress(total, total, 0.0, "Idle", (0.0, 0.0, 2.0), final=True)


def test_a_short_job_prints_a_line_at_each_tenth_and_the_end():
    shown = _paced(_linear_job(10.0, 1000))
    percents = [text.split("%")[0].strip() for _, text in shown]
    assert percents == [f"{10 * k}.0" for k in range(10)] + ["100.0"]
    # the 100 % line is the final report's: the controller Idle, not a report before it
    assert shown[-1] == (10.3, "100.0% 1000/1000 lines  elapsed 00:10  ETA 00:00  Idle "
                               "X0.00 Y0.00 Z2.00")  # fmt: skip


def test_a_long_job_prints_a_line_a_minute_between_tenths():
    """An hour's job: its tenths are 6 minutes apart, with a line each minute between them."""
    shown = _paced(_linear_job(3600.0, 80000))
    times = [t for t, _ in shown]
    assert times == [60.0 * k for k in range(60)] + [3600.3]
    assert "elapsed 12:00  ETA 48:00" in shown[12][1]


def test_a_held_job_still_prints_a_line_a_minute():
    """A hold, a door or a paused M0: nothing moves, and the log still says so each minute."""
    reports = [(0.0, StreamProgress(1, 100, 50.0, "Run", None))]
    reports += [(0.2 * k, StreamProgress(2, 100, 49.0, "Hold:0", None)) for k in range(1, 1600)]
    shown = _paced(reports)
    assert [t for t, _ in shown] == [0.0, 60.0, 120.0, 180.0, 240.0, 300.0]
    assert all(text.endswith("Hold:0") for _, text in shown[1:])


def test_the_clock_starts_at_the_first_report():
    clock = FakeClock()
    clock.t = 100.0  # the connection, check mode and the confirmation took this long
    lines = ProgressLines(now=clock)
    clock.t = 130.0
    assert "elapsed 00:00" in lines.text(StreamProgress(0, 10, 5.0, "Idle", None))
    clock.t = 142.0
    assert "elapsed 00:12" in lines.text(StreamProgress(3, 10, 3.0, "Run", None))


def test_the_terminal_bar_draws_the_formatters_text(capsys, monkeypatch):
    monkeypatch.setattr(options, "terminal_columns", lambda: 0)  # a terminal that does not say
    bar = _ProgressLine()
    bar.tty = True
    report = StreamProgress(7, 28, 12.0, "Run", (1.0, -2.0, -0.05))
    bar(report)
    bar.end()
    err = capsys.readouterr().err
    assert err == f"\r[#######.....................] {progress_text(report, 0.0)}\n"


@pytest.mark.parametrize("columns", [200, 120, 100, 80, 60])
def test_the_terminal_bar_stays_inside_the_terminals_width(columns, capsys, monkeypatch):
    """A line as wide as the terminal wraps, and every redraw would then start a row lower."""
    monkeypatch.setattr(options, "terminal_columns", lambda: columns)
    report = StreamProgress(33600, 80000, 2880.0, "Run", (-123.45, -167.89, -0.05))
    text = progress_text(report, 0.0)
    assert len(text) == 80  # an 80k-line job's line, without the bar
    bar = _ProgressLine()
    bar.tty = True
    bar(report)
    bar.end()
    line = capsys.readouterr().err.removeprefix("\r").removesuffix("\n")
    assert len(line) <= columns - 1
    if columns >= 80 + 4 + 8:  # the text, brackets and a space, and a bar of 8 at least
        found = re.fullmatch(r"\[(#*)(\.*)\] (.*)", line)
        assert found and found.group(3) == text, line
        width = len(found.group(1)) + len(found.group(2))
        assert width == min(28, columns - 1 - 80 - 3)
        assert len(found.group(1)) == int(0.42 * width)
    else:  # no bar; the words that fit, none cut (the 80: all but Z, not Z-0.0)
        kept = " 42.0% 33600/80000 lines  elapsed 00:00  ETA 48:00  Run X-123.45 Y-167.89"
        assert (
            line
            == {80: kept, 60: " 42.0% 33600/80000 lines  elapsed 00:00  ETA 48:00  Run"}[columns]
        )


def _marked(monkeypatch):
    """Replace the formatter by one that marks its lines: who prints them uses it."""
    monkeypatch.setattr(
        stream_job, "progress_text", lambda p, elapsed: f"MARK {p.acked}/{p.total} {p.final}"
    )


LINE = re.compile(
    r" *\d+\.\d% \d+/\d+ lines  elapsed \d\d:\d\d  ETA (\d\d:\d\d|--:--)  \S+"
    r"( X-?\d+\.\d\d Y-?\d+\.\d\d Z-?\d+\.\d\d)?"
)


def test_the_stream_command_prints_the_formatters_lines(tmp_path, capsys, monkeypatch):
    job = tmp_path / "job.gcode"
    write_job(job, 20)
    args = ["stream", str(job), "--port", "grblsim://?baud=0&time_scale=0.01", "--yes"]
    main([*args, "--banner-timeout", "0.3"])
    err = capsys.readouterr().err.splitlines()
    shown = [line for line in err if " lines  " in line]
    assert shown and all(LINE.fullmatch(line) for line in shown), shown
    assert shown[-1].startswith("100.0% 103/103 lines  elapsed ")
    assert " ETA 00:00  Idle X" in shown[-1]
    notes = [line for line in err if line.startswith("emulator at time_scale 0.01: ")]
    assert len(notes) == 1 and err.index(notes[0]) < err.index(shown[0])
    _marked(monkeypatch)
    main([*args, "--banner-timeout", "0.3"])
    err = capsys.readouterr().err.splitlines()
    marks = [line for line in err if line.startswith("MARK ")]
    assert marks and marks[-1] == "MARK 103/103 True"
    assert not [line for line in err if " lines  " in line]


def _exported_job(root: Path) -> JobLayout:
    """A job folder whose export/board.gcode holds a 20-stroke job, for the stream stage."""
    layout = JobLayout(root)
    gcode = layout.export_file("gcode")
    gcode.parent.mkdir(parents=True)
    write_job(gcode, 20)
    return layout


def test_the_pipelines_stream_stage_prints_the_formatters_lines(tmp_path, monkeypatch):
    layout = _exported_job(tmp_path / "job")
    said: list[str] = []
    run_stream_job(layout.root, "grblsim://?baud=0&time_scale=0.01", say=said.append)
    shown = [line for line in said if " lines  " in line]
    assert shown and all(line.startswith("  ") and LINE.fullmatch(line) for line in shown), said
    assert shown[-1].startswith("  100.0% 103/103 lines  elapsed ")
    _marked(monkeypatch)
    said.clear()
    run_stream_job(layout.root, "grblsim://?baud=0&time_scale=0.01", say=said.append)
    marks = [line for line in said if "MARK" in line]
    assert marks and marks[-1] == "  MARK 103/103 True", said


@pytest.mark.parametrize("columns", [0, 20, 40, 70, 200])
def test_the_terminal_bar_fits_narrow_terminals(columns, capsys, monkeypatch):
    """The stream's bar is the optimizer's (RedrawnLine): at 20 to 200 columns no redraw
    wraps, the bar narrows and goes, then whole words are kept; 0 columns (unknown): all."""
    from test_optimize_progress import drawn_lines, whole_words

    monkeypatch.setattr(options, "terminal_columns", lambda: columns)
    bar = _ProgressLine()
    bar.tty = True
    reports = [
        StreamProgress(33600, 80000, 2880.0, "Run", (-123.45, -167.89, -0.05)),
        StreamProgress(40000, 80000, 2000.0, "Run", (1.0, 2.0, -0.05)),
        StreamProgress(80000, 80000, 0.0, "Idle", (0.0, 0.0, 5.0), final=True),
    ]
    for report in reports:
        bar(report)
    bar.end()
    lines = drawn_lines(capsys.readouterr().err)
    assert len(lines) == 3
    for line, report in zip(lines, reports, strict=True):
        text = progress_text(report, 0.0)
        assert not columns or len(line) <= columns - 1
        width = 28 if not columns else min(28, columns - 1 - len(text) - 3)
        if width >= 8:
            fill = int(width * report.fraction)
            assert line.rstrip() == f"[{'#' * fill}{'.' * (width - fill)}] {text}"
        else:  # (spaces blank what a longer line before left)
            assert line.rstrip() == whole_words(text, columns - 1)
    words = {20: " 42.0% 33600/80000", 40: " 42.0% 33600/80000 lines  elapsed 00:00"}
    if columns in words:
        assert lines[0] == words[columns]


def _clock_seconds(text: str) -> int:
    """``mm:ss`` or ``h:mm:ss`` as seconds."""
    parts = [int(p) for p in text.split(":")]
    return sum(p * 60**k for k, p in enumerate(reversed(parts)))


def test_the_emulators_eta_counts_its_time_not_a_machines(tmp_path):
    """A stream to the emulator reports the machine's ETA; the emulator's own is that times
    its time_scale, and no less than its serial line needs for the lines left (10 bits a
    byte at its baud; the bytes sent read here from the file itself)."""
    from scratchfab.machine.protocol_grblsim import sim_options
    from scratchfab.machine.sender_program import load_program
    from scratchfab.machine.stream_job import EmulatorEta

    job = tmp_path / "job.gcode"
    write_job(job, 20)
    # what goes over the line: each line without its comments and spaces
    sent = [re.sub(r"\(.*?\)|;.*| ", "", ln) for ln in job.read_text().splitlines()]
    sent = [ln for ln in sent if ln]
    options = sim_options("grblsim://?time_scale=0.01&baud=2400", 115200)
    assert options is not None
    eta = EmulatorEta(options, load_program(job))
    for acked, machine_s in ((0, 600.0), (40, 600.0), (40, 0.5), (len(sent), 0.0)):
        link_s = sum(len(ln) + 1 for ln in sent[acked:]) * 10 / 2400
        report = StreamProgress(acked, len(sent), machine_s, "Run", None)
        assert eta(report).eta_s == pytest.approx(max(machine_s * 0.01, link_s))
        assert eta(report).acked == acked and report.eta_s == machine_s
    assert eta.note(3725.0) == (
        "emulator at time_scale 0.01: elapsed and ETA count its time (on a machine: ETA 1:02:05)"
    )


def test_the_pipelines_stream_eta_runs_with_the_emulators_elapsed(tmp_path):
    """With a time_scale the pipeline's lines give the ETA in the emulator's time (the
    machine's once, in a note): the first line's ETA is about the elapsed time at the end."""
    layout = _exported_job(tmp_path / "job")
    said: list[str] = []
    run_stream_job(layout.root, "grblsim://?baud=0&time_scale=0.02", say=said.append)
    (note,) = [line for line in said if "time_scale" in line]
    machine = re.fullmatch(
        r"  emulator at time_scale 0\.02: elapsed and ETA count its time "
        r"\(on a machine: ETA (\d\d:\d\d)\)",
        note,
    )
    assert machine is not None, note
    shown = [line for line in said if " lines  " in line]
    assert said.index(note) < said.index(shown[0])
    first_eta = _clock_seconds(shown[0].split("ETA ")[1].split()[0])
    assert abs(first_eta - 0.02 * _clock_seconds(machine.group(1))) <= 1
    assert first_eta >= 2  # a machine's ETA of about 2 minutes, scaled
    end = _clock_seconds(shown[-1].split("elapsed ")[1].split()[0])
    assert abs(end - first_eta) <= 1


def test_a_stream_to_the_emulator_reads_the_job_once(tmp_path, monkeypatch):
    """The emulator's ETA uses the program the stream loaded (an 80k-line job takes about
    two seconds to read), at the baud the port opened at (the request's here, which the
    ETA's caller did not give). Both the stream function and the pipeline's stage."""
    from scratchfab.machine import sender_program

    loads: list[Path] = []

    def counted(path, *args, **kwargs):
        loads.append(Path(path))
        return sender_program.load_program(path, *args, **kwargs)

    monkeypatch.setattr(stream_job, "load_program", counted)
    seen: list[StreamProgress] = []
    job = tmp_path / "job.gcode"
    write_job(job, 20)
    port = "grblsim://?time_scale=0"
    progress = stream_job.emulator_progress(port, None, job, seen.append, lambda _: None)
    cb = StreamCallbacks(progress, lambda _: None, lambda: "stop", lambda _: True)
    stream_job.stream_file(StreamRequest(gcode=job, port=port, baud=38400), cb)
    assert loads == [job]
    # time_scale 0: the ETA is what the line needs at 38400 baud for the lines not acked
    sent = [re.sub(r"\(.*?\)|;.*| ", "", ln) for ln in job.read_text().splitlines()]
    sent = [ln for ln in sent if ln]
    first = seen[0]
    link_s = sum(len(ln) + 1 for ln in sent[first.acked :]) * 10 / 38400
    assert first.eta_s == pytest.approx(link_s) and seen[-1].eta_s == 0.0
    loads.clear()
    layout = _exported_job(tmp_path / "job2")
    gcode = layout.export_file("gcode")
    run_stream_job(layout.root, "grblsim://?baud=0&time_scale=0.01", say=lambda _: None)
    assert loads == [gcode]
