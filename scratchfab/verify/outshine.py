"""What design's feasibility check found about the bare board outshining failing views.

verify's gate and the pipeline's report word it alike: the glint (where no scratch shows
the image) and the glint's shoulder at the layout's groove coverage (where the bare board
still outshines sparse grooves), with the scratch count that clears the shoulder. It
imports no renderer, so the report uses it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from scratchfab.design.feasibility import SHOULDER_WARN_FRACTION


def shoulder_shares(feasibility: Any) -> dict[str, float]:
    """Per view, its shoulder's share of the board where design warned of it.

    ``feasibility`` is ``design/feasibility.json`` as read (None or anything else: none);
    a view is named where its ``shoulder_fraction`` is at least
    :data:`~scratchfab.design.feasibility.SHOULDER_WARN_FRACTION`.
    """
    views = feasibility.get("views") if isinstance(feasibility, Mapping) else None
    shares = {}
    for name, entry in (views if isinstance(views, Mapping) else {}).items():
        share = entry.get("shoulder_fraction") if isinstance(entry, Mapping) else None
        if isinstance(share, int | float) and share >= SHOULDER_WARN_FRACTION:
            shares[str(name)] = float(share)
    return shares


def glint_matters(glint: float | None, shoulder: float | None) -> bool:
    """Whether a failing view's glint (share ``glint`` of the board) is worth naming.

    Any glint is, unless design warned of the view's shoulder (``shoulder``, a
    :func:`shoulder_shares` value) and the glint covers less of the board than the share
    under which design lets a shoulder pass: a speck of glint beside a warned shoulder
    costs the image little, and moving the camera for it would not mend the shoulder.
    """
    if not glint or glint <= 0:
        return False
    return shoulder is None or glint >= SHOULDER_WARN_FRACTION


def outshine_advice(
    glints: Mapping[str, float],
    shoulders: Mapping[str, float],
    feasibility: Any,
    count_setting: str,
    outlined: str | None = None,
) -> list[str]:
    """Clauses on the bare board outshining failing views' grooves, as design found it.

    Args:
        glints: Failing view -> the share of the board where the bare board glints into it.
        shoulders: Failing view -> its shoulder's share (:func:`shoulder_shares`).
        feasibility: ``design/feasibility.json`` as read, for ``shoulder_count`` and
            ``groove_coverage``.
        count_setting: How the user sets the scratch count (``design --count``,
            ``[scratch] count =``).
        outlined: Where the glint is outlined (the diff maps' folder), if anywhere.

    Returns:
        No clause, or one on the shoulder and one on the glint (no capital, no full stop):
        the glint's only for views where :func:`glint_matters`.
    """
    said = []
    if shoulders:
        data = feasibility if isinstance(feasibility, Mapping) else {}
        count, coverage = data.get("shoulder_count"), data.get("groove_coverage")
        at = f" at groove coverage {coverage:.2f}" if isinstance(coverage, int | float) else ""
        fix = (
            f"{count_setting} {count} or more (the count design's shoulder warning names), "
            "or move the cameras or the light as that warning says"
            if isinstance(count, int)
            else "no scratch count clears it: move the cameras or the light as design's "
            "shoulder warning says"
        )
        views = ", ".join(f"{n} on {100 * s:.1f}% of the board" for n, s in shoulders.items())
        said.append(
            f"past the glint the bare board still outshines the sparse grooves{at} (the "
            f"glint's shoulder; design warned): {views}; optimizing longer does not help, "
            f"more scratches do: {fix}"
        )
    named = [n for n, g in glints.items() if glint_matters(g, shoulders.get(n))]
    if named:
        where = f"; outlined in {outlined}" if outlined else ""
        shares = ", ".join(f"{100 * glints[n]:.1f}%" for n in named)
        said.append(
            f"the bare board glints into {', '.join(named)} (design warned; on {shares} of "
            f"the board{where}): no "
            "scratch shows the image there and the glint outshines the rest, so optimizing "
            "longer does not help: move the camera or the light as design's warning says"
        )
    return said
