"""A toolpath's record of its design holds what the plan depends on of it.

The reference is the plan itself: the toolpath stage runs on a design whose tables note
each field read, and every key of ``design.toml`` is then changed in turn. Planned from
given files or the job's initial layout, one the plan read makes the toolpath stale (the
up-to-date check names the design); one it did not read (the light, the views, the
board's finish and margin, the layout's bounds) leaves it current. Planned from the job's
optimized layout, a change to what optimize read makes that layout out of date, and the
plan with it.
"""

from __future__ import annotations

import dataclasses
import tomllib
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tomli_w
from test_toolpath import make_job

from scratchfab.toolpath import Toolpath, stage
from scratchfab.toolpath.inputs import PLAN_READS, input_changes

BUNDLED = "grbl-3018-diamond"


class _Noting:
    """A design (or one of its tables) that notes each field read, as ``(table, key)``."""

    def __init__(self, obj: Any, table: str, seen: set[tuple[str, str]]) -> None:
        object.__setattr__(self, "_of", (obj, table, seen))

    def __getattr__(self, name: str) -> Any:
        obj, table, seen = object.__getattribute__(self, "_of")
        held = getattr(type(obj), name, None)
        if isinstance(held, property):  # board.half_extent reads width_mm, height_mm
            return held.fget(self)  # type: ignore[misc]
        if callable(held):
            return types.MethodType(held, self)
        value = getattr(obj, name)
        if dataclasses.is_dataclass(value):
            return _Noting(value, name, seen)
        if isinstance(value, tuple) and value and dataclasses.is_dataclass(value[0]):
            return tuple(_Noting(v, name, seen) for v in value)
        seen.add((table, name))
        return value


def _plan(tmp: Path, how: str) -> tuple[Path, set[tuple[str, str]]]:
    """A job planned (``how``) through a noting design, and the fields the plan read.

    ``how``: ``initial`` (the job's, optimize not run), ``optimized`` (the job's), or
    ``given`` (its optimized layout and design named as files).
    """
    job = make_job(tmp, np.random.default_rng(7), optimize=how != "initial")
    seen: set[tuple[str, str]] = set()
    load = stage.load_design

    def noting(path: Path, require_views: bool = True) -> Any:
        return _Noting(load(path, require_views), "", seen)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(stage, "load_design", noting)
        if how == "given":
            files = (job / "optimize" / "scratches.csv", job / "design" / "design.toml")
            stage.run_toolpath(*files, job / "toolpath", BUNDLED)
        else:
            stage.run_toolpath_job(job, BUNDLED)
    return job, seen


def _stale_keys(job: Path) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    """Each ``(table, key)`` of the job's design.toml changed in turn: (stale, current)."""
    file = job / "design" / "design.toml"
    text = file.read_text()
    table = tomllib.loads(text)
    toolpath = Toolpath.load(job / "toolpath" / "toolpath.json")
    stale, current = [], []
    for name, key in _keys(table):
        edited = tomllib.loads(text)
        entry = edited[name][0] if isinstance(edited[name], list) else edited[name]
        entry[key] = _changed(entry[key])
        file.write_text(tomli_w.dumps(edited))
        changes, _ = input_changes(toolpath.inputs, toolpath.profile, job / "toolpath")
        said = [c for c in changes if str(file) in c]
        assert said in ([], [f"{file} changed since"]), changes
        (stale if said else current).append((name, key))
    file.write_text(text)
    assert input_changes(toolpath.inputs, toolpath.profile, job / "toolpath")[0] == []
    return stale, current


def _changed(value: Any) -> Any:
    """Another valid value of a design.toml key."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return value * 1.05 if value else 1.0
    if isinstance(value, str):
        return 8.0 if value == "auto" else value + "2"
    return [_changed(value[0]), *value[1:]]


def _keys(table: dict[str, Any]) -> list[tuple[str, str]]:
    """Each ``(table, key)`` of a design.toml (a view's of the first view)."""
    return [
        (name, key)
        for name, entries in table.items()
        for key in (entries[0] if isinstance(entries, list) else entries)
    ]


@pytest.mark.parametrize("how", ["initial", "given"])
def test_each_read_field_re_plans_and_no_other_does(tmp_path, how):
    job, seen = _plan(tmp_path, how)
    reads = {(t, k) for t, k in seen if t}
    assert reads == {(t, k) for t, keys in PLAN_READS.items() for k in keys}
    stale, current = _stale_keys(job)
    assert set(stale) == reads
    unread = {("light", "position_mm"), ("board", "margin_mm"), ("views", "fov_deg")}
    assert unread <= set(current)


def test_a_change_optimize_read_re_plans_its_layout(tmp_path):
    job, seen = _plan(tmp_path, "optimized")
    stale, current = _stale_keys(job)
    assert {(t, k) for t, k in seen if t} < set(stale)
    assert {("light", "position_mm"), ("board", "margin_mm"), ("views", "fov_deg")} <= set(stale)
    assert ("scratch", "count") in current  # the layout's CSV holds the scratches


@pytest.mark.parametrize("how", ["initial", "given"])
def test_a_record_of_every_optimize_field_stays_current_until_a_plan_field_changes(tmp_path, how):
    """A toolpath made before the key was narrowed hashed every field optimize reads.

    Its design rewritten by a rerun (a comment) keeps it current, as it did then; a field
    the plan reads still makes it stale, and one it does not read no longer does.
    """
    import json

    from scratchfab.model.job import design_content_sha256

    job, _ = _plan(tmp_path, how)
    file = job / "toolpath" / "toolpath.json"
    record = json.loads(file.read_text())
    design = job / "design" / "design.toml"
    entry = record["inputs"]["design"]
    assert entry["fields_sha256"] != design_content_sha256(design)  # narrowed today
    entry["fields_sha256"] = design_content_sha256(design)  # as 4046bc2 wrote it
    file.write_text(json.dumps(record))
    toolpath = Toolpath.load(file)
    text = design.read_text()
    design.write_text("# Resolved by a rerun of design\n" + text)
    assert input_changes(toolpath.inputs, toolpath.profile, job / "toolpath")[0] == []
    stale, current = _stale_keys(job)
    assert {(t, k) for t, keys in PLAN_READS.items() for k in keys} <= set(stale)
    assert ("light", "position_mm") in stale  # the old key's own strictness, no less
