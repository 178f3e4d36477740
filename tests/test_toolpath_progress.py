"""``plan_toolpath``'s ``progress``: the ordering's phases, and the same toolpath without it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scratchfab.machine.profile import load_profile
from scratchfab.model.design import Board
from scratchfab.model.scratches import ScratchSet
from scratchfab.toolpath import OrderOptions, OrderProgress, plan_toolpath
from scratchfab.toolpath.order import order_phases, tour_travel
from scratchfab.toolpath.stage import progress_lines

BOARD = Board(width_mm=150.0, height_mm=100.0)


def scratches(n: int, seed: int) -> ScratchSet:
    """``n`` seeded scratches of 2 to 10 mm across the board."""
    rng = np.random.default_rng(seed)
    mid = rng.uniform([-70.0, -45.0], [70.0, 45.0], (n, 2))
    angle = rng.uniform(0.0, np.pi, n)
    half = np.stack([np.cos(angle), np.sin(angle)], axis=1) * rng.uniform(1.0, 5.0, (n, 1))
    return ScratchSet.from_arrays(mid - half, mid + half, 0.1, 0.01)


@pytest.fixture(scope="module")
def profile():
    return load_profile("grbl-3018-diamond")


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        (OrderOptions(), ["greedy", "local search"]),
        (OrderOptions(window=60, kicks=400, seed=7), ["greedy", "regions", "local search"]),
        (OrderOptions(passes=0), ["greedy"]),
    ],
    ids=["whole tour", "regions", "greedy only"],
)
def test_the_phases_are_reported_and_change_nothing(profile, options, expected):
    board = scratches(300, seed=11)
    reports: list[OrderProgress] = []
    planned = plan_toolpath(board, BOARD, profile, None, options, reports.append)
    plain = plan_toolpath(board, BOARD, profile, None, options)
    assert planned.strokes.tobytes() == plain.strokes.tobytes()
    assert np.array_equal(planned.source_rows, plain.source_rows)
    assert planned.stats == plain.stats

    messages = [r for r in reports if r.message]
    phases = [r for r in reports if not r.message]
    assert messages[0].message == f"ordering 300 scratches for {profile.name} ..."
    assert all(math.isnan(r.travel_mm) and r.phase == "" for r in messages)
    assert list(order_phases(planned.stats["count"], options)) == expected
    assert [r.phase for r in phases] == expected
    assert [r.step for r in phases] == list(range(1, len(expected) + 1))
    assert {r.total for r in phases} == {len(expected)}
    assert [r.elapsed_s for r in phases] == sorted(r.elapsed_s for r in phases)
    # after greedy: the travel of the greedy-only plan, measured on its strokes
    greedy = plan_toolpath(board, BOARD, profile, None, OrderOptions(passes=0))
    start = np.asarray(profile.start_mm)
    greedy_travel = tour_travel(greedy.strokes[:, 0], greedy.strokes[:, 1], start)
    assert phases[0].travel_mm == pytest.approx(greedy_travel, rel=1e-12)
    # the last phase's tour is the plan's, measured on its strokes
    travel = tour_travel(planned.strokes[:, 0], planned.strokes[:, 1], start)
    assert phases[-1].travel_mm == pytest.approx(travel, rel=1e-12)
    assert [r.travel_mm for r in phases] == sorted((r.travel_mm for r in phases), reverse=True)


def test_a_board_of_one_stroke_has_no_phases(profile):
    reports: list[OrderProgress] = []
    plan_toolpath(scratches(1, seed=2), BOARD, profile, None, None, reports.append)
    assert [r.message for r in reports] == [f"ordering 1 scratches for {profile.name} ..."]


def test_the_stage_says_the_messages_only():
    said: list[str] = []
    tell = progress_lines(said.append)
    tell(OrderProgress.note("ordering 3 scratches ..."))
    tell(OrderProgress("greedy", 1, 2, 12.5, 0.1))
    tell(OrderProgress.note("compiling", 1, 2, 0.2))
    assert said == ["ordering 3 scratches ...", "compiling"]
