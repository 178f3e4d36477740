"""report.html's heading and stream lines over the stream's outcomes, and its move counts.

A plotter owner read "Ready to cut" over "The board is cut" after a finished stream, "the
last stream finished: it failed" after a failed one, and "cutting moves (G1) 2502" where
the plotter's G1 travel was counted with its cuts.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from scratchfab.export.gcode import gcode_text
from scratchfab.machine.profile import load_profile
from scratchfab.pipeline.report import write_report
from scratchfab.toolpath import Toolpath
from tests.test_report import GCODE, _journal, _verdict, fake_job

REASON = "the controller reset itself during check mode; nothing more was sent"
PORT = "/dev/ttyUSB0"
#: The manifest's statuses and how the stream's lines say them.
SAID = {"failed": "failed", "interrupted": "was interrupted", "running": "did not finish"}


def _cuts_by_hand(gcode: str) -> int:
    """The XY moves between a plunge below Z 0 and the next lift (a Z-mode file)."""
    down = False
    cuts = 0
    for line in gcode.splitlines():
        z = re.search(r"Z(-?[\d.]+)", line)
        if z:
            down = float(z.group(1)) < 0
        elif down and re.match(r"G[01] .*[XY]", line):
            cuts += 1
    return cuts


def _outcome(job: Path, status: str, started: str) -> None:
    entry = {"status": status, "started": started}
    if status != "running":  # a killed run records no reason
        entry["reason"] = REASON
    stages = {"export": {"status": "done"}, "stream": entry}
    (job / "manifest.json").write_text(json.dumps({"stages": stages}))


def _next(page: str) -> str:
    found = re.search(r"<ol data-next='([\w-]+)'>", page)
    assert found
    return found.group(1)


LINES = len([ln for ln in GCODE.splitlines() if ln.strip()])
CUT = (
    f"The board is cut: {_cuts_by_hand(GCODE)} scratch, all {LINES} G-code lines streamed to "
    f"the machine on {PORT}"
)


# (journal: None or (acked, finished, port)), manifest status of stream (None: done),
# whether the stream began after the journal's session (the same second: its own)
@pytest.mark.parametrize(
    ("journal", "status", "own", "verdict", "head", "steps"),
    [
        (None, None, True, "ready", "Ready to cut", "not-streamed"),
        ((LINES, True, "grblsim://"), None, True, "ready", "Ready to cut", "emulator"),
        ((3, False, "grblsim://"), None, True, "ready", "Ready to cut", "emulator"),
        ((LINES, True, PORT), None, True, "cut", CUT, "cut"),
        (
            (LINES, True, None),
            None,
            True,
            "cut",
            f"Streamed to the end (1 scratch, {LINES} G-code lines) to a port this report "
            "does not know: the board is cut if that port is your machine",
            "not-streamed",
        ),
        (
            (3, False, PORT),
            None,
            True,
            "not-ready",
            f"Not ready: the cut stopped after 3 of {LINES} lines",
            "resume",
        ),
        ((3, False, PORT), "failed", True, "not-ready", "Not ready: the stream failed", "resume"),
        ((LINES, True, PORT), "failed", False, "not-ready", "Not ready: the stream failed", "fix"),
        (
            (LINES, True, PORT),
            "interrupted",
            False,
            "not-ready",
            "Not ready: the stream was interrupted",
            "fix",
        ),
        (None, "running", True, "not-ready", "Not ready: the stream did not finish", "fix"),
    ],
)
def test_the_heading_follows_the_streams_outcome(
    tmp_path, journal, status, own, verdict, head, steps
):
    job = fake_job(tmp_path)
    if journal is not None:
        acked, finished, port = journal
        _journal(job, acked=acked, finished=finished, port=port)  # began 2026-01-01T00:00:00
    if status is not None:
        _outcome(job, status, "2026-01-01T00:00:00" if own else "2026-01-02T09:00:00")
    page = write_report(job).read_text()
    got, heading, lines = _verdict(page)
    assert (got, heading, _next(page)) == (verdict, head, steps)
    said = [t for s, t in lines if s == "fail" and "stream" in t]
    if status is not None:
        why = "" if status == "running" else f": {REASON}"
        assert said == [f"✘ no stream: the last one {SAID[status]}{why}"]
    elif steps == "resume":
        assert said == [
            f"✘ no stream: the cut stopped after 3 of {LINES} lines (its journal records no end)"
        ]
    else:
        assert said == []
    assert "finished: it" not in page
    if "The board is cut" in head:  # the heading and the steps say the same
        assert "The board is cut. Lift the tool" in page


def test_a_cut_board_names_its_warnings_and_its_failing_checks(tmp_path):
    job = fake_job(tmp_path)  # rho 0.912 and 0.877: right the weakest
    _journal(job, acked=LINES, finished=True, port=PORT)
    _, head, lines = _verdict(write_report(job, port=PORT, min_rho=0.85).read_text())
    warns = [t for s, t in lines if s == "warn"]
    assert len(warns) == 1 and "weakest view: right" in warns[0]
    assert head == f"{CUT} (read the 1 warning below)"
    verdict, head, _ = _verdict(write_report(job, port=PORT, min_rho=0.9).read_text())
    assert (verdict, head) == (
        "cut",
        f"{CUT}, though 1 check below fails: right rho 0.876 below 0.9",
    )
    _, head, _ = _verdict(write_report(job, port=PORT, min_rho=0.95).read_text())
    assert head.endswith(
        ", though 2 checks below fail: right rho 0.876 below 0.95; left rho 0.912 below 0.95"
    )


def _stats(page: str) -> dict[str, str]:
    return dict(re.findall(r"<td data-stat='gcode\.(\w+)'>([^<]*)</td>", page))


@pytest.mark.parametrize("name", ["grbl-plotter-scribe", "grbl-3018-diamond"])
def test_cutting_moves_are_the_strokes_not_every_g1(tmp_path, name):
    """A servo plotter travels with G1 (and a Z machine plunges with it): neither is a cut."""
    job = fake_job(tmp_path)
    profile = load_profile(name)
    x, y = profile.board.offset_mm
    rng = np.random.default_rng(7)
    strokes = np.stack(
        [rng.uniform([x + 1, y + 1], [x + 50, y + 30], (5, 2)) for _ in range(2)], axis=1
    )
    outline = np.array([[x, y], [x + 60, y], [x + 60, y + 40], [x, y + 40]], dtype=np.float64)
    toolpath = Toolpath(strokes, np.arange(5), (60.0, 40.0), outline, profile, {})
    text = gcode_text(toolpath)
    (job / "export" / "board.gcode").write_text(text)
    stats = _stats(write_report(job).read_text())
    words = [ln.split()[0] for ln in text.splitlines() if ln and not ln.startswith("(")]
    assert stats["cuts"] == str(len(strokes))
    assert (stats["G0"], stats["G1"]) == (str(words.count("G0")), str(words.count("G1")))
    travel = profile.feeds.travel_mm_min is not None
    assert travel == (name == "grbl-plotter-scribe")  # the two kinds of G1 this test covers
    # G1 besides the cuts: a servo's travel (to the start, each stroke, back), Z's plunges
    assert int(stats["G1"]) - len(strokes) == (len(strokes) + 2 if travel else len(strokes))
    assert "cutting moves (G1)" not in write_report(job).read_text()


def test_moves_are_counted_in_the_modal_motion_mode_and_cuts_only_where_known(tmp_path):
    job = fake_job(tmp_path)
    gcode = job / "export" / "board.gcode"
    # a line without its G word moves in the mode before; G28 is neither G0 nor G1
    gcode.write_text("G21\nG0 Z5\nG0 X1 Y1\nG1 Z-0.1 F200\nG1 X5 Y5 F600\nX6 Y7\nG0 Z5\nG28\nM2\n")
    stats = _stats(write_report(job).read_text())
    assert (stats["G0"], stats["G1"], stats["cuts"]) == ("3", "3", "2")
    # no Z and no tool output: the sender cannot tell a cut from travel, nor can the report
    gcode.write_text("G21\nG0 X1 Y1\nG1 X5 Y5 F600\nG0 X0 Y0\nM2\n")
    stats = _stats(write_report(job).read_text())
    assert (stats["G0"], stats["G1"]) == ("2", "1") and "cuts" not in stats
