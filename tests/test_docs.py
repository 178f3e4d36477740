"""docs/files.md against the code: every key of every table with its default, the job layout."""

from __future__ import annotations

import dataclasses
import re
import tomllib
import typing
from pathlib import Path

import pytest
from test_job_layout import SPEC_SECTION_6

from scratchfab.machine.grblsim import SimOptions
from scratchfab.machine.profile import MachineProfile
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


def profile_keys(cls: type, prefix: str = "") -> set[str]:
    """Dotted keys of a profile table, nested tables expanded."""
    keys = set()
    for field in dataclasses.fields(cls):
        if not field.init:
            continue
        tp = typing.get_type_hints(cls)[field.name]
        if dataclasses.is_dataclass(tp):
            keys |= profile_keys(tp, f"{prefix}{field.name}.")
        else:
            keys.add(prefix + field.name)
    return keys


def test_machine_profile_readme_lists_every_key():
    readme = (DOC.parents[1] / "machine_profiles" / "README.md").read_text()
    documented = set()
    for cell in re.findall(r"^\| `([^`]+)` \|", readme, flags=re.MULTILINE):
        table, _, names = cell.rpartition("] ") if cell.startswith("[") else ("", "", cell)
        prefix = table.lstrip("[") + "." if table else ""
        documented |= {prefix + name.strip() for name in names.split(",")}
    documented -= {"grbl-3018-diamond", "grbl-plotter-scribe"}  # the bundled list's rows
    assert documented == profile_keys(MachineProfile)


def test_readme_exit_codes_are_the_errors_own():
    """README's exit codes: each error class's own code, and the CLI's Ctrl-C code."""
    from scratchfab.errors import Interrupted, ScratchfabError
    from scratchfab.machine.sender import StreamFault
    from scratchfab.verify.verify import VerifyGateError

    readme = (Path(__file__).parents[1] / "README.md").read_text(encoding="utf-8")
    said = " ".join(readme.split("Exit codes:", 1)[1].split("\n\n", 1)[0].split())
    for code, what in (
        (ScratchfabError.exit_code, "a refusal or a mistake"),
        (VerifyGateError.exit_code, "the verify gate failed"),
        (StreamFault.exit_code, "the stream stopped on a machine fault"),
        (Interrupted.exit_code, "stopped by Ctrl-C"),
    ):
        assert re.search(rf"\b{code} [^;]*{re.escape(what)}", said), (code, what, said)
