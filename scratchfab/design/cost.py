"""What a layout will cost to cut, said when it is made, before any toolpath is planned.

The time is the toolpath stage's own estimate (:func:`scratchfab.toolpath.plan.estimate_time`)
on a named machine profile, over the scratches in the toolpath's first ordering step
(greedy nearest neighbour, :func:`scratchfab.toolpath.order.order_strokes` without its
local search): the travel comes out a little longer than the planned toolpath's (under
1 % more time for 400 scratches on 60 x 50 mm and 11,250 on 150 x 150 mm), and nothing
is clipped to the machine's envelope (a board larger than it is timed whole).
"""

from __future__ import annotations

import numpy as np

from scratchfab.console import duration_text
from scratchfab.errors import ConfigError
from scratchfab.machine.profile import MachineProfile, load_profile, machine_named, profile_ref
from scratchfab.model.design import Board
from scratchfab.model.scratches import ScratchSet
from scratchfab.toolpath.order import OrderOptions, order_strokes
from scratchfab.toolpath.plan import estimate_time

#: The toolpath's greedy ordering alone: no local search, no perturbation trials.
_GREEDY = OrderOptions(passes=0, kicks=0)


def cut_seconds(scratches: ScratchSet, board: Board, profile: MachineProfile) -> float:
    """Seconds to cut every scratch on ``profile``, as the toolpath stage estimates a job.

    Args:
        scratches: Board coordinates (SPEC section 3).
        board: Their board, placed on the machine as the profile's ``[board]`` says.
        profile: The machine (feeds, motion limits, tool control, start position).
    """
    if len(scratches) == 0:
        return 0.0
    size = (board.width_mm, board.height_mm)
    p0 = profile.board_to_machine(scratches.p0, size)
    p1 = profile.board_to_machine(scratches.p1, size)
    tour = order_strokes(p0, p1, profile.start_mm, _GREEDY)
    flip = tour.reverse[:, None]
    first = np.where(flip, p1[tour.order], p0[tour.order])
    last = np.where(flip, p0[tour.order], p1[tour.order])
    return estimate_time(np.stack([first, last], axis=1), profile)


def cut_line(scratches: ScratchSet, board: Board, machine: str | MachineProfile, fewer: str) -> str:
    """One line: the scratch count, the length of cut, and the time on ``machine``.

    Args:
        scratches: The layout.
        board: Its board.
        machine: A bundled profile's name or a profile file (``[toolpath] machine``), or
            the profile itself, loaded (``run`` reads its profile once).
        fewer: What sets the count (``--count``), named as the way to a shorter cut.
    """
    n = len(scratches)
    length_m = float(np.hypot(*(scratches.p1 - scratches.p0).T).sum()) / 1000.0
    head = f"cut: {n} scratches, {length_m:.1f} m of cut"
    try:
        profile = load_profile(machine)
    except ConfigError as exc:
        return f"{head}; no time estimate, toolpath.machine: {exc}"
    seconds = cut_seconds(scratches, board, profile)
    feeds = [f"engrave {profile.feeds.engrave_mm_min:g} mm/min"]
    if profile.tool_control.mode != "servo":
        feeds.append(f"plunge {profile.feeds.plunge_mm_min:g} mm/min")
    machine_text = machine_named(profile.name, profile_ref(profile), ", ".join(feeds))
    return (
        f"{head}; about {duration_text(seconds)} ({seconds / max(n, 1):.1f} s a scratch with "
        f"its travel) on {machine_text}, as toolpath estimates this initial layout, before "
        f"optimize (which usually shortens the cut); {fewer} lays fewer, the time falls about "
        "with the count"
    )
