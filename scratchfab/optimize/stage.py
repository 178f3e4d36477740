"""The ``optimize`` stage: ``JOB/design/`` in, ``JOB/optimize/`` out (SPEC section 6).

:func:`run_optimize` is what the CLI and the pipeline runner call. It reports progress
through a callback (the CLI draws the bar), stops cleanly after the current step on
Ctrl-C or when ``should_stop`` says so, and checkpoints atomically every
``checkpoint_every`` steps, so ``resume`` continues after Ctrl-C or ``kill -9`` on the
same trajectory.

Reproducibility: Dr.Jit's multithreaded CPU kernels add floats with atomics in an order
that varies between runs, so bit-identical trajectories (and resumes) need one thread
(``threads = 1``, the default). ``threads = 0`` uses every core and is faster, but two
runs then agree only to rounding.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import hashlib
import io
import json
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import drjit as dr
import numpy as np

from scratchfab.backend import array_module
from scratchfab.design.feasibility import design_glint_deg, outshine_limit_deg
from scratchfab.design.targets import job_cross_targets
from scratchfab.errors import ConfigError
from scratchfab.fileio import decode_json, load_numpy, write_json, write_text
from scratchfab.metrics import quality_report
from scratchfab.model.design import Design, design_fields
from scratchfab.model.job import JobLayout, design_digest, load_job_design
from scratchfab.model.schema import parse_table
from scratchfab.model.scratches import ScratchSet, load_scratches
from scratchfab.optimize.checkpoint import Checkpoint, read_checkpoint, save_checkpoint
from scratchfab.optimize.glint import view_glint
from scratchfab.optimize.loss import MERGE_PENALTY
from scratchfab.optimize.optimizer import LayoutOptimizer, NonFiniteError, Settings
from scratchfab.optimize.options import OptimizeOptions, StepSchedule
from scratchfab.optimize.plots import save_loss_plot, save_side_by_side
from scratchfab.optimize.prune import PruneReport, prune
from scratchfab.render.layout import write_render_layout
from scratchfab.render.renderer import ViewRenderer

#: Options that shape the trajectory; a resume must match them, but for :data:`ROUNDING_KEYS`.
TRAJECTORY_KEYS = (
    "seed",
    "backend",
    "space",
    "lr_position_mm",
    "lr_angle_deg",
    "lr_length_mm",
    "refresh_every",
    "merge_weight",
    "jitter_deg",
    "threads",
)
#: Trajectory keys a resume may change, with a note: the steps' arithmetic is the same, only
#: its rounding differs (a run made on CUDA goes on where no GPU is, or on the CPU as asked;
#: one thread's run goes on on every core, or the other way).
ROUNDING_KEYS = ("backend", "threads")


@dataclass(frozen=True)
class Progress:
    """One progress report.

    Attributes:
        iteration: Steps done.
        total: Steps asked for.
        loss: Loss of the layout the last step started from.
        elapsed_s: Optimizing time so far (including resumed sessions).
        eta_s: Estimated time to finish (NaN before the first step).
        message: A status line instead of a step ("" for steps).
    """

    iteration: int
    total: int
    loss: float
    elapsed_s: float
    eta_s: float
    message: str = ""


@dataclass(frozen=True)
class OptimizeResult:
    """What the stage produced.

    Attributes:
        out_dir: ``JOB/optimize``.
        scratches: The final (pruned, if asked) layout.
        iterations: Steps done in total.
        stopped: Why the loop ended: ``"done"``, ``"interrupted"`` or ``"time budget"``;
            :data:`NOTHING_TO_DO` for a resume of a run that had finished (outputs kept).
        loss: Final loss (fresh pairs).
        quality: :func:`scratchfab.metrics.quality_report` of the final renders.
        seconds_per_iteration: Mean over this session's steps (NaN without steps).
        prune: The pruning report, if pruning ran.
        glint: Per view whose image error left the bare board's glint out, its share of the
            board (``quality`` counts those pixels).
    """

    out_dir: Path
    scratches: ScratchSet
    iterations: int
    stopped: str
    loss: float
    quality: dict[str, Any]
    seconds_per_iteration: float
    prune: PruneReport | None = None
    glint: dict[str, float] = dataclasses.field(default_factory=dict)


#: ``OptimizeResult.stopped`` of a resume whose checkpoint had done every step asked
#: for, its outputs written: nothing compiled, nothing rewritten.
NOTHING_TO_DO = "nothing to do"


def checkpoint_request(job: str | Path, checkpoint: Checkpoint | None = None) -> dict[str, Any]:
    """What the run in ``JOB/optimize/checkpoint.npz`` was asked for, that a resume keeps.

    A resume that does not give them goes on with the run's own ``iterations`` (its total,
    as it was started or extended) and ``prune_tolerance``. A checkpoint made before it
    kept them takes them from the summary written from it (a run stopped by Ctrl-C or its
    time budget), else its total from a scheduled run's fingerprint while it has not done
    more steps (a run extended past that total went on to a total it did not keep). Each
    is left out where none of these tells a valid value, and all without a readable
    checkpoint (the resume then says what is wrong).

    Args:
        job: The job folder.
        checkpoint: Its checkpoint, already read (None: read here).
    """
    paths = JobLayout(Path(job))
    if checkpoint is None:
        try:
            checkpoint = read_checkpoint(paths.optimize_checkpoint)
        except ConfigError:
            return {}
    meta, done = checkpoint.meta, checkpoint.done
    keys = ("iterations", "prune_tolerance")
    own = {k: meta[k] for k in keys if k in meta}
    if len(own) < len(keys) and done is not None:
        summary = _summary_of(paths, done, meta.get("elapsed_s"))
        made = summary.get("options") if summary is not None else None
        for k in keys:
            if isinstance(made, dict) and k in made:
                own.setdefault(k, made[k])
    schedule = meta.get("fingerprint", {}).get("lr_schedule")
    total = schedule.get("iterations") if isinstance(schedule, dict) else None
    if "iterations" not in own and type(total) is int and done is not None and done <= total:
        own["iterations"] = total
    return {k: v for k, v in own.items() if _valid_option(k, v)}


#: Options a checkpoint's meta keeps that no step depends on: how the run checkpoints and
#: what its pruning's estimate of the machining time saved assumes.
KEPT_IN_META = ("checkpoint_every", "feed_mm_min", "stroke_overhead_s")


def checkpoint_settings(checkpoint: Checkpoint) -> dict[str, Any]:
    """The options of a checkpoint's run besides its total and prune (:func:`checkpoint_request`).

    Those that shaped its steps, as its fingerprint keeps them (:data:`TRAJECTORY_KEYS`
    and the schedule's shape and scales; scales 1 where it keeps none: constant steps),
    and those of :data:`KEPT_IN_META`, so that a resume that does not give them goes on
    as the run did, whatever started it (``scratchfab run`` takes the ``lr_*`` and
    ``refresh_every`` of its ``[optimize]`` table, which the command has no flags for).
    Each is left out where the checkpoint holds no valid value (a step's: the resume then
    says what differs; the others', as a checkpoint of an earlier scratchfab: the caller's).
    """
    meta = checkpoint.meta
    made = meta.get("fingerprint", {})
    own = {k: made[k] for k in TRAJECTORY_KEYS if k in made}
    own.update((k, meta[k]) for k in KEPT_IN_META if k in meta)
    schedule = made.get("lr_schedule", {"start": 1.0, "end": 1.0})
    if isinstance(schedule, dict):
        own.update(
            (SCHEDULE_OPTIONS[k], v)
            for k, v in schedule.items()
            if k in SCHEDULE_OPTIONS and k != "iterations"  # the total: checkpoint_request
        )
    return {k: v for k, v in own.items() if _valid_option(k, v)}


def _valid_option(name: str, value: Any) -> bool:
    """Whether ``value`` is one :class:`OptimizeOptions` takes for ``name`` (type and bounds)."""
    try:
        parse_table(OptimizeOptions, {name: value}, "checkpoint")
    except ConfigError:
        return False
    return True


def _summary_of(paths: JobLayout, done: int, elapsed_s: Any) -> dict[str, Any] | None:
    """``JOB/optimize/summary.json`` when it was written from the checkpoint at ``done`` steps.

    It was when it counts ``done`` steps and ``elapsed_s``, the time saved with the last
    checkpoint, which another run of as many steps killed before its summary does not
    share; else (or unreadable) None.
    """
    try:
        summary = decode_json(paths.optimize_summary.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if (
        not isinstance(summary, dict)
        or summary.get("iterations") != done
        or summary.get("elapsed_s") != elapsed_s
    ):
        return None
    return summary


def _finished(
    paths: JobLayout,
    design: Design,
    design_files: dict[str, str],
    done: int,
    elapsed_s: Any,
    options: OptimizeOptions,
) -> OptimizeResult | None:
    """The outputs of a run that did ``done`` steps, when they are this resume's result.

    They are when the summary written with them was written from this checkpoint
    (:func:`_summary_of`), was made from this design, and pruned as ``options`` ask; else
    None (the resume writes them again).
    """
    summary = _summary_of(paths, done, elapsed_s)
    if summary is None:
        return None
    try:
        pruned = summary["options"]["prune_tolerance"]
        if (
            summary["design_sha256"] != design_files
            or pruned != options.prune_tolerance
            or (pruned is not None and "prune" not in summary)
        ):
            return None
        scratches = load_scratches(paths.optimized_scratches, design.scratch, design.board)
        return OptimizeResult(
            out_dir=paths.optimize_dir,
            scratches=scratches,
            iterations=done,
            stopped=NOTHING_TO_DO,
            loss=float(summary["loss"]),
            quality=summary["quality"],
            seconds_per_iteration=math.nan,
            glint=g if isinstance(g := summary.get("glint_left_out"), dict) else {},
        )
    except (OSError, ValueError, KeyError, TypeError, ConfigError):
        return None


@contextlib.contextmanager
def interrupt_flag() -> Iterator[Callable[[], bool]]:
    """Turn the first Ctrl-C into a flag that the loop polls (a second one aborts)."""
    hit = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield hit.is_set
        return
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum: int, frame: Any) -> None:
        if hit.is_set():
            signal.signal(signal.SIGINT, previous)
            raise KeyboardInterrupt
        hit.set()

    signal.signal(signal.SIGINT, handler)
    try:
        yield hit.is_set
    finally:
        signal.signal(signal.SIGINT, previous)


def load_job_inputs(job: Path) -> tuple[Design, dict[str, np.ndarray], ScratchSet]:
    """The resolved design, the per-view linear targets and the initial layout of a job.

    Raises:
        ConfigError: Naming the missing or malformed file.
    """
    folder = JobLayout(job).design
    design_file = folder.design_toml
    if not design_file.exists():
        raise ConfigError(f"{design_file}: file not found (run `scratchfab design` first)")
    design = load_job_design(design_file)
    targets: dict[str, np.ndarray] = {}
    for view in design.views:
        path = folder.target_npy(view.name)
        if not path.exists():
            if view.target is not None:
                raise ConfigError(
                    f"{path}: file not found (view '{view.name}' has a target picture; "
                    "rerun `scratchfab design`)"
                )
            continue
        arr = load_numpy(path)
        if arr.shape != (view.height, view.width) or not np.issubdtype(arr.dtype, np.floating):
            raise ConfigError(
                f"{path}: expected float (H, W) = ({view.height}, {view.width}), "
                f"got {arr.dtype} {arr.shape}"
            )
        targets[view.name] = arr.astype(np.float64)
    if not targets:
        raise ConfigError(f"{folder.targets_dir}: no <view>.npy target for any view")
    scratches = load_scratches(folder.initial_scratches, design.scratch, design.board)
    if len(scratches) == 0:
        raise ConfigError(f"{folder.initial_scratches}: no scratches to optimize (header only)")
    return design, targets, scratches


def _sha256(whole: Any, name: bytes, *arrays: np.ndarray) -> str:
    """The SHA-256 of ``name`` and ``arrays`` as float64 bytes, also fed to ``whole``."""
    part = hashlib.sha256(name)
    whole.update(name)
    for arr in arrays:
        data = np.ascontiguousarray(arr, dtype=np.float64).tobytes()
        part.update(data)
        whole.update(data)
    return part.hexdigest()


def _fingerprint(
    options: OptimizeOptions, scratches: ScratchSet, targets: dict[str, Any], design: Design
) -> dict[str, Any]:
    digest = hashlib.sha256()
    layout = (scratches.p0, scratches.p1, scratches.width, scratches.depth)
    parts: dict[str, Any] = {"scratches": _sha256(digest, b"", *layout), "targets": {}}
    for name in sorted(targets):
        parts["targets"][name] = _sha256(digest, name.encode(), targets[name])
    out: dict[str, Any] = {k: getattr(options, k) for k in TRAJECTORY_KEYS}
    out["inputs_sha256"] = digest.hexdigest()
    # by part, to name what changed (inputs_sha256, which checkpoints of an earlier
    # scratchfab have too, decides)
    out["inputs"] = parts
    out["merge_penalty"] = MERGE_PENALTY  # a checkpoint of another penalty (or none) differs
    # a checkpoint without it (an earlier scratchfab's) tells the views' order alone:
    # _made_fingerprint
    out["design"] = design_fields(design)
    schedule = options.schedule()
    if schedule is not None:
        # its scales depend on the run's total, so a resume needs the same iterations;
        # only present with a schedule, so a constant run may still be extended
        out["lr_schedule"] = _schedule_fields(asdict(schedule))
    return out


def _differences(made: Any, now: Any) -> Iterator[tuple[tuple[str, ...], Any, Any]]:
    """(path, made's value, now's value) of each value where two JSON trees differ.

    A key that one tree lacks differs as a whole, its value None in that tree.
    """
    if isinstance(made, dict) and isinstance(now, dict):
        for key in dict.fromkeys([*now, *made]):
            if key in made and key in now:
                for path, a, b in _differences(made[key], now[key]):
                    yield (key, *path), a, b
            else:
                yield (key,), made.get(key), now.get(key)
    elif json.dumps(made, sort_keys=True) != json.dumps(now, sort_keys=True):
        yield (), made, now


def _shown(value: Any) -> str:
    """A design value as a person reads it: floats to 6 digits, lists in brackets."""
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(map(_shown, value)) + "]"
    return "not set" if value is None else str(value)


def _design_key(path: tuple[str, ...]) -> str:
    """A path in the design fingerprint as ``design.toml`` names it.

    ``("board", "roughness")``: ``[board] roughness``; ``("views", "left", "up")``:
    ``[[views]] 'left' up``; the empty path (a fingerprint that is no table): ``design``.
    """
    if not path:
        return "design"
    table, *rest = path
    if table != "views":
        return " ".join([f"[{table}]", *rest])
    return " ".join(["[[views]]", *(f"'{name}'" for name in rest[:1]), *rest[1:]])


def _design_changes(made: Any, now: Any) -> dict[str, str]:
    """How the design changed since a checkpoint, by key in ``design.toml``'s terms.

    ``{"[board] roughness": "0.05 -> 0.08", "[[views]] 'top'": "added"}``: from the
    checkpoint's ``design`` fingerprint (:func:`~scratchfab.model.design.design_fields`, as JSON) to ``now``.
    """
    out: dict[str, str] = {}
    for path, a, b in _differences(made, now):
        if not path:
            out[_design_key(path)] = "not readable in the checkpoint"
        elif path[0] == "views" and len(path) == 2:
            out[_design_key(path)] = "added" if a is None else "removed"
        elif path == ("view_order",):
            # A checkpoint made before the order was kept has none; views added or removed
            # are named as such.
            if a is not None and (not isinstance(a, list) or sorted(map(str, a)) == sorted(b)):
                out["[[views]] order"] = f"{_shown(a)} -> {_shown(b)}"
        else:
            was, is_ = _shown(a), _shown(b)
            if was == is_:  # they differ past the digits shown
                was, is_ = json.dumps(a), json.dumps(b)
            out[_design_key(path)] = f"{was} -> {is_}"
    return out


def _made_fingerprint(meta: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint's fingerprint, its design record given the views' order where it lacks one.

    A checkpoint of an earlier scratchfab records no design, or no order of the views; its
    log's columns (``psnr_<view>`` in the views' order: :func:`log_columns`) tell the order,
    which its digest of the targets (by name, sorted) does not cover: views swapped since
    would resume on other steps, their log rows under swapped columns.
    """
    made: dict[str, Any] = meta.get("fingerprint", {})
    design, columns = made.get("design", {}), meta.get("columns")
    if isinstance(design, dict) and "view_order" not in design and isinstance(columns, list):
        order = [c[5:] for c in columns if isinstance(c, str) and c.startswith("psnr_")]
        made = {**made, "design": {**design, "view_order": order}}
    return made


def _design_diff(made: dict[str, Any], now: dict[str, Any]) -> dict[str, str]:
    """How the design changed since a checkpoint (:func:`_design_changes`), where it tells.

    A checkpoint of an earlier scratchfab records fewer tables (only the views' order:
    :func:`_made_fingerprint`); those it holds are compared.
    """
    if "design" not in made:
        return {}
    was, is_ = made["design"], now["design"]
    if isinstance(was, dict):
        is_ = {k: v for k, v in is_.items() if k in was}
    return _design_changes(was, is_)


def _glint_limit(design: Design) -> float:
    """The glint rule's limit for ``design`` (:func:`design_glint_deg`) as checkpoints keep it."""
    return round(design_glint_deg(design), 6)


def _image_error(design: Design, glinting: bool) -> dict[str, Any]:
    """The image error's form, as a checkpoint keeps it.

    The glint rule's limit for this design (:func:`_glint_limit`) and whether a view glints
    (its pixels left out): with the design, which the checkpoint records besides, they
    tell which pixels the image error leaves out.
    """
    return {"glint_limit_deg": _glint_limit(design), "glint_left_out": glinting}


#: The ``image_error`` of the first glint rule's checkpoints, which kept no limit: they left
#: out the glint below :func:`outshine_limit_deg` at full coverage.
FIRST_GLINT_RULE = "glint left out"


def _image_error_change(made: Any, design: Design, glinting: Callable[[], bool]) -> str | None:
    """Why the image error a checkpoint's steps followed is not this run's; None when it is.

    One of this design (its design record is compared apart) and the same limit
    (:func:`_image_error`) left out the same pixels. One of another limit (another glint
    rule's) that left pixels out is refused; one that left none out, like one of an
    earlier scratchfab that keeps no form, counted every pixel, as this run does where no
    view glints. The first rule's checkpoints say :data:`FIRST_GLINT_RULE`.

    Args:
        made: The checkpoint's ``image_error`` (None where it keeps none).
        design: This run's design.
        glinting: Whether a view of this run glints; called only where the limits do not tell.
    """
    if made == FIRST_GLINT_RULE:
        tool = design.scratch
        first = outshine_limit_deg(tool.width_mm, tool.depth_mm, design.board.roughness, 1.0)
        made = {"glint_limit_deg": round(first, 6), "glint_left_out": True}
    now = _glint_limit(design)
    if isinstance(made, dict) and made.get("glint_limit_deg") == now:
        return None
    if not (isinstance(made, dict) and made.get("glint_left_out") is True):
        return None if not glinting() else FORM_SAID["image_error"]
    return (
        f"image error left out the bare board's glint below {_shown(made['glint_limit_deg'])} "
        f"degrees of half-vector tilt (this one below {_shown(now)} degrees)"
    )


def _glinting(design: Design, targets: dict[str, np.ndarray], m: Any) -> bool:
    """Whether a view of the run glints (:func:`view_glint`), without setting up the optimizer."""
    limit = design_glint_deg(design)
    return any(
        view_glint(ViewRenderer(design, v, m), limit).mask.any()
        for v in design.views
        if v.name in targets
    )


def _schedule_fields(fields: dict[str, Any]) -> dict[str, Any]:
    """The fields of a fingerprint's schedule (a StepSchedule's) that its steps depend on.

    Equal start and end scales make every step take that scale, whatever the shape and
    the total: such a run may be extended as a constant one can.
    """
    if fields.get("start") == fields.get("end"):
        return {k: v for k, v in fields.items() if k not in ("shape", "iterations")}
    return fields


def _extended_schedule(
    made: dict[str, Any], now: dict[str, Any], options: OptimizeOptions
) -> StepSchedule | None:
    """The schedule a checkpoint ran, when ``options`` extend that run to more iterations.

    Its steps follow the total it started with, and the steps past that total take its end
    scale (:meth:`StepSchedule.scale`), so a finished run can go on as a constant run can.
    None when the schedule differs otherwise, or the total is not larger.
    """
    was, wants = made.get("lr_schedule"), now.get("lr_schedule")
    if not (isinstance(was, dict) and isinstance(wants, dict)):
        return None
    if {k: v for k, v in was.items() if k != "iterations"} != {
        k: v for k, v in wants.items() if k != "iterations"
    }:
        return None
    total = was.get("iterations")
    if not isinstance(total, int) or isinstance(total, bool) or total >= options.iterations:
        return None
    return StepSchedule(**was)


# The fields of a fingerprint's "lr_schedule" (a StepSchedule) by option name.
SCHEDULE_OPTIONS = {
    "shape": "lr_schedule",
    "start": "lr_start_scale",
    "end": "lr_end_scale",
    "iterations": "iterations",
}


def _rounding_notes(made: dict[str, Any], options: OptimizeOptions, ckpt: Path) -> list[str]:
    """A note per :data:`ROUNDING_KEYS` option a resume changes from its checkpoint's value."""
    said = {
        "backend": lambda was, now: f"on the {was} backend; its steps go on on {now}",
        "threads": lambda was, now: f"with threads = {was}; its steps go on with threads = {now}",
    }
    return [
        f"note: {ckpt} was made {said[k](made[k], getattr(options, k))}, which rounds "
        "differently: the layout is not bit-identical to one run with either alone."
        for k in ROUNDING_KEYS
        if k in made and made[k] != getattr(options, k)
    ]


def _changed_keys(made: dict[str, Any], now: dict[str, Any]) -> list[str]:
    """Option names (or "inputs_sha256", or design keys) whose fingerprint values differ.

    A schedule's change is named by the options that changed (its total, ``iterations``,
    rather than ``lr_schedule``); a constant run has no schedule: scales 1, no total. A
    schedule of equal scales depends on neither its shape nor its total. A design change
    is named by its keys (:func:`_design_diff`). The image error's form is left to
    :func:`_image_error_change`, the digests of the inputs by part to :func:`_inputs_change`.
    """
    out: list[str] = []
    for k in dict.fromkeys([*now, *made]):
        a, b = made.get(k), now.get(k)
        if k == "design":
            out.extend(_design_diff(made, now))
            continue
        if k in ("inputs", "image_error", *ROUNDING_KEYS):  # inputs_sha256 decides; ...
            continue
        if k == "lr_schedule":  # a checkpoint may keep a constant scale's shape and total
            a, b = (_schedule_fields(v) if isinstance(v, dict) else v for v in (a, b))
        if json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True):
            continue
        if k != "lr_schedule" or not isinstance(a or b, dict):
            out.append(k)
            continue
        constant = {"start": 1.0, "end": 1.0}
        a, b = a or constant, b or constant
        named = [
            option
            for field, option in SCHEDULE_OPTIONS.items()
            if field in a and field in b and json.dumps(a[field]) != json.dumps(b[field])
        ]
        out.extend(named or [k])
    return out


def _made_with(
    made: dict[str, Any], changed: list[str], options: OptimizeOptions
) -> dict[str, Any] | None:
    """The checkpoint's values of the options that ``options`` must take to resume it.

    A changed schedule gives every field of the checkpoint's schedule that ``options``
    differ in (a constant run's: scales 1), so that giving them resumes it at once; its
    total only when ``options`` ask for fewer steps (more extend it). None when no options
    can resume it: the inputs changed, or the checkpoint lacks a changed key.
    """
    out: dict[str, Any] = {}
    for key in changed:
        if key in SCHEDULE_OPTIONS.values():
            continue
        if key not in TRAJECTORY_KEYS or key not in made:
            return None
        out[key] = made[key]
    if not set(changed) & set(SCHEDULE_OPTIONS.values()):
        return out
    was = made.get("lr_schedule", {"start": 1.0, "end": 1.0})
    if not isinstance(was, dict):
        return None
    fields = _schedule_fields(was)
    if not set(fields) <= set(SCHEDULE_OPTIONS) or type(fields.get("iterations", 0)) is not int:
        return None
    for field, option in SCHEDULE_OPTIONS.items():
        if field not in fields:
            continue
        value, now = fields[field], getattr(options, option)
        if value > now if option == "iterations" else value != now:
            out[option] = value
    if options.lr_schedule == "constant" and "lr_schedule" in made:  # it overrides the scales
        out.setdefault("lr_schedule", fields.get("shape", OptimizeOptions().lr_schedule))
    return out


#: The fingerprint's keys of the objective's form, as a refusal names a checkpoint of
#: another (an earlier scratchfab's): no option resumes it. The stage words the image
#: error's change (:func:`_image_error_change`).
FORM_SAID = {
    "merge_penalty": "merge penalty had another form",
    "image_error": "image error counted the bare board's glint (this one leaves it out)",
}
#: A changed ``inputs_sha256`` where the checkpoint does not tell which outputs changed.
INPUTS_CHANGED = (
    "the design's initial scratches or targets changed since it was made: design was rerun"
)


def _inputs_change(made: Any, now: dict[str, Any], paths: JobLayout) -> str:
    """Which of the design stage's outputs changed since a checkpoint, in a refusal's words.

    Args:
        made: The checkpoint's fingerprint's ``inputs`` (None in an earlier scratchfab's,
            which kept their digest only: then the words name both kinds).
        now: This run's.
        paths: The job, whose files are named.
    """
    folder = paths.design
    if isinstance(made, dict) and isinstance(targets := made.get("targets"), dict):
        files = [folder.initial_scratches] * (made.get("scratches") != now["scratches"])
        files += [
            folder.target_npy(name)
            for name in dict.fromkeys([*now["targets"], *targets])
            if targets.get(name) != now["targets"].get(name)
        ]
        if files:
            named = ", ".join(paths.relative(f) for f in files)
            return f"{named} changed since it was made: design was rerun"
    return INPUTS_CHANGED


class ResumeRefused(ConfigError):
    """A checkpoint made with other settings, inputs or design than the resume has.

    Its message names the options that differ and the values to give to resume it
    (``lr_start_scale = 1.0``: a pipeline's ``[optimize]`` key and an
    :class:`OptimizeOptions` field), the design stage's outputs that changed, the forms
    of the objective an earlier scratchfab had, and the design keys that changed since,
    with their values then and now; :meth:`message` spells the options' values another way.

    Attributes:
        path: The checkpoint.
        changed: The options (or ``"inputs_sha256"``, a key of :data:`FORM_SAID`, or design
            keys) whose values differ.
        made_with: The checkpoint's values of the options to give to resume it; None when
            none can (its inputs, objective or design differ).
        design: How each changed design key changed (``{"[board] roughness": "0.05 ->
            0.08"}``: :func:`_design_changes`).
        design_file: The design file those keys are in.
        said: The words of each changed key that is no option nor design key
            (``inputs_sha256``'s: :func:`_inputs_change`), where not :data:`FORM_SAID`'s.
    """

    def __init__(
        self,
        path: Path,
        changed: list[str],
        made_with: dict[str, Any] | None,
        design: dict[str, str] | None = None,
        design_file: Path | None = None,
        said: dict[str, str] | None = None,
    ) -> None:
        self.path, self.changed, self.made_with = path, changed, made_with
        self.design, self.design_file = design or {}, design_file
        self.said = {**FORM_SAID, "inputs_sha256": INPUTS_CHANGED, **(said or {})}
        super().__init__(self.message(self.as_keys))

    @staticmethod
    def as_keys(made_with: dict[str, Any]) -> str:
        """``key = value`` pairs, values in TOML (and JSON) form."""
        return ", ".join(f"{k} = {json.dumps(v)}" for k, v in made_with.items())

    def message(self, spell: Callable[[dict[str, Any]], str | None]) -> str:
        """The one-line refusal, the values to resume with written by ``spell``.

        Args:
            spell: Writes :attr:`made_with` as its caller's user gives them; None when
                that user cannot give them all.
        """
        given = spell(self.made_with) if self.made_with else None
        fix = f"it was made with {given}: give that to resume it, or " if given else ""
        return f"{self.path}: {self.reasons()}; {fix}run without --resume to start over"

    def reasons(self) -> str:
        """What changed since the checkpoint was made, in the user's terms, without advice."""
        options = [k for k in self.changed if k not in self.design and k not in self.said]
        total = "; a scheduled run's step sizes follow its total" * ("iterations" in options)
        why = [f"made with different settings ({', '.join(options)}{total})"] * bool(options)
        if "inputs_sha256" in self.changed:
            why.append(self.said["inputs_sha256"])
        if forms := [self.said[k] for k in self.changed if k in FORM_SAID]:
            why.append(f"made by an earlier scratchfab, whose {' and whose '.join(forms)}")
        if self.design:
            changes = ", ".join(f"{k} {v}" for k, v in self.design.items())
            why.append(
                f"{self.design_file or 'the design'} changed since it was made ({changes}): "
                "its steps so far fit the old design"
            )
        return "; ".join(why)


def log_columns(names: list[str]) -> list[str]:
    """Column names of ``log.csv``."""
    cols = ["iteration", "loss", "seconds"]
    for k in names:
        cols += [f"psnr_{k}", f"rho_{k}"]
        cols += [f"x_{k}_{j}" for j in names if j != k]
    return cols


def _log_row(iteration: int, loss: float, seconds: float, quality: dict[str, Any]) -> list[float]:
    names = quality["names"]
    row = [float(iteration), loss, seconds]
    for k in names:
        v = quality["views"][k]
        row += [v["psnr"], v["rho"]]
        row += [v["crosstalk"].get(j, math.nan) for j in names if j != k]
    return row


def _write_log(path: Path, columns: list[str], rows: list[list[float]]) -> None:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:  # a perfect PSNR is written "inf", an undefined rho "nan"
        writer.writerow([str(int(row[0]))] + [f"{v:.6g}" for v in row[1:]])
    write_text(path, buf.getvalue())


def run_optimize(
    job: str | Path,
    options: OptimizeOptions,
    progress: Callable[[Progress], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    checkpoint: Checkpoint | None = None,
) -> OptimizeResult:
    """Optimize the layout of ``job`` and write ``JOB/optimize/``.

    Args:
        job: The job folder (with ``design/`` written by the design stage).
        options: Stage settings.
        progress: Called after every step and with status lines.
        should_stop: Polled after every step; True stops cleanly (Ctrl-C does too).
        checkpoint: The job's checkpoint that ``options.resume`` continues, where the caller
            has read it (:func:`checkpoint_request`); None: read here.

    Raises:
        ConfigError: Missing or malformed inputs, or a checkpoint made with other settings.
        NonFiniteError: The loss or a gradient became non-finite (the last good
            checkpoint is kept).
    """
    job = Path(job)
    design_files = design_digest(job)
    design, targets, initial = load_job_inputs(job)
    report = progress or (lambda p: None)
    m = array_module(options.backend)
    threads_before = dr.thread_count()
    if options.backend == "llvm":
        dr.set_thread_count(options.threads if options.threads > 0 else (os.cpu_count() or 1))
    try:
        return _run(
            JobLayout(job),
            design,
            targets,
            initial,
            design_files,
            options,
            m,
            report,
            should_stop,
            checkpoint,
        )
    finally:
        if options.backend == "llvm":
            dr.set_thread_count(threads_before)


def _run(
    paths: JobLayout,
    design: Design,
    targets: dict[str, np.ndarray],
    initial: ScratchSet,
    design_files: dict[str, str],
    options: OptimizeOptions,
    m: Any,
    report: Callable[[Progress], None],
    should_stop: Callable[[], bool] | None,
    resumed: Checkpoint | None,
) -> OptimizeResult:
    rng = np.random.default_rng(options.seed)
    fingerprint = _fingerprint(options, initial, targets, design)
    start_layout = initial
    if options.jitter_deg > 0:
        turn = rng.normal(0.0, math.radians(options.jitter_deg), len(initial))
        c = 0.5 * (initial.p0 + initial.p1)
        half = 0.5 * (initial.p1 - initial.p0)
        cos, sin = np.cos(turn)[:, None], np.sin(turn)[:, None]
        rot = np.concatenate(
            [half[:, :1] * cos - half[:, 1:] * sin, half[:, :1] * sin + half[:, 1:] * cos], 1
        )
        start_layout = ScratchSet(c - rot, c + rot, initial.width, initial.depth)
    schedule = options.schedule()
    ckpt = paths.optimize_checkpoint
    made: dict[str, Any] = {}  # the checkpoint's fingerprint (a resume's)
    if options.resume:
        loaded = resumed if resumed is not None else read_checkpoint(ckpt)
        state, meta, log_rows = loaded.state, loaded.meta, loaded.log_rows
        made = _made_fingerprint(meta)
        if (extended := _extended_schedule(made, fingerprint, options)) is not None:
            schedule = extended
            fingerprint = {**fingerprint, "lr_schedule": made["lr_schedule"]}
        differ = _changed_keys(made, fingerprint)
        said = {"inputs_sha256": _inputs_change(made.get("inputs"), fingerprint["inputs"], paths)}
        glint_change = _image_error_change(
            made.get("image_error"), design, lambda: _glinting(design, targets, m)
        )
        if glint_change is not None:  # before "nothing to do": its outputs are the old error's
            differ.append("image_error")
            said["image_error"] = glint_change
        if differ:
            raise ResumeRefused(
                ckpt,
                differ,
                _made_with(made, differ, options),
                _design_diff(made, fingerprint),
                paths.design.design_toml,
                said,
            )
        done = loaded.done
        if done is None:
            raise ConfigError(f"{ckpt}: not a scratchfab checkpoint (no integer 'iteration')")
        for note in _rounding_notes(made, options, ckpt):
            report(Progress(done, options.iterations, math.nan, 0.0, math.nan, note))
        if done >= options.iterations and (
            kept := _finished(paths, design, design_files, done, meta.get("elapsed_s"), options)
        ):
            return kept
    settings = Settings.of(options, schedule)
    report(Progress(0, options.iterations, math.nan, 0.0, math.nan, "compiling kernels"))
    opt = LayoutOptimizer(design, targets, start_layout, settings, m)
    # the pixels the image error leaves out, as this run's checkpoints keep them
    fingerprint["image_error"] = _image_error(design, any(g.mask.any() for g in opt.glint))
    for note in opt.glint_notes():
        report(Progress(0, options.iterations, math.nan, 0.0, math.nan, note))
    cross = job_cross_targets(design) or {(k, k): t for k, t in targets.items()}
    names = [v.name for v in opt.views]
    columns = log_columns(names)
    rows: list[list[float]] = []
    elapsed0 = 0.0
    if options.resume:
        opt.load_state(state)
        rng.bit_generator.state = meta["rng"]
        rows = [list(map(float, r)) for r in log_rows]
        elapsed0 = float(meta["elapsed_s"])

    def checkpoint(elapsed: float) -> None:
        meta = {
            "fingerprint": fingerprint,
            "rng": rng.bit_generator.state,
            "elapsed_s": elapsed,
            "columns": columns,
            # what a resume that does not give them goes on with
            "iterations": options.iterations,
            "prune_tolerance": options.prune_tolerance,
            **{k: getattr(options, k) for k in KEPT_IN_META},
        }
        save_checkpoint(
            ckpt, opt.state(), meta, np.asarray(rows, dtype=np.float64).reshape(-1, len(columns))
        )
        _write_log(paths.optimize_log, columns, rows)

    paths.optimize_dir.mkdir(parents=True, exist_ok=True)
    stopped = "done"
    session_start = time.perf_counter()
    steps = 0
    step_time = 0.0
    with interrupt_flag() as interrupted:
        while opt.iteration < options.iterations:
            elapsed = elapsed0 + time.perf_counter() - session_start
            budget = options.time_budget_s
            # At least one step per session, unless a resumed run had spent the budget.
            if budget > 0 and elapsed >= budget and (steps or elapsed0 >= budget):
                stopped = "time budget"
                break
            t0 = time.perf_counter()
            before = opt.iteration
            try:
                result = opt.step()
            except NonFiniteError:
                _write_log(paths.optimize_log, columns, rows)
                raise
            steps += 1
            if steps > 1:  # the first step compiles the kernels
                step_time += time.perf_counter() - t0
            elapsed = elapsed0 + time.perf_counter() - session_start
            quality = quality_report(result.renders, targets, cross)
            rows.append(_log_row(before, result.loss, elapsed, quality))
            per = step_time / (steps - 1) if steps > 1 else math.nan
            left = options.iterations - opt.iteration
            eta = per * left
            if options.time_budget_s > 0:
                eta = min(eta, max(0.0, options.time_budget_s - elapsed))
            report(Progress(opt.iteration, options.iterations, result.loss, elapsed, eta))
            if opt.iteration % options.checkpoint_every == 0:
                checkpoint(elapsed)
            if interrupted() or (should_stop is not None and should_stop()):
                stopped = "interrupted"
                break
        elapsed = elapsed0 + time.perf_counter() - session_start
        checkpoint(elapsed)
        report(
            Progress(opt.iteration, options.iterations, math.nan, elapsed, 0.0, "writing outputs")
        )
        layout = opt.scratches()
        final = opt.evaluate(layout)
        quality = quality_report(final.renders, targets, cross)
        pruned: PruneReport | None = None
        if options.prune_tolerance is not None and stopped != "interrupted":
            report(
                Progress(opt.iteration, options.iterations, math.nan, elapsed, math.nan, "pruning")
            )
            pruned = prune(
                opt, layout, options.prune_tolerance, options.feed_mm_min, options.stroke_overhead_s
            )
            layout.save(paths.unpruned_scratches, design.scratch)
            layout = pruned.kept
            final = opt.evaluate(layout)
            quality = quality_report(final.renders, targets, cross)
        else:  # an earlier run's layout before its pruning is not this layout's
            paths.unpruned_scratches.unlink(missing_ok=True)
        final_rows = rows + [_log_row(opt.iteration, final.loss, elapsed, quality)]
        layout.save(paths.optimized_scratches, design.scratch)
        write_render_layout(paths.optimize_renders, final.renders)
        _write_log(paths.optimize_log, columns, final_rows)
        save_loss_plot(
            paths.loss_png,
            [r[0] for r in final_rows],
            [r[1] for r in final_rows],
            {k: [r[columns.index(f"rho_{k}")] for r in final_rows] for k in names},
        )
        save_side_by_side(
            paths.side_by_side_png, targets, final.renders, {g.name: g for g in opt.glint}
        )
        per_iter = step_time / (steps - 1) if steps > 1 else math.nan
        summary: dict[str, Any] = {
            "iterations": opt.iteration,
            "stopped": stopped,
            "loss": final.loss,
            "seconds_per_iteration": per_iter,
            "elapsed_s": elapsed,
            "scratches": len(layout),
            "pairs_per_view": dict(zip(names, opt.pair_counts(), strict=False)),
            "pair_margin_mm": opt.margin,
            "glint_left_out": {g.name: g.board_share for g in opt.glint if g.mask.any()},
            "options": asdict(options),
            "quality": quality,
            # What toolpath, verify and render check the layout against.
            "design_sha256": design_files,
        }
        if pruned is not None:
            summary["prune"] = {
                "removed": pruned.removed,
                "loss_before": pruned.loss_before,
                "loss_after": pruned.loss_after,
                "length_saved_mm": pruned.length_saved_mm,
                "time_saved_s": pruned.time_saved_s,
                "assumption": (
                    f"time = length / {pruned.feed_mm_min:g} mm/min + "
                    f"{pruned.stroke_overhead_s:g} s per stroke"
                ),
            }
        write_json(paths.optimize_summary, summary)
    return OptimizeResult(
        out_dir=paths.optimize_dir,
        scratches=layout,
        iterations=opt.iteration,
        stopped=stopped,
        loss=final.loss,
        quality=quality,
        seconds_per_iteration=per_iter,
        prune=pruned,
        glint=summary["glint_left_out"],
    )
