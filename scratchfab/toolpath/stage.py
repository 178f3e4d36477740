"""The toolpath stage on a job folder: JOB/optimize (or design) -> JOB/toolpath."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from scratchfab.machine.profile import load_profile
from scratchfab.model.design import load_design
from scratchfab.model.scratches import load_scratches
from scratchfab.toolpath.order import OrderOptions
from scratchfab.toolpath.plan import Toolpath, plan_toolpath, write_preview


def summary(toolpath: Toolpath) -> str:
    """One line: strokes kept and dropped, cut and travel lengths, estimated time."""
    s = toolpath.stats
    dropped = s["outside_count"] + s["short_count"] + s["merged_count"]
    return (
        f"{s['count']} strokes ({dropped} dropped: {s['outside_count']} outside, "
        f"{s['short_count']} too short, {s['merged_count']} duplicates); "
        f"cut {s['cut_length_mm']:.1f} mm, travel {s['travel_length_mm']:.1f} mm "
        f"(input order {s['travel_input_order_mm']:.1f} mm); "
        f"about {s['estimated_time_s'] / 60:.1f} min"
    )


def run_toolpath(
    scratch_file: Path,
    design_file: Path,
    out_dir: Path,
    machine: str | Path,
    options: OrderOptions | None = None,
    say: Callable[[str], Any] = print,
) -> Toolpath:
    """Plan the strokes of ``scratch_file`` for ``machine``; write toolpath.json and preview.png.

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
        say(
            f"warning: {s['outside_count']} scratches lie outside the machine's envelope and "
            f"{s['clipped_count']} were clipped to it: check the profile's [board] offset_mm "
            "and [envelope] (see preview.png)"
        )
    return result


def run_toolpath_job(
    job: Path,
    machine: str | Path,
    options: OrderOptions | None = None,
    say: Callable[[str], Any] = print,
) -> Toolpath:
    """``toolpath JOB``: the job's optimized layout (else the initial one) into JOB/toolpath."""
    from scratchfab.model.job import job_inputs

    design_file, scratch_file = job_inputs(job)
    if scratch_file.parent.name != "optimize":
        say(
            f"note: {job / 'optimize' / 'scratches.csv'} not found (optimize has not run); using {scratch_file}"
        )
    return run_toolpath(scratch_file, design_file, job / "toolpath", machine, options, say)
