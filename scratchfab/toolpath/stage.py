"""The toolpath stage on a job folder: JOB/optimize (or design) -> JOB/toolpath."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from scratchfab.console import Say, command_line, duration_text
from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.machine.profile import MachineProfile, load_profile
from scratchfab.model.design import load_design
from scratchfab.model.job import JobLayout, job_inputs, stale_layout, stale_layout_warning
from scratchfab.model.scratches import load_scratches
from scratchfab.toolpath.inputs import (
    check_current,
    initial_layout,
    planned_for,
    profile_changes,
    record_inputs,
)
from scratchfab.toolpath.order import OrderOptions, OrderProgress, OrderProgressCallback
from scratchfab.toolpath.plan import (
    Toolpath,
    plan_toolpath,
    unreached_text,
    write_preview,
)


def summary(toolpath: Toolpath) -> str:
    """One line: strokes kept and dropped, cut and travel lengths, estimated time.

    Scratches off the board are named where there are any (planned in memory: a scratch
    file's are checked when read).
    """
    s = toolpath.stats
    off = int(s.get("off_board_count", 0))
    dropped = off + s["outside_count"] + s["short_count"] + s["merged_count"]
    return (
        f"{s['count']} strokes ({dropped} dropped: "
        f"{f'{off} off the board, ' if off else ''}{s['outside_count']} outside, "
        f"{s['short_count']} too short, {s['merged_count']} duplicates); "
        f"cut {s['cut_length_mm']:.1f} mm, travel {s['travel_length_mm']:.1f} mm "
        f"(input order {s['travel_input_order_mm']:.1f} mm); "
        f"about {duration_text(s['estimated_time_s'])}"
    )


def progress_lines(say: Say) -> OrderProgressCallback:
    """A ``progress`` callback of :func:`plan_toolpath` that says its messages.

    The phases say nothing: the ordering takes seconds, and :func:`summary` follows.
    """

    def tell(p: OrderProgress) -> None:
        if p.message:
            say(p.message)

    return tell


def run_toolpath(
    scratch_file: Path,
    design_file: Path,
    out_dir: Path,
    machine: str | Path | MachineProfile,
    options: OrderOptions | None = None,
    say: Say = lambda _: None,
    refuse_partial: str | None = None,
    job: Path | None = None,
) -> Toolpath:
    """Plan the strokes of ``scratch_file`` for ``machine``; write toolpath.json and preview.png.

    ``machine`` is a profile name or file, or a profile already loaded. A board that the
    machine's envelope cuts short (scratches left out or clipped) is planned for what
    fits, with a warning, unless ``refuse_partial`` names the override (``--force``) that
    would allow it: then it is refused and nothing is written (an earlier toolpath.json
    planned for other machine settings is named, with its profile). toolpath.json records
    the inputs (:func:`~scratchfab.toolpath.inputs.record_inputs`; ``job``: the job
    folder whose layout picked the two files), which export checks.

    Raises:
        ScratchfabError: Bad inputs, tools that differ, a board outside the envelope, or
            (with ``refuse_partial``) one the envelope cuts short.
    """
    profile = load_profile(machine)
    design = load_design(design_file, require_views=False)
    scratches = load_scratches(scratch_file, design.scratch, design.board)
    result = plan_toolpath(
        scratches, design.board, profile, design.scratch, options, progress_lines(say)
    )
    lost = unreached_text(profile, (design.board.width_mm, design.board.height_mm), result.stats)
    if lost is not None:
        if refuse_partial is not None:
            raise ScratchfabError(
                f"{lost}; or give {refuse_partial} to plan only the part it reaches; "
                f"nothing written{_kept_plan(out_dir / 'toolpath.json', profile)}"
            )
    result = replace(result, inputs=record_inputs(scratch_file, design_file, profile, out_dir, job))
    result.save(out_dir / "toolpath.json")
    write_preview(result, out_dir / "preview.png")
    say(summary(result))
    initial = initial_layout(result, out_dir)
    if initial is not None:
        say(unoptimized_warning(initial))
    if lost is not None:
        say(f"warning: {lost} (see preview.png)")
    return result


def unoptimized_warning(initial: Path) -> str:
    """The warning of a toolpath planned from the design's ``initial`` layout.

    Where optimize has not run on the job it names the command; where it has (the
    files given), the job's optimized layout. Export and the G-code header mark it.
    """
    job = JobLayout(initial.parent.parent)
    optimized = job.optimized_scratches
    if optimized.is_file():
        why, advice = f"{job.root}'s optimized layout is {optimized}", ""
    else:
        rerun = command_line(["scratchfab", "optimize", job.root])
        why = f"optimize has not run on {job.root}"
        advice = f"to cut the optimized board, run `{rerun}` first, then toolpath again; "
    return (
        f"warning: {initial} is the design's initial layout, not optimized ({why}); {advice}"
        "planned as it is, export and the G-code header say it is not optimized"
    )


def _kept_plan(file: Path, profile: MachineProfile) -> str:
    """What a refused plan leaves in ``file``, when planned for another profile, else "".

    The earlier toolpath stays as it was; planned for other machine settings than the
    ones refused, export would write it for those, so the refusal says so.
    """
    try:
        earlier = Toolpath.load(file) if file.is_file() else None
    except ConfigError:  # not a toolpath export can write either
        return ""
    if earlier is None or not profile_changes(earlier.profile, profile):
        return ""
    # One that no longer matches its inputs export refuses, and says why.
    exported = "; export writes that plan" if check_current(earlier)[0] is None else ""
    return (
        f": {file} keeps its earlier plan, for {planned_for(earlier)}, not for "
        f"'{profile.name}' ({profile.source}){exported}"
    )


def job_toolpath_inputs(
    job: Path,
    scratches: Path | None = None,
    design: Path | None = None,
    refuse_stale: str | None = None,
) -> tuple[Path, Path, str | None]:
    """The scratch CSV and design a toolpath on ``job`` uses; given files win over the job's.

    Returns:
        (scratches, design, note): ``note`` warns of an optimized layout of an earlier
        design (:func:`~scratchfab.model.job.stale_layout_warning`), else None (the
        initial layout, optimize not run, :func:`run_toolpath` warns of after planning).

    Raises:
        ScratchfabError: The job's optimized layout was made from an earlier design and
            ``refuse_stale`` names the override (``--force``) that would plan it.
    """
    if scratches is not None and design is not None:
        return scratches, design, None
    design_file, scratch_file = job_inputs(job)
    note = None
    if scratches is None and scratch_file == JobLayout(job).optimized_scratches:
        stale = stale_layout(job)
        if stale is not None and refuse_stale is not None:
            rerun = command_line(["scratchfab", "optimize", job])
            raise ScratchfabError(
                f"{stale}: its toolpath would cut the earlier design's layout; rerun "
                f"`{rerun}` first, or give {refuse_stale} to plan it as it is; nothing written"
            )
        note = stale_layout_warning(job)
    return scratches or scratch_file, design or design_file, note


def run_toolpath_job(
    job: Path,
    machine: str | Path | MachineProfile,
    options: OrderOptions | None = None,
    say: Say = lambda _: None,
    refuse_partial: str | None = None,
) -> Toolpath:
    """``toolpath JOB``: the job's optimized layout (else the initial one, warned) into JOB/toolpath.

    ``refuse_partial`` as :func:`run_toolpath`'s.
    """
    scratch_file, design_file, note = job_toolpath_inputs(job)
    if note:
        say(note)
    return run_toolpath(
        scratch_file,
        design_file,
        JobLayout(job).toolpath_dir,
        machine,
        options,
        say,
        refuse_partial,
        job,
    )
