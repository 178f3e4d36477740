"""The GRBL emulator where Grbl 1.1h's source decides what a sender sees.

Each test names the place in gnea/grbl (v1.1h) it follows. References are closed forms
and the time-stepped controller of :mod:`test_grblsim_slowdown` (with Grbl's prepared
segments counted as it runs), never the emulator's own profiles.
"""

from __future__ import annotations

import math

import grbl_planner_sim as planner_sim
import pytest
from grbl_stepper_ticks import ticks_taken
from test_grblsim_slowdown import _assert_follows, _Machine, _Prepared, _run_both

# $100=1000 steps/mm and $120=1000 mm/s^2: 10 mm/s is reached in 0.05 mm, so 15 blocks of
# 0.02 mm are look-ahead enough and each takes 2 ms, less than one 10 ms segment.
_FAST = {100: 1000.0, 110: 1000.0, 120: 1000.0}
_SHORT = ["G1X1F600"] + [f"G1X{1.0 + 0.02 * k:.2f}" for k in range(1, 101)]


def test_a_hold_among_blocks_shorter_than_a_segment_acts_after_five_of_them():
    """``st_prep_buffer`` ends a segment with its block, so among 2 ms blocks the 5
    prepared segments are 5 blocks: a hold acts at the end of the 4th block after the one
    running (about 10 ms later, not 40-50 ms), then stops v^2 / 2a = 0.05 mm further. As
    the time-stepped reference with the same segments."""
    machine = _Machine(_FAST)
    machine.at(0.0, "".join(f"{line}\n" for line in _SHORT).encode())
    sent = 0.1503
    machine.at(sent, b"!")
    state, (x, _, _), _ = machine.report(1.0)
    ends = machine.times("exec")
    running = sum(1 for t in ends if t <= sent)  # blocks finished before the hold
    acts = ends[running + 4]  # that block's end, then 4 more blocks
    stood = 0.02 * (running + 5) + 0.05  # from x = 0: G1X1 is block 0, 1 mm long
    assert running > 20 and acts - sent < 0.012
    assert state == "Hold:0" and x == pytest.approx(1.0 - 0.02 + stood, abs=1e-3)
    reference = planner_sim.queued_blocks(
        _SHORT, planner_sim.Settings((1000.0,) * 3, (1000.0,) * 3, 0.01, (1000.0,) * 3)
    )
    stepper = _Prepared(reference)
    stepper.run_until(sent)
    stepper.send(b"!")
    stepper.run_to_stop()
    assert x == pytest.approx(stepper.position()[0], abs=2e-3)


def test_an_override_acts_once_the_prepared_segments_ran():
    """A feed override sent at 2.005 s into a 10 mm/s cruise changes nothing before 2.05 s
    (``st_update_plan_block_parameters`` re-plans from the end of the segment buffer),
    then slows down at $120. ``FS:`` is the speed where the prepared segments end
    (``st_get_realtime_rate``): 40 ms into the slowdown at 2.04 s, at 2.15 s 0.15 s into
    it (1.5 mm/s slower; the machine itself 1 mm/s, not 1.45), where it stands 0.1 s on."""
    machine = _Machine({110: 1000.0})
    machine.at(0.0, b"G1X100F600\n")
    machine.at(2.005, b"\x92" * 5)
    assert machine.report(2.04)[2] == pytest.approx(600.0 - 60.0 * 10.0 * 0.04, abs=0.6)
    assert machine.report(2.15)[2] == pytest.approx(600.0 - 60.0 * 10.0 * 0.15, abs=0.6)
    x = [machine.report(t)[1][0] for t in (2.15, 2.25)]
    assert x[1] - x[0] == pytest.approx(0.1 * (10.0 - 10.0 * 0.15), abs=5e-3)
    machine.until_still()


def test_an_override_just_before_a_block_ends_leaves_the_next_block_its_prepared_start():
    """A 50 % override at 1.48 s, 25 ms before G1X10.05 ends (at 1.505 s, x = 10.05): the
    segments prepared until then include the next block's first two (to 1.525 s), at the
    old speed; the slowdown starts there, in the next block, not where it begins. Against
    the time-stepped reference with the same segments. ``FS:`` reads the speed where the
    prepared segments end: at 1.5 s 1.545 s (the block's last segment from 1.5 s, then 4
    of 10 ms), at 1.52 s 1.565 s and at 1.55 s 1.595 s, 20, 40 and 70 ms into the slowdown."""
    samples = [1.5, 1.52, 1.55, 1.6, 1.8, 2.0, 2.5, 3.0]
    machine, got, want, stepper = _run_both(
        {110: 1000.0}, ["G1X10.05F600", "G1X30"], [(1.48, b"\x92" * 5)], samples
    )
    _assert_follows(got, want)
    rates = [600.0 - 60.0 * 10.0 * into for into in (0.02, 0.04, 0.07)]
    assert [rate for _, _, rate in got[:3]] == pytest.approx(rates, abs=0.6)
    assert machine.times("exec")[-1] == pytest.approx(stepper.t, abs=2e-3)


def test_steps_per_mm_changed_at_rest_keeps_the_step_count():
    """``settings_store_global_setting`` only stores ``$100``: ``sys_position`` stays 2500
    steps, reported as 2500 / 100 = 25 mm (``system_convert_axis_steps_to_mpos``), and the
    planner's position too, so G1X20 then runs from step 2500 to 2000 (5 mm at 100/mm:
    1 s up and 1 s down at 10 mm/s^2). Y's -501 steps read -4.008 mm at 125/mm and
    -2.004 again at 250/mm; ``$RST=$`` (250/mm) shows X's 2000 steps as 8 mm."""
    machine = _Machine({110: 1000.0})
    machine.at(0.0, b"G1X10Y-2.004F600\n")
    assert machine.report(5.0) == ("Idle", (10.0, -2.004, 0.0), 0.0)
    machine.at(5.1, b"$100=100\n$101=125\n")
    assert machine.report(5.2) == ("Idle", (25.0, -4.008, 0.0), 0.0)
    machine.at(5.25, b"$101=250\n")
    assert machine.report(5.3) == ("Idle", (25.0, -2.004, 0.0), 0.0)
    machine.at(5.3, b"G1X20\n")
    machine.until_still()
    assert machine.times("exec")[-1] == pytest.approx(5.3 + 2.0 * (5.0 / 10.0) ** 0.5, abs=1e-6)
    assert machine.sim.mpos == pytest.approx((20.0, -2.004, 0.0), abs=1e-9)
    machine.at(machine.clock[0] + 0.1, b"$RST=$\n")
    assert machine.report(machine.clock[0] + 0.2)[1] == pytest.approx((8.0, -2.004, 0.0))


def test_a_soft_limit_in_the_users_own_hold_kills_the_steppers_with_alarm_2():
    """A line outside the soft limits read while the user's hold slows down: not in a
    cycle, so ``limits_soft_check`` calls ``mc_reset`` at once, which kills the steppers
    (``STEP_CONTROL_EXECUTE_HOLD``: "position has likely been lost") and sets ALARM:3, but
    ``system_set_exec_alarm(EXEC_ALARM_SOFT_LIMIT)`` then overwrites it: the sender sees
    ALARM:2 only, with the machine stopped at speed where it was, not where the hold would
    have stood. The record says the speed it was stopped from."""
    machine = _Machine({110: 1000.0}, soft_limits=True, homed=True)
    machine.at(0.0, b"G1X-100F600\n")
    machine.at(2.005, b"!")  # acts at 2.05 s at x = -16.5, would stand at -21.5 at 3.05 s
    machine.at(2.55, b"G1X10\n")
    ran = 15.5 + 10.0 * 0.5 - 5.0 * 0.5**2
    x = ticks_taken((-1.0, -1.0, -1.0), (-100.0, -1.0, -1.0), ran, 5.0)[0]
    assert machine.text.endswith("ALARM:2\r\n[MSG:Reset to continue]\r\n")
    assert "ALARM:3" not in machine.text
    alarms = [e for e in machine.sim.record if e["ev"] == "alarm"]
    assert alarms == [{"t": 2.55, "ev": "alarm", "code": 2, "lost": pytest.approx(300.0)}]
    machine.at(3.0, b"\x18")
    machine.until_still()
    assert machine.sim.state == "Alarm" and machine.sim.mpos == (x, -1.0, -1.0)
    assert "ALARM:3" not in machine.text


def test_a_resume_runs_the_exact_distance_left_from_the_whole_steps_it_stood_on():
    """After a hold Grbl keeps the exact mm left (``pl_block->millimeters = mm_remaining``
    at the forced deceleration's end) and the whole steps left (``prep.steps_remaining``);
    the resume's profile covers the mm (``plan_cycle_reinitialize``), the steps run are
    the whole ones. A hold at 0.5025 s into G1X20F600 ($120=10) acts at 0.55 s
    (v = 5.5 mm/s, x = 1.5125) and stands v^2/2a = 1.5125 mm on: x = 3.025, on no step
    (3.025 x 250 = 756.25), reported at step 756 (3.024). The resume at 2 s runs the
    16.975 mm left: 1 s up, 0.6975 s at 10 mm/s, 1 s down."""
    machine = _Machine({110: 1000.0})
    machine.at(0.0, b"G1X20F600\n")
    machine.at(0.5025, b"!")
    assert machine.report(1.9) == ("Hold:0", (3.024, 0.0, 0.0), 0.0)
    machine.at(2.0, b"~")
    machine.until_still()
    assert machine.times("exec") == pytest.approx([2.0 + 2.0 + 6.975 / 10.0], abs=1e-6)
    assert machine.sim.mpos == (20.0, 0.0, 0.0)


def test_a_minor_axis_steps_within_an_event_and_a_reset_there_keeps_that_position():
    """G1X0.012Y0.008F6: 3 events, Y steps on 2 of them. At 0.1 mm/s (21 events/s) AMASS
    runs 8 ticks an event; Y's counter, left at 20 of 24 after event 2, steps on the 3rd
    tick of event 3, X (at 12) only on its 5th: between 2.25 and 2.5 events Grbl reports
    (2, 2) steps, a position no whole event stands on ((2, 1), then (3, 2)). A reset there
    (ALARM:3) stops the machine on it. Against the reference's ticks every 2.5 ms; the
    move (a = 10 / 0.83 mm/s^2, X's share limits it) is at speed after v/a = 8 ms, so
    ``done = v t - v^2 / 2a``."""
    machine = _Machine({})
    machine.at(0.0, b"G1X0.012Y0.008F6\n")
    end = (0.012, 0.008, 0.0)
    length = (0.012**2 + 0.008**2) ** 0.5
    shed = 0.1**2 / (2.0 * 10.0 / (0.012 / length))
    stop = (2.375 / 3.0 * length + shed) / 0.1
    for t in [0.02 + 0.0025 * k for k in range(40)] + [stop]:
        if t <= stop:
            want = ticks_taken((0.0, 0.0, 0.0), end, 0.1 * t - shed, 0.1)
            assert machine.report(t)[1] == pytest.approx(want, abs=1e-9), t
    assert machine.report(stop)[1] == (0.008, 0.008, 0.0)
    assert (0.008, 0.008, 0.0) not in [
        planner_sim.steps_taken((0.0, 0.0, 0.0), end, length * k / 3.0) for k in range(4)
    ]
    machine.at(stop, b"\x18")
    assert "ALARM:3" in machine.text
    machine.until_still()
    assert machine.sim.mpos == pytest.approx((0.008, 0.008, 0.0), abs=1e-12)


def test_a_block_queued_while_running_acts_once_the_prepared_segments_ran():
    """G1X10F600 alone slows down from x = 5 at 1 s to stop at 2 s. G1X20 queued at 1.2 s
    (at 8 mm/s) re-plans it (``planner_recalculate`` -> ``st_update_plan_block_parameters``)
    from the end of the segments prepared, at 1.25 s: it slows on to 7.5 mm/s at x =
    7.1875 first, then speeds up to 10 mm/s at 1.5 s, x = 9.375 (re-planned at once it
    would be 9.6), and the move ends 5.625 mm of cruise and 1 s of slowdown later, at
    3.0625 s. Against that and the time-stepped reference with the same segments."""
    machine = _Machine({110: 1000.0})
    machine.at(0.0, b"G1X10F600\n")
    machine.at(1.2, b"G1X20\n")
    assert machine.report(1.5)[1][0] == pytest.approx(9.375, abs=1 / 250.0)
    assert machine.report(1.8)[1][0] == pytest.approx(12.375, abs=1 / 250.0)
    machine.until_still()
    assert machine.times("exec")[-1] == pytest.approx(3.0625, abs=1e-6)
    reference = planner_sim.queued_blocks(
        ["G1X10F600", "G1X20"], planner_sim.Settings((1000.0,) * 3, (10.0,) * 3)
    )
    stepper = _Prepared(reference[:1])
    stepper.run_until(1.2)
    stepper.queue(reference[1])
    stepper.run_until(1.5)
    assert stepper.position()[0] == pytest.approx(9.375, abs=2e-3)
    assert stepper.run_to_stop() == pytest.approx(3.0625, abs=2e-3)


def test_fs_reads_the_speed_where_the_prepared_segments_end():
    """``st_get_realtime_rate`` reports ``prep.current_speed``: G1X10F600 speeds up for
    1 s and slows down for 1 s; at 0.303 s the segments prepared end at 0.35 s (3.5 mm/s,
    the machine itself goes 3.03), and near the end all of the move is prepared, so
    ``FS:0`` while it still runs its last segments."""
    machine = _Machine({110: 1000.0})
    machine.at(0.0, b"G1X10F600\n")
    assert machine.report(0.303)[2] == pytest.approx(60.0 * 3.5, abs=0.6)
    state, (x, _, _), rate = machine.report(1.97)
    assert (state, rate) == ("Run", 0.0) and x < 10.0
    assert machine.report(2.01) == ("Idle", (10.0, 0.0, 0.0), 0.0)


def _grbl_segments(length: float, rate: float, accel: float, per_mm: float) -> list:
    """(end time, speed there) of each segment ``st_prep_buffer`` prepares for one block
    from rest to rest, its ramps as it walks them (``RAMP_ACCEL``, ``RAMP_CRUISE``,
    ``RAMP_DECEL``): 10 ms (``DT_SEGMENT``), 10 ms more while a segment holds less than
    1.25 steps (``REQ_MM_INCREMENT_SCALAR``), the last one ending with the block."""
    decel_after = min(rate * rate / (2.0 * accel), 0.5 * length)  # mm from the end
    top = math.sqrt(2.0 * accel * decel_after)
    accel_until = length - decel_after
    ramp, v, left, t, out = "accel", 0.0, length, 0.0, []
    while left > 0.0:
        dt_max, dt, step, start, least = 0.01, 0.0, 0.01, left, max(left - 1.25 / per_mm, 0.0)
        while True:
            if ramp == "accel":
                left -= step * (v + 0.5 * accel * step)
                if left < accel_until:
                    left = accel_until
                    step = 2.0 * (start - left) / (v + top)
                    ramp, v = ("decel" if left == decel_after else "cruise"), top
                else:
                    v += accel * step
            elif ramp == "cruise":
                if left - top * step < decel_after:
                    step = (left - decel_after) / top
                    left, ramp = decel_after, "decel"
                else:
                    left -= top * step
            elif v > accel * step and left - step * (v - 0.5 * accel * step) > 0.0:
                left -= step * (v - 0.5 * accel * step)
                v -= accel * step
            else:
                step, left, v = 2.0 * left / v, 0.0, 0.0
            dt += step
            if left <= 0.0:
                break
            if dt < dt_max:
                step = dt_max - dt
            elif left > least:
                dt_max += 0.01
                step = dt_max - dt
            else:
                break
        t += dt
        out.append((t, v))
    return out


def _prepared_end(segments: list, t: float) -> tuple[float, float]:
    """Where the 5 segments prepared at ``t`` end (the one under way included), and the
    speed there (``prep.current_speed``; 0 once the last is prepared)."""
    running = next(k for k, (end, _) in enumerate(segments) if end > t)
    end, speed = segments[min(running + 4, len(segments) - 1)]
    return end, (speed if running + 4 < len(segments) - 1 else 0.0)


def test_segments_of_less_than_a_step_and_a_quarter_run_longer():
    """At $120=10 a move from rest runs 0.5 mm in its first 10 ms, less than 1.25 steps
    (5 um at 250 steps/mm): ``st_prep_buffer`` stretches that segment to 40 ms and the next
    to 20 ms. A hold at 5 ms so acts at 90 ms (not 50), at 0.9 mm/s, and the machine
    stands 0.081 mm on (0.025 with 10 ms segments), on step 20. Against a walk of Grbl's
    segment loop, which also gives ``FS:`` near the end, where the segments stretch again."""
    segments = _grbl_segments(10.0, 10.0, 10.0, 250.0)
    assert [round(end, 6) for end, _ in segments[:3]] == [0.04, 0.06, 0.07]
    acts, speed = _prepared_end(segments, 0.005)
    assert acts == pytest.approx(0.09) and speed == pytest.approx(0.9)
    machine = _Machine({})
    machine.at(0.0, b"G1X10F600\n")
    machine.at(0.005, b"!")
    stood = 0.5 * 10.0 * acts**2 + speed**2 / 20.0
    assert machine.report(0.5) == ("Hold:0", (math.floor(stood * 250.0) / 250.0, 0.0, 0.0), 0.0)
    assert machine.times("state", state="Hold:0") == pytest.approx([acts + speed / 10.0])
    machine = _Machine({110: 1000.0})
    machine.at(0.0, b"G1X10F600\n")
    for t in (0.003, 0.045, 0.503, 1.503, 1.903, 1.925, 1.935, 1.945, 1.955, 1.97):
        assert machine.report(t)[2] == pytest.approx(
            60.0 * _prepared_end(segments, t)[1], abs=0.6
        ), t


@pytest.mark.parametrize("feed", [1.0, 3.0, 6.0, 20.0])  # AMASS levels 3, 2, 1, 0
def test_a_report_counts_the_step_on_the_tick_that_takes_it_not_the_distance_run(feed):
    """``sys_position`` is counted on the interrupt tick that decides a step (its pulse
    goes out on the next tick), and the tick that loads a segment runs at once, where the
    exact distance left is a whole number of steps. So Grbl reports a step before the
    distance run reaches it: the major axis's step ``k`` on event ``k``'s first tick
    (``k - 1`` events run) without AMASS, on its middle tick (``k - 1/2``) with it, the
    last one so before the move ends. G1 at 1000 steps/mm to (50.12, 18.38, -10.27) steps
    (lround: 50, 18, -10) at 1-20 mm/s ($120-$122 so high that it cruises at once):
    against the reference's ticks at 100 instants of the cruise, and 0.4 of an event
    before the end, where the floor of the steps run is one X step short, Grbl reports and
    a reset leaves the move's end (ALARM:3, the record's partial move ends there)."""
    spm, accel = 1000.0, 1e7
    settings = {100 + k: spm for k in range(3)} | {110 + k: 6000.0 for k in range(3)}
    machine = _Machine(settings | {120 + k: accel for k in range(3)})
    machine.at(0.0, f"G1X0.05012Y0.01838Z-0.01027F{60.0 * feed:g}\n".encode())
    end, count = (0.05, 0.018, -0.01), 50
    length = math.sqrt(sum(v * v for v in end))
    shed = feed**2 / (2.0 * accel * length / end[0])  # X's share limits the acceleration

    def at_events(e: float) -> tuple[float, float]:  # the instant e events run, and the mm
        return (e / count * length + shed) / feed, e / count * length

    for e in [0.05 + k * (count - 0.1) / 100 for k in range(101)]:
        t, done = at_events(e)
        want = ticks_taken((0.0,) * 3, end, done, feed, (spm,) * 3)
        assert machine.report(t)[1] == pytest.approx(want, abs=1e-9), e
    t, done = at_events(count - 0.4)
    assert math.floor(done / length * end[0] * spm) == end[0] * spm - 1  # floor: X short
    assert ticks_taken((0.0,) * 3, end, done, feed, (spm,) * 3) == pytest.approx(end)
    assert machine.report(t)[1] == pytest.approx(end, abs=1e-9)
    machine.at(t, b"\x18")
    machine.until_still()
    assert "ALARM:3" in machine.text and machine.sim.mpos == pytest.approx(end, abs=1e-12)
    partial = [e for e in machine.sim.record if e["ev"] == "partial"]
    assert [e["to"] for e in partial] == [pytest.approx(list(end), abs=1e-9)]


def test_the_amass_level_is_the_segments_not_the_instants():
    """``st_prep_buffer`` picks a segment's AMASS level from its step rate: the events it runs
    over its time (``cycles_per_tick``; its first event starts on a whole step here, so no
    partial step carries over). G1 X10 Y7 at 1000 steps/mm from rest at $120 = $121 = 90:
    X runs at 90 t mm/s, 45000 t^2 events by t; the segment from 40 to 50 ms runs events
    72 to 112.5, 4050 a second: AMASS level 1 (16 MHz / 4050 = 3951 cycles, under
    ``AMASS_LEVEL2`` 4000), though until 44.4 ms X runs under 4000 a second (level 2).
    Reports there tick Y at level 1: ticks_taken at the segment's average speed, at 4
    points of each event from 73 on."""
    spm, accel = 1000.0, 90.0
    settings = {100 + k: spm for k in range(3)} | {110: 6000.0, 111: 6000.0}
    machine = _Machine(settings | {120: accel, 121: accel})
    machine.at(0.0, b"G1X10Y7F6000\n")
    end = (10.0, 7.0, 0.0)
    length = math.hypot(10.0, 7.0)
    per_mm = 10000 / length  # X's events per mm of the move
    average = (112.5 - 72.0) / per_mm / 0.01  # mm/s over the segment
    assert 16e6 / (average * per_mm) == pytest.approx(3950.6, abs=0.1)
    differs = 0
    for e in [k + f for k in range(72, 88) for f in (0.1, 0.35, 0.6, 0.85)]:
        t = math.sqrt(e / 45000.0)
        if 90.0 * t * 1000.0 >= 4000.0:
            break  # X's speed reached level 1 too
        want = ticks_taken((0.0,) * 3, end, e / per_mm, average, (spm,) * 3)
        assert machine.report(t)[1] == pytest.approx(want, abs=1e-9), e
        speed = 90.0 * t * length / 10.0  # along the move
        instant = ticks_taken((0.0,) * 3, end, e / per_mm, speed, (spm,) * 3)
        differs += instant != pytest.approx(want, abs=1e-9)
    assert differs >= 3  # the instant's level (2) would tick Y elsewhere
