"""What a layout will cost to cut, said when it is made, before any toolpath is planned.

The time is the toolpath stage's own plan and estimate
(:func:`scratchfab.toolpath.plan.plan_toolpath`) on a named machine profile, with the
ordering's first step only (greedy nearest neighbour,
:func:`scratchfab.toolpath.order.order_strokes` without its local search): the travel
comes out a little longer than the planned toolpath's (under 1 % more time for 400
scratches on 60 x 50 mm and 11,250 on 150 x 150 mm). As in the toolpath stage, what lies
beyond the machine's envelope is left out or clipped, and a warning says so in the
toolpath stage's words, with what to change (design still writes the layout: another
machine, or this one's profile changed, may hold the board).
"""

from __future__ import annotations

import numpy as np

from scratchfab.console import duration_text
from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.machine.profile import MachineProfile, load_profile, machine_named, profile_ref
from scratchfab.model.design import Board
from scratchfab.model.scratches import ScratchSet
from scratchfab.toolpath.order import OrderOptions
from scratchfab.toolpath.plan import Toolpath, partial_text, plan_toolpath, unreached_text

#: The toolpath's greedy ordering alone: no local search, no perturbation trials.
_GREEDY = OrderOptions(passes=0, kicks=0)


def cut_plan(scratches: ScratchSet, board: Board, profile: MachineProfile) -> Toolpath:
    """The toolpath stage's plan of ``scratches`` on ``profile``, greedily ordered.

    The scratches are planned as the machine's tool cuts them: a design for another tool
    is the toolpath stage's to refuse, and the tool changes neither the time nor the reach.

    Args:
        scratches: Board coordinates (SPEC section 3).
        board: Their board, placed on the machine as the profile's ``[board]`` says.
        profile: The machine (envelope, feeds, motion limits, tool control, start).

    Raises:
        ScratchfabError: The board lies wholly outside the machine's envelope (the
            toolpath stage's own refusal, naming what to change).
    """
    tool, n = profile.tool, len(scratches)
    as_cut = ScratchSet(
        scratches.p0, scratches.p1, np.full(n, tool.width_mm), np.full(n, tool.depth_mm)
    )
    return plan_toolpath(as_cut, board, profile, None, _GREEDY)


def cut_lines(
    scratches: ScratchSet,
    board: Board,
    machine: str | MachineProfile,
    fewer: str,
    reach: bool = True,
) -> list[str]:
    """The scratch count and length of cut, then a line a clause: the time on ``machine``.

    The first line is ``cut: N scratches, L m of cut``; each later one is indented by two
    spaces (one clause of the sentence they make joined by ``"; "``), and with ``reach``
    a last ``warning: ...`` line, unindented, says what the machine cannot reach.

    Args:
        scratches: The layout.
        board: Its board.
        machine: A bundled profile's name or a profile file (``[toolpath] machine``), or
            the profile itself, loaded (``run`` reads its profile once).
        fewer: What sets the count (``--count``), named as the way to a shorter cut.
        reach: Warn of a board the machine cannot reach whole (``run`` warned before its
            first stage).
    """
    length_m = float(np.hypot(*(scratches.p1 - scratches.p0).T).sum()) / 1000.0
    lines = [f"cut: {len(scratches)} scratches, {length_m:.1f} m of cut"]
    try:
        profile = load_profile(machine)
    except ConfigError as exc:
        return [*lines, f"  no time estimate, toolpath.machine: {exc}"]
    feeds = [f"engrave {profile.feeds.engrave_mm_min:g} mm/min"]
    if profile.tool_control.mode != "servo":
        feeds.append(f"plunge {profile.feeds.plunge_mm_min:g} mm/min")
    machine_text = machine_named(profile.name, profile_ref(profile), ", ".join(feeds))
    try:
        plan = cut_plan(scratches, board, profile)
    except ScratchfabError as exc:  # the board lies wholly outside the envelope
        lines.append(f"  no time estimate on {machine_text}")
        unreached: str | None = f"the toolpath stage will refuse this layout: {exc}"
    else:
        seconds, cut = float(plan.stats["estimated_time_s"]), int(plan.stats["count"])
        part = " of the part it reaches" if partial_text(plan.stats) is not None else ""
        lines += [
            f"  about {duration_text(seconds)}{part} ({seconds / max(cut, 1):.1f} s a scratch "
            f"with its travel) on {machine_text}",
            "  as toolpath estimates this initial layout, before optimize (which usually "
            "shortens the cut)",
            f"  {fewer} lays fewer, the time falls about with the count",
        ]
        unreached = unreached_text(profile, plan.board_mm, plan.stats)
    if reach and unreached is not None:
        lines.append(f"warning: {unreached}")
    return lines
