"""A small model of Grbl 1.1's motion planner that times G-code (a test reference).

Written for the tests from Grbl 1.1's documented behaviour (gnea/grbl ``planner.c``,
``gcode.c``, ``spindle_control.c``, ``motion_control.c``), independently of
:mod:`scratchfab.toolpath.timing`, which it checks. What it models:

- Each ``G0``/``G1`` becomes a block. Its length and unit vector come from positions
  rounded to whole steps (``$100``-``$102``); a block of no steps is dropped and does not
  change the previous direction. Its acceleration and its rate cap are the largest that
  keep every axis within ``$120``-``$122`` and ``$110``-``$112`` along that direction;
  a ``G0`` runs at the cap, a ``G1`` at its feed if lower.
- A junction's speed is at most the centripetal speed of junction deviation ``$11``
  (``v^2 = a_j d sin(t/2) / (1 - sin(t/2))``, with ``a_j`` the acceleration allowed along
  the difference of the unit vectors), a straight continuation is free, a reversal stops,
  and no block enters faster than its own or the previous block's nominal speed.
- Look-ahead: the planner holds ``buffer_blocks`` blocks (Grbl: 15), the executing one
  included, and the newest ends at rest. A sender that keeps the buffer full is assumed,
  so while block ``i`` runs the planner holds blocks ``i`` to ``i + 14``.
- Synchronising commands empty the planner first, so motion stops there and the next
  block starts from rest: a change of spindle state (``M3``/``M4``/``M5``), a new ``S``
  while the spindle runs, ``G4`` (then it waits ``P`` seconds) and ``M2``/``M30``.

Not modelled here: the stepper's segment timing (a few milliseconds), the serial link.

:class:`Stepper` runs planned blocks in small time steps instead, with feed holds and
overrides at any moment: a reference for the slowdown that is not built from profiles.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

GRBL_BUFFER_BLOCKS = 15  # BLOCK_BUFFER_SIZE 16, one slot always free
GRBL_JUNCTION_DEVIATION_MM = 0.01  # $11 default
GRBL_STEPS_PER_MM = (250.0, 250.0, 250.0)  # $100-$102 defaults
_STRAIGHT = 0.999999  # |cos| beyond which a junction counts as straight or reversing

_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass(frozen=True)
class Settings:
    """The Grbl settings that shape motion (mm, mm/min, mm/s^2 as ``$$`` shows them)."""

    max_rate_mm_min: tuple[float, float, float]  # $110-$112
    acceleration_mm_s2: tuple[float, float, float]  # $120-$122
    junction_deviation_mm: float = GRBL_JUNCTION_DEVIATION_MM  # $11
    steps_per_mm: tuple[float, float, float] = GRBL_STEPS_PER_MM  # $100-$102
    laser_mode: bool = False  # $32: an S change in a block with axis words does not stop


@dataclass
class Block:
    """One planned line: length (mm), nominal speed, acceleration, max entry speed^2."""

    length: float
    unit: tuple[float, float, float]
    nominal: float  # mm/s
    accel: float  # mm/s^2
    max_entry_sq: float  # (mm/s)^2, junction and nominal speeds included
    junction_sq: float = math.inf  # (mm/s)^2, the corner alone (0 from rest)
    rapid: bool = False
    rate: float = math.inf  # mm/s: the feed of a G1, the axis-limited cap of a G0
    cap: float = math.inf  # mm/s: the axis-limited rate along the block


@dataclass
class Run:
    """The simulated run: total seconds and where they went."""

    seconds: float = 0.0
    motion_s: float = 0.0
    dwell_s: float = 0.0
    blocks: int = 0
    syncs: int = 0  # planner emptied by a command (motion stopped there)
    junction_speeds: list[float] = field(default_factory=list)  # mm/s, between joined blocks


def axis_limited(limits: Sequence[float], unit: Sequence[float]) -> float:
    """The largest value along ``unit`` that keeps each axis within its limit."""
    return min((lim / abs(u) for lim, u in zip(limits, unit, strict=True) if u != 0.0))


def block_seconds(length: float, v0: float, v1: float, vmax: float, accel: float) -> float:
    """Seconds over a block entered at ``v0`` and left at ``v1`` (trapezoid or triangle)."""
    up = (vmax * vmax - v0 * v0) / (2.0 * accel)
    down = (vmax * vmax - v1 * v1) / (2.0 * accel)
    if up + down <= length:
        return (vmax - v0) / accel + (length - up - down) / vmax + (vmax - v1) / accel
    peak = math.sqrt(max(accel * length + 0.5 * (v0 * v0 + v1 * v1), 0.0))
    peak = max(peak, v0, v1)
    return (peak - v0) / accel + (peak - v1) / accel


class Planner:
    """Turns G-code lines into planned blocks between synchronisations, and times them."""

    def __init__(
        self,
        settings: Settings,
        start: Sequence[float] = (0.0, 0.0, 0.0),
        buffer_blocks: int | None = GRBL_BUFFER_BLOCKS,
    ) -> None:
        self.s = settings
        self.rate = [r / 60.0 for r in settings.max_rate_mm_min]
        self.accel = list(settings.acceleration_mm_s2)
        self.steps = [_lround(p * k) for p, k in zip(start, settings.steps_per_mm, strict=True)]
        self.target = list(map(float, start))
        self.buffer_blocks = buffer_blocks
        self.pending: list[Block] = []  # blocks since the planner last ran empty
        self.prev_unit: tuple[float, float, float] | None = None
        self.prev_nominal = 0.0
        self.motion = "G0"
        self.feed: float | None = None
        self.spindle = "M5"
        self.speed = 0.0
        self.run = Run()

    def line(self, text: str) -> None:
        """Execute one G-code line as Grbl's parser would (the words this writer uses)."""
        body = re.sub(r"\(.*?\)|;.*$", "", text).replace(" ", "").upper()
        if not body:
            return
        words = _WORD.findall(body)
        if "".join(a + b for a, b in words) != body:
            raise ValueError(f"cannot read G-code line {text!r}")
        axes: dict[int, float] = {}
        dwell = None
        spindle = None
        ending = False
        speed_sync = False
        for letter, raw in words:
            value = float(raw)
            if letter == "G":
                if value in (0.0, 1.0):
                    self.motion = f"G{int(value)}"
                elif value == 4.0:
                    dwell = 0.0
                elif value not in (17.0, 21.0, 90.0, 94.0):
                    raise ValueError(f"G{raw} not modelled ({text!r})")
            elif letter == "M":
                if value in (3.0, 4.0, 5.0):
                    spindle = f"M{int(value)}"
                elif value in (2.0, 30.0):
                    ending = True
                else:
                    raise ValueError(f"M{raw} not modelled ({text!r})")
            elif letter in "XYZ":
                axes["XYZ".index(letter)] = value
            elif letter == "F":
                self.feed = value
            elif letter == "P":
                dwell = value
            elif letter == "S":
                speed_sync = value != self.speed and self.spindle != "M5"
                self.speed = value
            else:
                raise ValueError(f"word {letter} not modelled ({text!r})")
        if speed_sync and not (self.s.laser_mode and axes):
            self.synchronize()
        if spindle is not None and spindle != self.spindle:
            self.synchronize()
            self.spindle = spindle
        if dwell is not None:
            self.synchronize()
            self.run.dwell_s += dwell
        if axes:
            target = [axes.get(k, self.target[k]) for k in range(3)]
            self.move(target, rapid=self.motion == "G0")
        if ending:
            self.synchronize()

    def move(self, target: list[float], rapid: bool) -> None:
        """Add a line to the planner (``plan_buffer_line``)."""
        self.target = target
        steps = [_lround(p * k) for p, k in zip(target, self.s.steps_per_mm, strict=True)]
        delta = [
            (b - a) / k for a, b, k in zip(self.steps, steps, self.s.steps_per_mm, strict=True)
        ]
        if steps == self.steps:
            return
        self.steps = steps
        length = math.sqrt(sum(d * d for d in delta))
        unit = (delta[0] / length, delta[1] / length, delta[2] / length)
        accel = axis_limited(self.accel, unit)
        cap = axis_limited(self.rate, unit)
        if rapid:
            nominal = cap
        else:
            if self.feed is None:
                raise ValueError("G1 without a feed (Grbl error 22)")
            nominal = min(self.feed / 60.0, cap)
        nominal = max(nominal, 1.0 / 60.0)  # MINIMUM_FEED_RATE
        if not self.pending or self.prev_unit is None:
            junction_sq = 0.0  # the planner is empty: start from rest
        else:
            cos = -sum(p * u for p, u in zip(self.prev_unit, unit, strict=True))
            if cos > _STRAIGHT:
                junction_sq = 0.0
            elif cos < -_STRAIGHT:
                junction_sq = math.inf
            else:
                diff = [u - p for p, u in zip(self.prev_unit, unit, strict=True)]
                norm = math.sqrt(sum(d * d for d in diff))
                a_j = axis_limited(self.accel, [d / norm for d in diff])
                half = math.sqrt(0.5 * (1.0 - cos))
                junction_sq = a_j * self.s.junction_deviation_mm * half / (1.0 - half)
        entry_cap = min(nominal, self.prev_nominal)
        rate = cap if rapid else self.feed / 60.0  # type: ignore[operator]
        self.pending.append(
            Block(
                length,
                unit,
                nominal,
                accel,
                min(entry_cap**2, junction_sq),
                junction_sq,
                rapid,
                rate,
                cap,
            )
        )
        self.prev_unit = unit
        self.prev_nominal = nominal

    def synchronize(self) -> None:
        """Run every pending block to a stop (``protocol_buffer_synchronize``)."""
        if not self.pending:
            return
        self.run.syncs += 1
        blocks = self.pending
        self.pending = []
        n = len(blocks)
        window = n if self.buffer_blocks is None else self.buffer_blocks
        v = 0.0
        for i, b in enumerate(blocks):
            last = min(i + window - 1, n - 1)
            exit_sq = 0.0  # entry of block i + 1 seen from the planner's newest block
            for j in range(last, i, -1):
                exit_sq = min(
                    blocks[j].max_entry_sq, exit_sq + 2.0 * blocks[j].accel * blocks[j].length
                )
            exit_sq = min(exit_sq, v * v + 2.0 * b.accel * b.length)
            v1 = math.sqrt(exit_sq)
            self.run.motion_s += block_seconds(b.length, v, v1, b.nominal, b.accel)
            if i + 1 < n:
                self.run.junction_speeds.append(v1)
            v = v1
        self.run.blocks += n


def simulate(
    lines: Iterable[str],
    settings: Settings,
    start: Sequence[float] = (0.0, 0.0, 0.0),
    buffer_blocks: int | None = GRBL_BUFFER_BLOCKS,
) -> Run:
    """Time a program from ``start`` (machine at rest there); the program ends at rest."""
    planner = Planner(settings, start, buffer_blocks)
    for text in lines:
        planner.line(text)
    planner.synchronize()
    run = planner.run
    run.seconds = run.motion_s + run.dwell_s
    return run


def queued_blocks(
    lines: Iterable[str], settings: Settings, start: Sequence[float] = (0.0, 0.0, 0.0)
) -> list[Block]:
    """The blocks ``lines`` queue in an empty planner (lines that empty it are not allowed)."""
    planner = Planner(settings, start)
    for text in lines:
        planner.line(text)
    if planner.run.syncs:
        raise ValueError("a line emptied the planner")
    return planner.pending


class Stepper:
    """Runs planned blocks in small time steps, all of them in the planner, from rest.

    Each step the speed changes by at most the block's acceleration times ``dt``, towards
    the fastest it may have where it will be: the block's nominal speed under the
    overrides (a G1 its feed times the feed override, capped by the axis rates; a G0 the
    cap times the rapid override; 1 mm/min at least), yet slow enough to brake, at each
    block's acceleration, to every later block's entry limit (its corner, both nominal
    speeds) and to a stop at the end. A held machine only slows down, at the acceleration
    of the block it is in, until it stands. Nothing here comes from a profile's closed form.

    Args:
        blocks: The planned blocks (:func:`queued_blocks`).
        start: Where the first block starts (mm).
        dt: The time step (s).
    """

    def __init__(
        self, blocks: Sequence[Block], start: Sequence[float] = (0.0, 0.0, 0.0), dt: float = 1e-4
    ) -> None:
        self.blocks = list(blocks)
        self.start = list(map(float, start))
        self.dt = dt
        self.ends = []
        total = 0.0
        for b in self.blocks:
            total += b.length
            self.ends.append(total)
        self.s = 0.0  # mm along the path
        self.v = 0.0  # mm/s
        self.t = 0.0  # s
        self.held = False
        self.feed_override = 100  # %
        self.rapid_override = 100  # %

    def nominal(self, b: Block) -> float:
        """A block's speed under the overrides (Grbl's ``plan_compute_profile_nominal_speed``)."""
        if b.rapid:
            speed = b.cap * self.rapid_override / 100.0
        else:
            speed = min(b.rate * self.feed_override / 100.0, b.cap)
        return max(speed, 1.0 / 60.0)

    def _index(self, s: float) -> int:
        return next((k for k, end in enumerate(self.ends) if s < end), len(self.ends) - 1)

    def limit(self, s: float) -> float:
        """The fastest the machine may go at ``s`` (mm/s)."""
        if s >= self.ends[-1]:
            return 0.0
        k = self._index(s)
        lim = self.nominal(self.blocks[k]) ** 2
        shed = 2.0 * self.blocks[k].accel * (self.ends[k] - s)
        for j in range(k + 1, len(self.blocks)):
            b, prev = self.blocks[j], self.blocks[j - 1]
            entry = min(b.junction_sq, self.nominal(b) ** 2, self.nominal(prev) ** 2)
            lim = min(lim, entry + shed)
            shed += 2.0 * b.accel * b.length
        return math.sqrt(min(lim, shed))

    def step(self, dt: float) -> None:
        """Advance ``dt`` seconds."""
        accel = self.blocks[self._index(self.s)].accel
        v = self.v
        if self.held:
            if v <= accel * dt:  # stands within this step
                self.s = min(self.s + 0.5 * v * v / accel, self.ends[-1])
                self.v = 0.0
                self.t += v / accel
                return
            new = v - accel * dt
        else:
            lim = self.limit(self.s + v * dt)
            new = max(v - accel * dt, lim) if v > lim else min(v + accel * dt, lim)
        self.s = min(self.s + 0.5 * (v + new) * dt, self.ends[-1])
        self.v = new
        self.t += dt

    def done(self) -> bool:
        """At rest at the end of the path (within a micrometre)."""
        return self.ends[-1] - self.s < 1e-6 and self.v <= self.blocks[-1].accel * self.dt

    def run_until(self, t: float) -> None:
        """Run to time ``t``; a held machine that stands waits there. ``t`` stays the time
        the motion ended if it ended before."""
        while self.t < t - 1e-12 and not self.done():
            if self.held and self.v == 0.0:
                self.t = t
                return
            self.step(min(self.dt, t - self.t))

    def run_to_stop(self) -> float:
        """Run until the machine stands (held, or at the end); the time it stood."""
        while not self.done() and not (self.held and self.v == 0.0):
            self.step(self.dt)
        return self.t

    def position(self) -> tuple[float, float, float]:
        """Where the machine is (mm)."""
        pos = list(self.start)
        begin = 0.0
        for b, end in zip(self.blocks, self.ends, strict=True):
            run = min(max(self.s - begin, 0.0), b.length)
            pos = [p + u * run for p, u in zip(pos, b.unit, strict=True)]
            begin = end
        return (pos[0], pos[1], pos[2])


def steps_taken(
    start: Sequence[float],
    end: Sequence[float],
    done: float,
    steps_per_mm: Sequence[float] = GRBL_STEPS_PER_MM,
) -> tuple[float, float, float]:
    """Where Grbl 1.1 reports a machine ``done`` mm into the line ``start`` -> ``end`` (mm).

    Grbl counts whole steps (``sys_position``, shown as steps / ``$100``-``$102``). The line
    runs between targets rounded to whole steps (``lround``); its step events are those of
    its longest axis, and ``st_prep_buffer`` has run all but ``ceil(events x mm left /
    length)`` of them. The stepper interrupt then steps each axis by its Bresenham counter
    (``stepper.c``): the counter starts at half the events, adds the axis's steps per
    event and steps the axis each time it exceeds the events (with AMASS, all scaled by 8).
    """
    a = [_lround(p * k) for p, k in zip(start, steps_per_mm, strict=True)]
    b = [_lround(p * k) for p, k in zip(end, steps_per_mm, strict=True)]
    delta = [j - i for i, j in zip(a, b, strict=True)]
    events = max(abs(d) for d in delta)
    length = math.sqrt(sum((d / k) ** 2 for d, k in zip(delta, steps_per_mm, strict=True)))
    pos = list(a)
    if events:
        left = max(length - done, 0.0)
        run = events - math.ceil(events * left / length - 1e-9)
        scaled = events << 3
        counters = [scaled >> 1] * 3
        for _ in range(run):
            for axis, d in enumerate(delta):
                counters[axis] += abs(d) << 3
                if counters[axis] > scaled:
                    counters[axis] -= scaled
                    pos[axis] += 1 if d > 0 else -1
    return (
        pos[0] / steps_per_mm[0],
        pos[1] / steps_per_mm[1],
        pos[2] / steps_per_mm[2],
    )


def _lround(x: float) -> int:
    """C's ``lround``: halves away from zero."""
    return int(math.floor(abs(x) + 0.5)) * (1 if x >= 0 else -1)
