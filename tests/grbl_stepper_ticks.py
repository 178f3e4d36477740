"""Grbl 1.1h's stepper interrupt tick by tick: where it reports a machine mid-move.

A test reference, written from gnea/grbl ``stepper.c`` (v1.1h), independently of the
emulator's closed form:

- ``st_prep_buffer`` carries a segment's partial step as time (``dt_remainder``), so a
  segment's first interrupt tick comes where the exact distance left is a whole number of
  steps, and the interrupt runs an event on the tick that loads a segment: event ``k`` of
  a block runs its first tick at ``k - 1`` events' distance;
- below 8 kHz AMASS runs ``2^L`` ticks an event (``L`` from the cycles per step at 16 MHz
  against ``AMASS_LEVEL1``-``3`` = ``F_CPU`` / 8000, / 4000, / 2000), tick ``i`` at
  ``k - 1 + (i - 1) / 2^L`` events;
- the Bresenham counters are scaled by 8 (``MAX_AMASS_LEVEL`` 3): each starts at half the
  scaled events, adds the axis's scaled steps shifted right by ``L`` each tick, and steps
  the axis when it exceeds the scaled events;
- at rest (a hold ended, a block ended) only whole events have run: ``count - ceil(steps
  left)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

F_CPU = 16_000_000
STEPS_PER_MM = (250.0, 250.0, 250.0)  # $100-$102 defaults


def amass_level(events_per_s: float) -> int:
    """The AMASS level of a segment stepping at ``events_per_s``."""
    cycles = math.ceil(F_CPU / events_per_s)
    for level, cutoff in enumerate((F_CPU // 8000, F_CPU // 4000, F_CPU // 2000)):
        if cycles < cutoff:
            return level
    return 3


def ticks_taken(
    start: Sequence[float],
    end: Sequence[float],
    done: float,
    speed: float,
    steps_per_mm: Sequence[float] = STEPS_PER_MM,
) -> tuple[float, float, float]:
    """Where Grbl reports a machine ``done`` mm into ``start`` -> ``end`` at ``speed`` mm/s.

    ``speed`` 0: at rest, whole events only.
    """
    a = [_lround(p * k) for p, k in zip(start, steps_per_mm, strict=True)]
    b = [_lround(p * k) for p, k in zip(end, steps_per_mm, strict=True)]
    delta = [q - p for p, q in zip(a, b, strict=True)]
    events = max(abs(d) for d in delta)
    pos = list(a)
    if events:
        length = math.sqrt(sum((d / k) ** 2 for d, k in zip(delta, steps_per_mm, strict=True)))
        progress = done / length * events
        level = amass_level(speed * events / length) if speed > 0.0 else 0
        ticks = 1 << level
        scaled = events << 3
        counters = [scaled >> 1] * 3
        for k in range(1, events + 1):
            for i in range(1, ticks + 1):
                if speed > 0.0:
                    runs = (k - 1) + (i - 1) / ticks <= progress + 1e-9
                else:
                    runs = k <= math.floor(progress + 1e-9)
                if not runs:
                    return _mm(pos, steps_per_mm)
                for axis, d in enumerate(delta):
                    counters[axis] += (abs(d) << 3) >> level
                    if counters[axis] > scaled:
                        counters[axis] -= scaled
                        pos[axis] += 1 if d > 0 else -1
    return _mm(pos, steps_per_mm)


def _mm(pos: Sequence[int], steps_per_mm: Sequence[float]) -> tuple[float, float, float]:
    return (pos[0] / steps_per_mm[0], pos[1] / steps_per_mm[1], pos[2] / steps_per_mm[2])


def _lround(x: float) -> int:
    """C's ``lround``: halves away from zero."""
    return int(math.floor(abs(x) + 0.5)) * (1 if x >= 0 else -1)
