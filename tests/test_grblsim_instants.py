"""The emulator's switches and buttons act on the state of their instant.

:meth:`GrblSim.open_door`, :meth:`~GrblSim.close_door`, :meth:`~GrblSim.cycle_start` and
:meth:`~GrblSim.drop_link` come from another thread than the emulator's, which may not have
run the events before their instant yet (under load it wakes late). Here the emulator runs
by a fake clock the test moves on without running it, as a late thread would leave it.
"""

from __future__ import annotations

import math

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
