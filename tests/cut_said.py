"""Design's cut estimate as it was said: the ``cut:`` line and the clause lines under it."""

from __future__ import annotations

from collections.abc import Sequence

#: How ``scratchfab design`` indents the stage's lines (``run`` indents them two more).
DESIGN = "  "


def _start(lines: Sequence[str], indent: str) -> int:
    """The index of the one ``cut:`` line said at ``indent``."""
    starts = [i for i, line in enumerate(lines) if line.startswith(f"{indent}cut: ")]
    assert len(starts) == 1, lines
    return starts[0]


def cut_sentence(lines: Sequence[str], indent: str = DESIGN) -> str:
    """The ``cut:`` line and its clause lines (indented two more spaces) joined by ``"; "``.

    Exactly one ``cut:`` line must have been said at ``indent``; the result keeps that
    indent, so it starts ``indent + "cut: "``.
    """
    start = _start(lines, indent)
    clauses = [lines[start]]
    for line in lines[start + 1 :]:
        if not line.startswith(f"{indent}  ") or line.startswith(f"{indent}   "):
            break
        clauses.append(line[len(indent) + 2 :])
    return "; ".join(clauses)


def cut_warning(lines: Sequence[str], indent: str = DESIGN) -> str | None:
    """The warning said right after the cut clauses (at ``indent``, which it drops), or None."""
    after = [
        line for line in lines[_start(lines, indent) + 1 :] if not line.startswith(f"{indent}  ")
    ]
    return after[0][len(indent) :] if after and after[0].startswith(f"{indent}warning: ") else None
