"""The GRBL emulator slows down as Grbl 1.1h does on a feed hold, a jog cancel and overrides.

Grbl's stepper (``st_prep_buffer``) decelerates a hold at the acceleration of the block it
is in, into the next block if it must (``STEP_CONTROL_EXECUTE_HOLD``), reporting ``Hold:1``
until it stands (``Hold:0``); a resume starts from rest (``plan_cycle_reinitialize``). A
changed feed or rapid override re-plans, and a head block left faster than its new speed
slows down at its acceleration (``RAMP_DECEL_OVERRIDE``; through the block where it is too
short, ``PREP_FLAG_DECEL_OVERRIDE``). Both act only once the stepper has run the segments
it had prepared (``st_prep_buffer``: 5 of 10 ms, the running one included, each block's
last one shorter), 40-50 ms after they came. References: the closed form ``v^2 / 2a`` and
the tests' time-stepped controller (:class:`grbl_planner_sim.Stepper`) with those segments
counted as it runs (:class:`_Prepared`).
"""

from __future__ import annotations

import copy
import math
import re
import threading

import grbl_planner_sim as planner_sim
import numpy as np
import pytest
from grbl_stepper_ticks import ticks_taken

from scratchfab.machine.grblsim import GrblSim, SimOptions

_REPORT = re.compile(r"<([^|>]+)\|MPos:([^|>]+)\|(?:Bf:(\d+),(\d+)\|)?FS:([^,|>]+),")


class _Machine:
    """An emulator in its own time (a fake clock), with what it answers kept by time."""

    def __init__(self, settings: dict[int, float], time_scale: float = 1.0, **options) -> None:
        self.clock = [0.0]
        self.sim = GrblSim(
            SimOptions(baud=0, time_scale=time_scale, settings=settings, **options),
            clock=lambda: self.clock[0],
        )
        self.sim.start(thread=False)
        self.text = ""

    def at(self, t: float, data: bytes = b"") -> str:
        """Run to ``t``, send ``data`` there; what came back meanwhile."""
        self.clock[0] = max(self.clock[0], t)
        self.sim.advance(self.clock[0])
        if data:
            self.sim.host_write(data)
            self.sim.advance(self.clock[0])
        out = self.sim.host_read(1 << 16, 0.0).decode()
        self.text += out
        return out

    def report(self, t: float) -> tuple[str, tuple[float, float, float], float]:
        """State, position (mm) and rate (mm/min) of a status report asked for at ``t``."""
        found = _REPORT.findall(self.at(t, b"?"))
        assert found, self.text[-300:]
        state, pos, _, _, rate = found[-1]
        x, y, z = (float(v) for v in pos.split(","))
        return state, (x, y, z), float(rate)

    def until_still(self) -> None:
        while (t := self.sim.next_event()) < math.inf:
            self.at(t)
        self.sim.close()

    def times(self, event: str, **match: object) -> list[float]:
        return [
            e["t"]
            for e in self.sim.record
            if e["ev"] == event and all(e.get(k) == v for k, v in match.items())
        ]


SEGMENT_S = 0.01  # Grbl's DT_SEGMENT: 1 / ACCELERATION_TICKS_PER_SECOND (100)
PREPARED = 5  # SEGMENT_BUFFER_SIZE 6: a ring of 6 holds 5, the running one included


class _Prepared(planner_sim.Stepper):
    """The time-stepped reference, with Grbl's segment buffer counted as it runs.

    Segments of 10 ms run from where a block starts (or the motion starts), the last one
    of a block ending with it. A hold or override sent during a segment acts at the end
    of the 5th segment from that one (the 4 prepared behind it run as they were).
    """

    def __init__(self, blocks: list[planner_sim.Block]) -> None:
        super().__init__(blocks)
        self.segment_ends = SEGMENT_S
        self.segment_from = 0.0  # where the segment under way started (mm along the path)
        self.block = 0
        self.waiting: list[list] = []  # [segments left, realtime byte]

    def step(self, dt: float) -> None:
        super().step(dt)
        block = self._index(self.s)
        if block != self.block:  # a block ended within this step, its last segment too
            self.block = block
            self.segment_ends = self.t + SEGMENT_S
            self.segment_from = self.s
            self._segment_ended()
        elif self.t >= self.segment_ends - 1e-9:
            self.segment_ends += SEGMENT_S
            # st_prep_buffer: a segment of less than 1.25 steps runs 10 ms more
            if self.s - self.segment_from >= 1.25 / self.steps_per_mm(block) - 1e-6:
                self.segment_from = self.s
                self._segment_ended()

    def steps_per_mm(self, block: int) -> float:
        """Step events (the most steps of an axis) per mm along a block (250 steps/mm)."""
        return 250.0 * max(abs(u) for u in self.blocks[block].unit)

    def _segment_ended(self) -> None:
        for item in self.waiting:
            item[0] -= 1
        for _, byte in [item for item in self.waiting if item[0] == 0]:
            self.act(byte)
        self.waiting = [item for item in self.waiting if item[0] > 0]

    def send(self, data: bytes) -> None:
        """Realtime bytes sent now: a resume acts at once, a hold or override later."""
        for byte in data:
            if byte == ord("~"):
                self.act(byte)
                self.segment_ends = self.t + SEGMENT_S  # segments from the resume
                self.segment_from = self.s
            elif self.v > 0.0:
                self.waiting.append([PREPARED, byte])
            else:
                self.act(byte)

    def prepared_speed(self) -> float:
        """The speed where the segments prepared now end (Grbl's ``FS:``, ``prep.current_speed``):
        a copy runs on to the end of the 5th segment, the one under way included; 0 if it
        stands or ends before."""
        ahead = copy.deepcopy(self)
        ahead.probed = None
        ahead.waiting.append([PREPARED, "probe"])
        while ahead.probed is None and not ahead.done() and not (ahead.held and ahead.v == 0.0):
            ahead.step(ahead.dt)
        return 0.0 if ahead.probed is None else ahead.probed

    def queue(self, block: planner_sim.Block) -> None:
        """A block queued now: the profile takes it in once the prepared segments ran."""
        if self.v > 0.0:
            self.waiting.append([PREPARED, block])
        else:
            self.act(block)

    def act(self, byte: int | str | planner_sim.Block) -> None:
        """A realtime byte or a queued block takes effect ("probe": the speed is noted)."""
        if isinstance(byte, planner_sim.Block):
            self.blocks.append(byte)
            self.ends.append(self.ends[-1] + byte.length)
        elif byte == "probe":
            self.probed = self.v
        elif byte == ord("!"):
            self.held = True
        elif byte == ord("~"):
            self.held = False
        elif byte == 0x90:
            self.feed_override = 100
        elif byte == 0x92:
            self.feed_override = max(10, self.feed_override - 10)
        elif 0x95 <= byte <= 0x97:
            self.rapid_override = (100, 50, 25)[byte - 0x95]


def _stepper(settings: dict[int, float], lines: list[str]) -> _Prepared:
    reference = planner_sim.Settings(
        tuple(settings.get(110 + k, 500.0) for k in range(3)),  # type: ignore[arg-type]
        tuple(settings.get(120 + k, 10.0) for k in range(3)),  # type: ignore[arg-type]
        settings.get(11, 0.01),
    )
    return _Prepared(planner_sim.queued_blocks(lines, reference))


def _run_both(settings, lines, events, samples):
    """The emulator's reports at ``samples`` and the reference there, and both end times."""
    machine = _Machine(settings)
    machine.at(0.0, "".join(f"{ln}\n" for ln in lines).encode())
    stepper = _stepper(settings, lines)
    got, want = [], []
    for t, kind, data in sorted(
        [(t, "event", d) for t, d in events] + [(t, "sample", b"") for t in samples]
    ):
        stepper.run_until(t)
        if kind == "event":
            machine.at(t, data)
            stepper.send(data)
        else:
            got.append(machine.report(t))
            want.append((stepper.position(), stepper.prepared_speed() * 60.0))
    machine.until_still()
    stepper.run_to_stop()
    return machine, got, want, stepper


def _prepared_until(t: float, start: float = 0.0) -> float:
    """Where the 5 segments prepared at ``t`` end, the one under way included, in a block
    running since ``start`` (10 ms each; not near its end)."""
    return start + (math.floor((t - start) / SEGMENT_S + 1e-9) + PREPARED) * SEGMENT_S


def _taken_x(x: float, speed: float) -> float:
    """What Grbl reports at ``x`` mm into a move along +X from 0 at ``speed`` mm/s: the
    steps its interrupt has taken (:mod:`grbl_stepper_ticks`)."""
    return ticks_taken((0.0, 0.0, 0.0), (50.0, 0.0, 0.0), x, speed)[0]


def _assert_follows(got, want) -> None:
    """The reports follow the reference: within its 2 um, and the step under way (Grbl
    reports the whole steps taken so far, 1 / $100 = 4 um)."""
    for (state, pos, rate), (ref_pos, ref_rate) in zip(got, want, strict=True):
        assert pos == pytest.approx(ref_pos, abs=2e-3 + 1 / 250.0), (state, pos, ref_pos)
        assert rate == pytest.approx(ref_rate, abs=1.0), (state, rate, ref_rate)


def test_a_feed_hold_slows_down_over_v2_over_2a_then_resumes_from_rest():
    """G1X50F600 at $120=10: 1 s up to 10 mm/s over 5 mm. A hold at 2.005 s is Hold:1 at
    once, but the segments prepared up to 2.05 s (the one from 2.00 s and 4 more) run
    first: at x = 15.5 it slows down for v/a = 1 s over v^2/2a = 5 mm
    (x = 15.5 + 10 t - 5 t^2), then Hold:0 at x = 20.5 from 3.05 s on. ``FS:`` is the speed
    where the prepared segments end (``st_get_realtime_rate``): at 2.03 s those end at
    2.08 s, 30 ms into the slowdown (582 mm/min), at 2.9 s at 2.95 s (60). The resume at 4 s
    starts from rest: 29.5 mm to go take 1 s up, 1.95 s at 10 mm/s and 1 s down, so the
    move ends at 7.95 s."""
    settings = {110: 1000.0}
    samples = [2.0, 2.03, 2.25, 2.5, 2.9, 3.1, 3.9, 4.5, 6.0, 7.9]
    machine, got, want, stepper = _run_both(
        settings, ["G1X50F600"], [(2.005, b"!"), (4.0, b"~")], samples
    )
    for t, (state, (x, _, _), rate) in zip(samples, got, strict=True):
        prepared = 60.0 * max(0.0, 10.0 - 10.0 * max(0.0, _prepared_until(t) - 2.05))
        if 2.005 <= t < 2.05:
            assert state == "Hold:1"
            assert x == _taken_x(10.0 * t - 5.0, 10.0)
            assert rate == pytest.approx(prepared, abs=0.6)
        elif 2.05 <= t < 3.05:
            tau = t - 2.05
            assert state == "Hold:1"
            speed = 10.0 - 10.0 * tau
            assert x == pytest.approx(
                _taken_x(15.5 + 10.0 * tau - 5.0 * tau * tau, speed), abs=6e-4
            )
            assert rate == pytest.approx(prepared, abs=0.6)
        elif 3.05 < t < 4.0:
            assert (state, x, rate) == ("Hold:0", 20.5, 0.0)
        else:
            assert state == "Run"
    _assert_follows(got, want)
    assert machine.times("state", state="Hold:1") == [2.005]
    assert machine.times("state", state="Hold:0") == pytest.approx([3.05], abs=1e-6)
    assert machine.times("exec") == pytest.approx([7.95], abs=1e-6)
    assert stepper.t == pytest.approx(7.95, abs=2e-3)  # the reference agrees
    assert machine.sim.mpos == (50.0, 0.0, 0.0)


def test_a_feed_hold_slows_down_into_the_next_block_at_its_acceleration():
    """A hold sent at 2.303 s acts at 2.35 s (the prepared segments run first), at
    x = 18.5, 1.5 mm before a shallow corner ($11=0.5: passed at full speed): it cannot
    stop in the X block, leaves it at v^2 = 10^2 - 2 a 1.5 and slows down on along the
    next block at that block's acceleration ($121=2 makes it 8.25 mm/s^2, not 10), to
    stand v^2 / 2a into it. Against that and the time-stepped reference, as are the resume
    and where and when the move ends."""
    settings = {110: 1000.0, 111: 1000.0, 121: 2.0, 11: 0.5}
    lines = ["G1X20F600", "G1X40Y5"]
    samples = [2.31, 2.4, 2.5, 2.7, 3.0, 3.3, 3.6, 3.9, 4.5, 5.0, 6.0]
    machine, got, want, stepper = _run_both(settings, lines, [(2.303, b"!"), (4.0, b"~")], samples)
    _assert_follows(got, want)
    states = [state for state, _, _ in got]
    assert states == ["Hold:1"] * 6 + ["Hold:0"] * 2 + ["Run"] * 3
    unit = np.array([20.0, 5.0]) / math.hypot(20.0, 5.0)
    accel = min(10.0 / unit[0], 2.0 / unit[1])
    corner_sq = 10.0**2 - 2.0 * 10.0 * 1.5
    block_end = machine.times("exec")[0]
    assert block_end == pytest.approx(2.35 + (10.0 - math.sqrt(corner_sq)) / 10.0, abs=1e-6)
    stop = machine.times("state", state="Hold:0")[0]
    assert stop == pytest.approx(block_end + math.sqrt(corner_sq) / accel, abs=1e-6)
    stood = planner_sim.steps_taken((20.0, 0.0, 0.0), (40.0, 5.0, 0.0), corner_sq / (2.0 * accel))
    assert got[6][1] == got[7][1] == pytest.approx(stood, abs=6e-4)
    assert machine.times("exec")[-1] == pytest.approx(stepper.t, abs=2e-3)
    assert machine.sim.mpos == (40.0, 5.0, 0.0)


def test_a_jog_cancel_slows_down_then_flushes_the_jog_where_it_stood():
    """0x85 at 1.505 s into a 20 mm jog at 10 mm/s acts at 1.55 s (x = 10.5 mm), once the
    prepared segments ran: the state stays Jog while it slows down over 1 s and 5 mm, then
    Idle at x = 15.5 with the jog's rest flushed. At 2.2 s ``FS:`` reads the speed where
    the prepared segments end, at 2.25 s: 3 mm/s (the machine itself goes 3.5)."""
    machine = _Machine({110: 1000.0})
    machine.at(0.0, b"$J=G91X20F600\n")
    machine.at(1.505, b"\x85")
    state, (x, _, _), rate = machine.report(2.2)
    assert state == "Jog" and x == pytest.approx(
        _taken_x(10.5 + 6.5 - 5.0 * 0.65**2, 3.5), abs=6e-4
    )
    assert rate == pytest.approx(60.0 * (10.0 - 10.0 * (_prepared_until(2.2) - 1.55)), abs=0.6)
    assert machine.report(2.6) == ("Idle", (15.5, 0.0, 0.0), 0.0)
    machine.until_still()
    assert machine.times("state", state="Idle")[-1] == pytest.approx(2.55, abs=1e-6)
    assert machine.sim.mpos == pytest.approx((15.5, 0.0, 0.0), abs=1e-6)
    assert machine.times("exec") == []


@pytest.mark.parametrize(("line", "ends"), [(b"$J=G91X5F600\n", 20.5), (b"G1X0F600\n", 0.0)])
def test_no_line_is_parsed_while_a_cancelled_jog_slows_down(line, ends):
    """Grbl's jog cancel sets ``SUSPEND_JOG_CANCEL`` at once, so its main loop stays in the
    suspend loop (``protocol_exec_rt_suspend``) until the jog stopped and was flushed: a
    line sent at 1.6 s, while the jog of 20 mm at 10 mm/s cancelled at 1.505 s slows down
    to x = 15.5 (from 1.55 s, once its prepared segments ran, until 2.55 s), is read only
    then, in Idle. So a new jog is not flushed with the old one (x = 15.5 + 5) and a G1
    runs, not refused (``error:9`` is for G-code during a jog)."""
    machine = _Machine({110: 1000.0})
    machine.at(0.0, b"$J=G91X20F600\n")
    machine.at(1.505, b"\x85")
    assert machine.at(1.6, line) == ""  # waiting in the suspend loop
    assert machine.report(2.5)[0] == "Jog"
    machine.until_still()
    stopped = min(t for t in machine.times("state", state="Idle") if t > 1.5)
    assert stopped == pytest.approx(2.55, abs=1e-6)
    answers = [(e["t"], e["r"]) for e in machine.sim.record if e["ev"] == "resp"]
    assert answers[0] == (0.0, "ok") and answers[1][1] == "ok" and len(answers) == 2
    assert answers[1][0] >= stopped
    runs = [(e["frm"][0], e["to"][0]) for e in machine.sim.record if e["ev"] == "exec"]
    assert runs == [(15.5, ends)]
    assert machine.sim.mpos == pytest.approx((ends, 0.0, 0.0), abs=1e-6)


def test_a_jog_takes_no_feed_override():
    """Grbl's ``jog_execute`` flags its moves ``PL_COND_FLAG_NO_FEED_OVERRIDE``: at 50 %
    a 20 mm jog at F600 ($120=10) still cruises at 10 mm/s (x = 5 + 10 (t - 1)); a G1 at
    F600 afterwards runs at 5 mm/s (0.5 s and 1.25 mm to reach it)."""
    machine = _Machine({110: 1000.0})
    machine.at(0.0, b"$J=G91X20F600\n")
    machine.at(0.5, b"\x92" * 5)
    assert machine.report(1.5) == ("Jog", (10.0, 0.0, 0.0), 600.0)
    assert machine.report(3.5) == ("Idle", (20.0, 0.0, 0.0), 0.0)
    machine.at(4.0, b"G1X0F600\n")
    x = ticks_taken((20.0, 0.0, 0.0), (0.0, 0.0, 0.0), 1.25 + 5.0 * 1.5, 5.0)[0]
    assert machine.report(6.0) == ("Run", (x, 0.0, 0.0), 300.0)
    machine.until_still()


@pytest.mark.parametrize(
    ("settings", "lines", "events", "lowered"),
    [
        # 20 mm/s, down to 50 % at 3 s (1 s to slow to 10 mm/s), back to 100 % at 6 s
        ({110: 2000.0}, ["G1X100F1200"], [(3.0, b"\x92" * 5), (6.0, b"\x90")], 600.0),
        # a rapid at 20 mm/s, rapid override 50 % at 3 s
        ({110: 1200.0}, ["G0X100"], [(3.0, b"\x96")], 600.0),
        # down to 10 % 0.1 s before 3 mm blocks: it slows down through three of them
        (
            {110: 2000.0},
            ["G1X10F1200", "G1X13", "G1X16", "G1X19", "G1X40"],
            [(1.9, b"\x92" * 9)],
            120.0,
        ),
    ],
)
def test_a_feed_override_changes_the_speed_at_the_acceleration(settings, lines, events, lowered):
    """Grbl re-plans on an override (``plan_cycle_reinitialize``): the running block
    slows down from the speed it has at its acceleration, not at once (``lowered`` mm/min
    is the new speed), and speeds up the same way; the reference is the time-stepped
    controller."""
    samples = [t for t in np.arange(1.85, 9.0, 0.25) if all(abs(t - e) > 1e-9 for e, _ in events)]
    machine, got, want, stepper = _run_both(settings, lines, events, samples)
    _assert_follows(got, want)
    assert machine.times("exec")[-1] == pytest.approx(stepper.t, abs=2e-3)
    after = next(k for k, t in enumerate(samples) if t > events[0][0])
    assert got[after][2] > lowered + 200.0  # still slowing down


def test_a_move_of_no_steps_takes_no_planner_block():
    """Grbl drops a move of no whole step (``PLAN_EMPTY_BLOCK``): ``Bf:`` counts only the
    one real move of three."""
    machine = _Machine({10: 3, 110: 1000.0})
    machine.at(0.0, b"G1X10F600\nG1X10\nG1X10.001\n")
    machine.at(0.1)
    found = _REPORT.findall(machine.at(0.2, b"?"))
    assert found and found[-1][0] == "Run" and found[-1][2:4] == ("14", "128")


@pytest.mark.parametrize(
    ("laser", "spindle", "waits"), [(1, "M3", True), (1, "M4", False), (0, "M3", False)]
)
def test_a_move_of_no_length_under_m3_in_laser_mode_waits_for_the_planner(laser, spindle, waits):
    """Grbl's ``mc_line``: a move ``plan_buffer_line`` drops (``PLAN_EMPTY_BLOCK``) calls
    ``spindle_sync`` in laser mode ($32=1) under M3 only, so its ``ok`` comes once the
    planner emptied (the 10 mm move before it ended); under M4 or with $32=0 at once."""
    machine = _Machine({32: laser, 110: 1000.0})
    machine.at(0.0, f"{spindle}S500\nG1X10F600\nG1X10\n".encode())
    machine.until_still()
    answers = [(e["t"], e["r"]) for e in machine.sim.record if e["ev"] == "resp"]
    assert [r for _, r in answers] == ["ok"] * 3
    ended = machine.times("exec")[0]
    assert ended > 1.0
    assert answers[2][0] == (pytest.approx(ended, abs=1e-9) if waits else 0.0)


def test_a_move_of_no_steps_takes_no_planning_time():
    """``plan_buffer_line`` returns ``PLAN_EMPTY_BLOCK`` before it plans anything, so a
    move of no whole step (0.25 of one) is answered at once where a real one takes the
    ``plan_time`` (0.1 s) of planning first."""
    machine = _Machine({110: 1000.0}, plan_time=0.1)
    machine.at(0.0, b"G1X0.001F600\n")
    machine.at(1.0, b"G1X0.01F600\n")
    machine.until_still()
    answers = [(e["t"], e["r"]) for e in machine.sim.record if e["ev"] == "resp"]
    assert answers == [(0.0, "ok"), (pytest.approx(1.1, abs=1e-9), "ok")]


def test_a_soft_limit_in_a_cycle_holds_first_then_alarms_where_it_stood():
    """Grbl's ``limits_soft_check`` in a cycle feeds a hold and waits for it (``Hold:1``,
    no line read, no ``ok``), then resets and raises ``ALARM:2`` at rest. Homed at x = -1,
    G1X-100F600 at $120=10 is at 10 mm/s after 1 s (5 mm); G1X10 (outside -$130..0) comes
    at 2.005 s: the hold acts at 2.05 s once the prepared segments ran (x = -16.5) and
    slows down over v/a = 1 s and v^2/2a = 5 mm, so ALARM:2 comes at 3.05 s at
    x = -21.5, where the position stays over the reset."""
    machine = _Machine({110: 1000.0}, soft_limits=True, homed=True)
    machine.at(0.0, b"G1X-100F600\n")
    machine.at(2.005, b"G1X10\nG1X-50\n")
    state, (x, _, _), _ = machine.report(2.55)
    ran = 15.5 + 10.0 * 0.5 - 5.0 * 0.5**2
    assert state == "Hold:1"
    assert x == ticks_taken((-1.0, -1.0, -1.0), (-100.0, -1.0, -1.0), ran, 5.0)[0]
    assert "ALARM" not in machine.text
    machine.at(3.049)
    assert "ALARM" not in machine.text
    machine.at(3.051)
    assert machine.text.endswith("ALARM:2\r\n[MSG:Reset to continue]\r\n")
    assert machine.times("alarm", code=2) == pytest.approx([3.05], abs=1e-6)
    assert [e["r"] for e in machine.sim.record if e["ev"] == "resp"] == ["ok"]
    assert [e["text"] for e in machine.sim.record if e["ev"] == "rx"][-1] == "G1X10"
    machine.at(3.5, b"\x18")
    state, pos, _ = machine.report(3.6)
    assert state == "Alarm" and pos == (-21.5, -1.0, -1.0)
    assert "ALARM:3" not in machine.text
    machine.until_still()


def test_a_soft_limit_before_the_cycle_starts_alarms_at_once():
    """Not in a cycle yet (both lines read before the auto cycle start), Grbl's
    ``limits_soft_check`` resets at once: the queued move is lost, nothing moved."""
    machine = _Machine({110: 1000.0}, soft_limits=True, homed=True)
    machine.at(0.0, b"G1X-100F600\nG1X10\n")
    assert machine.text.endswith("ALARM:2\r\n[MSG:Reset to continue]\r\n")
    machine.until_still()
    assert machine.sim.mpos == (-1.0, -1.0, -1.0) and machine.times("exec") == []


def test_a_soft_limit_after_a_spindle_change_alarms_once_the_motion_before_ended():
    """``gc_execute_line`` syncs a spindle change (``protocol_buffer_synchronize``) before
    ``mc_line`` checks the soft limits, so a line ``M3S1000G1X10`` (outside) sent while
    G1X-20F600 runs from x = -1 waits for that move to end (19 mm at 10 mm/s^2 from rest
    to rest: 2.9 s), Idle, then alarms at once there: no hold."""
    machine = _Machine({110: 1000.0}, soft_limits=True, homed=True)
    machine.at(0.0, b"G1X-20F600\n")
    machine.at(1.0, b"M3S1000G1X10\n")
    assert machine.report(2.0)[0] == "Run"
    machine.until_still()
    assert machine.times("alarm", code=2) == pytest.approx([2.9], abs=1e-6)
    assert machine.times("exec") == pytest.approx([2.9], abs=1e-6)
    assert machine.times("state", state="Hold:1") == []
    assert machine.sim.mpos == (-20.0, -1.0, -1.0)


_FUZZ_BYTES = [b"!", b"~", b"\x18", b"\x85", b"\x84", b"\x91", b"\x92", b"\x94", b"\x96"]


def _fuzz_lines(rng: np.random.Generator) -> bytes:
    pick = rng.integers(6)
    x, y = (float(v) for v in rng.uniform(-20.0, 20.0, 2))
    feed = float(rng.uniform(10.0, 3000.0))
    return [
        f"G1X{x:.3f}Y{y:.3f}F{feed:.0f}\n",
        f"G0X{x:.3f}\n",
        f"$J=G91X{x:.3f}F{feed:.0f}\n",
        f"G1X{x:.3f}Y{y:.3f}F{feed:.0f}\nG1X{x:.3f}Y{y + 0.001:.3f}\n",  # no whole step
        "$X\n",
        "G4P0.01\n",
    ][pick].encode()


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_holds_resumes_resets_and_jog_cancels_in_any_order_never_spin(seed):
    """Random holds, resumes, resets, jog cancels, doors and overrides among moves, jogs
    and dwells, at random times and time scales from 0 to 1: the emulator always reaches
    a still state in finite time, every report is finite and a resume, door close and
    unlock at the end run what is left to the end."""
    rng = np.random.default_rng(seed)
    for _ in range(25):
        scale = float(rng.choice([0.0, 1.0, rng.uniform(0.0, 1.0)], p=[0.2, 0.2, 0.6]))
        machine = _Machine({110: 3000.0, 111: 3000.0, 120: 50.0, 121: 20.0}, scale)
        error: list[BaseException] = []

        def run(machine: _Machine = machine, error: list[BaseException] = error) -> None:
            try:
                t = 0.0
                for _ in range(60):
                    t += float(rng.exponential(0.05))
                    data = (
                        _fuzz_lines(rng)
                        if rng.random() < 0.5
                        else _FUZZ_BYTES[rng.integers(len(_FUZZ_BYTES))]
                    )
                    machine.at(t, data)
                    if rng.random() < 0.1:
                        machine.sim.close_door()
                    state, pos, rate = machine.report(t)
                    assert all(math.isfinite(v) for v in (*pos, rate)), (state, pos, rate)
                for _ in range(3):  # a ~ while a hold or door still stops is ignored
                    machine.sim.close_door()
                    t += 0.01
                    machine.at(t, b"~")  # resume a hold or a closed door
                    while (nxt := machine.sim.next_event()) < math.inf:
                        t = max(t, nxt)
                        machine.at(t)
                assert machine.sim.state in ("Idle", "Alarm") and not machine.sim._planner
                machine.at(t, b"\x18$X\n")
                machine.until_still()
            except BaseException as exc:  # handed to the test's thread
                error.append(exc)

        worker = threading.Thread(target=run, daemon=True)
        worker.start()
        worker.join(20.0)
        assert not worker.is_alive(), f"the emulator spun (time_scale {scale})"
        if error:
            raise error[0]
        assert machine.sim.state == "Idle" and not machine.sim._planner
        assert all(math.isfinite(v) for v in machine.sim.mpos)
