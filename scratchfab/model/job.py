"""The job folder's layout (SPEC section 6): where each stage finds its inputs."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from scratchfab.console import command_line
from scratchfab.errors import ConfigError
from scratchfab.fileio import decode_json, file_sha256, write_json
from scratchfab.model.design import Design, design_fields, load_design, same_to_rounding

_EXPORT_STEM = "board"  # JOB/export/board.<format>


def diff_map_png(verify_dir: Path, view: str) -> Path:
    """``view``'s difference map in a verify output folder (``JOB/verify`` or ``--out``).

    In a folder of its own: beside the render layout, ``<view>_diff.png`` would be the
    preview of a view named so.
    """
    return verify_dir / "diff" / f"{view}.png"


@dataclass(frozen=True)
class DesignFolder:
    """The design stage's files: ``JOB/design/``, or the temporary folder that becomes it.

    Attributes:
        path: The folder.
    """

    path: Path

    @property
    def design_toml(self) -> Path:
        """The resolved design (absolute target paths, every default filled in)."""
        return self.path / "design.toml"

    @property
    def initial_scratches(self) -> Path:
        """The initial layout."""
        return self.path / "scratches.csv"

    @property
    def targets_dir(self) -> Path:
        """Each view's target in its camera pixels."""
        return self.path / "targets"

    def target_npy(self, view: str) -> Path:
        """``view``'s target, linear float32 (H, W); NaN outside the board."""
        return self.targets_dir / f"{view}.npy"

    def target_png(self, view: str) -> Path:
        """``view``'s target as a person looks at it."""
        return self.targets_dir / f"{view}.png"

    @property
    def boards_dir(self) -> Path:
        """The board-space pictures the design's views name as targets."""
        return self.path / "board"

    def board_png(self, view: str) -> Path:
        """``view``'s board-space picture (its target in ``design.toml``)."""
        return self.boards_dir / f"{view}.png"

    def feasibility_png(self, view: str) -> Path:
        """Where on the board the tool can light ``view``."""
        return self.path / f"feasibility_{view}.png"

    @property
    def feasibility_json(self) -> Path:
        """The feasibility report."""
        return self.path / "feasibility.json"

    @property
    def digested(self) -> tuple[Path, Path]:
        """The files an optimized layout is made from (optimize records their digests)."""
        return self.design_toml, self.initial_scratches

    def pictures(self) -> list[Path]:
        """Each view's target and board picture, which optimize reads too.

        Empty when ``design.toml`` does not load: its own digest tells the change then.
        """
        try:
            views = load_design(self.design_toml).views
        except ConfigError:
            return []
        return [p for v in views for p in (self.target_npy(v.name), self.board_png(v.name))]

    def relative(self, path: Path) -> str:
        """``path`` relative to the design folder, with forward slashes."""
        return path.relative_to(self.path).as_posix()


@dataclass(frozen=True)
class JobLayout:
    """Where each file of a job folder lies (SPEC section 6).

    The paths are ``root`` joined with the names, neither resolved nor checked, so a
    message that shows one shows it as the caller named the job.

    Attributes:
        root: The job folder.
    """

    root: Path

    @classmethod
    def for_export_file(cls, file: Path) -> JobLayout | None:
        """The job whose export folder holds ``file`` (as it is named), else None."""
        job = cls(file.parent.parent)
        return job if file.parent == job.export_dir else None

    def relative(self, path: Path) -> str:
        """``path`` relative to the job folder, with forward slashes."""
        return path.relative_to(self.root).as_posix()

    @property
    def design(self) -> DesignFolder:
        """``JOB/design/``: the design stage's files."""
        return DesignFolder(self.root / "design")

    @property
    def optimize_dir(self) -> Path:
        """The optimize stage's folder."""
        return self.root / "optimize"

    @property
    def optimized_scratches(self) -> Path:
        """The optimized layout (the board to cut)."""
        return self.optimize_dir / "scratches.csv"

    @property
    def unpruned_scratches(self) -> Path:
        """The optimized layout before pruning."""
        return self.optimize_dir / "scratches_unpruned.csv"

    @property
    def optimize_renders(self) -> Path:
        """``render`` layout of the optimized board."""
        return self.optimize_dir / "renders"

    @property
    def optimize_log(self) -> Path:
        """Iteration, loss and quality per view."""
        return self.optimize_dir / "log.csv"

    @property
    def optimize_summary(self) -> Path:
        """The optimize run's summary, with the digests of the design files it used."""
        return self.optimize_dir / "summary.json"

    @property
    def optimize_checkpoint(self) -> Path:
        """The state a resumed optimize run continues from."""
        return self.optimize_dir / "checkpoint.npz"

    @property
    def loss_png(self) -> Path:
        """The loss curve."""
        return self.optimize_dir / "loss.png"

    @property
    def side_by_side_png(self) -> Path:
        """Each view's target beside its optimized render."""
        return self.optimize_dir / "side_by_side.png"

    @property
    def verify_dir(self) -> Path:
        """``render`` layout from the independent renderer, and the metrics."""
        return self.root / "verify"

    @property
    def verify_metrics(self) -> Path:
        """The independent renderer's quality measures."""
        return self.verify_dir / "metrics.json"

    def verify_diff_png(self, view: str) -> Path:
        """Where ``view``'s verified render is brighter or darker than its target."""
        return diff_map_png(self.verify_dir, view)

    @property
    def render_dir(self) -> Path:
        """Where ``render JOB`` writes by default."""
        return self.root / "render"

    @property
    def toolpath_dir(self) -> Path:
        """The toolpath stage's folder."""
        return self.root / "toolpath"

    @property
    def toolpath_json(self) -> Path:
        """Ordered strokes in machine coordinates, with statistics."""
        return self.toolpath_dir / "toolpath.json"

    @property
    def toolpath_preview(self) -> Path:
        """The toolpath drawn over the board and the machine's envelope."""
        return self.toolpath_dir / "preview.png"

    @property
    def export_dir(self) -> Path:
        """The export stage's folder."""
        return self.root / "export"

    def export_file(self, fmt: str) -> Path:
        """The board exported as ``fmt`` (``gcode``, ``dxf``, ``svg``)."""
        return self.export_dir / f"{_EXPORT_STEM}.{fmt}"

    def export_files(self) -> list[Path]:
        """The board's exported files that exist, sorted by path."""
        return sorted(self.export_dir.glob(f"{_EXPORT_STEM}.*"))

    @property
    def stream_dir(self) -> Path:
        """The stream stage's folder."""
        return self.root / "stream"

    @property
    def journal(self) -> Path:
        """Acknowledged lines of the streaming runs."""
        return self.stream_dir / "journal.jsonl"

    @property
    def report_html(self) -> Path:
        """The page a person reads after a run."""
        return self.root / "report.html"

    @property
    def run_lock(self) -> Path:
        """Locked by ``scratchfab run`` while it works on the job (empty; a dot file)."""
        return self.root / ".run.lock"


def job_inputs(job: str | Path) -> tuple[Path, Path]:
    """The design and scratch files a stage working on a job uses.

    The design is ``JOB/design/design.toml``; the scratches are the optimized layout
    ``JOB/optimize/scratches.csv`` when present, else the initial ``JOB/design/scratches.csv``.

    Raises:
        ConfigError: Naming the missing file.
    """
    folder = Path(job)
    if not folder.is_dir():
        raise ConfigError(f"{folder}: job folder not found")
    layout = JobLayout(folder)
    design = layout.design.design_toml
    if not design.is_file():
        raise ConfigError(f"{design}: file not found (is {folder} a job folder?)")
    for scratches in (layout.optimized_scratches, layout.design.initial_scratches):
        if scratches.is_file():
            return design, scratches
    raise ConfigError(
        f"{folder}: no scratch layout (expected {layout.relative(layout.optimized_scratches)} "
        f"or {layout.relative(layout.design.initial_scratches)})"
    )


def design_digest(job: str | Path) -> dict[str, str]:
    """SHA-256 of each file of the job's design that optimize reads, by design-folder path.

    ``design.toml``'s is of what optimize's steps depend on (:func:`design_content_sha256`),
    so a rerun of design that rewrites only its comments and paths changes nothing; the
    others' (:attr:`DesignFolder.digested`, and each view's target and board picture:
    :meth:`DesignFolder.pictures`) of their bytes, so a picture swapped by hand counts.
    """
    folder = JobLayout(Path(job)).design
    files = [*folder.digested, *folder.pictures()]
    return {
        folder.relative(path): (
            design_content_sha256(path) if path == folder.design_toml else file_sha256(path)
        )
        for path in files
    }


def design_content_sha256(
    path: Path, pick: Callable[[Design], dict[str, Any]] = design_fields
) -> str:
    """SHA-256 of what ``pick`` takes of a design file, as JSON.

    So that a rerun of design that rewrites only the file's comments and target paths
    changes nothing; the bytes' SHA-256 when the file does not load (a broken file differs
    from any design). A file without views loads (the toolpath stage plans it).

    Args:
        path: The design file.
        pick: What counts: by default what optimize's steps depend on
            (:func:`~scratchfab.model.design.design_fields`); a toolpath's record takes
            what its plan reads (:func:`~scratchfab.toolpath.inputs.plan_fields`).
    """
    try:
        design = load_design(path, require_views=False)
    except ConfigError:
        return file_sha256(path)
    return _fields_sha256(design, pick)


def _fields_sha256(design: Design, pick: Callable[[Design], dict[str, Any]] = design_fields) -> str:
    text = json.dumps(pick(design), sort_keys=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class EarlierDesign:
    """A job's ``design.toml`` as it was before design wrote it again.

    Attributes:
        digests: Its bytes' and its fields' SHA-256: either is what optimize recorded of
            it when the layout was made from it (an earlier scratchfab recorded the bytes).
        fields: Its :func:`~scratchfab.model.design.design_fields`.
    """

    digests: frozenset[str]
    fields: dict[str, Any]


def earlier_design(job: str | Path) -> EarlierDesign | None:
    """The job's ``design.toml`` before a rerun of design, or None (none, or it does not load)."""
    file = JobLayout(Path(job)).design.design_toml
    try:
        design = load_design(file) if file.is_file() else None
    except ConfigError:
        return None
    if design is None:
        return None
    digests = frozenset({file_sha256(file), _fields_sha256(design)})
    return EarlierDesign(digests, design_fields(design))


def carry_optimize_record(job: str | Path, earlier: EarlierDesign | None) -> None:
    """Keep an optimized layout current over a rerun of design that changed no resolved value.

    Optimize records ``design.toml``'s digest. A record of an earlier scratchfab is of its
    bytes, and a file of before ``fov_deg = "auto"`` was kept (auto's number written out)
    is rewritten with ``"auto"``: the record then matches neither digest of the new file,
    and the layout would read stale. Where the record is of the ``earlier`` file and the
    new file resolves to the same values (floats to rounding, as ``"auto"`` is told from a
    number: :func:`~scratchfab.model.design.same_to_rounding`), the record becomes the new
    file's; else it is left as it is.
    """
    if earlier is None:
        return
    layout = JobLayout(Path(job))
    name = layout.design.design_toml.name
    try:
        summary = decode_json(layout.optimize_summary.read_text(encoding="utf-8"))
        recorded = summary["design_sha256"]
        if recorded[name] not in earlier.digests:
            return
        design = load_design(layout.design.design_toml)
    except (OSError, ValueError, TypeError, KeyError, ConfigError):
        return
    now = _fields_sha256(design)
    if recorded[name] != now and same_to_rounding(design_fields(design), earlier.fields):
        recorded[name] = now
        write_json(layout.optimize_summary, summary)


def design_changed_since_optimize(job: str | Path) -> list[str]:
    """The design files (job-relative) changed since ``JOB/optimize/scratches.csv`` was made.

    Optimize records :func:`design_digest` in ``optimize/summary.json``; a record of the
    scratchfab before, of ``design.toml``'s bytes, still matches an unchanged file. Empty
    when the layout is current, when there is none, or when there is no record to tell by.
    """
    layout = JobLayout(Path(job))
    if not layout.optimized_scratches.is_file():
        return []
    try:
        summary = decode_json(layout.optimize_summary.read_text(encoding="utf-8"))
        recorded = summary["design_sha256"]
    except (OSError, ValueError, TypeError, KeyError):
        return []
    if not isinstance(recorded, dict):
        return []
    folder = layout.design
    now = design_digest(layout.root)
    # A record of an earlier scratchfab lacks the pictures: the files it has are compared.
    pictures = [p for p in folder.pictures() if folder.relative(p) in recorded]
    changed = []
    for path in [*folder.digested, *pictures]:
        key = folder.relative(path)
        if recorded.get(key) not in (now[key], file_sha256(path)):
            changed.append(layout.relative(path))
    return changed


def stale_layout_warning(job: str | Path) -> str | None:
    """A warning when ``JOB/optimize/scratches.csv`` was made from another design.

    Rerunning design after optimize (README step 1's edit loop) leaves an optimized
    layout of the old design behind, which toolpath, verify and render would otherwise
    use without a word. None when the layout is current, or when there is no record.
    """
    stale = stale_layout(job)
    if stale is None:
        return None
    return (
        f"warning: {stale}: it is used as it is; rerun "
        f"`{command_line(['scratchfab', 'optimize', Path(job)])}` for the current design"
    )


def stale_layout(job: str | Path) -> str | None:
    """``JOB/optimize/scratches.csv was optimized from an earlier design (… changed since)``.

    None when the layout is current, or when there is no record to tell by.
    """
    folder = Path(job)
    changed = design_changed_since_optimize(folder)
    if not changed:
        return None
    return (
        f"{JobLayout(folder).optimized_scratches} was optimized from an earlier design "
        f"({', '.join(changed)} changed since)"
    )


def redesigned_note(job: str | Path) -> str | None:
    """After design wrote over a job that was optimized from another design: what to rerun.

    The optimized layout and what toolpath and export made from it stay until optimize
    runs again; toolpath warns then, but a maker editing design.toml should hear it now.
    """
    folder = Path(job)
    if not design_changed_since_optimize(folder):
        return None
    return (
        f"note: {JobLayout(folder).optimized_scratches} (and any toolpath or G-code made "
        "from it) comes from the earlier design; rerun "
        f"`{command_line(['scratchfab', 'optimize', folder])}` before toolpath and export"
    )


def load_job_design(design_file: str | Path) -> Design:
    """A job's ``design/design.toml``, each view's target read from the job's own copy.

    Raises:
        ConfigError: Naming the file and the key on any mistake.
    """
    return own_board_pictures(load_design(Path(design_file)))


def own_board_pictures(design: Design) -> Design:
    """``design`` with each target in some job's ``design/board/`` read from the file's own.

    A job's ``design.toml`` records its board pictures by absolute path (SPEC section 6);
    in a copy of the job they name the original's, which may be gone or designed anew
    since. Where the file is itself a job's ``design/design.toml`` with its own ``board/``
    picture of that name, as a copied job has, that copy is the target. A target anywhere
    else stays as the user named it.
    """
    boards = DesignFolder(design.base_dir).boards_dir
    views = []
    for view in design.views:
        path = design.target_path(view)
        own = boards / path.name if path is not None else None
        in_a_job = (
            path is not None
            and path.parent.name == "board"
            and path.parent.parent.name == "design"
            and design.base_dir.name == "design"
        )
        if own is not None and in_a_job and own.is_file() and own.resolve() != path:
            view = replace(view, target=str(own.resolve()))
        views.append(view)
    return design.with_views(tuple(views))
