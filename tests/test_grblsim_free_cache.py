"""When a planner block frees, as the emulator keeps it between the events that change it.

A line waiting for a full planner learns when the next block frees from a copy of the
motion run on (``GrblSim._next_free``). The emulator keeps that instant while the motion
runs on as the copy ran it (a change landing, a block ending) and finds it again only
after a new block, override, hold or resume. Reference: the instant found afresh from the
state at every look the waiting line takes.
"""

from __future__ import annotations

import collections
import math

import numpy as np
import pytest

from scratchfab.machine.grblsim import PLANNER_BLOCKS, GrblSim, SimOptions


class _Checked(GrblSim):
    """An emulator that, at each look at a kept instant, also finds it afresh."""

    def __init__(self, options: SimOptions, clock: list[float]) -> None:
        super().__init__(options, clock=lambda: clock[0])
        self.pairs: list[tuple[float, float]] = []

    def _block_free(self, t: float) -> bool:
        queued = self._blocks()
        if self._free_at is not None and queued >= PLANNER_BLOCKS:
            fresh = self._next_free(t, queued - PLANNER_BLOCKS + 1)
            self.pairs.append((self._free_at, fresh))
        return super()._block_free(t)


def _job(seed: int) -> list[str]:
    """Short strokes at mixed feeds between Z moves: the planner stays full."""
    rng = np.random.default_rng(seed)
    lines = ["G21 G90 G94", "G0 Z1"]
    for _ in range(40):
        x, y = rng.uniform(0.0, 50.0, 2)
        lines += [f"G0 X{x:.3f} Y{y:.3f}", "G1 Z-0.1 F300"]
        for _ in range(4):
            x, y = x + rng.uniform(-1.0, 1.0), y + rng.uniform(-1.0, 1.0)
            lines.append(f"G1 X{x:.3f} Y{y:.3f} F{rng.choice([400, 900, 2000])}")
        lines.append("G0 Z1")
    return lines


@pytest.mark.parametrize(
    "settings",
    [{}, {110: 4000.0, 111: 4000.0, 120: 300.0, 121: 300.0, 112: 2000.0, 122: 100.0}],
    ids=["defaults", "fast"],
)
def test_a_kept_free_instant_is_the_one_found_afresh(settings: dict[int, float]) -> None:
    """A character-counting sender with a feed override and a hold and resume on the way."""
    clock = [0.0]
    sim = _Checked(SimOptions(baud=115200, settings=settings), clock)
    sim.start(thread=False)
    todo = collections.deque((ln + "\n").encode() for ln in _job(seed=5))
    waiting: collections.deque[int] = collections.deque()
    buf = b""
    sent = 0
    held = False
    while todo or waiting:
        while todo and sum(waiting) + len(todo[0]) <= 127:
            waiting.append(sim.host_write(todo.popleft()))
            sent += 1
            if sent == 60:
                sim.host_write(bytes([0x91]))  # feed +10 %
            if sent == 120:
                sim.host_write(b"!")
                held = True
        sim.advance(clock[0])
        buf += sim.host_read(1 << 16, 0.0)
        *answers, buf = buf.split(b"\n")
        for answer in answers:
            if answer.strip() == b"ok":
                waiting.popleft()
        if held and sim._state_name() == "Hold:0":
            sim.host_write(b"~")
            held = False
        nxt = sim.next_event()
        assert nxt < math.inf, "the emulator waits, yet lines await their ok"
        clock[0] = max(clock[0], nxt)
    assert "Hold:0" in [e.get("state") for e in sim.record]  # the hold stopped, resumed
    assert len(sim.pairs) > 100  # the waiting line looked at kept instants
    for kept, fresh in sim.pairs:
        assert kept == pytest.approx(fresh, rel=1e-12, abs=1e-9)
