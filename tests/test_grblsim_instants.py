"""The emulator's switches and buttons act on the state of their instant.

:meth:`GrblSim.open_door`, :meth:`~GrblSim.close_door`, :meth:`~GrblSim.cycle_start` and
:meth:`~GrblSim.drop_link` come from another thread than the emulator's, which may not have
run the events before their instant yet (under load it wakes late). Here the emulator runs
by a fake clock the test moves on without running it, as a late thread would leave it.
"""

from __future__ import annotations

import math

import pytest

from scratchfab.machine.grblsim import GrblSim, SimOptions


def _sim_at_rest() -> tuple[GrblSim, list[float]]:
    clock = [0.0]
    sim = GrblSim(SimOptions(baud=0), clock=lambda: clock[0])
    sim.start(thread=False)
    sim.advance(0.0)
    return sim, clock


def _until(sim: GrblSim, clock: list[float], state: str) -> None:
    """Run the emulator event by event until its report's state is ``state``."""
    while sim._state_name() != state:
        t = sim.next_event()
        assert t < math.inf, f"the emulator waits before {state}"
        clock[0] = max(clock[0], t)
        sim.advance(clock[0])
        sim.host_read(1 << 16, 0.0)  # bytes for the host are events too


def _states(sim: GrblSim) -> list[str]:
    return [e["state"] for e in sim.record if e["ev"] == "state"]


def _in_time_order(sim: GrblSim) -> bool:
    times = [e["t"] for e in sim.record]
    return times == sorted(times)


def test_a_door_opened_after_the_move_ended_finds_the_machine_idle():
    """The move (1 mm from rest at 10 mm/s^2: 0.63 s) ended before the door opened at 5 s:
    the door stops nothing (Door:1 at once, not Door:2's stop of a move that had ended)."""
    sim, clock = _sim_at_rest()
    sim.host_write(b"G1X1F600\n")
    _until(sim, clock, "Run")
    end = 2.0 * math.sqrt(1.0 / 10.0)  # the reference: a triangle profile at $120 = 10
    clock[0] = 5.0
    sim.open_door()
    assert _states(sim)[-3:] == ["Run", "Idle", "Door:1"]
    (done,) = [e for e in sim.record if e["ev"] == "exec"]
    assert abs(done["t"] - end) < 1e-6
    assert _in_time_order(sim)


def test_a_cycle_start_after_the_hold_completed_resumes():
    """A feed hold that completed before the button was pressed: the cycle start resumes
    (it is lost if taken for one during Hold:1, which Grbl ignores) and the move ends."""
    sim, clock = _sim_at_rest()
    sim.host_write(b"G1X5F600\n")
    _until(sim, clock, "Run")
    clock[0] = 0.5
    sim.host_write(b"!")
    _until(sim, clock, "Hold:1")
    clock[0] += 10.0  # the hold (at most 1 s from 10 mm/s) completed unseen
    sim.cycle_start()
    assert _states(sim)[-2:] == ["Hold:0", "Run"]
    _until(sim, clock, "Idle")
    assert [e["ev"] for e in sim.record].count("exec") == 1
    assert sim.mpos == (5.0, 0.0, 0.0)
    assert _in_time_order(sim)


def test_a_link_dropped_after_the_move_ended_keeps_its_end():
    """A board powered over USB loses power when the link drops: the move that had ended
    before is whole (no partial move logged at the drop's instant)."""
    clock = [0.0]
    sim = GrblSim(SimOptions(baud=0, usb_powered=True), clock=lambda: clock[0])
    sim.start(thread=False)
    sim.advance(0.0)
    sim.host_write(b"G1X1F600\n")
    _until(sim, clock, "Run")
    clock[0] = 5.0
    sim.drop_link()
    assert [e["ev"] for e in sim.record if e["ev"] in ("exec", "partial")] == ["exec"]
    assert sim.mpos == (1.0, 0.0, 0.0)
    assert _in_time_order(sim)


# ------------------------------------------- a planner block frees once it is all prepared


def _full_planner(moves: int) -> tuple[GrblSim, list[float]]:
    """``moves`` 2 mm moves at 10 mm/s written at once (the RX buffer holds them), run by
    the fake clock until the motion ends; the host reads all along."""
    sim, clock = _sim_at_rest()
    sim.host_write(b"G1F600\n" + b"".join(f"X{2 * (k + 1)}\n".encode() for k in range(moves)))
    _until(sim, clock, "Run")
    _until(sim, clock, "Idle")
    return sim, clock


def test_a_line_waiting_for_a_block_is_planned_once_the_running_one_is_all_prepared():
    """Grbl frees a planner block when ``st_prep_buffer`` has prepared its last segment
    (``plan_discard_current_block``), not when it ends: the line waiting for a block gets
    its ``ok`` when the segment 5 ends (the buffer) before the block's end has run.

    The reference: a block runs from the previous one's end (its segments' 10 ms grid
    starts there, all 10 ms at these speeds, the last one shorter), so the 5th segment end
    before the block's end is at ``start + (ceil((end - start) / 10 ms) - 5) * 10 ms``:
    40 to 50 ms before the block ends.
    """
    sim, _ = _full_planner(20)
    ends = [e["t"] for e in sim.record if e["ev"] == "exec"]  # block k ends at ends[k - 1]
    rx = {e["n"]: e for e in sim.record if e["ev"] == "rx"}
    oks = {e["n"]: e["t"] for e in sim.record if e["ev"] == "resp"}
    dt = 0.01
    assert len(ends) == 20
    waited = 0
    for n in sorted(oks):
        # line n (G1F600 is 1) moves block n - 1; it waits for block n - 16 (1-based)
        k = n - 16
        if k < 2 or rx[n]["text"] == "G1F600":
            continue
        start, end = ends[k - 2], ends[k - 1]
        free = start + (math.ceil((end - start) / dt - 1e-9) - 5) * dt
        assert 0.04 - 1e-9 <= end - free <= 0.05 + 1e-9
        assert oks[n] == pytest.approx(free, abs=1e-6), n
        waited += 1
    assert waited == 4


def test_bf_counts_a_block_free_once_all_its_segments_are_prepared():
    """15 moves fill the planner (``Bf:0``); in the last 40-50 ms of the running block its
    block is free (``Bf:1``), though the machine is still in it."""
    moves = b"G1F600\n" + b"".join(f"X{2 * (k + 1)}\n".encode() for k in range(15))
    sim, clock = _sim_at_rest()
    sim.host_write(moves)
    _until(sim, clock, "Run")
    start = clock[0]
    while not any(e["ev"] == "exec" for e in sim.record):
        clock[0] = sim.next_event()
        sim.advance(clock[0])
        sim.host_read(1 << 16, 0.0)
    end = next(e["t"] for e in sim.record if e["ev"] == "exec")
    assert end - start > 0.1

    def bf_at(t: float) -> str:
        fresh = GrblSim(SimOptions(baud=0, settings={10: 3}), clock=lambda: clock[0])
        clock[0] = 0.0
        fresh.start(thread=False)
        fresh.advance(0.0)
        fresh.host_write(moves)
        clock[0] = t
        fresh.advance(t)
        fresh.host_read(1 << 16, 0.0)
        fresh.host_write(b"?")
        fresh.advance(t)
        report = fresh.host_read(1 << 16, 0.0).decode()
        return report.split("Bf:")[1].split(",")[0]

    assert bf_at(end - 0.06) == "0"
    assert bf_at(end - 0.03) == "1"
