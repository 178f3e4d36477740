"""``time_scale`` stretches the emulator's motion, and nothing else of it.

Over an instantaneous link (``baud=0``) every instant of a run comes from the motion, so a
run at ``time_scale`` s is the run at 1 with each instant times s: the same segments, the
same blocks freed, the same ``ok``s. Grbl's "very slow segment" rule (a segment runs on
past 10 ms until it holds 1.25 steps) is in the machine's own time; counted in the
scaled time, a slow-motion run (s > 1) merged fewer segments and answered earlier.
"""

from __future__ import annotations

import collections

import pytest
from test_grblsim_free_cache import _job

from scratchfab.machine.grblsim import GrblSim, SimOptions


def _answers(scale: float) -> list[tuple[str, float]]:
    """The record's ``ok``s and block ends of a character-counting stream, by time."""
    clock = [0.0]
    options = SimOptions(baud=0, time_scale=scale, settings={100: 80.0, 101: 80.0})
    sim = GrblSim(options, clock=lambda: clock[0])
    sim.start(thread=False)
    todo = collections.deque((ln + "\n").encode() for ln in _job(seed=5))
    waiting: collections.deque[int] = collections.deque()
    buf = b""
    while todo or waiting:
        while todo and sum(waiting) + len(todo[0]) <= 127:
            waiting.append(sim.host_write(todo.popleft()))
        sim.advance(clock[0])
        buf += sim.host_read(1 << 16, 0.0)
        *answers, buf = buf.split(b"\n")
        for answer in answers:
            if answer.strip() == b"ok":
                waiting.popleft()
        clock[0] = max(clock[0], sim.next_event())
    return [(e["ev"], e["t"]) for e in sim.record if e["ev"] in ("exec", "resp")]


@pytest.mark.parametrize("scale", [0.02, 2.0])
def test_a_scaled_run_is_the_run_at_1_scaled(scale: float) -> None:
    """80 steps/mm (1.25 steps: 0.0156 mm, so a start from rest runs slow segments)."""
    plain, scaled = _answers(1.0), _answers(scale)
    assert [ev for ev, _ in scaled] == [ev for ev, _ in plain]
    assert len(plain) > 400
    for (_, t1), (_, ts) in zip(plain, scaled, strict=True):
        # the record keeps 6 decimals: half a microsecond each side
        assert ts == pytest.approx(scale * t1, abs=0.5e-6 * (1.0 + scale) + 1e-9)
