"""Before streaming: compare the controller's ``$$`` with the machine profile and the job."""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from scratchfab.console import duration_text
from scratchfab.machine.grbl_codes import MM_PER_INCH
from scratchfab.machine.sender_program import (
    Block,
    Modal,
    Program,
    block_words,
    known_xyz,
    servo_up,
    strip_block,
    work_xyz,
    z_levels,
)

_AXES = "XYZ"
#: One digit of GRBL's coordinate reports in mm: 3 decimals in mm, 4 in inches under
#: ``$13=1`` (``N_DECIMAL_COORDVALUE_MM`` / ``_INCH``), so 0.001 mm or 0.00254 mm.
REPORT_DIGIT_MM = {False: 0.001, True: 0.0001 * MM_PER_INCH}
#: A change of GRBL's ``$11`` is told when it moves the job's time by more than this
#: share (and more than a second).
JUNCTION_TIME_SHARE = 0.01


def offset_tolerance_mm(inches: bool) -> float:
    """How far apart two readings of one work offset can be, per axis (mm).

    A reading is a sum of numbers GRBL printed, each rounded to a report digit ``d``:
    ``$#`` prints G5x, G92 and the tool length offset (on Z) apiece, a status report's
    ``WCO:`` prints their sum once. Two readings of one zero differ by their rounding
    errors, under ``3 * d/2 + 3 * d/2 = 3 d``, and both are whole multiples of ``d``: at
    most ``2 d`` apart. Half a digit more covers GRBL's float32 sums, its inch factor
    (0.0393701 for 1/25.4), the journal's 4 decimals of mm and a reading in the other unit
    (under ``1.5 d_mm + 1.5 d_inch``); a zero moved by 3 digits is told.

    Args:
        inches: Either reading came in inch reports (``$13=1``).
    """
    return 2.5 * REPORT_DIGIT_MM[inches]


def same_offset(a: Sequence[float], b: Sequence[float], inches: bool = False) -> bool:
    """Whether two work offsets in mm are one zero as GRBL reports it, axis by axis.

    ``inches``: either was read in inch reports (``$13=1``), whose digit is coarser.
    """
    limit = offset_tolerance_mm(inches)
    return max(abs(x - y) for x, y in zip(a, b, strict=True)) <= limit


class _Envelope(Protocol):
    @property
    def x_mm(self) -> tuple[float, float]: ...

    @property
    def y_mm(self) -> tuple[float, float]: ...

    @property
    def z_mm(self) -> tuple[float, float]: ...

    @property
    def max_travel_mm(self) -> tuple[float, float, float | None]: ...

    @property
    def coordinates(self) -> str: ...


class _Motion(Protocol):
    @property
    def max_rate_mm_min(self) -> tuple[float, float, float]: ...

    @property
    def acceleration_mm_s2(self) -> tuple[float, float, float]: ...

    @property
    def junction_deviation_mm(self) -> float: ...


class MachineLike(Protocol):
    """What the comparison reads from a machine profile (:class:`MachineProfile` fits)."""

    @property
    def name(self) -> str: ...  # noqa: D102

    @property
    def envelope(self) -> _Envelope: ...  # noqa: D102

    @property
    def motion(self) -> _Motion: ...  # noqa: D102


@dataclass
class Findings:
    """Warnings (stream anyway) and refusals (do not stream)."""

    warnings: list[str] = field(default_factory=list)
    refusals: list[str] = field(default_factory=list)


def job_extent(program: Program) -> tuple[list[float], list[float]]:
    """Per-axis [min], [max] of the programmed positions and arc sweeps (work mm).

    Only where the sender knows them (:func:`_axis_values`). Positions after a block the
    sender cannot follow (``Block.unfollowed``) are not trustworthy; :func:`compare`
    refuses such jobs.
    """
    lo = [math.inf] * 3
    hi = [-math.inf] * 3
    for k in range(3):
        for _, values in _axis_values(program, k):
            lo[k], hi[k] = min(lo[k], *values), max(hi[k], *values)
    return lo, hi


def _axis_values(program: Program, k: int) -> Iterator[tuple[Block, list[float]]]:
    """Per motion block, the values axis ``k`` reaches there (its end, an arc's sweep).

    Where known wherever the job began (:func:`known_xyz`): not Z before the file sets
    it, nor an axis still counted from the start the parse assumes (work X0 Y0, until
    :meth:`Program.placed_at` puts it where the machine stands), nor an arc's sweep from
    or to an X or Y so unknown.
    """
    before = known_xyz(Modal())
    for b in program.blocks:
        start, before = before, known_xyz(b.modal)
        if not b.motion:
            continue
        v = before[k]
        values = [] if v is None else [v]
        if b.arc_box is not None and k < 2 and None not in (*start[:2], *before[:2]):
            values += list(b.arc_box[2 * k : 2 * k + 2])
        if values:
            yield b, values


def _first_outside(program: Program, k: int, lo: float, hi: float) -> str:
    """``file:line`` of the first block whose axis ``k`` leaves ``lo..hi`` (mm), else ``file``."""
    line = _line_outside(program, k, lo, hi)
    return str(program.path) if line is None else f"{program.path}:{line}"


def _line_outside(program: Program, k: int, lo: float, hi: float) -> int | None:
    """The line number of the first block whose axis ``k`` leaves ``lo..hi`` (mm), else None."""
    for b, values in _axis_values(program, k):
        if min(values) < lo or max(values) > hi:
            return b.lineno
    return None


def _first_spanning(program: Program, k: int, span: float) -> str:
    """``file:line`` of the block at which axis ``k`` has spanned more than ``span`` mm."""
    lo, hi = math.inf, -math.inf
    for b, values in _axis_values(program, k):
        lo, hi = min(lo, *values), max(hi, *values)
        if hi - lo > span:
            return f"{program.path}:{b.lineno}"
    return str(program.path)


def axis_feeds(program: Program) -> list[float]:
    """The highest speed (mm/min) the job's feed moves ask of each axis, X, Y and Z.

    A G1 move at feed F runs each axis at F times its share of the move's length, which
    GRBL clamps to the axis' max rate ``$11x``. Arcs (G17) count at the full feed on X and Y.
    G0 runs at the max rates by definition, and G93's F is not a speed, so neither counts.
    """
    fastest = [0.0, 0.0, 0.0]
    prev = Modal()
    for b in program.blocks:
        m = b.modal
        if b.motion and not b.unfollowed and m.feed_mode == "G94" and m.motion != "G0":
            # an axis whose position is unknown at an end is not known to move; one counted
            # from the assumed start at both ends moves as counted (wherever the job began)
            delta = [
                v - u
                if u is not None and v is not None and (a in prev.assumed) == (a in m.assumed)
                else 0.0
                for a, u, v in zip("XYZ", work_xyz(prev), work_xyz(m), strict=True)
            ]
            length = math.hypot(*delta)
            share = [abs(d) / length if length > 0 else 0.0 for d in delta]
            if m.motion in ("G2", "G3"):
                share[0] = share[1] = 1.0
            for k in range(3):
                fastest[k] = max(fastest[k], m.feed_mm * share[k])
        prev = m
    return fastest


def compare(
    settings: dict[int, float],
    wco: tuple[float, float, float] | None,
    program: Program,
    profile: MachineLike | None = None,
    tolerance: float = 0.01,
    grbl_seconds: float | None = None,
    start_xy: Sequence[float] | None = None,
    wcs: str | None = "G54",
    tlo: float = 0.0,
) -> Findings:
    """Compare GRBL's settings, the job and (optionally) the machine profile.

    Refuses a job that leaves the profile's envelope, spans more than GRBL's travel
    ``$13x`` on any axis, or leaves the travel in machine coordinates
    (``-$13x <= work + WCO <= 0``) when soft limits (``$20=1``) or homing (``$22=1``)
    reference it; with ``wco`` None, an unknown work offset, and soft limits on, such a
    job is refused as unchecked. Refuses a profile whose travel exceeds GRBL's with soft
    limits on, and a profile written in machine coordinates (``coordinates = "machine"``)
    unless the work offset is known to be zero. With any of those checks to make, refuses
    a job holding a block whose position the sender cannot follow (G92, G10, another work
    coordinate system, a change of the tool length offset (G43.1, G49), G53, G28/G30,
    arcs outside G17): past it every check would be wrong. Warns about a GRBL travel
    longer than a machine-coordinate profile's envelope (a work-coordinate one names where
    the job may go, not the travel), GRBL max rates slower than the profile's or the
    job's feeds, accelerations lower than the profile's,
    a junction deviation ``$11`` other than the profile's that moves the job's time
    (:func:`junction_time_change`), and soft limits or homing being off. Every refusal
    starts with the G-code file (``file:line:`` at the first line that goes too far,
    where one does).

    ``grbl_seconds``: the job's time with ``settings``, where already computed (the
    ETA's, :func:`eta_settings`); the ``$11`` check then times the job only at the
    profile's ``$11``, and not at all when both are the same.

    ``start_xy``: where a fresh stream starts, work X and Y (mm) in the controller's work
    system ``wcs`` (the status report's ``WPos`` and ``$G``, as the stream reads them): the
    job's first moves are checked from there (:meth:`Program.placed_at`), as the machine
    runs them. None (a resume, or not known): the positions the file counts from where
    its job began (work X0 Y0 until it gives X or Y in absolute mode) are left out. A job
    that leaves the envelope only from there is refused naming the machine's position as
    such (:func:`_envelope_refusals`); where a work-coordinate profile meets a work offset
    of 0 on an axis refused, the last refusal says how to set the work zero.

    ``tlo``: the tool length offset on Z the machine has (mm, ``$#``'s ``[TLO:]``). The
    parse takes the file's first G49 (or G43.1 Z0) for GRBL's 0 after a reset, no change;
    with an offset set on the machine it moves work Z by it: refused as not followed.
    """
    own = program  # the file's own positions, without where the machine stands
    if start_xy is not None:
        program = program.placed_at(start_xy, wcs)
    out = Findings()
    path = program.path
    travel = [settings.get(130 + k) for k in range(3)]
    rates = [settings.get(110 + k) for k in range(3)]
    soft = bool(settings.get(20, 0))
    homed = bool(settings.get(22, 0))
    if settings and not soft:
        out.warnings.append(
            "GRBL soft limits are off ($20=0): nothing stops a move past the travel"
        )
    # a work-coordinate profile counts from the work zero set on the board: homing is no
    # need there, and the warning came on every stream of a plotter that has none
    work_frame = profile is not None and profile.envelope.coordinates != "machine"
    if settings and not settings.get(22, 0) and not work_frame:
        out.warnings.append("GRBL homing is off ($22=0): machine coordinates are not referenced")
    laser = laser_mode_warning(settings, program, profile)
    if laser is not None:
        out.warnings.append(laser)
    lo, hi = job_extent(program)
    unset = ""  # axes refused where a work-coordinate profile meets a work offset of 0
    if profile is not None or settings:
        unfollowed = [block for block in program.blocks if block.unfollowed]
        first = next((b for b in program.blocks if b.modal.tlo is not None), None)
        if first is not None and not first.unfollowed and tlo != 0.0:
            out.refusals.append(
                f"{path}:{first.lineno}: {first.text!r} cancels the tool length offset the "
                f"machine has ([TLO:] {tlo:.3f} mm, read with $#), moving work Z by it; the "
                "sender cannot follow the position past it, so the envelope cannot be "
                "checked: clear the offset (send G49) before streaming"
            )
        for block in unfollowed[:3]:
            out.refusals.append(
                f"{program.path}:{block.lineno}: {block.unfollowed} ({block.text!r}); the "
                "sender cannot follow the position past it, so the envelope cannot be checked"
            )
        if len(unfollowed) > 3:
            out.refusals.append(f"{path}: ... and {len(unfollowed) - 3} more such lines")
    if profile is not None:
        env = profile.envelope
        refusals, unset = _envelope_refusals(own, program, profile, start_xy, wco, tolerance)
        out.refusals += refusals
        # a job that never moves Z (a servo plotter's) is not slowed by GRBL's Z rates
        moves_z = len(z_levels(program.blocks)) > 1
        for k, axis in enumerate(_AXES):
            need = env.max_travel_mm[k]
            have = travel[k]
            if have is None or need is None:
                continue
            if have + tolerance < need:
                text = (
                    f"machine '{profile.name}' expects {need:g} mm of {axis} travel but GRBL has "
                    f"${130 + k}={have:g}"
                )
                if soft:
                    out.refusals.append(f"{path}: {text}")
                else:
                    out.warnings.append(text)
            elif have > need + 1.0 and env.coordinates == "machine":
                # (a work-coordinate envelope is where the job may go, not the travel)
                name = f"{axis.lower()}_mm"
                a, b = (env.x_mm, env.y_mm, env.z_mm)[k]
                out.warnings.append(
                    f"GRBL ${130 + k}={have:g} allows more {axis} travel than machine "
                    f"'{profile.name}' has in its profile ([envelope] {name} = [{a:g}, {b:g}], "
                    f"{need:g} mm): if the machine travels {have:g} mm, set {name} = "
                    f"[{-have:g}, 0] (a stock Grbl's travel after homing; a margin inside it "
                    f"is yours to keep); if not, set ${130 + k}={need:g} so that GRBL's soft "
                    "limits stop where it ends"
                )
            if k == 2 and not moves_z:
                continue
            rate = rates[k]
            want = profile.motion.max_rate_mm_min[k]
            if rate is not None and rate + tolerance < want:
                out.warnings.append(
                    f"GRBL ${110 + k}={rate:g} mm/min is below the {axis} max rate "
                    f"{want:g} of machine '{profile.name}': feeds are clamped, the estimate "
                    "is optimistic"
                )
            accel = settings.get(120 + k)
            want = profile.motion.acceleration_mm_s2[k]
            if accel is not None and accel + tolerance < want:
                out.warnings.append(
                    f"GRBL ${120 + k}={accel:g} mm/s^2 is below the {axis} acceleration "
                    f"{want:g} of machine '{profile.name}': the job takes longer than the "
                    "toolpath's estimate (the ETA here uses GRBL's)"
                )
        if 11 in settings:
            warning = _junction_warning(settings, program, profile, grbl_seconds)
            if warning:
                out.warnings.append(warning)
    for k, axis in enumerate(_AXES):
        t = travel[k]
        if t is not None and lo[k] <= hi[k] and hi[k] - lo[k] > t + tolerance:
            out.refusals.append(
                f"{_first_spanning(program, k, t + tolerance)}: the job spans "
                f"{hi[k] - lo[k]:g} mm in {axis} but GRBL's travel is ${130 + k}={t:g} mm: it "
                "cannot fit on this machine"
            )
    if soft and wco is None and any(a <= b for a, b in zip(lo, hi, strict=True)):
        out.refusals.append(
            f"{path}: GRBL soft limits are on ($20=1) but the work offset could not be read ($# and "
            "the status reports' WCO gave none), so the job cannot be checked against "
            "the travel under the current offset"
        )
    if homed and not soft and wco is None and any(a <= b for a, b in zip(lo, hi, strict=True)):
        out.warnings.append(
            "the work offset could not be read ($# and the status reports' WCO gave none): "
            "the job was not checked against the travel in machine coordinates"
        )
    if (soft or homed) and wco is not None and all(t is not None for t in travel):
        limit = (
            "GRBL soft limits allow -{t:g}..0 (ALARM:2)"
            if soft
            else "the travel after homing is -{t:g}..0 and soft limits are off: the machine "
            "would run into its end (not homed since power-on? home first, $H)"
        )
        for k, axis in enumerate(_AXES):
            if lo[k] > hi[k]:
                continue
            m_lo, m_hi = lo[k] + wco[k], hi[k] + wco[k]
            t = travel[k] or 0.0
            if m_lo < -t - tolerance or m_hi > tolerance:
                where = _first_outside(program, k, -t - tolerance - wco[k], tolerance - wco[k])
                out.refusals.append(
                    f"{where}: the job's {axis} range is {m_lo:g}..{m_hi:g} mm in machine "
                    f"coordinates (work offset {wco[k]:g}); " + limit.format(t=t)
                )
                work = profile is not None and profile.envelope.coordinates == "work"
                unset += axis if work and _zero(wco[k]) else ""
    if profile is not None and profile.envelope.coordinates == "machine":
        out.refusals.extend(
            f"{path}: {text}"
            for text in _machine_frame_refusals(profile.name, wco, bool(settings.get(13, 0)))
        )
    for k, (asked, rate) in enumerate(zip(axis_feeds(program), rates, strict=True)):
        if rate is not None and asked > rate + tolerance:
            out.warnings.append(
                f"the job moves {_AXES[k]} at up to {asked:g} mm/min but GRBL's "
                f"${110 + k}={rate:g} mm/min: GRBL clamps it, the job runs slower"
            )
    if unset:  # said once, last: the error line
        out.refusals.append(f"{path}: {_unset_zero(''.join(a for a in _AXES if a in unset))}")
    return out


def _envelope_refusals(
    own: Program,
    placed: Program,
    profile: MachineLike,
    start_xy: Sequence[float] | None,
    wco: tuple[float, float, float] | None,
    tolerance: float,
) -> tuple[list[str], str]:
    """Where the job leaves the profile's envelope, each from its first line that does.

    Where the file's own positions (``own``) leave it, their range is named per axis.
    Where only the moves from where the machine stands do (``placed``, as
    :meth:`Program.placed_at` draws them), that position is named as such, once for X
    and Y, with what to do: a homed machine whose work offset is still 0 stands at the
    machine's own zero, not on the board, in a work-coordinate profile.

    Returns:
        The refusals, and the axes where a work offset of 0 explains the start's position
        (:func:`_unset_zero` says what to do, once for every check).
    """
    env = profile.envelope
    envelope = f"machine '{profile.name}'"
    lo, hi = job_extent(own)
    p_lo, p_hi = job_extent(placed)
    out: list[str] = []
    started: list[int] = []  # axes that leave the envelope only from the start
    for k, (a, b) in enumerate((env.x_mm, env.y_mm, env.z_mm)):
        if lo[k] <= hi[k] and (lo[k] < a - tolerance or hi[k] > b + tolerance):
            where = _first_outside(own, k, a - tolerance, b + tolerance)
            out.append(
                f"{where}: the job's {_AXES[k]} range [{lo[k]:g}, {hi[k]:g}] mm leaves the "
                f"envelope [{a:g}, {b:g}] of {envelope}"
            )
        elif p_lo[k] <= p_hi[k] and (p_lo[k] < a - tolerance or p_hi[k] > b + tolerance):
            started.append(k)  # (only X and Y are placed)
    if not started:
        return out, ""
    assert start_xy is not None
    ranges = (env.x_mm, env.y_mm)
    lines = [
        _line_outside(placed, k, ranges[k][0] - tolerance, ranges[k][1] + tolerance)
        for k in started
    ]
    first = min((n for n in lines if n is not None), default=None)
    where = str(placed.path) if first is None else f"{placed.path}:{first}"
    at = " ".join(f"{_AXES[k]}{start_xy[k]:g}" for k in range(2))
    bounds = ", ".join(f"{_AXES[k]} [{ranges[k][0]:g}, {ranges[k][1]:g}]" for k in started)
    own_ranges = ", ".join(
        f"{_AXES[k]} [{lo[k]:g}, {hi[k]:g}]" if lo[k] <= hi[k] else f"no {_AXES[k]} of its own"
        for k in started
    )
    if all(ranges[k][0] - tolerance <= start_xy[k] <= ranges[k][1] + tolerance for k in started):
        spans = ", ".join(f"{_AXES[k]} [{p_lo[k]:g}, {p_hi[k]:g}]" for k in started)
        text = (
            f"{where}: run from where the machine stands now (work {at}), the job's moves "
            f"reach {spans} mm, outside the envelope ({bounds}) of {envelope}"
        )
    else:
        text = (
            f"{where}: the machine stands at work {at} now, outside the envelope ({bounds}) of "
            f"{envelope}, and the job's first moves run from there (the file itself: "
            f"{own_ranges} mm)"
        )
    if env.coordinates == "machine":
        return [*out, f"{text}; jog the tool into the envelope, then stream again"], ""
    unset = "".join(_AXES[k] for k in started if wco is not None and _zero(wco[k]))
    if unset:
        return [*out, text], unset
    advice = (
        "jog the tool into the envelope, or, if the work zero is not at the profile's X0 Y0, "
        "jog there and send `G10 L20 P0 X0 Y0` (P0: the work system in use), then stream again"
    )
    return [*out, f"{text}; {advice}"], ""


#: Why G10 sets a work zero a reset keeps: it sets the offset of a work system (G54-G59),
#: which GRBL stores, where a reset clears G92; P0 is the system in use, the one a
#: scratchfab G-code runs in (it selects none).
KEPT = "P0: the work system in use; a reset keeps it, unlike a G92 zero"

#: How to set a work zero again so that a reset keeps it, where the board point is not
#: known: the G-code's own origin, with the axis words GRBL needs (``G10 L20 P0`` alone
#: answers error:26, no axis words).
ZERO_KEPT = (
    "with the tool at the point the G-code counts from (its X0 Y0, Z0 where its Z counts "
    f"from), send `G10 L20 P0 X0 Y0 Z0` there ({KEPT})"
)


def laser_mode_warning(
    settings: Mapping[int, float], program: Program, profile: MachineLike | None
) -> str | None:
    """A servo held up with the spindle output on (``M3 S90``) under GRBL's laser mode.

    With ``$32=1`` GRBL switches the output off in a feed hold (every stop starts with
    one) and runs G0 moves with it off: the servo goes where PWM 0 puts it, and the
    scribe drops onto the board. The up command is the servo profile's ``off``, else
    the file's own (:attr:`Program.tool_up`). None where laser mode is off or not read,
    or the tool is lifted another way.
    """
    if not settings.get(32, 0):
        return None
    tool = getattr(profile, "tool_control", None)  # a MachineProfile's (not every MachineLike's)
    off = tool.command("off") if tool is not None and tool.mode == "servo" else None
    if off is None and not program.pen_mode:
        return None
    up = servo_up(program, off)
    words = dict(block_words(strip_block(up)))
    if not ("M" in words and words["M"] in (3.0, 4.0) and words.get("S", 0.0) > 0.0):
        return None
    return (
        f"GRBL laser mode is on ($32=1) and the scribe is held up by {up!r} with the output "
        "on: laser mode switches it off in a feed hold (every stop, Ctrl-C) and during G0 "
        "moves, where the servo drops the scribe onto the board; turn laser mode off "
        "($32=0) for a servo"
    )


def _zero(offset: float) -> bool:
    """Whether one axis of GRBL's work offset reads 0 (to a report digit, either unit)."""
    return abs(offset) <= offset_tolerance_mm(True)


def _unset_zero(axes: str) -> str:
    """What to do where a work-coordinate profile meets a work offset of 0 on ``axes``."""
    how = []
    if "X" in axes or "Y" in axes:
        how.append(
            "jog the tool to the profile's X0 Y0 (the board's [board] origin point lies at "
            "offset_mm from it) and send `G10 L20 P0 X0 Y0` (P0: the work system in use)"
        )
    if "Z" in axes:
        how.append(
            "lower the tool to the profile's Z0 (where the tool touches the board, for the "
            "[z] heights) and send `G10 L20 P0 Z0`"
        )
    named = " and ".join(filter(None, [", ".join(axes[:-1]), axes[-1]]))
    return (
        f"GRBL's work offset is 0 on {named}, so the work coordinates there are the machine's "
        f"own (no work zero set?): {'; '.join(how)}, then stream again"
    )


def eta_settings(
    settings: Mapping[int, float], profile: MachineLike | None = None
) -> dict[int, float]:
    """The settings the stream's ETA times the job with: GRBL's ``$$``.

    Where the firmware did not report ``$11``, the profile's ``junction_deviation_mm``
    stands in for it (rather than GRBL's default), when a profile is given.
    """
    out = dict(settings)
    if 11 not in out and profile is not None:
        out[11] = profile.motion.junction_deviation_mm
    return out


def junction_time_change(
    settings: Mapping[int, float],
    program: Program,
    junction_deviation_mm: float,
    grbl_seconds: float | None = None,
) -> tuple[float, float]:
    """The job's seconds with GRBL's settings, and how many more than at another ``$11``.

    Both timed by :meth:`Program.timed_for` with GRBL's rates and accelerations (without
    ``$110``-``$112`` and ``$120``-``$122`` corners cannot be timed: the change is 0),
    once per distinct ``$11``: ``grbl_seconds``, where given, is the first timing.
    """
    grbl = program.timed_for(settings).total_seconds if grbl_seconds is None else grbl_seconds
    if settings.get(11) == junction_deviation_mm:
        return grbl, 0.0
    other = program.timed_for({**settings, 11: junction_deviation_mm}).total_seconds
    return grbl, grbl - other


def _junction_warning(
    settings: Mapping[int, float],
    program: Program,
    profile: MachineLike,
    grbl_seconds: float | None = None,
) -> str:
    """A warning when GRBL's ``$11`` moves the job's time from the profile's by enough."""
    want = profile.motion.junction_deviation_mm
    total, change = junction_time_change(settings, program, want, grbl_seconds)
    base = total - change
    if abs(change) <= max(JUNCTION_TIME_SHARE * base, 1.0):
        return ""
    pace, more = ("slower", "longer") if change > 0 else ("faster", "less")
    return (
        f"GRBL $11={settings[11]:g} mm is not the junction deviation {want:g} mm of machine "
        f"'{profile.name}': corners are passed {pace}, the job takes "
        f"{duration_text(abs(change))} {more} ({100 * change / base:+.1f} %) than with the "
        "profile's (the ETA here uses GRBL's $11, the toolpath's estimate the profile's "
        "junction_deviation_mm)"
    )


def _machine_frame_refusals(
    name: str, wco: tuple[float, float, float] | None, inches: bool = False
) -> list[str]:
    """Refuse a profile in machine coordinates unless GRBL's work offset is known to be zero.

    Its G-code moves in the work coordinates, which equal the machine's only with the
    offset cleared; otherwise every move lands that far off, Z into the board or above it.
    """
    fix = "clear it (G10 L2 P0 X0 Y0 Z0 for the work system in use, G92.1, G49) and check with $#"
    if wco is None:
        return [
            f"machine '{name}' is written in GRBL machine coordinates, but the work offset "
            f"could not be read ($# and the status reports' WCO gave none); {fix}"
        ]
    if same_offset(wco, (0.0, 0.0, 0.0), inches):
        return []
    offset = " ".join(f"{axis}{w:g}" for axis, w in zip(_AXES, wco, strict=True))
    return [
        f"machine '{name}' is written in GRBL machine coordinates, but GRBL's work offset "
        f"is {offset} mm: every move would land that far off (Z into the board or above "
        f"it); {fix}"
    ]
