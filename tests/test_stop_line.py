"""The user's stop names where the machine stopped, not only the last line GRBL took.

GRBL takes lines up to a planner full ahead of the machine: after Ctrl-C the last
acknowledged line lies well past the one the machine stood in. The stop's message also
names the last line the machine surely ran and the line ``--resume`` restarts at, both
as the journal has them (its ``executed_through``, and ``resume_point`` of the blocks it
counts done, as ``stream --resume`` reads them).
"""

from __future__ import annotations

import re

from stream_helpers import executed_blocks, interrupt_after, stream_program, stroke_job

from scratchfab.machine.sender import StreamStopped, open_port
from scratchfab.machine.sender_journal import done_blocks, read_journal
from scratchfab.machine.sender_program import load_program, resume_point


def test_the_users_stop_names_the_line_the_machine_ran_to_and_the_resumes_start(tmp_path):
    job = tmp_path / "job.gcode"
    stroke_job(job, 30)
    prog = load_program(job)
    progress = interrupt_after(40)
    port = open_port("grblsim://?baud=0&time_scale=0.05", 115200)
    try:
        try:
            stream_program(
                port, prog, tmp_path / "j.jsonl", on_progress=progress, ask_interrupt=lambda: "stop"
            )
        except StreamStopped as exc:
            text = str(exc)
    finally:
        port.close()
    events = read_journal(tmp_path / "j.jsonl")
    through = events[-1]["executed_through"]
    acked = [e["line"] for e in events if e["ev"] == "ack" and "line" in e]
    restart = resume_point(prog, done_blocks(events, prog.sha256, "j", program=prog))
    got = re.match(
        r"stopped by the user after line (\d+) \(the last one GRBL accepted; the machine had "
        r"run through line (\d+): a resume restarts at line (\d+)\); machine held",
        text,
    )
    assert got is not None, text
    assert int(got[1]) == acked[-1]
    assert int(got[2]) == prog.blocks[through].lineno < acked[-1]  # a planner full behind
    assert int(got[3]) == prog.blocks[restart].lineno
    ran = executed_blocks(port.sim.record)
    assert all(i in ran for i in range(through + 1) if prog.blocks[i].motion)
