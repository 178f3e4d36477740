"""The optimize stage's settings, apart from the stage so that reading them stays light.

Pipeline files parse ``[optimize]`` into :class:`OptimizeOptions` without loading Dr.Jit,
SciPy or the optimizer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from scratchfab.model.schema import check_bounds, spec


@dataclass(frozen=True)
class StepSchedule:
    """Multiples of the Adam step sizes over a run: large early, smaller late.

    Step t (0-based) of a run of n steps takes the step sizes times

        scale(t) = end + (start - end) w(x),   x = min(t / max(n - 1, 1), 1),

    with w(x) = 1 - x (``"linear"``) or (1 + cos(pi x)) / 2 (``"cosine"``), so step 0
    takes ``start`` and step n - 1 ``end``. It depends on the step index and the run's
    total only (not on time), so a resumed run follows the same schedule; steps past n
    (a finished run extended) take ``end``.

    Attributes:
        shape: ``"linear"`` or ``"cosine"``.
        start: Scale of the first step.
        end: Scale of the last step.
        iterations: The run's total steps n.
    """

    shape: Literal["linear", "cosine"]
    start: float
    end: float
    iterations: int

    def scale(self, t: int) -> float:
        """The multiple of the step sizes at step ``t``."""
        x = min(t / max(self.iterations - 1, 1), 1.0)
        w = 1.0 - x if self.shape == "linear" else 0.5 * (1.0 + math.cos(math.pi * x))
        return self.end + (self.start - self.end) * w

    def largest(self) -> float:
        """The largest scale of any step (both shapes are monotonic)."""
        return max(self.start, self.end)


@dataclass(frozen=True)
class OptimizeOptions:
    """Settings of the optimize stage (the ``[optimize]`` table of a pipeline file).

    Attributes:
        iterations: Total Adam steps (a resumed run continues up to this count).
        time_budget_s: Stop after this many seconds of optimizing (0: no limit); a run
            takes one step at least, unless it resumes one that had spent them.
        seed: Seed of the run's random generator (initial angle jitter).
        backend: ``"llvm"`` (CPU) or ``"cuda"``.
        space: Image error in ``"linear"`` or ``"perceptual"`` (sRGB) space.
        lr_position_mm: Adam step size of the centres.
        lr_angle_deg: Adam step size of the angles.
        lr_length_mm: Adam step size of the lengths.
        lr_schedule: Shape of the step sizes' change over the run, ``"linear"`` or
            ``"cosine"`` (:class:`StepSchedule`); ``"constant"`` keeps the ``lr_*``
            throughout, whatever the scales say.
        lr_start_scale: The step sizes of the first step, as multiples of the ``lr_*``
            (4: at full size the images' error is 6 % lower after 300 steps than with
            constant steps, +0.2 dB mean PSNR, and 22 % less length is cut twice by
            overlapping scratches; benchmarks/bench_quality.py).
        lr_end_scale: The step sizes of the last step (step ``iterations - 1``), as
            multiples of the ``lr_*``; equal start and end scales keep them constant.
        refresh_every: Steps between pixel-pair refreshes at the ``lr_*`` step sizes (a
            schedule above them refreshes more often, below them less: the pair
            margin covers this many steps of the ``lr_*``).
        checkpoint_every: Steps between checkpoints.
        merge_weight: Weight of the penalty on the length (mm) that overlapping scratches
            cut twice, side by side or crossing within 35 degrees of parallel, weighted
            by how close (divided by the scratch count; :mod:`scratchfab.optimize.loss`).
        jitter_deg: Standard deviation of a random turn of each initial scratch.
        threads: CPU threads (1: bit-reproducible; 0: all cores).
        resume: Continue from ``JOB/optimize/checkpoint.npz``; the options that shape the
            steps must be the run's (:func:`scratchfab.optimize.stage.checkpoint_settings`
            reads them from it).
        prune_tolerance: When set, drop scratches while the loss rises by at most this
            fraction.
        feed_mm_min: Engrave feed for the machining-time estimate of pruning.
        stroke_overhead_s: Per-stroke overhead (rapid, plunge, retract) for that estimate.
    """

    iterations: int = field(default=300, metadata=spec(ge=0))
    time_budget_s: float = field(default=0.0, metadata=spec(ge=0))
    seed: int = field(default=0, metadata=spec(ge=0))
    backend: Literal["llvm", "cuda"] = "llvm"
    space: Literal["linear", "perceptual"] = "linear"
    lr_position_mm: float = field(default=0.03, metadata=spec(gt=0))
    lr_angle_deg: float = field(default=0.25, metadata=spec(gt=0))
    lr_length_mm: float = field(default=0.03, metadata=spec(gt=0))
    lr_schedule: Literal["constant", "linear", "cosine"] = "cosine"
    lr_start_scale: float = field(default=4.0, metadata=spec(gt=0))
    lr_end_scale: float = field(default=1.0, metadata=spec(gt=0))
    refresh_every: int = field(default=8, metadata=spec(gt=0))
    checkpoint_every: int = field(default=25, metadata=spec(gt=0))
    merge_weight: float = field(default=0.02, metadata=spec(ge=0))
    jitter_deg: float = field(default=0.0, metadata=spec(ge=0))
    threads: int = field(default=1, metadata=spec(ge=0))
    resume: bool = False
    prune_tolerance: float | None = field(default=None, metadata=spec(ge=0))
    feed_mm_min: float = field(default=300.0, metadata=spec(gt=0))
    stroke_overhead_s: float = field(default=2.0, metadata=spec(ge=0))

    def __post_init__(self) -> None:
        check_bounds(self)

    def schedule(self) -> StepSchedule | None:
        """The step-size schedule over ``iterations`` (None: the ``lr_*`` throughout)."""
        if self.lr_schedule == "constant" or self.lr_start_scale == self.lr_end_scale == 1.0:
            return None
        return StepSchedule(
            self.lr_schedule, self.lr_start_scale, self.lr_end_scale, self.iterations
        )

    def learning_rates(self) -> dict[str, float]:
        """Per-variable learning rates in the optimizer's units (mm, rad)."""
        return {
            "cx": self.lr_position_mm,
            "cy": self.lr_position_mm,
            "theta": math.radians(self.lr_angle_deg),
            "length": self.lr_length_mm,
        }
