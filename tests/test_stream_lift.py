"""The sender raises the tool after it stops a job (``StreamOptions.lift``), on the emulator.

The truth is the emulator's own record: what it received after the stop's soft reset, the
moves it executed and where its machine position ended. Every stop here leaves the tool at
depth (a cut of many short segments keeps GRBL's planner full, so the stop lands inside it)
unless the test says otherwise.
"""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import pytest
from stream_helpers import FAST, interrupt_after, stream_program

from scratchfab.cli import main
from scratchfab.machine.grblsim import DEFAULT_SETTINGS
from scratchfab.machine.profile import Z_UNLIMITED_MM, load_profile, profile_from_mapping
from scratchfab.machine.sender import (
    Status,
    Streamer,
    StreamFault,
    StreamStopped,
    open_port,
)
from scratchfab.machine.sender_journal import Journal, done_blocks, read_journal
from scratchfab.machine.sender_program import load_program, resume_point

LIFT = replace(FAST, lift=True)
SEGMENTS = 60
#: Half the emulator's Z step ($102): Grbl stands on whole steps, so at -0.05 it reports -0.052.
HALF_STEP = 0.5 / DEFAULT_SETTINGS[102] + 1e-6


def z_job(
    path: Path,
    strokes: int = 2,
    travel: float = 2.0,
    depth: float = -0.05,
    clearance: float | None = None,
    x0: float = 0.0,
    y0: float = 0.0,
) -> None:
    """A Z job: each stroke plunges and cuts ``SEGMENTS`` 1 mm segments along X."""
    lines = ["G21 G90 G17 G94"]
    if clearance is not None:
        lines.append(f"G0 Z{clearance:g}")
    lines.append(f"G0 Z{travel:g}")
    for s in range(strokes):
        lines += [f"G0 X{x0:g} Y{y0 + 2 * s:g}", f"G1 Z{depth:g} F200"]
        lines += [f"G1 X{x0 + k:g} F300" for k in range(1, SEGMENTS + 1)]
        lines.append(f"G0 Z{travel:g}")
    if clearance is not None:
        lines.append(f"G0 Z{clearance:g}")
    lines.append("M2")
    path.write_text("\n".join(lines) + "\n")


def servo_job(path: Path, strokes: int = 2) -> None:
    """A plotter job: M3 lowers the scribe, M5 lifts it; no Z."""
    lines = ["G21 G90 G17 G94", "M5"]
    for s in range(strokes):
        lines += [f"G1 X10 Y{10 + 2 * s} F4000", "M3 S60", "G4 P0.15"]
        lines += [f"G1 X{10 + k} F1200" for k in range(1, SEGMENTS + 1)]
        lines += ["M5", "G4 P0.15"]
    lines.append("M2")
    path.write_text("\n".join(lines) + "\n")


def segment_index(prog, x: float) -> int:
    """Index of the first stroke's cut segment ending at ``x``."""
    return next(b.index for b in prog.blocks if b.text.startswith(f"G1X{x:g}F"))


def run(tmp_path, prog, query, options=LIFT, stop_at=None, journal=None, **kwargs):
    """Stream ``prog`` to ``grblsim://?<query>``; returns (exception, messages, emulator).

    ``stop_at``: press Ctrl-C (answered with stop) once that many blocks are acknowledged.
    """
    messages: list[str] = []
    if stop_at is not None:
        kwargs.setdefault("on_progress", interrupt_after(stop_at))
        kwargs.setdefault("ask_interrupt", lambda: "stop")
    port = open_port(f"grblsim://?baud=0&{query}", 115200)
    exc = None
    try:
        stream_program(
            port, prog, journal or tmp_path / "j.jsonl", options, on_message=messages.append,
            **kwargs,
        )  # fmt: skip
    except (StreamFault, StreamStopped) as e:
        exc = e
    finally:
        port.close()
    return exc, messages, port.sim


def after_reset(sim, kind):
    """The emulator's ``kind`` events after the stop's (first) soft reset."""
    reset = next(e["t"] for e in sim.record if e["ev"] == "reset")
    return [e for e in sim.record if e["ev"] == kind and e["t"] > reset]


def lift_record(journal: Path) -> dict:
    stop = read_journal(journal)[-1]
    assert stop["ev"] == "stop"
    return stop["lift"]


def assert_raised_z_only(sim, work_z: float, machine_z: float, depth: float) -> None:
    """One rapid after the reset, from depth straight up to ``work_z``; ends at ``machine_z``.

    Heights within :data:`HALF_STEP`: Grbl stands on whole steps.
    """
    moves = after_reset(sim, "exec")
    assert len(moves) == 1, moves
    move = moves[0]
    assert move["rapid"] and move["frm"][:2] == move["to"][:2]  # no other axis moved
    assert move["frm"][2] == pytest.approx(depth, abs=HALF_STEP)  # it was at depth
    assert move["to"][2] == pytest.approx(work_z, abs=HALF_STEP)
    assert sim.mpos[2] == pytest.approx(machine_z, abs=HALF_STEP)
    assert not any(e["ev"] == "alarm" for e in sim.record)


# --------------------------------------------------------------------------- Z tools


@pytest.mark.parametrize("wco", [(0.0, 0.0, 0.0), (5.0, 7.0, -10.0)])
def test_an_error_mid_stroke_raises_the_tool_to_the_travel_height(tmp_path, wco):
    job = tmp_path / "job.gcode"
    z_job(job)
    prog = load_program(job)
    bad = segment_index(prog, 30)  # parsed once the planner has room: the cut is running
    query = f"time_scale=0.2&error_at={bad + 1}&wco={wco[0]:g},{wco[1]:g},{wco[2]:g}"
    exc, messages, sim = run(tmp_path, prog, query)
    assert isinstance(exc, StreamFault)
    assert f"job.gcode:{prog.blocks[bad].lineno}: error:20" in str(exc)
    # the machine Z is named only where the work offset makes it another number
    height = "Z 2.000" + (f" (machine Z {2 + wco[2]:.3f})" if wco[2] else "")
    assert str(exc).endswith(f"; tool raised to {height}")
    assert f"raising the tool to {height}" in messages
    received = [e["text"] for e in after_reset(sim, "rx")]
    assert received == [f"G21G53G0Z{2 + wco[2]:g}", "G4P0"]
    assert_raised_z_only(sim, 2.0, 2.0 + wco[2], -0.05)
    assert lift_record(tmp_path / "j.jsonl") == {
        "result": "raised",
        "z": 2.0,
        "machine_z": 2.0 + wco[2],
        "from_machine_z": pytest.approx(-0.05 + wco[2], abs=HALF_STEP),
    }


def test_a_users_stop_mid_stroke_raises_the_tool(tmp_path):
    job = tmp_path / "job.gcode"
    z_job(job)
    prog = load_program(job)
    exc, messages, sim = run(tmp_path, prog, "time_scale=0.2", stop_at=segment_index(prog, 20))
    assert isinstance(exc, StreamStopped)
    assert "soft-reset (spindle off); tool raised to Z 2.000; continue" in str(exc)
    assert_raised_z_only(sim, 2.0, 2.0, -0.05)


def test_the_lift_goes_to_the_jobs_height_when_the_reset_clears_g92(tmp_path):
    """The job ran under G92 Z-3 (work zero 3 mm above the G54 one); GRBL's reset clears
    G92, so a lift in work coordinates would stop 3 mm short. G53 places it in the job's."""
    job = tmp_path / "job.gcode"
    z_job(job)
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.2", 115200)
    messages: list[str] = []
    try:
        streamer = Streamer(port, LIFT, on_message=messages.append, ask_interrupt=lambda: "stop")
        streamer.on_progress = _stop_after(segment_index(prog, 20))
        streamer.connect()
        streamer._command("G92Z-3")  # at machine Z 0: work Z -3 there, the offset is +3
        streamer._read_work_offset()
        assert streamer.info.g92 == (0.0, 0.0, 3.0)
        journal = Journal(tmp_path / "j.jsonl").open()
        with pytest.raises(StreamStopped):
            streamer.stream(prog, journal)
        journal.close()
        after = streamer._status_now()
    finally:
        port.close()
    assert after.wco == (0.0, 0.0, 0.0)  # the reset cleared G92
    sim = port.sim
    assert sim.mpos[2] == pytest.approx(5.0)  # work Z 2 of the job's frame
    moves = after_reset(sim, "exec")
    assert len(moves) == 1 and moves[0]["frm"][:2] == moves[0]["to"][:2]
    assert "raising the tool to Z 2.000 (machine Z 5.000)" in messages


_stop_after = interrupt_after


def test_a_tool_already_at_travel_height_is_not_moved(tmp_path):
    job = tmp_path / "job.gcode"
    # a dwell waits until Z2 is reached; the long rapid then runs at Z2 when the error comes
    job.write_text("G21G90\nG0Z2\nG4P0.1\nG0X60\nG0Y1\nG1Z-0.05F200\nG1X61F300\nG0Z2\nM2\n")
    prog = load_program(job)
    exc, messages, sim = run(tmp_path, prog, "time_scale=0.2&error_at=5")
    assert isinstance(exc, StreamFault) and str(exc).endswith("; the tool was already up")
    assert any(
        re.match(r"the tool is at machine Z 2\.000, already at or above", m) for m in messages
    )
    assert after_reset(sim, "rx") == [] and after_reset(sim, "exec") == []
    # stopped before the rapid's end: the reset may come before its first whole step (X 0)
    assert sim.mpos[2] == pytest.approx(2.0) and 0.0 <= sim.mpos[0] < 60.0
    assert lift_record(tmp_path / "j.jsonl")["result"] == "up"


def test_a_foreign_file_is_raised_to_its_own_highest_z(tmp_path):
    """Without a profile the height is the highest Z of the file's moves: its clearance
    Z5 here, above the Z2 it travels at between strokes."""
    job = tmp_path / "job.gcode"
    z_job(job, clearance=5.0)
    prog = load_program(job)
    exc, messages, sim = run(tmp_path, prog, "time_scale=0.2", stop_at=segment_index(prog, 20))
    assert isinstance(exc, StreamStopped)
    assert_raised_z_only(sim, 5.0, 5.0, -0.05)


def test_a_file_without_a_travel_height_is_not_raised_and_says_so(tmp_path):
    """A file that never goes above where it cuts shows no height that clears the board."""
    job = tmp_path / "job.gcode"
    lines = ["G21G90", "G1Z-0.05F200"] + [f"G1X{k}F300" for k in range(1, SEGMENTS)]
    job.write_text("\n".join([*lines, "M2"]) + "\n")
    prog = load_program(job, z_threshold=0.5)
    exc, messages, sim = run(tmp_path, prog, "time_scale=0.2", stop_at=20)
    assert isinstance(exc, StreamStopped)
    assert "the tool was NOT raised (the file shows no travel height" in str(exc)
    assert after_reset(sim, "rx") == []


def _profile(name: str, **tables):
    data = load_profile(name).to_table()
    for table, values in tables.items():
        data[table] = {**data[table], **values}
    return profile_from_mapping(data, f"<{name} for the test>")


def test_a_profile_sets_the_height_not_the_files_highest_z(tmp_path):
    """grbl-3018-diamond (machine coordinates, soft limits, homed): its z.safe_mm -27,
    though the file also rapids to -20."""
    profile = load_profile("grbl-3018-diamond")
    job = tmp_path / "job.gcode"
    z_job(job, travel=-27.0, depth=-30.2, clearance=-20.0, x0=-70.0, y0=-10.0)
    prog = load_program(job)
    options = replace(LIFT, profile=profile)
    exc, messages, sim = run(
        tmp_path, prog, "time_scale=0.2&soft_limits=1&homed=1", options,
        stop_at=segment_index(prog, -50),
    )  # fmt: skip
    assert isinstance(exc, StreamStopped)
    assert_raised_z_only(sim, -27.0, -27.0, -30.2)


def _travel_above_the_machine_top():
    """The 3018 in work coordinates with a travel height (Z 3) above the machine's top."""
    return _profile(
        "grbl-3018-diamond",
        envelope={"coordinates": "work", "z_mm": [-40.0, 5.0]},
        z={"safe_mm": 3.0, "engrave_mm": -2.0},
    )


def _stop_under_the_top(tmp_path, settings: str):  # type: ignore[no-untyped-def]
    """A job travelling at work Z 0.5, stopped near its end under soft limits on a homed
    emulator with ``settings`` added (its work offset): (exception, messages, emulator)."""
    job = tmp_path / "job.gcode"
    z_job(job, travel=0.5, depth=-2.0, x0=-70.0, y0=-10.0)
    prog = load_program(job)
    return run(
        tmp_path, prog, f"time_scale=0.2&soft_limits=1&homed=1&{settings}",
        replace(LIFT, profile=_travel_above_the_machine_top()),
        stop_at=segment_index(prog, -50),
    )  # fmt: skip


def test_soft_limits_cap_the_lift_at_machine_z_0(tmp_path):
    """A travel height above GRBL's travel (machine Z 0 with $20=1) would raise ALARM:2."""
    # work zero 1 mm below the machine's top: the file travels at machine -0.5
    exc, messages, sim = _stop_under_the_top(tmp_path, "wco=0,0,-1")
    assert isinstance(exc, StreamStopped)
    assert (
        "raising the tool to Z 1.000 (machine Z 0.000), capped at machine Z 0.000, the top of "
        "GRBL's soft-limit travel"
    ) in messages
    assert_raised_z_only(sim, 1.0, 0.0, -2.0)


def test_with_hard_limits_the_lift_stays_the_pull_off_below_the_z_switch(tmp_path):
    """Homing leaves Grbl 1.1h's Z switch at machine Z 0 and pulls off by $27: with hard
    limits on, a rapid to Z 0 can trip it (ALARM:1, position lost), and grblHAL's soft
    limits end at -$27 there. The lift stops at machine Z -$27 (1.5 mm here)."""
    exc, messages, sim = _stop_under_the_top(tmp_path, "wco=0,0,-3&$21=1&$27=1.5")
    assert isinstance(exc, StreamStopped)
    assert (
        "raising the tool to Z 1.500 (machine Z -1.500), capped at machine Z -1.500, the "
        "homing pull-off ($27) below the Z limit switch (hard limits are on, $21=1)"
    ) in messages
    assert [e["text"] for e in after_reset(sim, "rx")] == ["G21G53G0Z-1.5", "G4P0"]
    assert_raised_z_only(sim, 1.5, -1.5, -2.0)


@pytest.mark.parametrize(
    ("safe", "envelope", "machine_z", "capped"),
    [
        (9.0, (-40.0, 5.0), -5.0, True),  # above the top: capped there
        (3.0, (-40.0, 5.0), -7.0, False),
        (9.0, Z_UNLIMITED_MM, -1.0, False),  # no Z range: nothing to cap at
    ],
)
def test_the_lift_stays_under_the_profiles_envelope_top(
    tmp_path, safe, envelope, machine_z, capped
):
    """The envelope's top Z caps the travel height. No valid profile travels above it
    (load_profile refuses one), so the lift is driven directly, under a work offset Z -10,
    with a controller that goes where it is sent."""
    job = tmp_path / "job.gcode"
    z_job(job)
    s = Streamer.__new__(Streamer)
    s._program = load_program(job)
    s.info = SimpleNamespace(settings={})  # soft limits off
    s.options = SimpleNamespace(command_timeout=1.0)
    messages: list[str] = []
    s.on_message = messages.append
    sent: list[str] = []

    def send_lift(lines, timeout):
        sent.extend(lines)
        s.status = Status(state="Idle", mpos=(0.0, 0.0, float(lines[0].partition("Z")[2])))
        return ""

    s._send_lift = send_lift
    profile = SimpleNamespace(
        z=SimpleNamespace(safe_mm=safe), envelope=SimpleNamespace(z_mm=envelope)
    )
    lifted = s._lift_z(Status(state="Idle", mpos=(0.0, 0.0, -12.0)), (0.0, 0.0, -10.0), profile)
    assert sent == [f"G21G53G0Z{machine_z:g}", "G4P0"]
    work_z = machine_z + 10.0
    told = f"raising the tool to Z {work_z:.3f} (machine Z {machine_z:.3f})"
    assert (told + f", capped at the envelope's top Z {work_z:.3f}" if capped else told) in messages
    assert lifted.record == {
        "result": "raised", "z": work_z, "machine_z": machine_z, "from_machine_z": -12.0
    }  # fmt: skip


def test_a_file_that_changes_its_work_offset_is_not_raised(tmp_path):
    """Past a G92 in the file the sender cannot tell which frame its travel height is in
    (a build without the WCO field never says): the lift is refused, and says why."""
    job = tmp_path / "job.gcode"
    z_job(job)
    lines = job.read_text().splitlines()
    lines.insert(2, "G92 Z2")  # after the first G0 Z2: the work zero moves down 2 mm
    job.write_text("\n".join(lines) + "\n")
    prog = load_program(job)
    exc, messages, sim = run(tmp_path, prog, "time_scale=0.2", stop_at=segment_index(prog, 20))
    assert isinstance(exc, StreamStopped)
    assert (
        "the tool was NOT raised (line 3 (G92 changes the work coordinates) leaves the job's "
        "coordinate frame unknown; jog Z up)"
    ) in str(exc)
    assert after_reset(sim, "rx") == [] and after_reset(sim, "exec") == []
    assert lift_record(tmp_path / "j.jsonl")["result"] == "skipped"


# --------------------------------------------------------------------------- never


def test_nothing_is_sent_after_an_alarm(tmp_path):
    job = tmp_path / "job.gcode"
    lines = ["G21G90", "G0Z-2", "G0X-20", "G1Z-3F200"] + [f"G1X{k - 20}F300" for k in range(1, 60)]
    job.write_text("\n".join(lines) + "\nG0Z-2\nM2\n")  # X reaches +39: past machine X 0
    prog = load_program(job)
    exc, messages, sim = run(tmp_path, prog, "time_scale=0.2&soft_limits=1&homed=1")
    assert isinstance(exc, StreamFault) and "ALARM:2" in str(exc)
    assert "the tool was NOT raised (after an alarm GRBL is locked" in str(exc)
    alarm = next(e["t"] for e in sim.record if e["ev"] == "alarm")
    assert not [e for e in sim.record if e["ev"] in ("rx", "exec") and e["t"] > alarm]
    assert lift_record(tmp_path / "j.jsonl")["result"] == "skipped"


def test_an_open_safety_door_is_told_not_lifted(tmp_path):
    job = tmp_path / "job.gcode"
    z_job(job)
    prog = load_program(job)
    holder: dict = {}

    def progress(p):
        sim = holder["sim"]
        if p.acked > segment_index(prog, 20) and not holder.get("opened"):
            holder["opened"] = True
            sim.open_door()
        elif p.state == "Door:1":
            raise KeyboardInterrupt

    port = open_port("grblsim://?baud=0&time_scale=0.2", 115200)
    holder["sim"] = port.sim
    messages: list[str] = []
    try:
        with pytest.raises(StreamStopped) as exc:
            stream_program(
                port, prog, tmp_path / "j.jsonl", LIFT, on_progress=progress,
                ask_interrupt=lambda: "stop", on_message=messages.append,
            )  # fmt: skip
    finally:
        port.close()
    assert "the tool was NOT raised (the safety door is open (Door:1)" in str(exc.value)
    assert after_reset(port.sim, "rx") == [] and after_reset(port.sim, "exec") == []
    assert port.sim.mpos[2] == pytest.approx(-0.05, abs=HALF_STEP)


def test_the_lift_can_be_turned_off(tmp_path):
    job = tmp_path / "job.gcode"
    z_job(job)
    prog = load_program(job)
    exc, messages, sim = run(tmp_path, prog, "time_scale=0.2", FAST, segment_index(prog, 20))
    assert isinstance(exc, StreamStopped) and "tool" not in str(exc)
    assert after_reset(sim, "rx") == [] and sim.mpos[2] == pytest.approx(-0.05, abs=HALF_STEP)
    assert "lift" not in read_journal(tmp_path / "j.jsonl")[-1]


# --------------------------------------------------------------------------- servo scribes


def test_the_plotter_profiles_up_command_is_the_resets_m5(tmp_path):
    job = tmp_path / "job.gcode"
    servo_job(job)
    prog = load_program(job)
    assert prog.pen_mode
    options = replace(LIFT, profile=load_profile("grbl-plotter-scribe"))
    exc, messages, sim = run(tmp_path, prog, "time_scale=0.2", options, segment_index(prog, 25))
    assert isinstance(exc, StreamStopped) and "the reset's M5 lifted the scribe" in str(exc)
    assert after_reset(sim, "rx") == []
    spindle = [e for e in sim.record if e["ev"] == "spindle"]
    assert spindle[-1]["spindle"] == "M3"  # down when stopped; the reset switched it off
    assert lift_record(tmp_path / "j.jsonl") == {"result": "reset", "up": "M5"}


def test_a_servo_whose_up_command_is_not_m5_gets_it_sent(tmp_path):
    profile = _profile("grbl-plotter-scribe", tool_control={"off": "M3 S10"})
    job = tmp_path / "job.gcode"
    servo_job(job)
    prog = load_program(job)
    exc, messages, sim = run(
        tmp_path, prog, "time_scale=0.2", replace(LIFT, profile=profile), segment_index(prog, 25)
    )
    assert isinstance(exc, StreamStopped) and "scribe raised (M3 S10)" in str(exc)
    assert [e["text"] for e in after_reset(sim, "rx")] == ["M3S10", "G4P0.15"]
    assert [(e["spindle"], e["s"]) for e in after_reset(sim, "spindle")] == [("M3", 10.0)]
    assert after_reset(sim, "exec") == []


# --------------------------------------------------------------------------- resume


def test_resume_after_a_lifted_stop_cuts_every_segment(tmp_path):
    """The journal's stop carries the lift and still says what ran: the resume cuts every
    segment at least once and none more than twice."""
    job = tmp_path / "job.gcode"
    z_job(job, strokes=3)
    prog = load_program(job)
    journal = tmp_path / "j.jsonl"
    exc, _, first = run(
        tmp_path, prog, "time_scale=0.2", stop_at=segment_index(prog, 20) + SEGMENTS + 4
    )
    assert isinstance(exc, StreamStopped)
    assert lift_record(journal)["result"] == "raised"
    done = done_blocks(read_journal(journal), prog.sha256, journal, program=prog)
    start = resume_point(prog, done)
    port = open_port("grblsim://?baud=0&time_scale=0.01", 115200)
    try:
        stream_program(port, prog, journal, LIFT, resume_at=start)
    finally:
        port.close()
    counts: dict[tuple, int] = {}
    for record in (first.record, port.sim.record):
        for e in record:
            if e["ev"] == "exec" and not e["rapid"] and e["to"][2] < 0 and e["frm"][2] < 0:
                key = (round(e["to"][0], 3), round(e["to"][1], 3))
                counts[key] = counts.get(key, 0) + 1
    segments = {(float(x), float(2 * s)) for s in range(3) for x in range(1, SEGMENTS + 1)}
    assert set(counts) == segments
    assert max(counts.values()) <= 2
    assert read_journal(journal)[-1]["ev"] == "end"


# --------------------------------------------------------------------------- failed lifts


class _DuringLift:
    """A port that calls ``act(sim)`` once the lift's move has been written."""

    def __init__(self, port, act):
        object.__setattr__(self, "_port", port)
        object.__setattr__(self, "_act", act)

    def write(self, data):
        n = self._port.write(data)
        if data.startswith(b"G21G53"):
            self._act(self._port)
        return n

    def __getattr__(self, name):
        return getattr(self._port, name)

    def __setattr__(self, name, value):
        setattr(self._port, name, value)


def _lift_disturbed(tmp_path, act, options=LIFT):
    job = tmp_path / "job.gcode"
    z_job(job)
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.2", 115200)
    messages: list[str] = []
    try:
        with pytest.raises(StreamStopped) as exc:
            stream_program(
                _DuringLift(port, act), prog, tmp_path / "j.jsonl", options,
                on_progress=_stop_after(segment_index(prog, 20)),
                ask_interrupt=lambda: "stop", on_message=messages.append,
            )  # fmt: skip
    finally:
        port.close()
    return str(exc.value), messages, port.sim


def test_a_door_opened_during_the_lift_is_told_and_nothing_more_is_sent(tmp_path):
    text, messages, sim = _lift_disturbed(tmp_path, lambda port: port.sim.open_door())
    assert "the tool was NOT raised (the safety door opened during the lift (Door:" in text
    # GRBL parses no line while the door is open: the move waits in its buffer for the
    # cycle start, and the sender sent nothing after it
    assert "G4P0" not in [e["text"] for e in after_reset(sim, "rx")]
    assert after_reset(sim, "exec") == [] and sim.mpos[2] == pytest.approx(-0.05, abs=HALF_STEP)
    assert lift_record(tmp_path / "j.jsonl")["result"] == "failed"
    assert not any(e["ev"] == "alarm" for e in sim.record)


def test_a_lift_that_does_not_finish_in_time_is_held_and_reset_not_retried(tmp_path):
    """The machine's own feed hold stops the lift; the sender gives up after its timeout
    (command_timeout + 3 x the move's time at $112), holds and resets, sends nothing more."""
    options = replace(LIFT, command_timeout=0.5)
    text, messages, sim = _lift_disturbed(tmp_path, lambda port: port.write(b"!"), options)
    assert re.search(r"the tool was NOT raised \(the lift \(G21G53G0Z2 G4P0\) did not finish "
                     r"within \d\.\d s; feed hold and soft reset sent", text)  # fmt: skip
    # the hold comes as the lift's move starts from rest, so Grbl is at Hold:0 at once and
    # its suspend loop parses no more lines: the dwell is read only if it came first
    assert [e["text"] for e in after_reset(sim, "rx")] in (
        ["G21G53G0Z2"],
        ["G21G53G0Z2", "G4P0"],
    )
    resets = [e for e in sim.record if e["ev"] == "reset"]
    assert len(resets) == 2  # the stop's and the one ending the lift
    assert not any(e["ev"] == "alarm" for e in sim.record)  # reset from Hold:0
    assert -0.05 - HALF_STEP <= sim.mpos[2] < 2.0  # stopped on the way up, maybe in its first step
    assert lift_record(tmp_path / "j.jsonl")["result"] == "failed"


def test_ctrl_c_during_the_lift_stops_it_where_it_is(tmp_path):
    def interrupt(port):
        raise KeyboardInterrupt

    text, messages, sim = _lift_disturbed(tmp_path, interrupt)
    assert "the tool was NOT raised (interrupted while raising it" in text
    assert len([e for e in sim.record if e["ev"] == "reset"]) == 2
    assert not any(e["ev"] == "alarm" for e in sim.record)
    stop = read_journal(tmp_path / "j.jsonl")[-1]
    assert stop["ev"] == "stop" and stop["lift"]["result"] == "interrupted"


def test_work_position_reports_are_placed_by_the_reports_own_offset(tmp_path):
    """With $10=0 GRBL reports WPos; after the reset only a report's own WCO turns it into a
    machine position (the offset from before may be gone with G92)."""
    job = tmp_path / "job.gcode"
    z_job(job)
    prog = load_program(job)
    stop = segment_index(prog, 20)
    exc, _, sim = run(tmp_path, prog, "time_scale=0.2&$10=0&wco=5,7,-10", stop_at=stop)
    assert isinstance(exc, StreamStopped)
    assert_raised_z_only(sim, 2.0, -8.0, -0.05)
    # a build without the WCO field: the machine position after the reset is unknown
    exc, messages, sim = run(
        tmp_path, prog, "time_scale=0.2&$10=0&wco=5,7,-10&wco_field=0", stop_at=stop
    )
    assert (
        "the tool was NOT raised (the status reports after the reset give the work position "
        "(WPos, $10=0) without the WCO field (a build without it), so the machine position is "
        "unknown; jog Z up (with $10=1, MPos reports, the tool is raised))"
    ) in str(exc)
    assert after_reset(sim, "rx") == [] and sim.mpos[2] == pytest.approx(-10.05, abs=HALF_STEP)
    assert lift_record(tmp_path / "j.jsonl")["result"] == "skipped"
    # the same build with MPos reports ($10=1): the frame is the $# offset read at connect
    exc, messages, sim = run(tmp_path, prog, "time_scale=0.2&wco=5,7,-10&wco_field=0", stop_at=stop)
    assert isinstance(exc, StreamStopped)
    assert_raised_z_only(sim, 2.0, -8.0, -0.05)


@pytest.mark.parametrize("flag", [None, "--no-lift"])
def test_the_stream_command_lifts_by_default_and_not_with_no_lift(tmp_path, capsys, flag):
    """`scratchfab stream` turns the lift on (``StreamRequest.lift``); ``--no-lift`` off."""
    job = tmp_path / "job.gcode"
    z_job(job)
    prog = load_program(job)
    bad = segment_index(prog, 30)
    rec = tmp_path / "rec.jsonl"
    url = f"grblsim://?baud=0&time_scale=0.2&error_at={bad + 1}&record={rec}"
    args = ["stream", str(job), "--port", url, "--yes", "--banner-timeout", "0.5"]
    with pytest.raises(SystemExit) as exc:
        main(args + ([flag] if flag else []))
    assert exc.value.code == 3
    err = capsys.readouterr().err
    record = [json.loads(line) for line in rec.read_text().splitlines()]
    reset = next(e["t"] for e in record if e["ev"] == "reset")
    moves = [e for e in record if e["ev"] == "exec" and e["t"] > reset]
    if flag is None:
        assert "tool raised to Z 2.000 (machine Z" not in err and "tool raised to Z 2.000" in err
        assert len(moves) == 1 and moves[0]["rapid"] and moves[0]["to"][2] == pytest.approx(2.0)
    else:
        assert "raised" not in err
        assert moves == []


def test_a_startup_line_in_inches_does_not_turn_the_lift_into_inches(tmp_path):
    """A startup line ``$N0=G20`` runs after every reset, the stop's too: GRBL is in inches
    when the lift comes. The lift states G21, so the 2 mm travel height is not taken as
    2 inches (machine Z 50.8, above the job by 48.8 mm)."""
    job = tmp_path / "job.gcode"
    z_job(job)
    prog = load_program(job)
    port = open_port("grblsim://?baud=0&time_scale=0.2&wco=5,7,-10", 115200)
    port.sim.startup_lines[0] = "G20"
    progress = interrupt_after(segment_index(prog, 20))
    try:
        with pytest.raises(StreamStopped):
            stream_program(
                port, prog, tmp_path / "j.jsonl", LIFT, on_progress=progress,
                ask_interrupt=lambda: "stop",
            )  # fmt: skip
    finally:
        port.close()
    sim = port.sim
    assert [e["text"] for e in after_reset(sim, "rx")] == ["G21G53G0Z-8", "G4P0"]
    assert_raised_z_only(sim, 2.0, -8.0, -0.05)


def test_an_inch_file_on_a_controller_reporting_inches_is_raised_in_mm(tmp_path):
    """A G20 file (travel 0.1 in) and $13=1 (reports, WCO and $# in inches): the height and
    the offset are both taken in mm, and the lift is sent in mm (G21) in machine coordinates."""
    job = tmp_path / "job.gcode"
    lines = ["G20 G90 G17 G94", "G0 Z0.1", "G0 X0 Y0", "G1 Z-0.002 F8"]
    lines += [f"G1 X{0.04 * k:g} F12" for k in range(1, SEGMENTS + 1)] + ["G0 Z0.1", "M2"]
    job.write_text("\n".join(lines) + "\n")
    prog = load_program(job)
    exc, messages, sim = run(
        tmp_path, prog, "time_scale=0.2&$13=1&$10=0&wco=5,7,-10", stop_at=segment_index(prog, 0.8)
    )
    assert isinstance(exc, StreamStopped)
    assert "raising the tool to Z 2.540 (machine Z -7.460)" in messages
    assert [e["text"] for e in after_reset(sim, "rx")] == ["G21G53G0Z-7.46", "G4P0"]
    assert_raised_z_only(sim, 2.54, -7.46, -0.0508)
