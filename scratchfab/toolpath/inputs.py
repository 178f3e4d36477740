"""What a toolpath was planned from, and whether those inputs are still what they were.

``toolpath.json`` records its inputs under ``"inputs"``: the scratch CSV and the design
(each by its path relative to the toolpath's own folder and its SHA-256; the design also
by what the plan depends on, ``fields_sha256`` (:func:`depends_on`): a rerun of design
that rewrites only its comments and target paths changes nothing, nor does an edit to
what neither the plan nor the layout's optimize read; a record of an earlier scratchfab,
without it, is compared by the board's size and the tool the plan holds), the machine
profile (a bundled one by name, a file by its path), and the job folder when the job
picked the layout (its optimized one, else the initial one). Paths are relative so that
a job moved or copied whole keeps its record. ``export`` compares the record with the
files as they are now (:func:`input_changes`), so that a toolpath left from before
optimize, design or the profile changed is not written out as if it were current.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from scratchfab.bundled import bundled_name
from scratchfab.console import command_line
from scratchfab.errors import ConfigError
from scratchfab.fileio import decode_json, file_sha256
from scratchfab.machine.profile import MachineProfile, load_profile, machine_named
from scratchfab.model.design import Design, design_fields, load_design, same_to_rounding
from scratchfab.model.job import JobLayout, design_content_sha256, job_inputs

if TYPE_CHECKING:
    from scratchfab.toolpath.plan import Toolpath


#: The design's fields a toolpath's plan reads, by table: the board's size (its outline on
#: the machine, the scratch CSV's on-board check) and the tool's dent (the CSV's width and
#: depth where it has none, the check against the machine's tool).
PLAN_READS: dict[str, tuple[str, ...]] = {
    "board": ("width_mm", "height_mm"),
    "scratch": ("width_mm", "depth_mm"),
}


def plan_fields(design: Design) -> dict[str, Any]:
    """What a toolpath's plan reads of ``design`` (:data:`PLAN_READS`), by table."""
    return {
        table: {key: getattr(getattr(design, table), key) for key in keys}
        for table, keys in PLAN_READS.items()
    }


def depends_on(scratch_file: Path, job: Path | None) -> Callable[[Design], dict[str, Any]]:
    """What a plan of ``scratch_file`` depends on of its design, as a toolpath records it.

    What the plan reads (:func:`plan_fields`); where the scratches are ``job``'s optimized
    layout, what optimize read too (:func:`~scratchfab.model.design.design_fields`): a
    design changed since makes that layout, and so the plan, out of date (optimize is
    named first, then toolpath).
    """
    optimized = job is not None and os.path.abspath(scratch_file) == os.path.abspath(
        JobLayout(job).optimized_scratches
    )
    return design_fields if optimized else plan_fields


def _relative(path: Path, folder: Path) -> str:
    """``path`` relative to ``folder`` (forward slashes), else absolute (another drive)."""
    try:
        return Path(os.path.relpath(os.path.abspath(path), os.path.abspath(folder))).as_posix()
    except ValueError:
        return os.path.abspath(path)


def _resolve(recorded: str, folder: Path) -> Path:
    """A recorded path, relative to the toolpath's ``folder``, as a path a person can read."""
    return Path(os.path.normpath(folder / recorded))


def _machine_record(profile: MachineProfile, folder: Path) -> dict[str, str] | None:
    """A bundled profile by name, a profile file by its path; None for one made in memory."""
    source = Path(profile.source)
    name = bundled_name("machine_profiles", source)
    if name is not None:
        return {"name": name}
    if source.is_file():
        return {"file": _relative(source, folder)}
    return None


def record_inputs(
    scratch_file: Path,
    design_file: Path,
    profile: MachineProfile,
    folder: Path,
    job: Path | None = None,
) -> dict[str, Any]:
    """The ``"inputs"`` record of a toolpath written into ``folder``.

    Args:
        scratch_file: The scratch CSV planned.
        design_file: The design TOML.
        profile: The machine; recorded when its ``source`` is a bundled profile or a file.
        folder: The toolpath's folder (where ``toolpath.json`` goes).
        job: The job folder whose layout picked ``scratch_file`` and ``design_file``
            (None: the files were given).
    """
    record: dict[str, Any] = {
        role: {"file": _relative(file, folder), "sha256": file_sha256(file)}
        for role, file in (("scratches", scratch_file), ("design", design_file))
    }
    pick = depends_on(scratch_file, job)
    record["design"]["fields_sha256"] = design_content_sha256(design_file, pick)
    machine = _machine_record(profile, folder)
    if machine is not None:
        record["machine"] = machine
    if job is not None:
        record["job"] = _relative(job, folder)
    return record


def initial_layout(toolpath: Toolpath, folder: Path | None = None) -> Path | None:
    """The design's initial layout a toolpath was planned from, else None.

    ``JOB/design/scratches.csv`` with its ``design.toml``; None for an optimized layout,
    other files, or no record. Optimize had not run on the job, or the files were given so: the toolpath stage
    warns, and export and the G-code header say the board is not optimized.

    Args:
        toolpath: The toolpath, its ``inputs`` as :func:`record_inputs` writes them.
        folder: The folder its record's paths are relative to; default that of the file
            it was loaded from (None for one planned in memory: no record to read).
    """
    folder = folder or (toolpath.file.parent if toolpath.file is not None else None)
    inputs = toolpath.inputs
    if not inputs or folder is None:
        return None
    design = _resolve(inputs["design"]["file"], folder)
    scratches = _resolve(inputs["scratches"]["file"], folder)
    job = _resolve(inputs["job"], folder) if "job" in inputs else design.parent.parent
    own = JobLayout(job).design
    pairs = ((own.design_toml, design), (own.initial_scratches, scratches))
    same = all(os.path.abspath(a) == os.path.abspath(b) for a, b in pairs)
    return scratches if same else None


def checked_record(data: Any, where: str) -> dict[str, Any] | None:
    """A toolpath.json's ``"inputs"`` as :func:`record_inputs` writes it (None: absent).

    Raises:
        ConfigError: Naming ``where`` and what is malformed.
    """
    if data is None:
        return None

    def strings(entry: Any, keys: tuple[str, ...], name: str) -> None:
        if not isinstance(entry, dict) or not all(isinstance(entry.get(k), str) for k in keys):
            raise ConfigError(
                f"{where}: malformed toolpath (inputs.{name} must be a table of "
                f"{' and '.join(keys)} strings)"
            )

    if not isinstance(data, dict):
        raise ConfigError(f"{where}: malformed toolpath (inputs must be a table)")
    for role in ("scratches", "design"):
        strings(data.get(role), ("file", "sha256"), role)
    if not isinstance(data["design"].get("fields_sha256", ""), str):
        raise ConfigError(
            f"{where}: malformed toolpath (inputs.design.fields_sha256 must be a string)"
        )
    machine = data.get("machine")
    if machine is not None:
        named = isinstance(machine, dict) and "name" in machine
        strings(machine, ("name",) if named else ("file",), "machine")
    if not isinstance(data.get("job", ""), str):
        raise ConfigError(f"{where}: malformed toolpath (inputs.job must be a path string)")
    return dict(data)


def _value(value: Any) -> str:
    """A profile value as TOML writes it (near enough): ``[-220.0, -161.0]``, ``"center"``."""
    return json.dumps(value)


def profile_changes(
    planned: MachineProfile, other: MachineProfile, tables: tuple[str, ...] | None = None
) -> list[str]:
    """``table.key = value (planned: value)`` for each setting ``other`` has otherwise.

    Args:
        planned: The profile the toolpath was planned for.
        other: The profile to compare with.
        tables: Only these tables (``board``, ``tool``); None: the whole profile.
    """
    ours, theirs = planned.to_table(), other.to_table()
    names = tables if tables is not None else tuple(dict.fromkeys([*ours, *theirs]))
    differ = []
    for name in names:
        a, b = ours.get(name), theirs.get(name)
        if isinstance(a, dict) or isinstance(b, dict):
            a, b = a or {}, b or {}
            pairs = [(f"{name}.{k}", a.get(k), b.get(k)) for k in dict.fromkeys([*a, *b])]
        else:
            pairs = [(name, a, b)]
        differ += [f"{k} = {_value(y)} (planned: {_value(x)})" for k, x, y in pairs if x != y]
    return differ


def _machine_now(record: Any, folder: Path) -> tuple[MachineProfile | None, str]:
    """The recorded machine profile as it is now (None: not to be found), and its name."""
    if isinstance(record.get("name"), str):
        return load_profile(record["name"]), record["name"]
    path = _resolve(str(record.get("file")), folder)
    return (load_profile(path) if path.is_file() else None), str(path)


def _same_design(
    entry: dict[str, Any],
    file: Path,
    planned: MachineProfile,
    board_mm: tuple[float, float] | None,
    pick: Callable[[Design], dict[str, Any]],
) -> bool:
    """Whether the design ``file``, its bytes changed, is still the one a plan was made from.

    A record with ``fields_sha256`` compares what ``pick`` takes, what the plan depends on
    (:func:`depends_on`: a rerun of design that rewrites its comments and target paths
    changes nothing). One of an earlier scratchfab
    holds the bytes' digest alone, and the first rerun of design rewrites them (``fov_deg
    = "auto"`` for auto's number): then the file is compared with what the plan holds of
    it, the board's size (floats to rounding,
    :func:`~scratchfab.model.design.same_to_rounding`) and the tool (the machine's, which
    the design's must match); neither known (``board_mm`` None), it has changed.
    """
    if "fields_sha256" in entry:
        # A record made before the key was narrowed to ``pick`` hashed every field optimize
        # reads, which holds all of ``pick``'s: its match proves them unchanged too.
        return any(
            entry["fields_sha256"] == design_content_sha256(file, fields)
            for fields in dict.fromkeys((pick, design_fields))
        )
    if board_mm is None:
        return False
    from scratchfab.toolpath.plan import tool_mismatch  # plan imports this module

    try:
        design = load_design(file, require_views=False)
    except ConfigError:
        return False
    size = (float(design.board.width_mm), float(design.board.height_mm))
    return same_to_rounding(size, tuple(map(float, board_mm))) and (
        tool_mismatch(planned, design.scratch) is None
    )


def input_changes(
    inputs: dict[str, Any] | None,
    planned: MachineProfile,
    folder: Path,
    check_machine: bool = True,
    board_mm: tuple[float, float] | None = None,
) -> tuple[list[str], list[str]]:
    """What differs between a toolpath's recorded inputs and the files as they are now.

    Args:
        inputs: The toolpath's record (:func:`record_inputs`); None for a toolpath.json
            written before scratchfab kept one.
        planned: The profile the toolpath holds.
        folder: The toolpath's folder, which the record's paths are relative to.
        check_machine: Compare the recorded machine profile too (not when exporting for
            another profile: ``export --machine``).
        board_mm: The board's size the toolpath holds: a design recorded by its bytes
            alone is compared with it (and the tool) where the bytes changed.

    Returns:
        (changes, notes): each change in words (a file changed, another layout picked,
        profile settings changed); notes on what could not be checked.
    """
    if inputs is None:
        return [], [
            "it records no inputs (an earlier scratchfab, or saved without the toolpath "
            "stage), so it cannot be checked against the current layout, design and "
            "machine profile"
        ]
    changes: list[str] = []
    notes: list[str] = []
    picked: tuple[Path, Path] | None = None  # the job's (design, layout) now
    job = _resolve(inputs["job"], folder) if "job" in inputs else None
    pick = depends_on(_resolve(inputs["scratches"]["file"], folder), job)
    if job is not None:
        if not JobLayout(job).design.design_toml.is_file():  # moved away from its job
            notes.append(
                f"the job folder it names, {os.path.abspath(job)}, holds no "
                "design/design.toml (moved away from its job?): not checked"
            )
        else:
            try:
                picked = job_inputs(job)
            except ConfigError as exc:  # the job lost every layout
                changes.append(str(exc))
    for role in ("scratches", "design") if picked or "job" not in inputs else ():
        entry = inputs[role]
        file = _resolve(entry["file"], folder)
        now = file if picked is None else picked[0 if role == "design" else 1]
        if os.path.abspath(now) != os.path.abspath(file):
            changes.append(f"the job's layout is now {now} (planned from {file})")
        elif not now.is_file():  # a file given, not the job's: moved away with its toolpath
            notes.append(f"{file}, planned from, is not found: not checked")
        elif file_sha256(now) != entry["sha256"] and (
            role != "design" or not _same_design(entry, now, planned, board_mm, pick)
        ):
            changes.append(f"{now} changed since")
    machine = inputs.get("machine")
    if check_machine and machine is not None:
        try:
            profile, where = _machine_now(machine, folder)
        except ConfigError as exc:
            changes.append(f"the machine profile no longer loads ({exc})")
        else:
            if profile is None:
                notes.append(f"machine profile {where} is not found: not checked")
            elif differ := profile_changes(planned, profile):
                changes.append(f"machine profile {where} changed since: {'; '.join(differ)}")
    return changes, notes


def machine_argument(record: dict[str, str] | None, folder: Path) -> str | None:
    """A toolpath's recorded machine profile as ``--machine`` takes it, or None (none recorded).

    Args:
        record: The record's ``"machine"`` entry (:func:`record_inputs`): a bundled
            profile's name, else a file's path relative to ``folder``.
        folder: The toolpath's folder.
    """
    if not record:
        return None
    if "name" in record:
        return record["name"]
    return str(_resolve(record["file"], folder)) if "file" in record else None


def planned_for(toolpath: Toolpath) -> str:
    """``machine 'NAME' (grbl-3018-diamond)``: the profile a toolpath was planned for.

    In brackets the profile as its record names it (:func:`machine_argument`), where it
    names one.
    """
    folder = toolpath.file.parent if toolpath.file is not None else Path(".")
    where = machine_argument((toolpath.inputs or {}).get("machine"), folder)
    return machine_named(toolpath.profile.name, where)


def rerun_command(
    inputs: dict[str, Any] | None, folder: Path, profile: MachineProfile | None = None
) -> str:
    """The ``scratchfab toolpath`` command that plans the current inputs again.

    Args:
        inputs: The toolpath's record (None: an old toolpath; the job is then taken to be
            the folder above ``folder``).
        folder: The toolpath's folder.
        profile: The profile to name (``export --machine``'s); None: the recorded one.
    """
    record = inputs or {}
    held = (_machine_record(profile, folder) if profile else None) or record.get("machine")
    machine = machine_argument(held, folder) or "PROFILE"
    args: list[str | Path] = ["scratchfab", "toolpath"]
    if "job" in record or inputs is None:
        job = _resolve(record.get("job", ".."), folder)
        args.append(job)
        if os.path.normpath(folder) != os.path.normpath(job / "toolpath"):
            args += ["--out", folder]
    else:
        args += ["--scratches", _resolve(record["scratches"]["file"], folder)]
        args += ["--design", _resolve(record["design"]["file"], folder), "--out", folder]
    return command_line([*args, "--machine", machine])


def _machine_source(file: Path) -> MachineProfile | None:
    """The profile an old toolpath.json (no ``inputs``) names as its ``machine_source``.

    Only its name is wanted, for the command that plans it again; None when the file
    no longer names one that loads.
    """
    try:
        source = decode_json(file.read_text(encoding="utf-8")).get("machine_source")
        return load_profile(Path(source)) if isinstance(source, str) else None
    except (OSError, ValueError, AttributeError, ConfigError):
        return None


def check_current(
    toolpath: Toolpath, profile: MachineProfile | None = None
) -> tuple[str | None, list[str]]:
    """Whether a loaded toolpath was planned from the inputs as they are now.

    Args:
        toolpath: A toolpath loaded from its file (one planned in memory is current).
        profile: The profile it is exported for, where not its own (its machine
            profile is then not compared: the export checks board and tool itself).

    Returns:
        (stale, notes): what changed and the command that plans it again, in words
        (None: nothing changed); lines on what could not be checked.
    """
    if toolpath.file is None:
        return None, []
    folder = toolpath.file.parent
    changes, notes = input_changes(
        toolpath.inputs, toolpath.profile, folder, profile is None, toolpath.board_mm
    )
    if toolpath.inputs is None:
        command = "scratchfab toolpath"
        if JobLayout(folder.parent).design.design_toml.is_file():  # in its job's folder
            machine = profile or _machine_source(toolpath.file)
            command = rerun_command(None, folder, machine)
        notes = [
            f"{toolpath.file}: {note}; if they changed since, rerun `{command}`" for note in notes
        ]
    else:
        notes = [f"{toolpath.file}: {note}" for note in notes]
    if not changes:
        return None, notes
    return (
        f"{toolpath.file} was planned from other inputs than there are now: "
        f"{'; '.join(changes)}; rerun `{rerun_command(toolpath.inputs, folder, profile)}`, "
        "then export",
        notes,
    )
