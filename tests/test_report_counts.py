"""report.html's G-code line counts: the file's lines and the ones stream sends.

A maker read 7210 lines in the report and 7206 "lines" from stream: the report counted
the file's comment lines, which the sender drops. The report now gives both, the sent
count being the one stream and the journal give.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from scratchfab.machine.stream_job import StreamCallbacks, StreamRequest, stream_file
from scratchfab.pipeline.report import write_report
from tests.test_report import fake_job

# Comments of both kinds, blank and whitespace-only lines, a comment-only line after code.
GCODE = (
    "(scratchfab toolpath for a test)\n"
    "(board top edge, design +y, faces machine +Y)\n"
    "G21\n"
    "\n"
    "G90 ; absolute\n"
    "G0 Z5\n"
    "   \n"
    "G0 X1 Y1 (to the start)\n"
    "; a whole-line comment\n"
    "G1 Z-0.1 F200\n"
    "G1 X5 Y5 F600\n"
    "G0 Z5\n"
    "M2\n"
)


def _stats(page: str) -> dict[str, str]:
    return dict(re.findall(r"<td data-stat='gcode\.(\w+)'>([^<]*)</td>", page))


def test_the_report_counts_the_lines_stream_sends_beside_the_files(tmp_path):
    job = fake_job(tmp_path)
    gcode = job / "export" / "board.gcode"
    gcode.write_text(GCODE)
    alone = tmp_path / "alone.gcode"  # outside the job: stream reads no toolpath beside it
    alone.write_text(GCODE)
    said: list[str] = []
    request = StreamRequest(gcode=alone, port="grblsim://?time_scale=0")
    callbacks = StreamCallbacks(lambda p: None, said.append, lambda: "stop", lambda _: True)
    stream_file(request, callbacks)
    done = re.search(r"done: (\d+) lines acknowledged", said[-1])
    assert done, said
    streamed = int(done.group(1))
    # Independently: GRBL drops (...) and ; comments and whitespace; an empty line is not sent.
    by_hand = sum(1 for ln in GCODE.splitlines() if re.sub(r"\(.*?\)|;.*|\s", "", ln))
    assert streamed == by_hand == 8
    journal = Path(f"{alone}.journal.jsonl")
    start = json.loads(journal.read_text().splitlines()[0])
    assert start["blocks"] == streamed
    (job / "stream").mkdir(exist_ok=True)
    journal.replace(job / "stream" / "journal.jsonl")
    page = write_report(job, port="grblsim://?time_scale=0").read_text()
    stats = _stats(page)
    assert stats["lines"] == str(len(GCODE.splitlines())) and stats["sent"] == str(streamed)
    # The Stream section counts the same lines.
    assert f"<span data-stat='stream.lines'>{streamed}</span>" in page
    assert "lines sent to the machine" in page and "lines in the file" in page


def test_a_file_stream_refuses_says_so_in_place_of_the_sent_count(tmp_path):
    job = fake_job(tmp_path)
    gcode = job / "export" / "board.gcode"
    gcode.write_text("G21\nG0 X1\n$H\n")  # homing in a job: stream refuses it
    stats = _stats(write_report(job).read_text())
    assert stats["lines"] == "3"
    assert stats["sent"].startswith("none: stream refuses the file (board.gcode:3: ")
    assert str(tmp_path) not in stats["sent"]
