"""Tests of the step-size schedule: its scales, the bounded steps, pairs, freeze and resume."""

from __future__ import annotations

import dataclasses
import math
import re
import typing
from pathlib import Path

import click
import drjit as dr
import numpy as np
import pytest
from conftest import make_design
from test_optimize_helpers import cross_of, make_job, make_layout

from scratchfab.cli import main
from scratchfab.cli.optimize_cmd import optimize as optimize_command
from scratchfab.errors import ConfigError
from scratchfab.model.schema import parse_table
from scratchfab.model.scratches import ScratchSet
from scratchfab.optimize import optimizer as optimizer_module
from scratchfab.optimize.optimizer import LayoutOptimizer, Settings
from scratchfab.optimize.options import OptimizeOptions, StepSchedule
from scratchfab.optimize.params import KEYS, BoundedAdam, max_step_mm
from scratchfab.optimize.stage import ResumeRefused, run_optimize

LR = {"cx": 0.03, "cy": 0.03, "theta": math.radians(0.25), "length": 0.03}


@pytest.fixture(scope="module")
def board() -> tuple:  # type: ignore[type-arg]
    design = make_design(resolution=24, size_mm=30.0)
    targets, _ = cross_of(design)
    return design, targets


# ---------------------------------------------------------------- the scales


def test_scales_follow_the_hand_formula() -> None:
    lin = StepSchedule("linear", 4.0, 1.0, 7)  # x = t / 6
    assert [lin.scale(t) for t in (0, 2, 3, 6)] == pytest.approx([4.0, 3.0, 2.5, 1.0], abs=1e-15)
    cos = StepSchedule("cosine", 3.0, 1.0, 5)  # x = t / 4
    expected = [3.0, 1 + 2 * (1 + math.sqrt(0.5)) / 2, 2.0, 1 + 2 * (1 - math.sqrt(0.5)) / 2, 1.0]
    assert [cos.scale(t) for t in range(5)] == pytest.approx(expected, abs=1e-15)
    assert cos.scale(9) == 1.0  # past the run: the end's scale
    assert StepSchedule("cosine", 0.5, 2.0, 1).scale(0) == 0.5  # a one-step run: the start
    assert StepSchedule("linear", 0.5, 2.0, 3).largest() == 2.0


def test_options_give_a_schedule_only_when_the_scales_differ_from_one() -> None:
    assert OptimizeOptions(lr_start_scale=1.0).schedule() is None
    assert OptimizeOptions().schedule() == StepSchedule("cosine", 4.0, 1.0, 300)  # the default
    options = OptimizeOptions(iterations=50, lr_start_scale=2.0, lr_schedule="linear")
    assert options.schedule() == StepSchedule("linear", 2.0, 1.0, 50)
    assert OptimizeOptions(lr_start_scale=0.5, lr_end_scale=0.5).schedule() is not None


def test_a_constant_schedule_in_a_table_is_the_constant_run_whatever_the_scales() -> None:
    """``lr_schedule = "constant"`` (as the CLI's ``--lr-schedule constant``) leaves the
    default scales unused: the run and its checkpoint's record are those of scales 1."""
    from scratchfab.optimize.stage import _fingerprint

    table = parse_table(OptimizeOptions, {"lr_schedule": "constant"}, "p.toml", "optimize")
    assert table.lr_start_scale == 4.0 and table.schedule() is None
    ones = OptimizeOptions(lr_start_scale=1.0)
    scratches = ScratchSet.from_arrays(np.zeros((1, 2)), np.ones((1, 2)), 0.1, 0.01)
    targets = {"v": np.zeros((2, 2))}
    design = make_design()
    assert _fingerprint(table, scratches, targets, design) == _fingerprint(
        ones, scratches, targets, design
    )


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"lr_schedul": "linear"}, "lr_schedule"),
        ({"lr_schedule": "step"}, "lr_schedule"),
        ({"lr_start_scale": 0}, "lr_start_scale"),
        ({"lr_end_scale": -1.0}, "lr_end_scale"),
        ({"lr_start_scale": "2"}, "lr_start_scale"),
    ],
)
def test_bad_schedule_keys_are_refused_naming_the_key(table: dict, message: str) -> None:  # type: ignore[type-arg]
    with pytest.raises(ConfigError) as exc:
        parse_table(OptimizeOptions, table, "p.toml", "optimize")
    text = str(exc.value)
    assert text.startswith("p.toml") and message in text and "\n" not in text


# ---------------------------------------------------------------- steps


def test_scaled_adam_steps_at_most_scale_times_lr(m) -> None:
    """A gradient burst after a quiet spell: each step stays within scale x lr; a scale of
    1 gives the unscaled steps bit for bit."""
    lr = 0.1
    runs = {"bounded": BoundedAdam(lr=lr), "one": BoundedAdam(lr=lr)}
    scales = {"0.5": 0.5, "3": 3.0}
    for name in scales:
        runs[name] = BoundedAdam(lr=lr)
    steps: dict[str, list[np.ndarray]] = {k: [] for k in runs}
    for it in range(60):
        g = 1e-6 if it < 50 else 1e3
        for name, opt in runs.items():
            if it == 0:
                opt["x"] = m.Float64([0.0, 0.0, 1.0])
            x = opt["x"]
            before = np.asarray(x).copy()
            dr.backward(dr.sum(x * m.Float64([g, -g, 0.3 * g])))
            if name in scales or name == "one":
                opt.scale = dr.opaque(m.Float64, scales.get(name, 1.0), 1)
            opt.step()
            steps[name].append(np.asarray(opt["x"]) - before)
    assert all(np.array_equal(a, b) for a, b in zip(steps["one"], steps["bounded"], strict=True))
    for name, s in scales.items():
        largest = max(float(np.abs(d).max()) for d in steps[name])
        assert largest <= s * lr * (1 + 1e-12)
        assert largest >= 0.99 * s * lr  # the burst reaches the clip
        # below the clip a step is the unscaled one times the scale
        np.testing.assert_allclose(steps[name][10], s * steps["bounded"][10], rtol=1e-12)


def _raw(opt: LayoutOptimizer) -> dict[str, np.ndarray]:
    return {k: np.array(opt.opt[k], dtype=np.float64) for k in KEYS}


def test_no_step_moves_a_scratch_farther_than_the_pair_margin_assumed(m, board) -> None:
    """Per step |d raw| <= scale(t) lr; since a refresh, endpoints move at most the margin's
    reach and angles the merge slack; exact fresh pairs are always among those in use."""
    design, targets = board
    layout = make_layout(design, 120, seed=5)
    lr = {"cx": 0.08, "cy": 0.08, "theta": math.radians(1.0), "length": 0.08}
    schedule = StepSchedule("linear", 3.0, 0.2, 30)  # refreshes at 0-10, 12, ..., 21, 26
    settings = Settings(lr=lr, refresh_every=4, schedule=schedule)
    opt = LayoutOptimizer(design, targets, layout, settings, m)
    assert opt.budget == 4
    reach = opt.margin - float(np.max(layout.width)) / 2  # what pair_margin allowed for
    assert reach >= 4 * max_step_mm(lr, opt.bounds.max_length)
    refreshes: list[int] = []
    raw_at_refresh = _raw(opt)
    moved = 0.0
    fullest = 0.0
    for t in range(30):
        before = _raw(opt)
        opt.step()
        if opt.refresh_due(t):
            refreshes.append(t)
            raw_at_refresh, moved = before, 0.0
        after = _raw(opt)
        s = schedule.scale(t)
        for k in KEYS:
            step = float(np.abs(after[k] - before[k]).max())
            assert step <= s * lr[k] * (1 + 1e-9), (t, k)
            fullest = max(fullest, step / (s * lr[k]))
        moved += s
        assert moved <= opt.budget * (1 + 1e-12)
        current = opt.scratches()
        stale = opt.refresh_ends.astype(np.float64)  # type: ignore[union-attr]
        shift = np.maximum(
            np.hypot(*(current.p0 - stale[:, 0:2]).T), np.hypot(*(current.p1 - stale[:, 2:4]).T)
        )
        assert shift.max() <= reach
        turn = np.abs(after["theta"] - raw_at_refresh["theta"]).max()
        assert turn <= opt.budget * lr["theta"] * (1 + 1e-9)
        for r, used in zip(opt.renderers, opt.pairs, strict=True):
            fresh = r.find_pairs(current.p0, current.p1, current.width / 2, 0.0)
            fresh_set = set(zip(fresh.pixel_np.tolist(), fresh.scratch_np.tolist(), strict=True))
            used_set = set(zip(used.pixel_np.tolist(), used.scratch_np.tolist(), strict=True))
            assert fresh_set <= used_set
    assert fullest > 0.9  # some step is clipped: the bound is reached, not vacuous
    gaps = np.diff(refreshes)
    # scale 3 early: a refresh every step; below 1 late: fewer than every K = 4
    assert gaps[0] == 1 and gaps.max() > 4
    assert refreshes[0] == 0


def test_a_scale_above_k_widens_margin_and_merge_slack_to_its_budget(
    m, board, monkeypatch: pytest.MonkeyPatch
) -> None:
    """K = 2 but one step of scale 2.5 moves 2.5 lr: the budget is 3 steps (rounded up);
    margin and merge slack cover it, and refreshes follow the greedy plan exactly."""
    design, targets = board
    layout = make_layout(design, 80, seed=7)
    lr = {"cx": 0.08, "cy": 0.08, "theta": math.radians(1.0), "length": 0.08}
    schedule = StepSchedule("linear", 2.5, 0.5, 5)  # 2.5, 2, 1.5, 1, 0.5
    slacks: list[float] = []
    real = optimizer_module.neighbour_pairs

    def spy(*args: object, **kwargs: object) -> object:
        slacks.append(float(args[3]))  # type: ignore[arg-type]
        return real(*args, **kwargs)

    monkeypatch.setattr(optimizer_module, "neighbour_pairs", spy)
    opt = LayoutOptimizer(design, targets, layout, Settings(lr, 2, schedule=schedule), m)
    budget = 3
    assert opt.budget == budget
    reach = opt.margin - float(np.max(layout.width)) / 2
    assert reach >= budget * max_step_mm(lr, opt.bounds.max_length)
    # the plan: refresh before a step that would take the scales' sum past the budget
    expected, moved = [], math.inf
    for t in range(5):
        if moved + schedule.scale(t) > budget:
            expected.append(t)
            moved = 0.0
        moved += schedule.scale(t)
    assert expected == [0, 1, 2]  # steps 3 and 4 bring the sum to exactly 3: no refresh
    for _ in range(5):
        opt.step()
    assert [t for t in range(5) if opt.refresh_due(t)] == expected
    assert slacks == pytest.approx([2 * budget * lr["theta"]] * len(expected), rel=1e-15)


def test_scheduled_frozen_steps_replay_the_traced_trajectory(m, board) -> None:
    """The scale is a frozen step's input, not a recorded constant; it changes the run."""
    design, targets = board
    layout = make_layout(design, 200, seed=6)
    scheduled = Settings(lr=LR, refresh_every=3, schedule=StepSchedule("linear", 3.0, 0.5, 8))
    runs = [LayoutOptimizer(design, targets, layout, scheduled, m, freeze=f) for f in (True, False)]
    plain = LayoutOptimizer(
        design, targets, layout, dataclasses.replace(scheduled, schedule=None), m
    )
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        for _ in range(8):
            for opt in (*runs, plain):
                opt.step()
    finally:
        dr.set_thread_count(threads)
    a, b, c = (opt.state() for opt in (*runs, plain))
    for key in a:
        assert np.array_equal(a[key], b[key]), key
    assert not np.array_equal(a["raw_cx"], c["raw_cx"])


def _twin_jobs(tmp_path: Path) -> tuple[Path, Path]:
    """Two jobs of the same small design and layout: one runs straight, one is resumed."""
    design = make_design(resolution=24, size_mm=30.0)
    return make_job(tmp_path / "a", design, count=150), make_job(tmp_path / "b", design, count=150)


def _stop_after(steps: int):  # type: ignore[no-untyped-def]
    """A should_stop that asks to stop after ``steps`` steps."""
    done = [0]

    def stop() -> bool:
        done[0] += 1
        return done[0] == steps

    return stop


def _same_run(a: Path, b: Path) -> list[str]:
    """Assert the two jobs wrote the same scratches and log (but its seconds); a's log."""
    assert (b / "optimize" / "scratches.csv").read_bytes() == (
        a / "optimize" / "scratches.csv"
    ).read_bytes()
    log_a = (a / "optimize" / "log.csv").read_text().splitlines()
    log_b = (b / "optimize" / "log.csv").read_text().splitlines()
    strip = [lambda line: line.split(",")[:2] + line.split(",")[3:]][0]  # not the seconds
    assert [strip(x) for x in log_a] == [strip(x) for x in log_b]
    return log_a


# ---------------------------------------------------------------- resume


def test_scheduled_resume_matches_uninterrupted_and_needs_the_same_iterations(
    tmp_path: Path,
) -> None:
    a, b = _twin_jobs(tmp_path)
    options = OptimizeOptions(
        iterations=20, checkpoint_every=4, lr_start_scale=3.0, lr_end_scale=0.5, refresh_every=4
    )
    run_optimize(a, options)
    # after step 9, between checkpoints and refreshes
    first = run_optimize(b, options, should_stop=_stop_after(9))
    assert first.stopped == "interrupted" and first.iterations == 9
    run_optimize(b, dataclasses.replace(options, resume=True))
    _same_run(a, b)
    # the scales depend on the total: a smaller total, or no schedule, is another run; the
    # refusal names the options that changed, not the fingerprint's "lr_schedule"
    # and says what the checkpoint was made with; those resume it
    for other, named, made in (
        (
            dataclasses.replace(options, iterations=12, resume=True),
            "(iterations; ",
            "iterations = 20",
        ),
        (
            dataclasses.replace(options, lr_start_scale=1.0, lr_end_scale=1.0, resume=True),
            "(lr_start_scale, lr_end_scale)",
            "lr_start_scale = 3.0, lr_end_scale = 0.5",
        ),
        (
            dataclasses.replace(options, lr_schedule="linear", resume=True),
            "(lr_schedule)",
            'lr_schedule = "cosine"',
        ),
        (  # a linear run of scales 1 at 12 steps differs in every field of the schedule
            dataclasses.replace(
                options,
                iterations=12,
                lr_schedule="linear",
                lr_start_scale=1.0,
                lr_end_scale=1.0,
                seed=4,
                resume=True,
            ),
            "(seed, lr_start_scale, lr_end_scale)",
            'seed = 0, lr_schedule = "cosine", lr_start_scale = 3.0, lr_end_scale = 0.5, '
            "iterations = 20",
        ),
    ):
        with pytest.raises(ResumeRefused) as exc:
            run_optimize(b, other)
        text = str(exc.value)
        assert "different settings" in text and named in text and "\n" not in text
        assert f"it was made with {made}: give that to resume it" in text
        assert dataclasses.replace(other, **(exc.value.made_with or {})) == dataclasses.replace(
            options, resume=True
        )


def test_a_scheduled_run_extends_past_its_total_at_the_end_scale(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """--resume with more iterations goes on past the total the run started with at its end
    scale, as a fresh run whose schedule has that total does (and so does a resume of the
    extended run); the checkpoint keeps the first total."""
    a, b = _twin_jobs(tmp_path)
    options = OptimizeOptions(
        iterations=12, checkpoint_every=4, lr_start_scale=3.0, lr_end_scale=0.5, refresh_every=4
    )
    run_optimize(b, options)
    longer = dataclasses.replace(options, iterations=20, resume=True)
    # the extension stopped part way, then resumed again
    assert run_optimize(b, longer, should_stop=_stop_after(5)).stopped == "interrupted"
    assert run_optimize(b, longer).iterations == 20
    first = options.schedule()
    monkeypatch.setattr(OptimizeOptions, "schedule", lambda self: first)
    run_optimize(a, dataclasses.replace(options, iterations=20))
    assert _same_run(a, b)[-1].startswith("20,")


def test_equal_scales_resume_with_more_iterations_as_constant_steps(tmp_path: Path) -> None:
    """Start and end scales equal (not 1): every step takes that scale, whatever the total
    and the shape, so a finished run extends to more iterations (with another shape too)
    and ends as a run that had the larger count from the start."""
    a, b = _twin_jobs(tmp_path)
    options = OptimizeOptions(
        iterations=16, checkpoint_every=4, lr_start_scale=0.5, lr_end_scale=0.5, refresh_every=4
    )
    schedule = options.schedule()
    assert schedule is not None
    assert {schedule.scale(t) for t in range(16)} == {0.5}
    run_optimize(a, options)
    short = dataclasses.replace(options, iterations=7, lr_schedule="linear")
    assert run_optimize(b, short).iterations == 7
    resumed = run_optimize(b, dataclasses.replace(options, resume=True))
    assert resumed.iterations == 16
    assert _same_run(a, b)[-1].startswith("16,")
    # another equal scale is another run, named by its options
    with pytest.raises(ConfigError, match=r"\(lr_start_scale, lr_end_scale\)"):
        run_optimize(
            b, dataclasses.replace(options, lr_start_scale=0.7, lr_end_scale=0.7, resume=True)
        )


def test_a_checkpoint_that_kept_an_equal_scales_total_still_resumes() -> None:
    """Checkpoints written before kept the shape and total of equal scales: still the same."""
    from scratchfab.optimize.stage import _changed_keys

    made = {
        "seed": 0,
        "lr_schedule": {"shape": "cosine", "start": 0.5, "end": 0.5, "iterations": 9},
    }
    now = {"seed": 0, "lr_schedule": {"start": 0.5, "end": 0.5}}
    assert _changed_keys(made, now) == []
    varying = {"shape": "cosine", "start": 0.5, "end": 0.25, "iterations": 9}
    assert _changed_keys({**made, "lr_schedule": varying}, now) == ["lr_end_scale"]


def test_equal_scales_above_k_resume_an_interrupted_shorter_run(tmp_path: Path) -> None:
    """Equal scales above K (the pair budget widened to the scale: a refresh before every
    step at 3.0 with K = 2) in a shorter cosine run interrupted between checkpoints,
    resumed as a longer linear one: the same scratches and log as the longer run from the
    start (checkpoint, refresh plan and margins depend on neither total nor shape)."""
    a, b = _twin_jobs(tmp_path)
    options = OptimizeOptions(
        iterations=13,
        checkpoint_every=3,
        lr_start_scale=3.0,
        lr_end_scale=3.0,
        refresh_every=2,
        lr_schedule="linear",
    )
    run_optimize(a, options)
    short = dataclasses.replace(options, iterations=5, lr_schedule="cosine")
    # after step 4 of 5, one past a checkpoint
    first = run_optimize(b, short, should_stop=_stop_after(4))
    assert first.stopped == "interrupted" and first.iterations == 4
    assert run_optimize(b, dataclasses.replace(options, resume=True)).iterations == 13
    assert len(_same_run(a, b)) == 15


def test_a_constant_checkpoint_resumes_from_the_command_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A checkpoint of constant steps (the default before the schedule) resumes with
    ``optimize --resume`` alone as the run it was, not under the command's default
    schedule; a scale given that the run was not made with is refused, naming the
    checkpoint's."""
    a, b = _twin_jobs(tmp_path)
    constant = OptimizeOptions(iterations=10, checkpoint_every=4, lr_start_scale=1.0)
    assert constant.schedule() is None
    run_optimize(a, constant)
    assert run_optimize(b, constant, should_stop=_stop_after(6)).iterations == 6
    resume = ["optimize", str(b), "--checkpoint-every", "4", "--resume"]
    with pytest.raises(SystemExit):  # constant steps take no scale
        main([*resume, "--lr-schedule", "constant", "--lr-end-scale", "2"])
    assert "--lr-end-scale" in capsys.readouterr().err
    # the other spellings of a schedule: flags for the options that have one
    with pytest.raises(SystemExit):
        main([*resume, "--lr-schedule", "linear", "--lr-start-scale", "2", "--seed", "5"])
    err = capsys.readouterr().err
    assert "it was made with --lr-start-scale 1.0 --seed 0: give that" in err
    main(resume)
    _same_run(a, b)


@pytest.mark.parametrize(
    ("made", "asked", "advice"),
    [
        # constant steps asked for: the checkpoint's schedule whole, as the scales left out
        # take their defaults (4 and 1), not constant's 1 and 1
        ({}, ["--lr-schedule", "constant"], "--lr-schedule cosine --lr-start-scale 4.0 "),
        (
            {"lr_schedule": "linear", "lr_end_scale": 0.5},
            ["--lr-schedule", "constant"],
            "--lr-schedule linear --lr-start-scale 4.0 --lr-end-scale 0.5",
        ),
        (
            {"lr_start_scale": 1.0, "lr_end_scale": 0.5},
            ["--lr-schedule", "constant"],
            "--lr-schedule cosine --lr-start-scale 1.0 --lr-end-scale 0.5",
        ),
        (
            {"lr_start_scale": 0.5, "lr_end_scale": 0.5},
            ["--lr-schedule", "constant"],
            "--lr-schedule cosine --lr-start-scale 0.5 --lr-end-scale 0.5",
        ),
        # a constant checkpoint and a scale given (which constant refuses): the scales
        ({"lr_start_scale": 1.0}, ["--lr-schedule", "linear", "--lr-start-scale", "2"], None),
        ({"lr_start_scale": 1.0}, ["--lr-start-scale", "1", "--lr-end-scale", "2"], None),
        # a constant checkpoint under a schedule given, with another option
        (
            {"lr_start_scale": 1.0, "seed": 2},
            ["--lr-schedule", "cosine", "--lr-start-scale", "4", "--seed", "0"],
            "--lr-start-scale 1.0 --seed 2",
        ),
    ],
)
def test_the_flags_a_refused_resume_gives_resume_it(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    made: dict[str, typing.Any],
    asked: list[str],
    advice: str | None,
) -> None:
    """The flags a refused ``optimize --resume`` names, added to its command line, resume
    the run it stopped (the same scratches and log as the run uninterrupted), whatever
    schedule flags the command gave."""
    a, b = _twin_jobs(tmp_path)
    options = OptimizeOptions(iterations=6, checkpoint_every=2, **made)
    run_optimize(a, options)
    assert run_optimize(b, options, should_stop=_stop_after(3)).iterations == 3
    resume = ["optimize", str(b), "--iterations", "6", "--checkpoint-every", "2", *asked]
    with pytest.raises(SystemExit):
        main([*resume, "--resume"])
    err = capsys.readouterr().err
    found = re.search(r"it was made with (.*): give that to resume it", err)
    assert found, err
    if advice is not None:
        assert found[1].startswith(advice.strip())
    main([*resume, "--resume", *found[1].split()])
    _same_run(a, b)


@pytest.mark.parametrize(
    "option",
    [
        "iterations",
        "time_budget_s",
        "seed",
        "threads",
        "lr_start_scale",
        "lr_end_scale",
        "prune_tolerance",
        "checkpoint_every",
    ],
)
def test_the_command_line_takes_what_the_options_take(option: str) -> None:
    """Each ``optimize`` flag of an OptimizeOptions field defaults to the field's default
    and accepts a value near its bounds exactly when the dataclass does."""
    params = {p.name: p for p in optimize_command.params}
    param = params[option]
    default = getattr(OptimizeOptions(), option)
    if param.default is not None or default is not None:
        assert param.default == default
    for value in (-1, -1e-9, 0, 1e-9, 1, 2.5):
        if isinstance(default, int) and value != int(value):
            continue
        try:
            OptimizeOptions(**{option: value})
            takes = True
        except ValueError:
            takes = False
        try:
            param.type.convert(str(value), param, None)
            accepted = True
        except click.BadParameter:
            accepted = False
        assert accepted == takes, (option, value)


def test_the_schedule_flag_names_every_shape_of_the_options() -> None:
    """``--lr-schedule`` offers the options' shapes and ``constant``."""
    param = {p.name: p for p in optimize_command.params}["lr_schedule"]
    shapes = typing.get_args(typing.get_type_hints(OptimizeOptions)["lr_schedule"])
    assert set(param.type.choices) == {*shapes, "constant"}
