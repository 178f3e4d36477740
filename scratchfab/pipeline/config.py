"""Pipeline files: a design plus one table of options per stage (SPEC section 5).

Every table is parsed strictly (unknown keys are errors naming the nearest valid key),
like the design itself.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from scratchfab.bundled import find_bundled, names_a_file
from scratchfab.errors import ConfigError
from scratchfab.model.design import Design, design_from_mapping
from scratchfab.model.schema import load_toml, parse_table, spec
from scratchfab.optimize.options import OptimizeOptions
from scratchfab.verify.verify import DEFAULT_SPP, bad_sweep_frames

if TYPE_CHECKING:
    from scratchfab.machine.profile import MachineProfile

STAGES = ("design", "optimize", "verify", "toolpath", "export", "stream")
#: The key that lets the toolpath stage plan a board the envelope cuts short (a partial board).
TOOLPATH_FORCE = "[toolpath] force = true"
#: The design stage's override, which also allows a partial board where TOOLPATH_FORCE is not given.
PIPELINE_FORCE = "[pipeline] force = true"


@dataclass(frozen=True)
class PipelineOptions:
    """``[pipeline]``: the job as a whole, and the design stage's options.

    Attributes:
        name: Shown in the report.
        out: Default job folder, relative to the pipeline file (like its targets);
            ``--out`` (relative to the current directory) overrides.
        fit: How target images meet the board's aspect ("contain" or "cover").
        seed: Seed of the initial layout (as ``scratchfab design --seed``).
        force: Go on when the feasibility check fails or a target is black (as
            ``scratchfab design --force``). Where ``[toolpath] force`` is not given it
            also plans a board the machine's envelope cuts short, as it did before that
            key (:meth:`Pipeline.partial_key`), with a note naming the key.
    """

    name: str = "scratchfab job"
    out: str | None = None
    fit: Literal["contain", "cover"] = "contain"
    seed: int = field(default=0, metadata=spec(ge=0))
    force: bool = False


@dataclass(frozen=True)
class VerifyOptions:
    """``[verify]``: bounds as ``scratchfab verify-render``'s options.

    ``sweep`` is 0 (no sweep) or at least 2 frames; :class:`StageTables` checks that.
    """

    spp: int = field(default=DEFAULT_SPP, metadata=spec(ge=2))
    min_rho: float | None = field(default=0.8, metadata=spec(ge=-1, le=1))
    sweep: int = field(default=0, metadata=spec(ge=0))
    sky: bool = False
    jitter: bool = False
    backend: Literal["llvm", "cuda"] = "llvm"
    seed: int = field(default=0, metadata=spec(ge=0))


@dataclass(frozen=True)
class ToolpathOptions:
    """``[toolpath]``: the machine, and the ordering's options (as ``scratchfab toolpath``).

    Attributes:
        machine: Bundled profile name or a profile TOML path.
        passes: Cap on local-search work, in visits per stroke.
        kicks: Perturbation trials in all (None: the default per stroke, capped).
        seed: Seed of the perturbations.
        force: Plan a board the machine's envelope cuts short: only the part it reaches
            (as ``scratchfab toolpath --force``). None (not given): ``[pipeline] force``'s
            value, as an older file meant it.
    """

    machine: str = "grbl-3018-diamond"
    passes: int = field(default=50, metadata=spec(ge=0))
    kicks: int | None = field(default=None, metadata=spec(ge=0))
    seed: int = field(default=0, metadata=spec(ge=0, lt=2**32))
    force: bool | None = None


@dataclass(frozen=True)
class ExportOptions:
    """``[export]``."""

    formats: tuple[Literal["gcode", "dxf", "svg"], ...] = ("gcode", "dxf", "svg")


@dataclass(frozen=True)
class StreamOptions:
    """``[stream]``: only run when ``port`` is set (a non-empty string).

    A run after an interrupted stream of the same G-code resumes it from the journal;
    ``recut_unsure`` then also cuts again what a lost link left unsure (see ``stream``).
    """

    port: str | None = None
    protocol: Literal["counting", "simple"] = "counting"
    baud: int | None = field(default=None, metadata=spec(gt=0))  # None: the profile's
    check: bool = False
    recut_unsure: bool = False


@dataclass(frozen=True)
class StageTables:
    """The stage tables of a pipeline file, with the checks that span keys.

    Raises:
        ValueError: From ``__post_init__``, starting with the dotted key;
            :func:`parse_table` prefixes the file name.
    """

    pipeline: PipelineOptions = PipelineOptions()
    optimize: OptimizeOptions = OptimizeOptions()
    verify: VerifyOptions = VerifyOptions()
    toolpath: ToolpathOptions = ToolpathOptions()
    export: ExportOptions = ExportOptions()
    stream: StreamOptions = StreamOptions()

    def __post_init__(self) -> None:
        if (why := bad_sweep_frames(self.verify.sweep)) is not None:
            raise ValueError(f"verify.sweep: {why}")
        port = self.stream.port
        if port is not None and not port.strip():
            raise ValueError(
                f"stream.port: expected a serial device, pty path or URL, got {port!r} "
                "(leave the key out to stop after export)"
            )
        if port is not None and _grblsim_record(port):
            raise ValueError(
                "stream.port: a pipeline's [stream] port may not set the emulator's record= "
                "(it would overwrite that file on every run); record on the command line "
                "instead: `scratchfab grbl-sim --record FILE` or `scratchfab stream --port "
                "'grblsim://?record=FILE'`"
            )
        if port is not None and "gcode" not in self.export.formats:
            raise ValueError(
                'stream.port: streaming needs "gcode" in export.formats, '
                f"got export.formats = {list(self.export.formats)}"
            )


def _grblsim_record(port: str) -> bool:
    """True when ``port`` opens the GRBL emulator with a ``record`` key in its query.

    Read by the emulator's own URL reader
    (:func:`~scratchfab.machine.protocol_grblsim.grblsim_query`), so no spelling slips past.
    """
    from scratchfab.machine.protocol_grblsim import grblsim_query

    try:
        query = grblsim_query(port.strip())
    except ConfigError as exc:  # a key given twice
        raise ValueError(f"stream.port: {exc}") from None
    return query is not None and any(key.strip().lower() == "record" for key in query)


def parse_stage_tables(data: Mapping[str, Any], source: str) -> StageTables:
    """The stage tables of a pipeline file's ``data`` (other tables are left alone).

    The one parser of ``[pipeline]`` and the later stages' tables, for ``scratchfab
    run`` (:func:`load_pipeline`) and ``scratchfab design`` given a pipeline file.

    Raises:
        ConfigError: Naming ``source`` and the dotted key on any mistake.
    """
    tables = {f.name for f in fields(StageTables)}
    stage_data = {k: v for k, v in data.items() if k in tables}
    return parse_table(StageTables, stage_data, source)


_NOT_DESIGN = ("name", "out")  # [pipeline] keys that change nothing the design stage makes


def design_options(tables: Mapping[str, Any]) -> dict[str, Any]:
    """The design stage's options in a pipeline's design tables, for its fingerprint.

    Left out: ``[pipeline]`` ``name`` (the report's title) and ``out`` (where the job
    lies), so renaming either keeps the job's stages; and each view's ``target`` path,
    which the fingerprint takes as the image's bytes, wherever the image lies.
    """
    options = dict(tables)
    if isinstance(options.get("pipeline"), dict):
        options["pipeline"] = {k: v for k, v in options["pipeline"].items() if k not in _NOT_DESIGN}
    if isinstance(options.get("views"), list):
        options["views"] = [
            {k: v for k, v in view.items() if k != "target"} if isinstance(view, dict) else view
            for view in options["views"]
        ]
    return options


@dataclass(frozen=True)
class Pipeline:
    """A parsed pipeline file.

    Attributes:
        design_tables: The file's tables as read, less the stage tables after design
            (what the design stage depends on).
        profile: The toolpath machine's profile, loaded once with the file.
    """

    path: Path
    design: Design
    pipeline: PipelineOptions
    optimize: OptimizeOptions
    verify: VerifyOptions
    toolpath: ToolpathOptions
    export: ExportOptions
    stream: StreamOptions
    design_tables: dict[str, Any] = field(compare=False, repr=False)
    profile: MachineProfile = field(compare=False, repr=False)

    def job_dir(self, out: Path | None = None) -> Path:
        """The job folder for ``run``.

        ``out`` as given, else ``[pipeline] out`` read relative to this file (like its
        targets), else ``job-<file name>`` in the current directory.
        """
        if out is not None:
            return out
        if self.pipeline.out is not None:
            return self.path.parent / self.pipeline.out
        return Path(f"job-{self.path.stem}")

    def partial_key(self) -> str | None:
        """The key that lets the toolpath stage plan a board the envelope cuts short, or None.

        ``[toolpath] force`` where given, else ``[pipeline] force`` (an older file's key for
        both the design's refusals and a partial board).
        """
        if self.toolpath.force is not None:
            return TOOLPATH_FORCE if self.toolpath.force else None
        return PIPELINE_FORCE if self.pipeline.force else None

    def machine_ref(self) -> str:
        """The toolpath machine as named: a bundled name, or its path (resolved)."""
        return resolve_machine_ref(self.toolpath.machine, self.path)


def resolve_machine_ref(ref: str, pipeline_file: Path) -> str:
    """``[toolpath] machine``: a bundled name, or a path resolved against ``pipeline_file``."""
    if names_a_file(ref):
        candidate = Path(ref)
        return str(candidate if candidate.is_absolute() else (pipeline_file.parent / candidate))
    return ref


def load_pipeline(path: str | Path) -> Pipeline:
    """Load and validate a pipeline file (design tables + stage tables).

    Args:
        path: A pipeline TOML, or the name of a bundled one (``demo``).

    Raises:
        ConfigError: Naming the file and the key on any mistake.
    """
    file = find_bundled("pipelines", path, "pipeline")
    data = load_toml(file)
    design = design_from_mapping(data, str(file), file.resolve().parent)
    tables = parse_stage_tables(data, str(file))
    from scratchfab.machine.profile import load_profile

    machine = resolve_machine_ref(tables.toolpath.machine, file.resolve())
    try:
        profile = load_profile(machine)
    except ConfigError as exc:
        raise ConfigError(f"{file}: toolpath.machine: {exc}") from None
    return Pipeline(
        path=file.resolve(),
        design=design,
        pipeline=tables.pipeline,
        optimize=tables.optimize,
        verify=tables.verify,
        toolpath=tables.toolpath,
        export=tables.export,
        stream=tables.stream,
        design_tables={k: v for k, v in data.items() if k not in STAGES[1:]},
        profile=profile,
    )
