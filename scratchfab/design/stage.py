"""The design stage: images and a scene in, ``JOB/design/`` out (SPEC section 6).

Everything is computed first and written into a temporary folder beside
``JOB/design``, which then replaces it in one rename, so a failed run leaves the old
folder (or none) and never half of a new one.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import time
import unicodedata
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from scratchfab.bundled import bundled_name
from scratchfab.console import Say
from scratchfab.design.cost import cut_lines
from scratchfab.design.feasibility import DESIGN_ANYWAY, FeasibilityReport, check_feasibility
from scratchfab.design.images import invert_picture, load_image
from scratchfab.design.layout import initial_layout
from scratchfab.design.quick import SOURCE as QUICK_SOURCE
from scratchfab.design.quick import quick_mapping
from scratchfab.design.targets import (
    FITS,
    board_image_png,
    board_pixels,
    fit_picture,
    picture_area,
    preview_png,
    quantize_like_png,
    warp_to_view,
)
from scratchfab.errors import ConfigError
from scratchfab.fileio import atomic_folder, save_npy, save_png, write_json, write_text
from scratchfab.machine.profile import MachineProfile
from scratchfab.model.camera import Camera
from scratchfab.model.design import (
    MAX_FOV_DEG,
    Board,
    Design,
    View,
    auto_fov,
    design_from_mapping,
)
from scratchfab.model.job import (
    DesignFolder,
    JobLayout,
    carry_optimize_record,
    earlier_design,
    own_board_pictures,
)
from scratchfab.model.schema import load_toml
from scratchfab.model.scratches import ScratchSet
from scratchfab.pipeline.config import StageTables, parse_stage_tables, resolve_machine_ref

#: A target whose brightness varies less than this (linear, 0..1) is uniform: a warning,
#: or, when it is black too (nothing brighter than this), refused unless forced.
UNIFORM_TARGET_SPREAD = 0.01
#: A target whose mean linear brightness over its picture's part of the board (the bars
#: of a ``contain`` fit left out) is above this gets a warning: bright parts are cut, and
#: a picture that is mostly cut shows poorly. Measured on pictures filling the board (two
#: quick-form views on 100 x 80 mm, 60 steps, the other view a light star on dark):
#: bars of bright share 0.1 / 0.3 / 0.4 / 0.5 / 0.6 / 0.7 / 0.9 reached rho 0.84 / 0.92 /
#: 0.93 / 0.92 / 0.91 / 0.88 / 0.73, the other view's light leaking into them ever more
#: (crosstalk 0.01 to 0.11); black "HI" on white (mean 0.93) rho 0.65, 11.4 dB, inverted
#: (0.07) 0.995, 30.1 dB; a dark star on white (0.80) rho 0.81, the light star 0.99.
BRIGHT_TARGET_MEAN = 0.5


@dataclass(frozen=True)
class DesignResult:
    """What the design stage made.

    Attributes:
        folder: ``JOB/design``.
        design: The resolved design as written to ``design.toml`` (its targets are the
            board-space images in ``JOB/design/board/``).
        targets: View name -> (H, W) float32 target in camera pixels, NaN off the board.
        scratches: The initial layout.
        report: The feasibility report.
    """

    folder: Path
    design: Design
    targets: dict[str, np.ndarray]
    scratches: ScratchSet
    report: FeasibilityReport

    @property
    def design_file(self) -> Path:
        """``JOB/design/design.toml``."""
        return DesignFolder(self.folder).design_toml


def load_source(
    source: str | Path | Design,
    count: int | None = None,
    resolution: tuple[int, int] | None = None,
) -> tuple[Design, StageTables]:
    """The design to work on, with command-line overrides applied as if written in the file.

    A file's stage tables are parsed as ``scratchfab run`` parses them, so a mistake in
    them is refused here too.

    Returns:
        (design, the file's stage tables, ``[toolpath] machine`` a bundled name or a path
        resolved against the file as ``run`` resolves it; the defaults for a Design).

    Raises:
        ConfigError: Naming the file and the key.
    """
    if isinstance(source, Design):
        design = source
        if resolution is not None:
            raise ConfigError(
                f"{design.source}: resolution: give it when building the design, "
                "not to a resolved one"
            )
        if count is not None:
            try:
                design = replace(design, scratch=replace(design.scratch, count=count))
            except ValueError as exc:
                raise ConfigError(f"{design.source}: count: {exc}") from None
        return design, StageTables()
    file = Path(source)
    data = load_toml(file)
    if count is not None:
        data.setdefault("scratch", {})
        if isinstance(data["scratch"], dict):
            data["scratch"]["count"] = count
    if resolution is not None and isinstance(data.get("views"), list):
        for view in data["views"]:
            if isinstance(view, dict):
                view["resolution"] = list(resolution)
    design = own_board_pictures(design_from_mapping(data, str(file), file.resolve().parent))
    tables = parse_stage_tables(data, str(file))
    machine = resolve_machine_ref(tables.toolpath.machine, file.resolve())
    return design, replace(tables, toolpath=replace(tables.toolpath, machine=machine))


#: The origin comment's first line, by which a later design knows its own design.toml.
ORIGIN_HEADER = "# Resolved by `scratchfab design`. Each target is the board-space image made from"
#: Starts the line under a view's picture that names what an earlier design made it from.
EARLIER = "#   the board picture an earlier design made from "
#: The line after it when that image was fitted anew to this board's shape.
REFITTED = "#   refitted from that image to this board's shape, each step's options in turn"
#: The last line under a view's picture when this design inverted it (``invert``).
INVERTED = "#   inverted (1 - its sRGB-encoded value) before the options above"
#: One design's options in the heading comment: fit, gamma, contrast, and whether it
#: inverted the picture first.
_STEP = r"\(fit = (contain|cover), gamma = ([^,()]+), contrast = ([^,()]+)(, inverted)?\)"


def _origin_comment(
    design: Design,
    fit: str,
    gamma: float,
    contrast: float,
    seed: int,
    refitted: frozenset[Path] = frozenset(),
    inverted: frozenset[str] = frozenset(),
    rewritten: DesignFolder | None = None,
) -> str:
    """The comment heading ``design.toml``: each view's picture and the options applied to it.

    A picture that is an earlier design's board picture (a rerun from ``JOB/design/
    design.toml``) gets a second line naming the image that design started from, as its
    own comment named it, and a third when that image was fitted anew (``refitted``); a
    view named in ``inverted`` a last line saying its picture was inverted first. A
    picture in the board folder of ``rewritten`` (the design folder this run replaces) is
    named where this run writes the view's board picture: the old one is gone then, and a
    view renamed in the file would name its old name's picture.
    """
    options = f"fit = {fit}, gamma = {gamma:g}, contrast = {contrast:g}"
    lines = [
        ORIGIN_HEADER,
        f"# the picture named below ({options}),",
        "# so a run from this file reproduces targets/*.npy; layout seed = "
        + str(seed)
        + "; "
        + _board_text(design.board)
        + ".",
    ]
    for view in design.views:
        path = design.target_path(view)
        assert path is not None
        shown = path
        if rewritten is not None and path.parent.resolve() == rewritten.boards_dir.resolve():
            shown = rewritten.board_png(view.name)
        lines.append(f"# {view.name}: {_comment_safe(str(shown))}")
        earlier = _earlier_origin(path)
        if earlier:
            lines.append(EARLIER + earlier)
            if path in refitted:
                lines.append(REFITTED)
        if view.name in inverted:
            lines.append(INVERTED)
    return "\n".join(lines) + "\n"


def _board_text(board: Board) -> str:
    """``board W x H mm``, as the heading comment records the board it was designed for."""
    return f"board {board.width_mm:g} x {board.height_mm:g} mm"


def _earlier_board(source: str) -> str | None:
    """The board (:func:`_board_text`) the heading comment of ``source`` was written for.

    None where ``source`` is no design.toml that ``design`` wrote, or one written before
    the comment recorded the board.
    """
    try:
        with open(source, encoding="utf-8") as file:
            head = [file.readline().rstrip("\n") for _ in range(3)]
    except (OSError, UnicodeDecodeError):
        return None
    found = re.search(r"; (board \S+ x \S+ mm)\.$", head[2])
    return found.group(1) if head[0] == ORIGIN_HEADER and found else None


def _cm(distances: list[float]) -> str:
    """Distances (mm) in whole centimetres: one figure, or the least to the most."""
    low, high = round(min(distances) / 10), round(max(distances) / 10)
    return f"{low} cm" if low == high else f"{low}-{high} cm"


def resized_board_note(
    design: Design,
    earlier: str | None,
    reshaped: bool,
    count: int | None = None,
    resolution: tuple[int, int] | None = None,
) -> str | None:
    """A note on the values a rerun on another board keeps that the quick form sets by board.

    A job's design.toml keeps its scratch count, its cameras' and light's distances and
    its views' resolutions when its board is edited; the quick form would choose them
    anew for this board (:func:`scratchfab.design.quick.quick_mapping`). Nothing is
    changed.

    Args:
        design: The design being run.
        earlier: The board its heading comment was written for (:func:`_earlier_board`).
        reshaped: A target picture was made for a board of another shape (known without
            ``earlier`` in a file written before the comment recorded the board).
        count: The count given on the command line (then not kept).
        resolution: The resolution given on the command line (then not kept).

    Returns:
        The note, or None where the board is the earlier one or every kept value is the
        quick form's.
    """
    board = design.board
    if earlier == _board_text(board) or (earlier is None and not reshaped):
        return None
    quick = quick_mapping(
        [Path(f"view{i}.png") for i in range(len(design.views))],
        (board.width_mm, board.height_mm),
    )
    kept = []
    if count is None and design.scratch.count != quick["scratch"]["count"]:
        kept.append(
            f"[scratch] count {design.scratch.count} (the quick form lays "
            f"{quick['scratch']['count']} here)"
        )
    far = float(quick["views"][0]["distance_mm"])
    cameras = [
        float(np.linalg.norm(v.camera_position - np.asarray(v.look_at_mm))) for v in design.views
    ]
    lights = [
        float(np.linalg.norm(v.light_position_mm or design.light.position_mm)) for v in design.views
    ]
    if _cm(cameras + lights) != _cm([far]):
        stand = (
            f"the cameras' and the light's {_cm(cameras)}"
            if _cm(cameras) == _cm(lights)
            else f"the cameras' {_cm(cameras)} and the light's {_cm(lights)}"
        )
        kept.append(f"{stand} (it stands them at {_cm([far])})")
    wanted = list(quick["views"][0]["resolution"])
    shown = sorted({str(list(v.resolution)) for v in design.views})
    if resolution is None and shown != [str(wanted)]:
        kept.append(f"resolution {', '.join(shown)} (it would use {wanted})")
    if not kept:
        return None
    what = f"the {earlier[len('board ') :]} one" if earlier else "the earlier board"
    return (
        f"note: the board is now {board.width_mm:g} x {board.height_mm:g} mm; kept from "
        f"{what}: {'; '.join(kept)}; change them in {design.source} if you want"
    )


def _earlier_origin(picture: Path) -> str | None:
    """What an earlier design made ``picture`` from, when it is that design's board picture.

    Read from the comment heading the design.toml beside ``board/`` (written by
    :func:`_origin_comment`): the image its line names with that design's options, or,
    when that was a rerun too, what its own second line names, followed by that design's
    options where they changed the picture (an inversion, gamma or contrast other than 1;
    the fit of a board picture changes nothing). None for any other picture, or a
    design.toml without the comment.
    """
    if picture.parent.name != DesignFolder(picture.parent.parent).boards_dir.name:
        return None
    try:
        text = DesignFolder(picture.parent.parent).design_toml.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    lines = text.splitlines()
    if len(lines) < 2 or lines[0] != ORIGIN_HEADER:
        return None
    found = re.search(r"\((fit = [^)]*)\)", lines[1])
    options = f"({found.group(1)})" if found else ""
    own = f"# {picture.stem}: "
    for i, line in enumerate(lines):
        if not line.startswith("#"):
            break
        if line.startswith(own):
            below = list(itertools.takewhile(lambda s: s.startswith("#   "), lines[i + 1 :]))
            if options and INVERTED in below:
                options = f"{options[:-1]}, inverted)"
            earlier = next((s[len(EARLIER) :] for s in below if s.startswith(EARLIER)), None)
            if earlier is None:
                return " ".join(filter(None, [line[len(own) :], options]))
            if not options or options.endswith("gamma = 1, contrast = 1)"):
                return earlier
            return f"{earlier}, then {options}"
    return None


def _steps(origin: str) -> tuple[Path, list[tuple[str, float, float, bool]]] | None:
    """The image and each design's (fit, gamma, contrast, inverted), from :func:`_earlier_origin`."""
    found = re.fullmatch(rf"(.*?) {_STEP}((?:, then {_STEP})*)", origin)
    if not found:
        return None
    try:
        steps = [
            (f, float(g), float(c), bool(i))
            for f, g, c, i in re.findall(_STEP, origin[found.end(1) :])
        ]
    except ValueError:
        return None
    return Path(found.group(1)), steps


def target_picture(
    path: Path, board: Board, fit: str, gamma: float, contrast: float, invert: bool = False
) -> tuple[np.ndarray, np.ndarray, Path | None]:
    """A view's target file as a linear board-space image (``targets.board_image``).

    An earlier design's board picture made for a board of another shape would be fitted
    again, its own bars or crop inside the new ones; it is made anew instead from the
    image that design started from, with each design's options in turn (as its heading
    comment names them), then this run's. A file is inverted (``invert``, or the first
    design's) as it is read, its colours alone: a transparent ground stays black
    (``load_image``). A picture an earlier design fitted is inverted on its own part
    alone: the black bars of a ``contain`` fit stay black, bare board.

    Returns:
        (image, the picture's own part of it: bool, False on the bars of a ``contain``
        fit, an earlier design's too; the image it was made anew from, or None).

    Raises:
        ConfigError: A file is unreadable; for a picture to make anew, naming it and the
            image it was made from.
    """
    origin = _earlier_origin(path)
    steps = _steps(origin) if origin is not None else None
    # an earlier design's board picture is opaque: inverted below, its bars left black
    picture = load_image(path, invert and steps is None)
    rows, cols = picture.shape
    aspect = board.width_mm / board.height_mm
    # one pixel of the short side: the rounding of a picture fitted to this shape
    if origin is not None and abs(math.log(cols / rows / aspect)) > 1.0 / min(rows, cols):
        where = (
            f"{path} is the board picture an earlier design made for a board of another shape "
            f"({cols} x {rows} pixels, this board is {board.width_mm:g} x {board.height_mm:g} mm)"
        )
        if steps is None:
            raise ConfigError(
                f"{where} and its design.toml names no image it was made from; set the "
                "target to the image itself to fit it to this board"
            )
        made_from, options = steps
        try:
            picture = load_image(made_from, options[0][3])
        except ConfigError as exc:
            raise ConfigError(
                f"{where}, and the image it was made from cannot be read ({exc}); set the "
                "target to that image, or another, to fit it to this board"
            ) from None
        fits = [step[0] for step in options]
        shape = picture.shape
        # later steps, and this run, invert the opaque picture the one before made, on
        # the picture's own part of it (the steps' fits of a picture of ones)
        for k, (step_fit, step_gamma, step_contrast, step_invert) in enumerate(options):
            if step_invert and k > 0:
                picture = _invert_within(picture, picture_area(shape, board, fits[:k]))
            step = fit_picture(picture, board, step_fit, step_gamma, step_contrast)
            picture = quantize_like_png(step)
        if invert:
            picture = _invert_within(picture, picture_area(shape, board, fits))
        area = picture_area(shape, board, [*fits, fit])
        return fit_picture(picture, board, fit, gamma, contrast), area, made_from
    earlier = None if steps is None else _earlier_area(steps, board)
    if invert and earlier is not None:
        picture = _invert_within(picture, _on_grid(earlier, picture.shape))
    image = fit_picture(picture, board, fit, gamma, contrast)
    area = picture_area(picture.shape, board, [fit])
    if earlier is not None:  # an earlier design's board picture: its bars are in it
        area &= _on_grid(earlier, image.shape)
    return image, area, None


def _invert_within(picture: np.ndarray, area: np.ndarray) -> np.ndarray:
    """``picture`` inverted (:func:`invert_picture`) on ``area`` alone, black elsewhere kept.

    ``area`` is on the picture's grid: where an earlier fit put the picture, so that the
    black bars it added stay black (bare board) when a rerun inverts its picture.
    """
    return np.where(area, invert_picture(picture), picture)


def _earlier_area(
    steps: tuple[Path, list[tuple[str, float, float, bool]]], board: Board
) -> np.ndarray:
    """The part of this board an earlier design's picture covers, from its image's fits.

    The whole board where the image it was made from cannot be read (as it need not be).
    """
    made_from, options = steps
    try:
        shape = load_image(made_from).shape
    except ConfigError:
        return np.ones((1, 1), dtype=bool)
    return picture_area(shape, board, [step[0] for step in options])


def _on_grid(mask: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """A board-space mask on another grid of the same board (nearest cell centre)."""
    rows = (np.arange(shape[0]) + 0.5) * mask.shape[0] // shape[0]
    cols = (np.arange(shape[1]) + 0.5) * mask.shape[1] // shape[1]
    return mask[np.ix_(rows.astype(np.intp), cols.astype(np.intp))]


def _comment_safe(text: str) -> str:
    """``text`` safe inside a TOML comment: control characters written as Python escapes.

    A newline would end the comment; lone surrogates (undecodable file-name bytes) are no UTF-8.
    """
    return "".join(repr(c)[1:-1] if unicodedata.category(c) in ("Cc", "Cs") else c for c in text)


def run_design(
    source: str | Path | Design,
    out_job: str | Path,
    force: bool | None = None,
    fit: str | None = None,
    gamma: float = 1.0,
    contrast: float = 1.0,
    count: int | None = None,
    resolution: tuple[int, int] | None = None,
    seed: int | None = None,
    progress: Say = lambda _: None,
    invert: bool = False,
    machine: str | MachineProfile | None = None,
    reach: bool = True,
) -> DesignResult:
    """Run the design stage.

    Args:
        source: A design or pipeline TOML file (stage tables are checked as ``run``
            checks them; a ``[pipeline]`` table supplies ``fit``, ``seed`` and ``force``
            defaults), or a resolved :class:`Design` (the quick form).
        out_job: The job folder; ``design/`` is (re)written inside it.
        force: Go on although the feasibility check found errors or a target is black.
        fit: ``"contain"`` or ``"cover"`` (default ``"contain"``).
        gamma: Exponent on the linear target values.
        contrast: Contrast about the picture's mean (1 = unchanged).
        count: Overrides ``[scratch] count``.
        resolution: Overrides every view's ``resolution`` (W, H); file sources only.
        seed: Seed of the initial layout, at least 0 (default 0).
        progress: Called with one line per step.
        invert: Invert every view's target first (``targets.invert_picture``), as a
            view's ``invert = true`` inverts its own.
        machine: The machine whose time to cut the layout is told (a bundled profile's
            name, a profile file, or the profile loaded); default: a file's ``[toolpath] machine``, else the
            bundled default.
        reach: Warn when ``machine`` cannot reach the whole layout (``run`` warns of
            the board once itself, before its first stage).

    Raises:
        ConfigError: One line naming the file and what is wrong; nothing is written.
    """
    start = time.perf_counter()
    design, tables = load_source(source, count, resolution)
    defaults = tables.pipeline
    _check_job_folder(Path(out_job))
    fit = fit if fit is not None else defaults.fit
    seed = seed if seed is not None else defaults.seed
    force = force if force is not None else defaults.force
    if fit not in FITS:
        raise ConfigError(f"{design.source}: fit must be one of {', '.join(FITS)}, got {fit!r}")
    if seed < 0:
        raise ConfigError(f"{design.source}: seed must be at least 0, got {seed}")
    for i, view in enumerate(design.views):
        if view.target is None:
            raise ConfigError(f"{design.source}: views[{i}] ('{view.name}'): missing target image")
        # No board pixel: nothing to optimize for, the run would end with loss 0 and rho 0.
        if not board_pixels(design.board, view).any():
            raise ConfigError(
                f"{design.source}: views[{i}] ('{view.name}'): no pixel of its "
                f"{view.width}x{view.height} image has its centre on the board, so it has "
                "nothing to show; raise resolution, narrow fov_deg, or aim the camera at the "
                "board from less grazing a direction"
            )

    views = len(design.views)
    progress(
        f"design: {views} view{'' if views == 1 else 's'}, {design.scratch.count} scratches on a "
        f"{design.board.width_mm:g} x {design.board.height_mm:g} mm board"
    )
    for i, view in enumerate(design.views):
        _check_frame(design.source, i, view, design.board, progress)
    boards: dict[str, np.ndarray] = {}
    cache: dict[tuple[Path, bool], tuple[np.ndarray, np.ndarray]] = {}
    refitted: set[Path] = set()
    inverted = frozenset(v.name for v in design.views if invert or v.invert)
    cli = design.source == QUICK_SOURCE or not isinstance(source, Design)  # takes --invert
    for i, view in enumerate(design.views):
        path = design.target_path(view)
        assert path is not None
        key = (path, view.name in inverted)
        if key not in cache:
            try:
                image, area, made_from = target_picture(
                    path, design.board, fit, gamma, contrast, key[1]
                )
            except ConfigError as exc:
                # The image's own message names the file; say which key pointed at it.
                raise ConfigError(
                    f"{design.source}: views[{i}].target ('{view.name}'): {exc}"
                ) from None
            cache[key] = quantize_like_png(image), area
            if made_from is not None:
                refitted.add(path)
                progress(
                    f"  target '{view.name}': {path} was made for a board of another shape; "
                    f"made anew from {made_from}, fitted to this "
                    f"{design.board.width_mm:g} x {design.board.height_mm:g} mm board"
                )
        boards[view.name], area = cache[key]
        flipped = key[1]
        option = _invert_option(design.source, i, len(design.views), cli, invert and flipped)
        _check_brightness(
            design.source,
            i,
            view.name,
            path,
            boards[view.name],
            area,
            force,
            progress,
            flipped,
            option,
        )
    progress(f"  loaded {len(cache)} target image(s)")
    note = resized_board_note(
        design, _earlier_board(design.source), bool(refitted), count, resolution
    )
    if note is not None:
        progress(f"  {note}")

    report = check_feasibility(design, boards=boards)
    # Without --force the errors end the stage in one message of their own.
    for line in report.summary_lines(errors=force):
        progress(f"  {line}")
    if not force:
        report.raise_if_errors(design.source)

    job = Path(out_job).resolve()
    files = JobLayout(job).design
    folder = files.path
    targets: dict[str, np.ndarray] = {}
    for view in design.views:
        t0 = time.perf_counter()
        targets[view.name] = warp_to_view(boards[view.name], design.board, view).astype(np.float32)
        progress(
            f"  target '{view.name}' {view.width}x{view.height} warped "
            f"({time.perf_counter() - t0:.1f} s)"
        )

    t0 = time.perf_counter()
    scratches = initial_layout(
        design, {k: v.astype(np.float64) for k, v in targets.items()}, seed, progress
    )
    progress(f"  initial layout: {len(scratches)} scratches ({time.perf_counter() - t0:.1f} s)")
    # a bundled pipeline lives in the installed package: its count is set in a copy
    copy = "a copy of " if bundled_name("pipelines", design.source) is not None else ""
    ways = [f"[scratch] count in {copy}{design.source}"]
    if design.source == QUICK_SOURCE:
        ways = ["--count"]
    elif not isinstance(source, Design):  # a pipeline's design: `run` takes no --count
        ways.insert(0, "--count")
    fewer = " or ".join(ways)
    machine = machine if machine is not None else tables.toolpath.machine
    for line in cut_lines(scratches, design.board, machine, fewer, reach):
        progress(f"  {line}")

    # the board pictures are inverted already: a rerun from the file keeps them as they are
    resolved = design.with_views(
        tuple(replace(v, target=str(files.board_png(v.name)), invert=False) for v in design.views)
    )
    resolved = replace(resolved, base_dir=folder, source=str(files.design_toml))

    # read before the new folder replaces the old one, whose design.toml they may read
    comment = _origin_comment(
        design, fit, gamma, contrast, seed, frozenset(refitted), inverted, files
    )
    earlier = earlier_design(job)
    with atomic_folder(folder) as tmp:
        staged = DesignFolder(tmp)
        write_text(staged.design_toml, comment + resolved.to_toml())
        for view in design.views:
            save_png(staged.board_png(view.name), board_image_png(boards[view.name]))
            save_npy(staged.target_npy(view.name), targets[view.name])
            save_png(staged.target_png(view.name), preview_png(targets[view.name]))
            save_png(staged.feasibility_png(view.name), report.map_image(view.name))
        scratches.save(staged.initial_scratches, design.scratch)
        write_json(staged.feasibility_json, report.to_json())
    carry_optimize_record(job, earlier)
    progress(f"design: wrote {folder} ({time.perf_counter() - start:.1f} s)")
    return DesignResult(folder, resolved, targets, scratches, report)


#: A view whose frame sees less of the board than this share gets a warning.
FRAME_SHARE = 0.99
#: Board points per side on which :func:`share_seen` counts (the share to 4 / this).
_SHARE_GRID = 512


def share_seen(board: Board, view: View) -> float:
    """The share of the board's area that ``view``'s frame sees.

    Counted on a grid of the board's points (cell centres), each projected through the camera.
    """
    n = _SHARE_GRID
    hw, hh = board.half_extent
    xs = (np.arange(n) + 0.5) / n * 2 * hw - hw
    ys = (np.arange(n) + 0.5) / n * 2 * hh - hh
    gx, gy = np.meshgrid(xs, ys)
    points = np.stack([gx, gy, np.zeros_like(gx)], axis=-1)
    st, in_front = Camera.from_view(view).project(points)
    inside = (
        in_front
        & (st[..., 0] >= 0)
        & (st[..., 0] <= view.width)
        & (st[..., 1] >= 0)
        & (st[..., 1] <= view.height)
    )
    return float(inside.mean())


def _check_frame(source: str, index: int, view: View, board: Board, say: Say) -> None:
    """Warn of a view whose frame misses part of the board, naming the fov that frames it.

    A numeric ``fov_deg`` frames the board it was chosen for: a design.toml edited to a
    larger board, or a camera moved nearer, keeps it and would show a crop of the picture.
    """
    share = share_seen(board, view)
    if share >= FRAME_SHARE:
        return
    try:
        auto: float | None = auto_fov(view, board)
        why = f"it would need {MAX_FOV_DEG:g} degrees or more"
    except ValueError:
        auto, why = None, "part of the board lies behind the camera"
    if auto is not None and auto < MAX_FOV_DEG:
        fix = (
            f'to frame the whole board, set views[{index}] fov_deg = "auto" in {source} '
            f"({auto:.6g} degrees here)"
        )
    else:  # "auto" is refused from there too (resolve_view)
        fix = (
            f"no fov frames the whole board from where it stands ({why}): move "
            f"views[{index}]'s camera farther from the board (its position_mm or "
            f"distance_mm in {source})"
        )
    say(
        f"  warning: view '{view.name}' sees {math.floor(share * 100)} % of the "
        f"{board.width_mm:g} x {board.height_mm:g} mm board (fov_deg = {view.fov:.6g}), so it "
        f"shows only that part of its picture; {fix}"
    )


def _invert_option(source: str, index: int, views: int, cli: bool, flag: bool) -> str:
    """What inverts view ``index``'s picture alone, as the brightness messages name it.

    Args:
        source: The design's source (the quick form, a design file or a pipeline's).
        index: The view's index.
        views: How many views the design has: with more than one, ``--invert`` turns
            every view's picture negative, a light one too.
        cli: The command takes ``--invert`` (``design``; ``run`` does not).
        flag: ``--invert`` inverted it (the option to leave off).
    """
    key = f"views[{index}] invert = true"
    if flag or (source == QUICK_SOURCE and views == 1):
        return "--invert"
    if cli and views == 1:
        return f"--invert or {key} in {source}"
    if source == QUICK_SOURCE:
        return (
            f"{key} in the job's design/design.toml, as the file to design from "
            f"(--invert would turn all {views} views negative)"
        )
    return f"{key} in {source}" + (
        f" (--invert would turn all {views} views negative)" if cli else ""
    )


def _check_brightness(
    source: str,
    index: int,
    name: str,
    path: Path,
    board: np.ndarray,
    area: np.ndarray,
    force: bool,
    say: Say,
    inverted: bool = False,
    option: str = "--invert",
) -> None:
    """Refuse a black target unless forced; warn of a uniform or a mostly bright one.

    Bright parts of a target are cut and dark parts stay bare board. A black target
    shows nothing and asks nothing of the layout (its best exposure is 0, so its error
    is 0 whatever the render); a uniform one asks for an even glow; a mostly bright
    one (text dark on white) shows poorly: the warning names the option that inverts
    it, or, where the picture was ``inverted``, says to leave that off. Brightness is
    measured over the picture's own ``area`` of the board: the bars of a ``contain``
    fit would dilute a letterboxed photo's (:data:`BRIGHT_TARGET_MEAN` was measured on
    pictures filling their board). ``option``: what inverts this view's picture, or
    what did (:func:`_invert_option`).

    Raises:
        ConfigError: A black target without ``force``, naming the view's key and file.
    """
    spread = float(np.ptp(board))
    mean = float(board.mean())
    own = float(board[area].mean()) if area.any() else mean
    if float(board.max()) < UNIFORM_TARGET_SPREAD and not force:
        raise ConfigError(
            f"{source}: views[{index}].target ('{name}'): {path}: the picture is black on "
            f"the board (brightest {float(board.max()):.3f}"
            + (f", inverted by {option}" if inverted else "")
            + "), so the view would show nothing: bright parts are cut, dark ones stay bare "
            "board, and transparent pixels read as black (inverted or not); give a picture "
            "with light shapes on a dark ground ("
            + (
                f"leave {option} off for one that is light on dark already"
                if inverted
                # a refused quick form wrote no design.toml to set a view's invert in
                else "a dark logo on a transparent ground: make the logo white, or design "
                f"again with {'--invert' if source == QUICK_SOURCE else option}"
            )
            + ") "
            + DESIGN_ANYWAY
        )
    transparent = "transparent pixels read as black (bare board), inverted or not"
    if spread < UNIFORM_TARGET_SPREAD:
        say(
            f"  warning: target '{name}' is uniform (brightness {mean:.3f} everywhere, spread "
            f"{spread:.4f}): the view will show an even board; {transparent}"
        )
    elif own > BRIGHT_TARGET_MEAN:
        fix = (
            f"it was inverted ({option}): leave that off for an image that is light on dark "
            f"already; {transparent}"
            if inverted
            else f"to invert a dark-on-white image, design again with {option}"
        )
        where = (
            "on the board"
            if area.all()
            else f"on its part of the board, the fit's black bars left out ({mean:.2f} with them)"
        )
        say(
            f"  warning: target '{name}' is mostly bright (mean linear brightness {own:.2f} "
            f"{where}, above {BRIGHT_TARGET_MEAN:g}) and will show poorly: bright = cut, "
            f"dark = bare board, so light shapes on a dark ground show best; {fix}"
        )


def _check_job_folder(job: Path) -> None:
    """Fail before any work when the job folder cannot be created or written."""
    parent = next((p for p in (job, *job.parents) if p.exists()), Path("."))
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise ConfigError(
            f"{job}: cannot create the job folder ({parent} is not a writable folder)"
        )
