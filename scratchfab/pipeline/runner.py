"""``scratchfab run``: the stages of a pipeline file, in order, into one job folder.

Each stage reads what the stage before it wrote (SPEC section 6). The manifest records
every stage's inputs; a stage whose inputs and options did not change is skipped, and
once a computing stage runs, every computing stage after it runs too. The stream stage
moves a machine: it runs only when its own inputs changed (the G-code's bytes, the
``[stream]`` options), when the last stream of this G-code did not finish (it resumes),
or when asked (``--from stream``, ``--force``), never merely because an earlier stage
wrote the same G-code again. A failing stage leaves the earlier outputs as they are, so
the next run starts again at that stage.
"""

from __future__ import annotations

import contextlib
import re
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from scratchfab.console import Confirm, Say
from scratchfab.errors import ConfigError, Interrupted, ScratchfabError
from scratchfab.fileio import decode_json, try_lock
from scratchfab.model.job import JobLayout
from scratchfab.pipeline.config import (
    PIPELINE_FORCE,
    STAGES,
    TOOLPATH_FORCE,
    Pipeline,
    ToolpathOptions,
    design_options,
)
from scratchfab.pipeline.manifest import (
    MANIFEST_NAME,
    Legacy,
    Manifest,
    file_digest,
    fingerprint,
    matches_format_1,
)
from scratchfab.pipeline.report import write_report


def is_emulator(port: str) -> bool:
    """True for the built-in GRBL emulator (``grblsim://...``), which moves nothing.

    :func:`scratchfab.machine.stream_job.is_emulator`, imported when asked: the sender's
    modules load with the stream stage, not with every ``run``.
    """
    from scratchfab.machine.stream_job import is_emulator as emulator

    return emulator(port)


#: The sender's words where a stop may have lost the machine's position (a reset, a link).
_POSITION_LOST = re.compile(
    r"los(?:t|es) (?:its|the) position|position (?:may be|is likely|was likely) lost"
)


def as_run_advice(text: str) -> str:
    """The sender's advice as it applies in ``run``, which resumes a stream by running again.

    The note goes on a line of its own where the sender's message has several (a fault's
    clauses, :func:`~scratchfab.machine.stream_job.fault_lines`), and names ``--homed``
    where the position may be lost: the resume then asks, and ``run --yes`` refuses
    without it; where the sender's advice is to add ``--zero-here`` (the tool jogged back to
    the board's point and zeroed there again, which stands for ``--homed``), that flag.
    """
    later = "continue later with --resume"
    if later in text:
        return text.replace(later, "run the same command again later: it resumes")
    if "--resume" not in text:
        return text
    note = "(here `scratchfab run` has no --resume: run it again and it resumes)"
    if "add --zero-here" in text:
        note = (
            "(here `scratchfab run` has no --resume: run it again with --zero-here and it resumes)"
        )
    elif _POSITION_LOST.search(text):
        note = f"once the position is found again as said above, add --homed {note}"
    return text + ("\n  " if "\n" in text else " ") + note


def _number(value: Any) -> float | None:
    """A JSON number as a float (NaN and infinity as written); None for anything else."""
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


@dataclass(frozen=True)
class ViewMetrics:
    """One view's verify measurements.

    Attributes:
        name: The view.
        rho: Pearson correlation of the verify render with the view's target (rho_kk,
            1 = perfect); None for a view without a target.
        psnr: PSNR of the render against the target, in dB (the render scaled by its
            best exposure, peak 1); None without a target.
        passed: Whether ``rho`` reaches the gate's ``min_rho``; None without a gate (or
            at -1, which gates nothing), or for a view without a target (the gate does
            not check it).
    """

    name: str
    rho: float | None
    psnr: float | None
    passed: bool | None


@dataclass(frozen=True)
class VerifyMetrics:
    """The verify stage's measurements, as ``JOB/verify/metrics.json`` holds them.

    Attributes:
        views: Each view's, in the design's order.
        min_rho: The gate verify ran with (None: no gate).
        passed: Whether every view checked reached ``min_rho`` (None: no gate, or -1).
        file: The ``metrics.json`` read, which holds every other measurement.
    """

    views: tuple[ViewMetrics, ...]
    min_rho: float | None
    passed: bool | None
    file: Path

    def view(self, name: str) -> ViewMetrics:
        """The view named ``name``.

        Raises:
            KeyError: No view of that name was verified.
        """
        for view in self.views:
            if view.name == name:
                return view
        raise KeyError(f"no view {name!r} in {self.file}; views: {[v.name for v in self.views]}")

    @classmethod
    def read(cls, path: Path) -> VerifyMetrics | None:
        """The measurements in ``path`` (a ``metrics.json``); None where it is unreadable.

        A ``min_rho`` of -1 is no gate (:func:`~scratchfab.verify.gate.gate_applies`):
        ``passed`` is None then, as without one.

        Raises:
            ConfigError: The file's ``gate`` is damaged (not an object, or its
                ``failing`` or ``unchecked`` not a list of view names).
        """
        from scratchfab.verify.gate import gate_applies

        try:
            data = decode_json(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        views = data.get("views") if isinstance(data, dict) else None
        if not isinstance(views, dict):
            return None
        gate = data.get("gate")
        if gate is not None and not isinstance(gate, dict):
            raise ConfigError(f"{path}: gate: expected an object, got {gate!r}")
        gate = gate or {}
        failing, unchecked = (_view_names(path, gate, key) for key in ("failing", "unchecked"))
        min_rho = _number(gate.get("min_rho"))
        gated = gate_applies(min_rho)
        names = data.get("names")
        order = [str(n) for n in names] if isinstance(names, list) else list(views)
        found = []
        for name in order:
            entry = views.get(name)
            entry = entry if isinstance(entry, dict) else {}
            rho = _number(entry.get("rho"))
            passed = None if not gated or rho is None or name in unchecked else name not in failing
            found.append(ViewMetrics(name, rho, _number(entry.get("psnr")), passed))
        passed = gate.get("passed")
        return cls(
            tuple(found), min_rho, passed if gated and isinstance(passed, bool) else None, path
        )


def _view_names(path: Path, gate: dict[str, Any], key: str) -> set[str]:
    """The gate's ``key`` in ``path``: a list of view names (none where it is missing).

    Raises:
        ConfigError: It is something else.
    """
    value = gate.get(key)
    if value is None:
        return set()
    if not isinstance(value, list) or not all(isinstance(n, str) for n in value):
        raise ConfigError(f"{path}: gate.{key}: expected a list of view names, got {value!r}")
    return set(value)


@dataclass(frozen=True)
class ToolpathFigures:
    """The toolpath stage's figures, as ``JOB/toolpath/toolpath.json`` holds them.

    Attributes:
        strokes: Strokes to cut.
        scratches: Scratches it was planned from.
        left_out: Scratches not cut: off the board, outside the machine's travel or
            shorter than the tool's minimum (duplicates merged into one stroke are cut).
        clipped: Strokes the machine's travel cuts short.
        cut_mm: Length cut.
        travel_mm: Pen-up travel, from the start position and back to it.
        estimated_s: Estimated machining time.
        strokes_id: The ordered strokes' id, which the G-code's header carries.
        file: The ``toolpath.json`` read.
    """

    strokes: int
    scratches: int
    left_out: int
    clipped: int
    cut_mm: float
    travel_mm: float
    estimated_s: float
    strokes_id: str
    file: Path

    @classmethod
    def read(cls, path: Path) -> ToolpathFigures | None:
        """The figures of ``path`` (a ``toolpath.json``); None where it is unreadable."""
        from scratchfab.toolpath import Toolpath

        try:
            toolpath = Toolpath.load(path)
            s = toolpath.stats
            scratches = int(s["input_count"])
            return cls(
                len(toolpath),
                scratches,
                scratches - len(toolpath) - int(s["merged_count"]),
                int(s["clipped_count"]),
                float(s["cut_length_mm"]),
                float(s["travel_length_mm"]),
                float(s["estimated_time_s"]),
                toolpath.strokes_id,
                path,
            )
        except (ConfigError, KeyError, TypeError, ValueError):
            return None


@dataclass
class RunResult:
    """What a pipeline run did.

    Attributes:
        job: The job folder.
        ran: Stages that ran.
        skipped: Stages skipped because their inputs did not change.
        report: The report written at the end (also after a failure).
        seconds: Wall time of the whole run.
        verify: The verify metrics, where verify ran or was up to date (else None, as
            when ``--until`` stopped before it or it is not in the pipeline).
        toolpath: The toolpath's figures, where toolpath ran or was up to date.
    """

    job: Path
    ran: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    report: Path | None = None
    seconds: float = 0.0
    verify: VerifyMetrics | None = None
    toolpath: ToolpathFigures | None = None


def partial_by_pipeline_force(path: Path) -> str:
    """The note of a partial board planned under ``[pipeline] force`` alone (its older meaning)."""
    return (
        f"note: the part the machine reaches was planned because of {PIPELINE_FORCE}, which "
        f"also meant that before a partial board had its own key; set [toolpath] force in "
        f"{path}: true to keep planning it, false to refuse a partial board"
    )


def _toolpath_options(options: ToolpathOptions, machine: bool) -> dict[str, Any]:
    """``[toolpath]`` as the toolpath stage's fingerprint records it.

    ``force`` only where given: a job planned before the key keeps its fingerprint (and
    ``[pipeline] force``, its older meaning, is in the design stage's); ``machine`` only
    where ``machine`` (a format-1 fingerprint named it; format 2 takes the profile's bytes).
    """
    return {
        k: v
        for k, v in asdict(options).items()
        if not (k == "force" and v is None) and (machine or k != "machine")
    }


class _Stages:
    """The stage table: inputs, action and outputs of each stage of one pipeline."""

    def __init__(
        self,
        pipe: Pipeline,
        job: Path,
        say: Say,
        confirm: Confirm | None,
        homed: bool = False,
        zero_here: bool = False,
    ) -> None:
        self.pipe = pipe
        self.job = job
        self.layout = JobLayout(job)
        self.say = say
        self.confirm = confirm
        self.homed = homed  # the stream stage's resume after a lost position (--homed)
        self.zero_here = zero_here  # the stream stage zeroes where the tool stands
        self.resume = False  # continue the stage's interrupted work (optimize's checkpoint)

    # -- inputs -----------------------------------------------------------------------
    def _spec(self, stage: str) -> tuple[list[Path], dict[str, Path], dict[str, Any]]:
        """What ``stage`` reads: job files, the user's files by role, and its options."""
        pipe, layout = self.pipe, self.layout
        design_dir = layout.design.path
        if stage == "design":
            return [], self._targets(), {"tables": design_options(pipe.design_tables)}
        if stage == "optimize":
            return [design_dir], {}, asdict(pipe.optimize)
        if stage == "verify":
            files = [design_dir, layout.optimized_scratches, layout.optimize_renders]
            # jitter moves the scratches by the machine's [tool] tolerance_mm
            machine = {"machine": Path(pipe.profile.source)} if pipe.verify.jitter else {}
            return files, machine, asdict(pipe.verify)
        if stage == "toolpath":
            files = [layout.design.design_toml, layout.optimized_scratches]
            # the profile by its bytes: a bundled name and a copy of its file are one machine
            options = _toolpath_options(pipe.toolpath, machine=False)
            return files, {"machine": Path(pipe.profile.source)}, options
        if stage == "export":
            return [layout.toolpath_json], {}, asdict(pipe.export)
        if stage == "stream":
            # recut_unsure only steers a resume: turning it on must not cut a finished board
            # again; the baud is the one used (leaving out the profile's own changes nothing)
            options = {k: v for k, v in asdict(pipe.stream).items() if k != "recut_unsure"}
            options["baud"] = pipe.stream.baud or pipe.profile.serial.baud
            return [self.gcode()], {}, options
        raise KeyError(stage)

    def _targets(self) -> dict[str, Path]:
        """Each view's target image, by view."""
        design = self.pipe.design
        return {
            f"target:{v.name}": path
            for v in design.views
            if (path := design.target_path(v)) is not None
        }

    def inputs(self, stage: str) -> dict[str, Any]:
        """The fingerprint of ``stage``'s inputs as they are now."""
        files, sources, options = self._spec(stage)
        return fingerprint(files, sources, options, self.job)

    def design_edited(self, manifest: Manifest) -> str | None:
        """A line when ``JOB/design/design.toml`` changed since the design stage wrote it.

        In a pipeline job the design stage writes that file from the pipeline file, so an
        edit by hand holds only until the design stage runs again. Where the manifest does
        not hold what design wrote (an earlier scratchfab's): the file as optimize read it.
        """
        file = self.layout.design.design_toml
        was = manifest.digest("design", file, "written")
        was = was or manifest.digest("optimize", file, "read")
        if was is None or not file.is_file() or file_digest(file) == was:
            return None
        return (
            f"  {file} was edited since the design stage wrote it: the stages after design "
            f"use it as it is now, but this job's design comes from {self.pipe.path}, and the "
            "design stage writes it over whenever that file changes: make the edit there"
        )

    def legacy(self, stage: str) -> Legacy:
        """Whether a format-1 fingerprint (an earlier scratchfab's) matches ``stage`` now."""
        files, sources, options = self._spec(stage)
        if stage == "design":  # format 1 took the tables whole
            options = {"tables": self.pipe.design_tables}
        elif stage == "toolpath":  # ... and the machine as named
            options = _toolpath_options(self.pipe.toolpath, machine=True)
        elif stage == "verify":  # ... and no machine
            sources = {}
        return lambda recorded: matches_format_1(recorded, files, sources, options, self.job)

    def gcode(self) -> Path:
        """The G-code file the stream stage sends."""
        return self.layout.export_file("gcode")

    def streamed_to_end(self) -> bool:
        """False when the journal's last run streamed the current G-code and did not finish.

        A later run of another file (``scratchfab stream`` on a hand-edited copy) does not
        make the board's own finished stream count as unfinished.
        """
        from scratchfab.machine.sender_journal import (
            default_journal_path,
            interrupted,
            read_journal,
        )

        try:
            events = read_journal(default_journal_path(self.gcode()))
        except ConfigError:
            return False  # the stream stage reads it again and names the damage
        return not interrupted(events, file_digest(self.gcode()))

    def wanted(self, stage: str) -> bool:
        """False for stages the pipeline does not ask for (stream without a port)."""
        return stage != "stream" or self.pipe.stream.port is not None

    # -- actions ----------------------------------------------------------------------
    def run(self, stage: str) -> list[str]:
        """Run ``stage``; returns its outputs relative to the job folder."""
        return list(getattr(self, f"_run_{stage}")())

    def _say_in(self, line: str) -> None:
        """A stage's own line, indented under its ``[stage] running``."""
        self.say(f"  {line}")

    def _relative(self, *paths: Path) -> list[str]:
        """``paths`` (in the job folder) as the manifest records outputs."""
        return [self.layout.relative(p) for p in paths]

    def _run_design(self) -> Sequence[str]:
        from scratchfab.design.feasibility import DESIGN_ANYWAY
        from scratchfab.design.stage import run_design
        from scratchfab.design.stand import stand_lines

        opts = self.pipe.pipeline
        try:
            result = run_design(
                replace(self.pipe.design, source=str(self.pipe.path)),
                self.job,
                force=opts.force,
                fit=opts.fit,
                seed=opts.seed,
                progress=self._say_in,
                machine=self.pipe.profile,
                reach=False,  # the run warned of the board before its first stage
            )
        except ScratchfabError as exc:  # `run --force` reruns stages: name the file's key
            if exc.args and DESIGN_ANYWAY in str(exc.args[0]):
                anyway = f"(set [pipeline] force = true in {self.pipe.path} to design anyway)"
                exc.args = (str(exc.args[0]).replace(DESIGN_ANYWAY, anyway), *exc.args[1:])
            raise
        for line in stand_lines(result.design):  # as `design` ends (also in the report)
            self._say_in(line)
        design = self.layout.design
        return self._relative(design.design_toml, design.initial_scratches, design.targets_dir)

    def _run_optimize(self) -> Sequence[str]:
        from scratchfab.optimize.progress import progress_printer
        from scratchfab.optimize.stage import NOTHING_TO_DO, ResumeRefused, run_optimize

        progress = progress_printer(self._say_in)
        layout = self.layout
        options = self.pipe.optimize
        if self.resume and layout.optimize_checkpoint.is_file():
            self._say_in(f"continuing the run from {layout.optimize_checkpoint}")
            try:
                result = run_optimize(self.job, replace(options, resume=True), progress=progress)
                if result.stopped == NOTHING_TO_DO:  # finished by `optimize --resume` since
                    self._say_in("it had finished: its outputs are kept")
            except ConfigError as exc:
                why = str(exc)
                if isinstance(exc, ResumeRefused):  # its advice is for `optimize --resume`
                    why = f"{exc.path}: {exc.reasons()}"
                self._say_in(f"cannot continue it ({why}); optimizing from the start")
                result = run_optimize(self.job, options, progress=progress)
        else:
            result = run_optimize(self.job, options, progress=progress)
        if result.stopped == "interrupted":
            raise Interrupted(
                f"[optimize] interrupted after {result.iterations} of {options.iterations} "
                f"iterations; the pipeline stops here. Its work is saved: run again to "
                f"continue from {layout.optimize_checkpoint}"
            )
        return self._relative(
            layout.optimized_scratches, layout.optimize_renders, layout.optimize_log
        )

    def _run_verify(self) -> Sequence[str]:
        from scratchfab.verify.verify import VerifyGateError, VerifySettings, run_verify_job

        v = self.pipe.verify
        settings: dict[str, Any] = {
            "spp": v.spp,
            "seed": v.seed,
            "backend": v.backend,
            "sweep": v.sweep,
            "min_rho": v.min_rho,
        }
        if v.sky:
            from scratchfab.verify.scene import Sky

            settings["sky"] = Sky()
        if v.jitter:
            from scratchfab.verify.jitter import Tolerance

            settings["jitter"] = Tolerance.from_profile(self.pipe.machine_ref(), self.pipe.profile)
        try:
            metrics = run_verify_job(self.job, VerifySettings(**settings), progress=self._say_in)
        except VerifyGateError as exc:  # named as the pipeline file names it
            named = exc.named("[verify] min_rho =", str(self.pipe.path))
            named.metrics = VerifyMetrics.read(exc.metrics_file)  # no RunResult to hold them
            raise named from None
        # The difference maps too (views with a target), so a deleted one reruns verify.
        diffs = [self.layout.verify_diff_png(name) for name in metrics["names"]]
        return self._relative(self.layout.verify_metrics, *(p for p in diffs if p.is_file()))

    def _run_toolpath(self) -> Sequence[str]:
        from scratchfab.toolpath import OrderOptions
        from scratchfab.toolpath.plan import partial_text
        from scratchfab.toolpath.stage import run_toolpath_job

        t = self.pipe.toolpath
        options = OrderOptions(passes=t.passes, kicks=t.kicks, seed=t.seed)
        key = self.pipe.partial_key()
        plan = run_toolpath_job(
            self.job,
            self.pipe.profile,
            options,
            say=self._say_in,
            refuse_partial=None if key else TOOLPATH_FORCE,
        )
        if key == PIPELINE_FORCE and partial_text(plan.stats) is not None:
            self._say_in(partial_by_pipeline_force(self.pipe.path))
        return self._relative(self.layout.toolpath_json, self.layout.toolpath_preview)

    def _run_export(self) -> Sequence[str]:
        from scratchfab.export import FORMATS, export
        from scratchfab.toolpath import Toolpath

        toolpath = Toolpath.load(self.layout.toolpath_json)
        for fmt in FORMATS:  # a format left out of [export] formats: its old file goes
            stale = self.layout.export_file(fmt)
            if fmt not in self.pipe.export.formats and stale.is_file():
                stale.unlink()
                self._say_in(f"removed {stale} (not in [export] formats)")
        outputs = []
        for fmt in self.pipe.export.formats:
            out = self.layout.export_file(fmt)
            export(toolpath, None, out, fmt)
            self._say_in(f"wrote {out}")
            outputs.append(self.layout.relative(out))
        return outputs

    def _run_stream(self) -> Sequence[str]:
        from scratchfab.machine.stream_job import run_stream_job

        s = self.pipe.stream
        assert s.port is not None
        try:
            run_stream_job(
                self.job,
                port=s.port,
                protocol=s.protocol,
                baud=s.baud,
                check=s.check,
                machine=self.pipe.profile,
                recut_unsure=s.recut_unsure,
                homed=self.homed,
                zero_here=self.zero_here,
                say=self._say_in,
                # None (--yes): nobody is asked, and a partial board is refused
                confirm=(lambda _: True) if is_emulator(s.port) else self.confirm,
            )
        except ScratchfabError as exc:  # the sender's advice names `stream`'s option
            if exc.args:
                exc.args = (as_run_advice(str(exc.args[0])), *exc.args[1:])
            raise
        return self._relative(self.layout.journal)


def run_pipeline(
    pipe: Pipeline,
    job: Path,
    start: str | None = None,
    until: str | None = None,
    force: bool = False,
    say: Say = lambda _: None,
    confirm: Confirm | None = None,
    homed: bool = False,
    zero_here: bool = False,
) -> RunResult:
    """Run the pipeline's stages into ``job``.

    Args:
        pipe: The parsed pipeline file.
        job: The job folder (created when missing).
        start: Run this stage and every later one even when up to date (``--from``).
        until: Stop after this stage (``--until``).
        force: Run every stage.
        say: Called with one line per event (progress).
        confirm: Asked before the stream stage moves a real machine (any port but the
            emulator), after its settings check as ``stream`` asks; False stops with
            nothing sent. None: the caller has consent.
        homed: The machine was homed, or its work zero set again, since an alarm that may
            have lost its position in the stream being resumed (``run --homed``; without
            it the stream stage asks, and refuses where ``confirm`` is None).
        zero_here: The stream stage sets the work zero where the tool stands once
            connected (``run --zero-here``; :attr:`~scratchfab.machine.stream_job.StreamRequest.zero_here`).

    A stage is marked running in the manifest before it starts, so one killed midway is
    run again next time. An optimize stopped by Ctrl-C (or killed) on the same inputs
    continues from its checkpoint, unless ``force`` or ``start`` asks for it afresh.

    Raises:
        Interrupted: Ctrl-C stopped optimize; its work is saved, later stages did not run.
        ScratchfabError: A stage failed; earlier outputs and the manifest stay consistent,
            and the report is still written.
    """
    for name in (start, until):
        if name is not None and name not in STAGES:
            raise ScratchfabError(f"unknown stage '{name}'; stages: {', '.join(STAGES)}")
    if start is not None and until is not None and STAGES.index(start) > STAGES.index(until):
        raise ScratchfabError(f"--from {start} comes after --until {until}; nothing to run")
    job.mkdir(parents=True, exist_ok=True)
    with _job_lock(JobLayout(job).run_lock):
        return _run_stages(pipe, job, start, until, force, say, confirm, homed, zero_here)


@contextlib.contextmanager
def _job_lock(path: Path) -> Iterator[None]:
    """Hold ``path`` locked, or refuse: two runs on one job would mix their files and cut twice.

    The lock (``flock``) goes with the process, so a killed run leaves none behind.
    """
    try:
        handle = open(path, "a")  # held for the whole run
    except OSError as exc:
        raise ScratchfabError(f"{path}: cannot write ({exc.strerror or exc})") from None
    with handle:
        if not try_lock(handle):
            raise ScratchfabError(
                f"{path.parent}: another `scratchfab run` is working on this job; "
                "wait until it ends"
            )
        yield


def _board_overhang(pipe: Pipeline) -> str | None:
    """The warning for a board the machine cannot reach whole, or None when it can.

    The toolpath stage refuses a board whose scratches the envelope cuts short (unless
    :meth:`Pipeline.partial_key`), and one wholly outside it; said before design and optimize run,
    a person can fix the board or the profile before minutes of work. Scratches keep
    ``[board] margin_mm`` inside the board's edges, so a board that overhangs by less says
    nothing.
    """
    import numpy as np

    from scratchfab.toolpath.plan import envelope_text, fit_advice, xy_text

    board, profile = pipe.design.board, pipe.profile
    size = (board.width_mm, board.height_mm)
    corners = profile.board_outline(size)
    env = profile.envelope
    # The board turns by quarter turns only: its outline is an axis-aligned rectangle.
    laid = np.stack([corners.min(axis=0) + board.margin_mm, corners.max(axis=0) - board.margin_mm])
    if env.contains_xy(laid).all():
        return None
    where = (
        f"warning: the {board.width_mm:g} x {board.height_mm:g} mm board (corners "
        f"{xy_text(corners)})"
    )
    envelope = envelope_text(profile)
    fix = fit_advice(profile, size)
    kept = "design and optimize do not use the machine: their work is kept for the next run"
    # The board turns by quarter turns only: its outline is an axis-aligned rectangle.
    lo, hi = corners.min(axis=0).tolist(), corners.max(axis=0).tolist()
    if not all(
        min(hi[i], span[1]) > max(lo[i], span[0]) for i, span in enumerate((env.x_mm, env.y_mm))
    ):
        return (
            f"{where} lies wholly outside {envelope}: the toolpath stage will refuse it; "
            f"{fix} ({kept})"
        )
    key = pipe.partial_key()
    older = ", [toolpath] force not given: set it to false to refuse it" * (key == PIPELINE_FORCE)
    when = (
        f"will leave out the scratches beyond it and clip those across its edge ({key}{older})"
        if key
        else f"will stop there if a scratch lies beyond it, unless {TOOLPATH_FORCE}, "
        "which cuts only the part it reaches"
    )
    return (
        f"{where} reaches beyond {envelope}: the toolpath stage {when}. To cut the whole "
        f"board, {fix}; Ctrl-C now to make the change ({kept})"
    )


def _has_stage_outputs(layout: JobLayout) -> bool:
    """Whether the job folder holds a folder a stage writes (design/, optimize/, ...)."""
    folders = (
        layout.design.path,
        layout.optimize_dir,
        layout.verify_dir,
        layout.toolpath_dir,
        layout.export_dir,
        layout.stream_dir,
    )
    return any(folder.is_dir() for folder in folders)


def _run_stages(
    pipe: Pipeline,
    job: Path,
    start: str | None,
    until: str | None,
    force: bool,
    say: Say,
    confirm: Confirm | None,
    homed: bool,
    zero_here: bool = False,
) -> RunResult:
    """The body of :func:`run_pipeline`, under the job's lock."""
    t0 = time.perf_counter()
    manifest = Manifest.load(job)
    stages = _Stages(pipe, job, say, confirm, homed, zero_here)
    result = RunResult(job)
    last = STAGES.index(until) if until else len(STAGES) - 1
    # Said once, before the first stage of the run that comes ahead of toolpath, also when
    # --until stops before it (the board is for a later run's toolpath; the toolpath stage
    # says what it left out itself; a run with nothing to do says nothing).
    overhang = _board_overhang(pipe)
    rerun = force
    # A folder the single commands made (they keep no manifest): said once, where a stage
    # is checked, so that the run does not seem to redo their work for no reason.
    unrecorded = not (job / MANIFEST_NAME).exists() and _has_stage_outputs(stages.layout)
    try:
        for index, stage in enumerate(STAGES[: last + 1]):
            if not stages.wanted(stage):
                continue
            inputs, legacy = stages.inputs(stage), stages.legacy(stage)
            checked = False  # the manifest was asked whether the stage is up to date
            if stage == "stream":
                asked = force or start == "stream"
                checked = not asked
                current = manifest.is_current(stage, inputs, legacy)
                if not asked and current and stages.streamed_to_end():
                    result.skipped.append(stage)
                    say(
                        f"[stream] {stages.gcode()} is unchanged and was streamed to the end; "
                        "not cutting it again (run with --from stream to cut it again)"
                    )
                    continue
            else:
                asked = force or (start is not None and STAGES.index(start) <= index)
                rerun = rerun or asked
                checked = not rerun
                if checked and manifest.is_current(stage, inputs, legacy):
                    result.skipped.append(stage)
                    say(f"[{stage}] up to date, skipped")
                    if stage == "design" and (edited := stages.design_edited(manifest)):
                        say(edited)
                    continue
            if checked and manifest.recorded_in_format_1(stage):
                say(
                    f"[{stage}] {job / 'manifest.json'} holds this stage's inputs as an earlier "
                    "scratchfab recorded them (by absolute path and file time); they do not "
                    "match the files now: running it again"
                )
            if checked and unrecorded:
                say(
                    f"no record of earlier runs in {job} (only `scratchfab run` keeps one, its "
                    f"{MANIFEST_NAME}), so every stage runs"
                )
                unrecorded = False
            if overhang is not None and index < STAGES.index("toolpath"):
                say(overhang)
            overhang = None
            say(f"[{stage}] running")
            began = time.perf_counter()
            # Whatever changed since: optimize's checkpoint knows what its steps depend on,
            # and says what changed when it cannot go on (then it starts over).
            stages.resume = not asked and manifest.stopped(stage)
            manifest.start(stage, inputs)
            try:
                outputs = stages.run(stage)
            except Interrupted as exc:
                manifest.interrupt(stage, inputs, str(exc))
                raise
            except BaseException as exc:
                # a user's mistake in its own words; anything else with its kind
                why = (
                    str(exc)
                    if isinstance(exc, ScratchfabError)
                    else "interrupted (Ctrl-C)"
                    if isinstance(exc, KeyboardInterrupt)
                    else f"{type(exc).__name__}: {exc}"
                )
                manifest.invalidate(stage, why)
                raise
            # Record what the stage read, as it was when the stage ran.
            # what design wrote, to tell a later edit by hand (design_edited)
            written = [stages.layout.design.design_toml] if stage == "design" else []
            manifest.record(stage, inputs, outputs, time.perf_counter() - began, written)
            result.ran.append(stage)
            rerun = True
            say(f"[{stage}] done in {time.perf_counter() - began:.1f} s")
    finally:
        result.report = write_report(
            job,
            pipe.pipeline.name,
            port=pipe.stream.port,
            min_rho=pipe.verify.min_rho,
            pipeline_file=pipe.path,
        )
        result.seconds = time.perf_counter() - t0
    this_run = {*result.ran, *result.skipped}  # the outputs in the folder are current
    if "verify" in this_run:
        result.verify = VerifyMetrics.read(stages.layout.verify_metrics)
    if "toolpath" in this_run:
        result.toolpath = ToolpathFigures.read(stages.layout.toolpath_json)
    return result
