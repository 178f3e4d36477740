"""``--resume --zero-here`` on a controller that kept the run's zero (it did not reset).

A controller that sends no banner as its port opens did not reset then: it kept its
machine position, and the work zero the run set. Zeroing again where the tool stopped
would shift the rest of the job from what was cut: refused under ``--yes`` and asked
otherwise, unless the tool stands where the run's zero was set. The pty emulator keeps its
state across connections and boots only once, before the first one.
"""

from __future__ import annotations

import time

import pytest
import serial
from test_stream import read_record
from test_stream_cli_input import _stream
from test_stream_lift import servo_job

from scratchfab.errors import ScratchfabError
from scratchfab.machine.grblsim import SimOptions
from scratchfab.machine.grblsim_pty import GrblPty
from scratchfab.machine.sender_journal import default_journal_path, read_journal

PLOTTER = "grbl-plotter-scribe"


def _jog(path: str, line: str) -> None:
    """Send one jog to the pty controller as a person would, and wait until it is done."""
    with serial.Serial(path, 115200, timeout=0.2) as port:
        port.write(line.encode() + b"\n")
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            port.write(b"?")
            if b"<Idle" in port.read(4000):
                return
        raise AssertionError("the jog did not end")


@pytest.mark.parametrize("back", [False, True])
def test_a_resume_does_not_zero_again_where_the_controller_kept_the_zero(tmp_path, back):
    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=3)
    rec = tmp_path / "rec.jsonl"
    options = SimOptions(
        baud=0, time_scale=0.01, wco=(12, -7, 0), error_at=60, record=str(rec),
        settings={130: 300, 131: 200},
    )  # fmt: skip
    base = [str(job), "--port", "", "--machine", PLOTTER, "--zero-here"]
    with GrblPty(options) as pty:
        pty.start()
        base[2] = pty.path
        code, _, err = _stream([*base, "--yes"], "")
        assert code == 3, err
        assert "no banner" in err  # booted before the port opened: it keeps what it has
        assert "add --zero-here" not in err  # no advice to zero again on resuming
        events = read_journal(default_journal_path(job))
        stop, was = events[-1], events[0]["wco"]
        assert stop["ev"] == "stop" and not stop.get("lost")
        if back:  # the tool back where the zero was set (machine 0, 0 at that connection)
            _jog(pty.path, "$J=G53 G21 G90 X0 Y0 F3000")
        for answer in ("", "n\n"):
            args = [*base, "--resume"] + (["--yes"] if not answer else [])
            code, out, err = _stream(args, answer)
            if back:
                assert code == 0, err
                break
            shift = [stop["mpos"][k] for k in (0, 1)]  # mpos less the zero's 0, 0
            moved = f"move the rest X{round(shift[0], 3):+g} Y{round(shift[1], 3):+g} mm"
            last = err.rstrip().splitlines()[-1]
            assert code == 2 and moved in err and "Traceback" not in err, err
            assert "resume without --zero-here" in last and "nothing was sent" in last
            assert ("--yes" in last) is not answer
        if not back:  # the resume without the flag: the kept zero, the strokes in place
            code, out, err = _stream([*base[:-1], "--resume", "--yes"], "")
            assert code == 0, err
    starts = [e for e in read_journal(default_journal_path(job)) if e["ev"] == "start"]
    assert starts[-1]["wco"][:2] == pytest.approx(was[:2], abs=0.01)
    zeroes = [e for e in read_record(rec) if e["ev"] == "rx" and e["text"].startswith("G21G10")]
    assert len(zeroes) == (2 if back else 1)  # a refusal sent none


def test_no_answer_to_the_zero_question_names_yes_as_its_answer(tmp_path):
    """--yes answers --zero-here's question (it says the tool stands at the point)."""
    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=1)
    rec = tmp_path / "rec.jsonl"
    port = f"grblsim://?baud=0&time_scale=0.01&wco=12,-7,0&$130=300&$131=200&record={rec}"
    code, _, err = _stream([str(job), "--port", port, "--machine", PLOTTER, "--zero-here"], "")
    last = err.rstrip().splitlines()[-1]
    assert code == 2 and last.startswith("error: no answer came"), err
    assert "--yes refuses" not in last and "pass --yes, which says the tool stands" in last
    assert not any(e["text"].startswith("G21G10") for e in read_record(rec) if e["ev"] == "rx")
    # and --yes indeed answers it: the zero is set, the job streamed
    code, _, err = _stream(
        [str(job), "--port", port, "--machine", PLOTTER, "--zero-here", "--yes"], ""
    )
    assert code == 0, err


def test_run_names_zero_here_where_the_stream_says_to_add_it(tmp_path):
    """`run` turns the stream's stop advice into its own: the stream's "add --zero-here"
    stands, with no "add --homed" after it (--zero-here stands for --homed)."""
    from scratchfab.pipeline.runner import as_run_advice

    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=3)
    port = "grblsim://?baud=0&time_scale=0.01&wco=12,-7,0&$130=300&$131=200&reset_after=40"
    code, _, err = _stream(
        [str(job), "--port", port, "--machine", PLOTTER, "--zero-here", "--yes"], ""
    )
    assert code == 3, err
    text = err[err.index("error: ") + len("error: ") :].split("\nreport:")[0].rstrip()
    assert "add --zero-here" in text and "may be lost" in text  # the stream's own advice
    advice = as_run_advice(text)
    assert "--homed" not in advice
    assert "run it again with --zero-here and it resumes" in advice


def test_the_zero_question_says_where_the_first_travel_goes(tmp_path):
    """The question names the job's first travel, from the board's point: which way the
    tool moves once the zero is set."""
    from scratchfab.machine.profile import load_profile
    from scratchfab.machine.stream_job import StreamCallbacks, StreamRequest, stream_file

    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=1)
    first = next(line for line in job.read_text().splitlines() if " X" in line)
    words = dict((w[0], float(w[1:])) for w in first.split()[1:] if w[0] in "XY")
    x, y = load_profile(PLOTTER).board.offset_mm
    port = "grblsim://?baud=0&time_scale=0&wco=12,-7,0&$130=300&$131=200"
    asked: list[str] = []

    def no(question: str) -> bool:
        asked.append(question)
        return False

    request = StreamRequest(job, port, machine=PLOTTER, zero_here=True, banner_timeout=0.3)
    with pytest.raises(ScratchfabError, match="not confirmed"):
        stream_file(request, StreamCallbacks(lambda _: None, print, lambda: "stop", no))
    dx, dy = words["X"] - x, words["Y"] - y
    expected = f"first travel goes to X{words['X']:g} Y{words['Y']:g}, X{dx:+g} Y{dy:+g} mm from it"
    assert expected in asked[0]


def test_a_failed_check_after_the_zero_was_set_says_so(tmp_path):
    """--zero-here sets the zero before check mode: its failure says that the zero changed."""
    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=1)
    rec = tmp_path / "rec.jsonl"
    port = f"grblsim://?baud=0&time_scale=0&wco=12,-7,0&$130=300&$131=200&error_at=3&record={rec}"
    args = [str(job), "--port", port, "--machine", PLOTTER, "--zero-here", "--yes", "--check"]
    code, _, err = _stream(args, "")
    last = err.rstrip().splitlines()[-1]
    assert code == 2 and "check mode found 1 problem(s)" in last, err
    sent = next(e["text"] for e in read_record(rec) if e["ev"] == "rx" and "G10" in e["text"])
    assert sent.startswith("G21G10L20P0")  # the zero went out before check mode
    assert "nothing moved (the work zero was set: `G10 L20 P0 X" in last


def test_zero_here_reads_the_machine_position_from_wpos_reports_and_the_offset(tmp_path):
    """$10=0 on a build whose reports carry no WCO: `$#`'s offset and WPos give MPos."""
    from scratchfab.machine.profile import load_profile

    job = tmp_path / "plot.gcode"
    servo_job(job, strokes=1)
    rec = tmp_path / "rec.jsonl"
    port = (
        "grblsim://?baud=0&time_scale=0&wco=12,-7,0&$130=300&$131=200&$10=0&wco_field=0"
        f"&record={rec}"
    )
    code, _, err = _stream(
        [str(job), "--port", port, "--machine", PLOTTER, "--zero-here", "--yes"], ""
    )
    assert code == 0, err
    x, y = load_profile(PLOTTER).board.offset_mm
    start = next(e for e in read_record(rec) if e["ev"] == "exec")["frm"]
    assert start[:2] == pytest.approx([x, y])  # the tool stood at the board's corner
