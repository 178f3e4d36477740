"""`stream` rests by default: a stop at a travel's end is then not cut again on --resume.

The sender's rests (StreamOptions.rests: up to 24 a session it feeds nothing after a move
whose end GRBL's step rounding leaves open, tool up, until the controller stands there)
were off wherever stream built its options, so the CLI and the pipeline never took one
(test_stop_rest shows what one buys). Now on: the stream rests, within the limit, only
where the tool is up, and cuts every stroke once.
"""

from __future__ import annotations

from stream_helpers import spy_rests
from test_stream import cut_counts, read_record, write_job
from test_stream_cli_input import _stream

from scratchfab.machine.sender_program import load_program
from scratchfab.machine.stream_job import REST_LIMIT

#: 800 steps/mm and an offset with more digits than $# prints, no WCO: field: rounding is open
URL = (
    "grblsim://?baud=0&time_scale=0&wco=-100.12345,-80.54321,-30.98765&wco_field=0"
    "&$100=800&$101=800&$102=800&$130=300&$131=180&$132=45"
)


def test_stream_rests_where_the_tool_is_up_and_within_the_limit(tmp_path, monkeypatch):
    job = tmp_path / "job.gcode"
    cuts = write_job(job, 40)
    prog = load_program(job)
    rested = spy_rests(monkeypatch)
    rec = tmp_path / "rec.jsonl"
    code, out, err = _stream([str(job), "--port", f"{URL}&record={rec}", "--yes"], "")
    assert code == 0, err
    assert "done:" in out
    assert 0 < len(rested) <= REST_LIMIT  # it rested, no more than the limit
    for j in rested:  # the travel height of write_job is Z2, its cuts Z-0.05
        assert prog.blocks[j].modal.z is not None and prog.blocks[j].modal.z > 0, j
    assert cut_counts([read_record(rec)], cuts) == [1] * len(cuts)
