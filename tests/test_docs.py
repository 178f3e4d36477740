"""docs/files.md against the code: every key of every table with its default, the job layout."""

from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path

import pytest
from test_job_layout import SPEC_SECTION_6

from scratchfab.machine.grblsim import SimOptions
from scratchfab.model.design import Board, Light, ScratchTool, View
from scratchfab.model.schema import to_table
from scratchfab.optimize.options import OptimizeOptions
from scratchfab.pipeline.config import (
    ExportOptions,
    PipelineOptions,
    StreamOptions,
    ToolpathOptions,
    VerifyOptions,
)

DOC = Path(__file__).parents[1] / "docs" / "files.md"

TABLES = {
    "[board]": Board,
    "[light]": Light,
    "[scratch]": ScratchTool,
    "[[views]]": View,
    "[pipeline]": PipelineOptions,
    "[optimize]": OptimizeOptions,
    "[verify]": VerifyOptions,
    "[toolpath]": ToolpathOptions,
    "[export]": ExportOptions,
    "[stream]": StreamOptions,
}


def doc_tables() -> dict[str, dict[str, str]]:
    """``{heading: {key: default cell}}`` of every ``### heading`` followed by a key table."""
    tables: dict[str, dict[str, str]] = {}
    heading = None
    for line in DOC.read_text().splitlines():
        if line.startswith("### "):
            heading = line[4:].strip()
            tables[heading] = {}
        elif heading is not None and (row := re.match(r"\| `(\w+)` \| ([^|]+) \|", line)):
            tables[heading][row.group(1)] = row.group(2).strip()
    return tables


def expected_cell(field: dataclasses.Field) -> object:
    """What the default column must say for ``field``: a TOML value, required or unset."""
    if field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
        return "required"
    if field.default is None:
        return "unset"
    return to_table(field.default)


@pytest.mark.parametrize("heading", list(TABLES))
def test_each_table_lists_the_codes_keys_and_defaults(heading):
    documented = doc_tables()[heading]
    fields = {f.name: f for f in dataclasses.fields(TABLES[heading]) if f.init}
    assert list(documented) == list(fields)  # same keys, in the code's order
    for name, field in fields.items():
        cell = documented[name]
        if cell in ("required", "unset"):
            assert cell == expected_cell(field), name
        else:
            assert cell.startswith("`") and cell.endswith("`"), (name, cell)
            assert tomllib.loads(f"v = {cell[1:-1]}")["v"] == expected_cell(field), name


def test_every_emulator_key_is_named():
    text = DOC.read_text()
    for field in dataclasses.fields(SimOptions):
        if field.name != "settings":  # given as $N=value, which the text shows
            assert f"`{field.name}`" in text, field.name
    assert "`$N=value`" in text


def test_job_folder_table_names_every_path_of_the_layout():
    listed = set(re.findall(r"^\| `([^`]+)` \|", DOC.read_text(), flags=re.MULTILINE))
    for path in SPEC_SECTION_6.values():
        path = path.replace("sun", "<view>")
        assert path in listed or any(p.startswith(path + "/") for p in listed), path
