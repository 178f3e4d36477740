"""The toolpath stage on a job folder: JOB/optimize (or design) -> JOB/toolpath."""

from __future__ import annotations

from pathlib import Path

from scratchfab.console import Say, duration_text
from scratchfab.machine.profile import MachineProfile, load_profile
from scratchfab.model.design import load_design
from scratchfab.model.job import JobLayout, job_inputs, stale_layout_warning
from scratchfab.model.scratches import load_scratches
from scratchfab.toolpath.order import OrderOptions
from scratchfab.toolpath.plan import Toolpath, oversize_text, plan_toolpath, write_preview


def summary(toolpath: Toolpath) -> str:
    """One line: strokes kept and dropped, cut and travel lengths, estimated time."""
    s = toolpath.stats
    dropped = s["outside_count"] + s["short_count"] + s["merged_count"]
    return (
        f"{s['count']} strokes ({dropped} dropped: {s['outside_count']} outside, "
        f"{s['short_count']} too short, {s['merged_count']} duplicates); "
        f"cut {s['cut_length_mm']:.1f} mm, travel {s['travel_length_mm']:.1f} mm "
        f"(input order {s['travel_input_order_mm']:.1f} mm); "
        f"about {duration_text(s['estimated_time_s'])}"
    )


def run_toolpath(
    scratch_file: Path,
    design_file: Path,
    out_dir: Path,
    machine: str | Path | MachineProfile,
    options: OrderOptions | None = None,
    say: Say = lambda _: None,
) -> Toolpath:
    """Plan the strokes of ``scratch_file`` for ``machine``; write toolpath.json and preview.png.

    ``machine`` is a profile name or file, or a profile already loaded.

    Raises:
        ScratchfabError: Bad inputs, tools that differ, or a board outside the envelope.
    """
    profile = load_profile(machine)
    design = load_design(design_file, require_views=False)
    scratches = load_scratches(scratch_file, design.scratch, design.board)
    say(f"ordering {len(scratches)} scratches for {profile.name} ...")
    result = plan_toolpath(scratches, design.board, profile, design.scratch, options)
    result.save(out_dir / "toolpath.json")
    write_preview(result, out_dir / "preview.png")
    say(summary(result))
    s = result.stats
    if s["outside_count"] or s["clipped_count"]:
        fix = oversize_text(profile, (design.board.width_mm, design.board.height_mm)) or (
            "check the profile's [board] offset_mm and [envelope]"
        )
        say(
            f"warning: {s['outside_count']} of {s['input_count']} scratches lie outside the "
            f"machine's envelope (not cut) and {s['clipped_count']} were clipped to it: "
            f"{fix} (see preview.png)"
        )
    return result


def job_toolpath_inputs(
    job: Path, scratches: Path | None = None, design: Path | None = None
) -> tuple[Path, Path, str | None]:
    """The scratch CSV and design a toolpath on ``job`` uses; given files win over the job's.

    Returns:
        (scratches, design, note): ``note`` says so when the job's layout is the initial
        one because optimize has not run, or an optimized one of an earlier design
        (:func:`~scratchfab.model.job.stale_layout_warning`), else None.
    """
    if scratches is not None and design is not None:
        return scratches, design, None
    design_file, scratch_file = job_inputs(job)
    optimized = JobLayout(job).optimized_scratches
    note = None
    if scratches is None and scratch_file != optimized:
        note = f"note: {optimized} not found (optimize has not run); using {scratch_file}"
    elif scratches is None:
        note = stale_layout_warning(job)
    return scratches or scratch_file, design or design_file, note


def run_toolpath_job(
    job: Path,
    machine: str | Path | MachineProfile,
    options: OrderOptions | None = None,
    say: Say = lambda _: None,
) -> Toolpath:
    """``toolpath JOB``: the job's optimized layout (else the initial one) into JOB/toolpath."""
    scratch_file, design_file, note = job_toolpath_inputs(job)
    if note:
        say(note)
    return run_toolpath(
        scratch_file, design_file, JobLayout(job).toolpath_dir, machine, options, say
    )
