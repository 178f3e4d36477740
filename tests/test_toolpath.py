from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import shapely
from PIL import Image
from scipy.spatial import cKDTree

from scratchfab.cli import main
from scratchfab.errors import ScratchfabError
from scratchfab.machine.profile import load_profile, profile_from_mapping
from scratchfab.model.design import Board, ScratchTool
from scratchfab.model.scratches import ScratchSet
from scratchfab.toolpath import OrderOptions, Toolpath, order_strokes, plan_toolpath
from scratchfab.toolpath.geometry import clip_strokes, merge_collinear
from scratchfab.toolpath.local_search import (
    _chain,
    _flip,
    _wrap,
    cut_region,
    expand_region,
    improve,
)
from scratchfab.toolpath.order import tour_travel
from scratchfab.toolpath.timing import path_times


def random_segments(rng, n, half=50.0, lo=1.0, hi=12.0):
    c = rng.uniform(-half + hi / 2, half - hi / 2, (n, 2))
    th = rng.uniform(0, np.pi, n)
    ln = rng.uniform(lo, hi, n)
    u = np.stack([np.cos(th), np.sin(th)], 1) * (ln / 2)[:, None]
    return c - u, c + u


def naive_travel(p0, p1, order, reverse, start):
    pos = np.asarray(start, float)
    total = 0.0
    for k, r in zip(order, reverse, strict=True):
        a, b = (p1[k], p0[k]) if r else (p0[k], p1[k])
        total += math.dist(pos, a)
        pos = b
    return total + math.dist(pos, start)


def naive_greedy(p0, p1, start):
    """O(N^2) nearest-endpoint greedy with reversal, from ``start``."""
    left = set(range(len(p0)))
    pos = np.asarray(start, float)
    order, rev = [], []
    while left:
        best = None
        for k in left:
            for r, a in ((False, p0[k]), (True, p1[k])):
                d = math.dist(pos, a)
                if best is None or d < best[0]:
                    best = (d, k, r)
        _, k, r = best
        left.remove(k)
        order.append(k)
        rev.append(r)
        pos = p0[k] if r else p1[k]
    return np.array(order), np.array(rev)


def test_order_is_a_permutation_and_travel_is_right(rng):
    p0, p1 = random_segments(rng, 400)
    start = (-60.0, -60.0)
    res = order_strokes(p0, p1, start)
    assert sorted(res.order.tolist()) == list(range(400))
    assert res.travel_mm == pytest.approx(naive_travel(p0, p1, res.order, res.reverse, start))
    assert res.travel_input_mm == pytest.approx(
        naive_travel(p0, p1, np.arange(400), np.zeros(400, bool), start)
    )
    assert res.travel_mm <= res.travel_greedy_mm < res.travel_input_mm


def test_greedy_step_matches_brute_force(rng):
    p0, p1 = random_segments(rng, 150)
    start = (55.0, -55.0)
    res = order_strokes(p0, p1, start, OrderOptions(passes=0, neighbours=4))
    order, rev = naive_greedy(p0, p1, start)
    assert res.travel_greedy_mm == pytest.approx(naive_travel(p0, p1, order, rev, start))
    assert np.array_equal(res.order, order) and np.array_equal(res.reverse, rev)


def test_local_search_is_optimal_on_tiny_sets(rng):
    from itertools import permutations, product

    for _ in range(8):
        p0, p1 = random_segments(rng, 5, half=20.0)
        start = (0.0, -30.0)
        best = min(
            naive_travel(p0, p1, np.array(o), np.array(r), start)
            for o in permutations(range(5))
            for r in product([False, True], repeat=5)
        )
        got = order_strokes(p0, p1, start).travel_mm
        assert got == pytest.approx(best, rel=1e-9)


def test_wrap_is_modulo_on_the_positions_it_is_given():
    """The local search's division-free wrap equals i % m for -m <= i < 2m."""
    for m in (1, 2, 7, 100):
        span = range(-m, 2 * m)
        assert [_wrap(i, m) for i in span] == [i % m for i in span]


def test_ordering_is_deterministic_and_seeded(rng):
    p0, p1 = random_segments(rng, 300)
    a = order_strokes(p0, p1, (0.0, 0.0), OrderOptions(seed=3))
    b = order_strokes(p0, p1, (0.0, 0.0), OrderOptions(seed=3))
    assert np.array_equal(a.order, b.order) and np.array_equal(a.reverse, b.reverse)
    plain = order_strokes(p0, p1, (0.0, 0.0), OrderOptions(kicks=0))
    assert a.travel_mm <= plain.travel_mm + 1e-9 <= plain.travel_greedy_mm + 1e-9


def test_never_worse_than_input_order():
    # Already optimal in input order: a row of strokes leading away from the start and back.
    xs = np.arange(10.0)
    p0 = np.stack([xs, np.zeros(10)], 1)
    p1 = p0 + [0.5, 0.0]
    res = order_strokes(p0, p1, (-0.5, 0.0))
    assert res.travel_mm <= res.travel_input_mm + 1e-12
    assert res.travel_mm == pytest.approx(tour_travel(p0, p1, np.array([-0.5, 0.0])))


def test_clip_against_dense_sampling(rng):
    region = shapely.box(-10, -5, 10, 5)
    p0 = rng.uniform(-15, 15, (300, 2))
    p1 = rng.uniform(-15, 15, (300, 2))
    keep, q0, q1 = clip_strokes(p0, p1, region)
    t = np.linspace(0, 1, 20001)
    for k in range(300):
        pts = p0[k] + t[:, None] * (p1[k] - p0[k])
        inside = (np.abs(pts[:, 0]) <= 10) & (np.abs(pts[:, 1]) <= 5)
        length = np.linalg.norm(p1[k] - p0[k]) * inside.mean()
        if k in keep:
            j = int(np.flatnonzero(keep == k)[0])
            assert np.linalg.norm(q1[j] - q0[j]) == pytest.approx(length, abs=2e-3 * 30)
            assert np.dot(q1[j] - q0[j], p1[k] - p0[k]) > 0
            for q in (q0[j], q1[j]):
                assert abs(q[0]) <= 10 + 1e-9 and abs(q[1]) <= 5 + 1e-9
        else:
            assert length < 2e-3 * 30


def test_merge_collinear_duplicates():
    tol = 0.01
    p0 = np.array(
        [
            [0.0, 0.0],  # A
            [3.0, 0.004],  # overlaps A, within tolerance
            [5.0, 0.0],  # collinear with A..B, touching B's end -> same group
            [20.0, 0.0],  # collinear but far away -> alone
            [0.0, 1.0],  # parallel, 1 mm off -> alone
            [4.0, -0.003],  # reversed duplicate inside A..B
        ]
    )
    p1 = np.array([[4.0, 0.0], [6.0, 0.004], [8.0, 0.0], [22.0, 0.0], [4.0, 1.0], [1.0, -0.003]])
    q0, q1, groups = merge_collinear(p0, p1, tol)
    assert len(q0) == 3
    merged = [g for g in groups if len(g) > 1]
    assert len(merged) == 1 and sorted(merged[0].tolist()) == [0, 1, 2, 5]
    k = [i for i, g in enumerate(groups) if len(g) > 1][0]
    ends = sorted([q0[k][0], q1[k][0]])
    assert ends[0] == pytest.approx(0.0, abs=tol) and ends[1] == pytest.approx(8.0, abs=tol)
    singles = sorted(int(g[0]) for g in groups if len(g) == 1)
    assert singles == [3, 4]


def test_trapezoid_matches_quadrature():
    from scipy.integrate import quad

    for length, feed, accel in [(50.0, 600.0, 100.0), (0.3, 600.0, 100.0), (5.0, 3000.0, 20.0)]:
        vmax = feed / 60

        def slowness(x, vmax=vmax, accel=accel, length=length):
            # Fastest speed profile at x: accelerate from rest, cruise, brake to rest.
            return 1.0 / min(vmax, math.sqrt(2 * accel * x), math.sqrt(2 * accel * (length - x)))

        half = length / 2
        want = quad(slowness, 0, half, limit=200)[0] + quad(slowness, half, length, limit=200)[0]
        got = path_times(np.array([[length, 0.0, 0.0]]), feed, (1e9, 1e9, 1e9), (accel, 1, 1))
        assert got[0] == pytest.approx(want, rel=1e-6)
    # Diagonal move: each axis keeps its own limit (speed 10/0.6 mm/s, accel 50/0.8 mm/s^2).
    d = np.array([[3.0, 4.0, 0.0]])
    t = path_times(d, np.inf, (600.0, 300.0, 100.0), (100.0, 50.0, 10.0))[0]
    speed, accel = min(10 / 0.6, 5 / 0.8), min(100 / 0.6, 50 / 0.8)
    assert 5.0 >= speed * speed / accel  # reaches its cruise speed
    assert t == pytest.approx(5.0 / speed + speed / accel)


def board_and_scratches(rng, n=200):
    board = Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0)
    p0, p1 = random_segments(rng, n, half=20.0, lo=0.3, hi=6.0)
    return board, ScratchSet.from_arrays(p0, p1, 0.1, 0.01)


def test_plan_counts_clip_short_and_duplicates(rng):
    board, s = board_and_scratches(rng)
    p0 = np.vstack([s.p0, [[0.0, 0.0], [-30.0, 0.0]]])
    p1 = np.vstack([s.p1, [[0.0, 0.2], [-25.0, 0.0]]])  # one too short, one off the board
    p0 = np.vstack([p0, s.p0[:1]])  # and an exact duplicate of scratch 0
    p1 = np.vstack([p1, s.p1[:1]])
    scratches = ScratchSet.from_arrays(p0, p1, 0.1, 0.01)
    profile = load_profile("grbl-3018-diamond")
    tp = plan_toolpath(scratches, board, profile, ScratchTool())
    st = tp.stats
    assert st["input_count"] == len(scratches)
    assert st["off_board_count"] == 1 and st["outside_count"] == 0  # the board fits
    assert st["short_count"] >= 1 and st["merged_count"] >= 1
    dropped = st["off_board_count"] + st["short_count"] + st["merged_count"]
    assert st["count"] == len(tp) == len(scratches) - dropped
    lengths = np.linalg.norm(tp.strokes[:, 1] - tp.strokes[:, 0], axis=1)
    assert lengths.min() >= profile.tool.min_length_mm
    outline = shapely.Polygon(tp.outline).buffer(1e-9)
    assert all(outline.contains(shapely.Point(q)) for q in tp.strokes.reshape(-1, 2))
    assert st["travel_length_mm"] <= st["travel_input_order_mm"]
    assert st["cut_length_mm"] == pytest.approx(lengths.sum())


def test_plan_refuses_tool_mismatch_and_board_off_machine(rng):
    board, s = board_and_scratches(rng, 20)
    profile = load_profile("grbl-3018-diamond")
    with pytest.raises(ScratchfabError, match="width_mm = 0.3"):
        plan_toolpath(s, board, profile, ScratchTool(width_mm=0.3))
    wide = ScratchSet(s.p0, s.p1, s.width.copy(), s.depth)
    wide.width[7] = 0.2
    with pytest.raises(ScratchfabError, match="scratch 8"):
        plan_toolpath(wide, board, profile)
    table = profile.to_table()
    table["board"]["offset_mm"] = [500.0, 500.0]
    with pytest.raises(ScratchfabError, match="outside the envelope"):
        plan_toolpath(s, board, profile_from_mapping(table, "<far>"))


def test_toolpath_json_round_trip(rng, tmp_path):
    board, s = board_and_scratches(rng)
    tp = plan_toolpath(s, board, load_profile("grbl-plotter-scribe"))
    tp.save(tmp_path / "toolpath.json")
    back = Toolpath.load(tmp_path / "toolpath.json")
    assert np.array_equal(back.strokes, tp.strokes)
    assert np.array_equal(back.source_rows, tp.source_rows)
    assert back.profile == tp.profile and back.stats == tp.stats
    data = json.loads((tmp_path / "toolpath.json").read_text())
    assert data["statistics"]["count"] == len(tp)
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(ScratchfabError, match="bad.json"):
        Toolpath.load(tmp_path / "bad.json")


def make_job(tmp_path: Path, rng, optimize: bool) -> Path:
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from conftest import make_design

    job = tmp_path / "job"
    design = make_design()
    design.save(job / "design" / "design.toml")
    board, s = board_and_scratches(rng, 120)
    s.save(job / "design" / "scratches.csv", design.scratch)
    if optimize:
        s.subset(np.arange(60)).save(job / "optimize" / "scratches.csv", design.scratch)
    return job


def test_cli_toolpath_and_export(rng, tmp_path, capsys):
    job = make_job(tmp_path, rng, optimize=True)
    main(["toolpath", str(job), "--machine", "grbl-3018-diamond"])
    tp = Toolpath.load(job / "toolpath" / "toolpath.json")
    assert tp.stats["input_count"] == 60
    with Image.open(job / "toolpath" / "preview.png") as im:
        assert im.size[0] > 100
    for fmt in ("gcode", "dxf", "svg"):
        main(["export", str(job), "--format", fmt])
        assert (job / "export" / f"board.{fmt}").stat().st_size > 0
    main(["export", str(job), "-o", str(tmp_path / "out.nc")])
    assert (tmp_path / "out.nc").read_text().startswith("G21 G90 G17 G94\n")
    out = capsys.readouterr().out
    assert "strokes" in out and "lines" in out


def test_cli_toolpath_job_inputs_note_and_given_files(rng, tmp_path, capsys):
    job = make_job(tmp_path, rng, optimize=False)
    main(["toolpath", str(job), "--machine", "grbl-3018-diamond"])
    said = capsys.readouterr().out
    assert "optimize has not run" in said and str(job / "design" / "scratches.csv") in said
    assert Toolpath.load(job / "toolpath" / "toolpath.json").stats["input_count"] == 120
    # Given files win: the JOB folder need not hold a design or a layout of its own.
    other = tmp_path / "other"
    other.mkdir()
    given = ["--scratches", str(job / "design" / "scratches.csv")]
    given += ["--design", str(job / "design" / "design.toml")]
    main(["toolpath", str(other), "--machine", "grbl-3018-diamond", *given])
    assert "optimize has not run" in capsys.readouterr().out  # the initial layout still
    assert Toolpath.load(other / "toolpath" / "toolpath.json").stats["input_count"] == 120


def test_cli_toolpath_passes_its_seed_passes_and_kicks_on(rng, tmp_path, monkeypatch):
    import scratchfab.cli.toolpath_cmd as toolpath_cmd

    seen = []
    monkeypatch.setattr(toolpath_cmd, "run_toolpath", lambda *a, **k: seen.append(a[4]))
    job = make_job(tmp_path, rng, optimize=True)
    base = ["toolpath", str(job), "--machine", "grbl-3018-diamond"]
    main([*base, "--seed", "7", "--passes", "3"])
    main([*base, "--kicks", "40"])
    assert seen == [OrderOptions(passes=3, seed=7), OrderOptions(kicks=40)]


@pytest.mark.parametrize(
    ("field", "value"),
    [("neighbours", 0), ("passes", -1), ("kicks", -5), ("seed", -1), ("seed", 2**32), ("depth", 0)],
)
def test_order_options_refuse_values_the_search_cannot_take(field, value):
    with pytest.raises(ValueError, match=field):
        OrderOptions(**{field: value})


@pytest.mark.parametrize(
    ("option", "value"), [("--seed", str(2**40)), ("--kicks", "-1"), ("--passes", "-1")]
)
def test_cli_toolpath_refuses_an_option_out_of_range(rng, tmp_path, capsys, option, value):
    job = make_job(tmp_path, rng, optimize=True)
    with pytest.raises(SystemExit) as exc:
        main(["toolpath", str(job), "--machine", "grbl-3018-diamond", option, value])
    assert exc.value.code == 2
    assert option in capsys.readouterr().err
    assert not (job / "toolpath").exists()


def test_cli_falls_back_to_design_scratches_and_standalone(rng, tmp_path, capsys):
    job = make_job(tmp_path, rng, optimize=False)
    main(["toolpath", str(job), "--machine", "grbl-plotter-scribe"])
    assert "is the design's initial layout, not optimized" in capsys.readouterr().out
    assert Toolpath.load(job / "toolpath" / "toolpath.json").stats["input_count"] == 120
    out = tmp_path / "alone"
    main(
        [
            "toolpath",
            "--machine",
            "grbl-plotter-scribe",
            "--scratches",
            str(job / "design" / "scratches.csv"),
            "--design",
            str(job / "design" / "design.toml"),
            "--out",
            str(out),
        ]
    )
    assert (out / "toolpath.json").is_file() and (out / "preview.png").is_file()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["toolpath", "{job}", "--machine", "nope"], "not a bundled profile"),
        (["toolpath", "--machine", "grbl-3018-diamond"], "give a JOB folder"),
        (["export", "{job}"], "give --format"),
        (["export", "{job}", "-o", "{tmp}/x.pdf"], "unknown file extension"),
        (["export", "{job}", "-f", "dxf", "-o", "{tmp}/x.gcode"], "the extension says gcode"),
        (["export", "{job}", "--format", "gcode"], "run `scratchfab toolpath` first"),
        (["export", "{job}", "-f", "gcode", "-m", "grbl-plotter-scribe"], "board.offset_mm"),
    ],
)
def test_cli_errors_are_one_line(rng, tmp_path, capsys, args, message):
    job = make_job(tmp_path, rng, optimize=True)
    if "-m" in args:
        main(["toolpath", str(job), "--machine", "grbl-3018-diamond"])
    capsys.readouterr()
    argv = [a.format(job=job, tmp=tmp_path) for a in args]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code != 0
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not (job / "export").exists() or not any((job / "export").iterdir())


def test_kicks_undo_through_the_changed_positions_at_scale(rng):
    # 16k strokes in one tour (no regions): a trial's reversals can outgrow the undo log
    # (the full-copy path) too.
    p0, p1 = random_segments(rng, 16_000, half=200.0)
    start = (0.0, 0.0)
    whole = OrderOptions(window=20_000, kicks=0)
    plain = order_strokes(p0, p1, start, whole)
    res = order_strokes(p0, p1, start, replace(whole, kicks=3000, seed=1))
    assert np.array_equal(np.sort(res.order), np.arange(16_000))
    assert res.travel_mm == pytest.approx(naive_travel(p0, p1, res.order, res.reverse, start))
    assert res.travel_mm < plain.travel_mm


def tour_length(points, ent):
    """Travel of an item tour: each item's exit (ent ^ 1) to the next item's entry."""
    return float(np.hypot(*(points[np.roll(ent, -1)] - points[ent ^ 1]).T).sum())


def random_tour(rng, m):
    """A random tour of m items, each entered at a random end."""
    return (rng.permutation(m) * 2 + rng.integers(0, 2, m)).astype(np.int64)


def test_region_stand_ins_keep_the_tour_length_up_to_a_constant(rng):
    # Any tour of a region's strokes and stand-ins expands to a tour of all items whose
    # length is the small tour's plus the same constant (the stand-ins' own runs).
    m = 300
    points = rng.uniform(0, 100, (2 * m, 2))
    ent = random_tour(rng, m)
    centre = 0.5 * (points[0::2] + points[1::2])
    inside = (np.abs(centre[ent >> 1] - 50.0) < 25.0).all(axis=1)
    starts, ends = cut_region(inside)
    w = len(starts)
    assert w > inside.sum()  # some stand-ins
    sub = np.empty((2 * w, 2))
    sub[0::2], sub[1::2] = points[ent[starts]], points[ent[ends] ^ 1]
    same = expand_region(ent, starts, ends, np.arange(0, 2 * w, 2, dtype=np.int64))
    shift = int(np.flatnonzero(same == ent[0])[0])
    assert np.array_equal(np.roll(same, -shift), ent)
    constants = []
    for _ in range(20):
        sub_ent = random_tour(rng, w)
        full = expand_region(ent, starts, ends, sub_ent)
        assert np.array_equal(np.sort(full >> 1), np.arange(m))
        constants.append(tour_length(points, full) - tour_length(sub, sub_ent))
    assert np.ptp(constants) < 1e-9 * tour_length(points, ent)


def best_two_opt_gain(points, ent):
    """Brute force over every flip of a stretch of the tour (2-opt): the largest gain."""
    m = len(ent)
    best = 0.0
    before = tour_length(points, ent)
    for i in range(m):
        for j in range(i + 1, m):
            trial = ent.copy()
            trial[i : j + 1] = trial[i : j + 1][::-1] ^ 1
            best = max(best, before - tour_length(points, trial))
    return best


@pytest.mark.parametrize("depth", [1, 3])
def test_local_optimum_has_no_improving_two_opt_move(rng, depth):
    m = 70
    p0, p1 = random_segments(rng, m)
    points = np.empty((2 * m, 2))
    points[0::2], points[1::2] = p0, p1
    near = np.argsort(np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1)), axis=1)
    near = np.ascontiguousarray(near[:, 1:])  # every other endpoint: the search is exact
    ent = random_tour(rng, m)
    before = tour_length(points, ent)
    improve(points, ent, near, 50, 0, 0, 1e-9, depth, 0)
    assert np.array_equal(np.sort(ent >> 1), np.arange(m))
    assert tour_length(points, ent) < before
    assert best_two_opt_gain(points, ent) < 1e-6


def improved_lengths(rng, m, settled_values, half=150.0):
    """Tour lengths after the local search from one random tour of m items, per ``settled``."""
    p0, p1 = random_segments(rng, m, half=half)
    points = np.empty((2 * m, 2))
    points[0::2], points[1::2] = p0, p1
    near = np.ascontiguousarray(cKDTree(points).query(points, k=11)[1][:, 1:], dtype=np.int64)
    tour = random_tour(rng, m)
    tours = {}
    for settled in settled_values:
        ent = tour.copy()
        improve(points, ent, near, 50, 0, 0, 1e-9, 3, settled)
        assert np.array_equal(np.sort(ent >> 1), np.arange(m))
        tours[settled] = ent
    return {s: tour_length(points, e) for s, e in tours.items()}, tours, tour_length(points, tour)


def test_sweeps_that_find_little_end_the_search_near_the_local_optimum(rng):
    # The early end (a sweep finding under one move per `settled` items) is a prefix of
    # the search to the end (settled 0), so it is longer, by little.
    length, _, start = improved_lengths(rng, 3000, (0, 100))
    assert length[0] < length[100] <= 1.002 * length[0]
    assert length[0] < 0.1 * start


def test_tours_of_up_to_settled_strokes_search_to_the_end(rng):
    # 1000 strokes and the start: 1001 items. Stopping at a sweep that finds one move
    # (settled 999) changes this tour; settled 1000 must not stop there.
    _, tours, _ = improved_lengths(rng, 1001, (0, 999, 1000), half=80.0)
    assert not np.array_equal(tours[999], tours[0])
    assert np.array_equal(tours[1000], tours[0])


def test_longer_flip_chains_give_shorter_local_optima(rng):
    sets = [random_segments(rng, 600) for _ in range(4)]
    totals = {}
    for depth in (1, 3):
        opts = OrderOptions(kicks=0, depth=depth)
        totals[depth] = sum(order_strokes(p0, p1, (0.0, 0.0), opts).travel_mm for p0, p1 in sets)
    assert totals[3] < 0.98 * totals[1]


def test_regions_give_a_valid_improved_tour(rng):
    # 1500 strokes in regions of about 200 (the path large boards take), cheaply.
    p0, p1 = random_segments(rng, 1500, half=80.0)
    start = (-90.0, 0.0)
    opts = OrderOptions(window=200, kicks=20_000)
    res = order_strokes(p0, p1, start, opts)
    assert np.array_equal(np.sort(res.order), np.arange(1500))
    assert res.travel_mm == pytest.approx(naive_travel(p0, p1, res.order, res.reverse, start))
    whole = order_strokes(p0, p1, start, OrderOptions(window=2000, kicks=0))
    assert res.travel_mm < whole.travel_mm
    again = order_strokes(p0, p1, start, opts)
    assert np.array_equal(res.order, again.order) and np.array_equal(res.reverse, again.reverse)


def test_flip_chain_gain_is_the_real_change(rng):
    # Chains are judged on virtual positions; applied for real (where a reversal may take
    # the complement of the arc) they must change the tour by exactly the claimed gain.
    checked = 0
    for trial in range(400):
        m = int(rng.integers(3, 25))
        points = rng.uniform(0, 10, (2 * m, 2))
        if trial % 3 == 0:  # repeated points and zero-length strokes
            points[rng.integers(0, 2 * m, m)] = points[rng.integers(0, 2 * m, m)]
        ent = random_tour(rng, m)
        pos = np.empty(m, dtype=np.int64)
        pos[ent >> 1] = np.arange(m)
        dist = np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1))
        near = np.ascontiguousarray(np.argsort(dist, axis=1, kind="stable")[:, 1:])
        depth = int(rng.integers(1, 6))
        p = int(rng.integers(0, m))
        x0, t1 = int(ent[p] ^ 1), int(ent[(p + 1) % m])
        # A large start gain lets chains run to full depth whatever the geometry.
        bonus = 100.0
        g0 = float(dist[x0, t1]) + bonus
        for f1 in near[x0]:
            if f1 == t1 or f1 == x0:
                continue
            chain = np.empty((depth, 2), dtype=np.int64)
            scratch = np.empty((3, 2 * depth + 2), dtype=np.int64)
            gain, flips = _chain(
                points, ent, pos, near, x0, t1, f1, g0, depth, -1e9, chain, scratch
            )
            if flips == 0:
                continue
            after, after_pos = ent.copy(), pos.copy()
            for k in range(flips):
                _flip(after, after_pos, chain[k, 0], chain[k, 1], np.zeros(2, dtype=np.int64))
            assert np.array_equal(np.sort(after >> 1), np.arange(m))
            assert np.array_equal(after_pos[after >> 1], np.arange(m))
            real = tour_length(points, ent) - tour_length(points, after)
            assert real == pytest.approx(gain - bonus, abs=1e-9)
            checked += 1
    assert checked > 1000


def test_board_partly_off_the_envelope_is_shown_and_warned(rng, tmp_path, capsys):
    import tomli_w

    job = make_job(tmp_path, rng, optimize=True)
    table = load_profile("grbl-3018-diamond").to_table()
    offset = table["board"]["offset_mm"]
    # The envelope's right edge runs through the middle of the 40 mm board.
    table["envelope"]["x_mm"] = [table["envelope"]["x_mm"][0], offset[0] + 20.0]
    table["start_mm"] = [offset[0] - 5.0, offset[1] - 5.0]
    tight = tmp_path / "tight.toml"
    tight.write_text(tomli_w.dumps(table))
    main(["toolpath", str(job), "--machine", str(tight), "--force"])
    tp = Toolpath.load(job / "toolpath" / "toolpath.json")
    lost = tp.stats["outside_count"] + tp.stats["clipped_count"]
    assert lost > 0 and tp.strokes[..., 0].max() <= offset[0] + 20.0
    said = capsys.readouterr().out
    assert f"{tp.stats['outside_count']} of {tp.stats['input_count']} scratches lie outside" in said
    # The envelope's edge is drawn (blue) across the board, between its left and right.
    with Image.open(job / "toolpath" / "preview.png") as im:
        rgb = np.asarray(im.convert("RGB")).astype(int)
    blue = (rgb[..., 2] > 180) & (rgb[..., 0] < 100) & (rgb[..., 1] < 130)
    cols = np.flatnonzero(blue.sum(axis=0) > 0.3 * rgb.shape[0])
    assert len(cols) and 0.3 * rgb.shape[1] < cols.mean() < 0.7 * rgb.shape[1]
    main(["export", str(job), "--format", "gcode"])
    assert f"{tp.stats['outside_count']} of 60 scratches lie outside" in capsys.readouterr().err


def _preview_case(rng, start_offset, envelope_cut=None):
    from scratchfab.toolpath.plan import preview_figure

    board, s = board_and_scratches(rng, 80)
    table = load_profile("grbl-3018-diamond").to_table()
    offset = table["board"]["offset_mm"]
    table["start_mm"] = [offset[0] + start_offset[0], offset[1] + start_offset[1]]
    if envelope_cut is not None:
        table["envelope"]["x_mm"] = [table["envelope"]["x_mm"][0], offset[0] + envelope_cut]
    tp = plan_toolpath(s, board, profile_from_mapping(table, "t"), ScratchTool())
    fig = preview_figure(tp, max_px=500)
    return tp, fig, np.asarray(fig.image.convert("RGB")).astype(int)


def _mask(rgb, color):
    return np.all(rgb == np.array(color), axis=-1)


def test_preview_start_ring_sits_at_the_start_and_the_key_matches_the_colours(rng):
    from scratchfab.toolpath import plan

    tp, fig, full = _preview_case(rng, (-3.0, -4.0), envelope_cut=30.0)
    assert fig.start_inside
    # The plot: left of the key, below the title band (the key starts a margin down).
    m = plan.PREVIEW_MARGIN_PX
    top, left = fig.legend_box[1] - m, fig.legend_box[0] - m
    rgb = full[top:, :left]
    # Map mm to pixels from the drawn board outline alone: its grey pixels span the
    # outline's corners (2 px wide lines, centred on the corners).
    ys, xs = np.nonzero(_mask(rgb, plan.BOARD_RGB))
    (x0, y0), (x1, y1) = tp.outline.min(axis=0), tp.outline.max(axis=0)
    sx = (xs.max() - xs.min()) / (x1 - x0)
    sy = (ys.max() - ys.min()) / (y1 - y0)
    assert sx == pytest.approx(sy, rel=0.02)
    want = np.array([xs.min() + (tp.start[0] - x0) * sx, ys.max() - (tp.start[1] - y0) * sy])
    ry, rx = np.nonzero(_mask(rgb, plan.START_RGB))
    assert np.abs(np.array([rx.mean(), ry.mean()]) - want).max() < 2.0
    # The whole ring is in the picture, clear of its border.
    assert rx.min() > 2 and ry.min() > 2 and ry.max() < rgb.shape[0] - 3
    # The envelope's right edge (30 mm into the board) is drawn where it belongs.
    blue = _mask(rgb, plan.ENVELOPE_RGB)
    cols = np.flatnonzero(blue.sum(axis=0) > 0.5 * rgb.shape[0])
    assert len(cols) and np.abs(cols - (xs.min() + 30.0 * sx)).max() < 2.0
    # Every colour drawn in the plot is in the key, and every key colour is drawn.
    drawn = {tuple(c) for c in np.unique(rgb.reshape(-1, 3), axis=0)} - {(255, 255, 255)}
    keyed = {it.color for it in fig.legend}
    assert drawn == keyed
    box = fig.legend_box
    key = full[box[1] : box[3] + 1, box[0] : box[2] + 1]
    for color in keyed:
        assert _mask(key, color).any(), color


def test_preview_travel_to_a_far_start_ends_in_arrows_at_the_frame(rng):
    from scratchfab.toolpath import plan

    tp, fig, full = _preview_case(rng, (200.0, 120.0))
    assert not fig.start_inside
    m = plan.PREVIEW_MARGIN_PX
    top, left = fig.legend_box[1] - m, fig.legend_box[0] - m
    travel = _mask(full[top:, :left], plan.TRAVEL_RGB)
    # The start lies up and to the right: the two legs toward it stop in arrows on the
    # drawn extent's top or right edge, a margin inside the plot's border.
    ys, xs = np.nonzero(travel)
    h, w = travel.shape
    assert xs.max() < w - m + 3 and ys.min() > m - 3
    assert xs.max() > w - m - 3 or ys.min() < m + 3
    # Beyond the strokes' own reach there are only the two arrows (and their label).
    beyond = int(fig.to_px(tp.strokes.reshape(-1, 2))[:, 0].max()) + 2
    assert travel[:, beyond:].sum() > 20
    assert any(it.kind == "arrow" and it.color == plan.TRAVEL_RGB for it in fig.legend)
    assert not any(it.kind == "ring" for it in fig.legend)
    assert not _mask(full, plan.START_RGB).any()


@pytest.mark.parametrize("rotation", [0, 90, 180, 270])
def test_the_board_top_is_marked_in_the_preview_and_the_gcode(rng, rotation):
    """A board turned on the bed cuts the same; the preview and G-code say which edge is up."""
    from scratchfab.export.gcode import gcode_lines
    from scratchfab.toolpath import plan

    board, s = board_and_scratches(rng, 40)
    table = load_profile("grbl-3018-diamond").to_table()
    table["board"]["rotation_deg"] = rotation
    tp = plan_toolpath(s, board, profile_from_mapping(table, "t"), ScratchTool())
    # Where the design's +y goes, from the outline alone: the edge whose corners came from
    # the board's two top corners (the outline is the board's corners, mapped).
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * 0.5 * np.array(tp.board_mm)
    mapped = tp.profile.board_to_machine(corners, tp.board_mm)
    top_mid = mapped[2:].mean(axis=0)
    outward = top_mid - mapped.mean(axis=0)
    axis = int(np.argmax(np.abs(outward)))
    name = ("+" if outward[axis] > 0 else "-") + "XY"[axis]
    assert f"(board top edge, design +y, faces machine {name})" in gcode_lines(tp)
    fig = plan.preview_figure(tp, max_px=500)
    rgb = np.asarray(fig.image.convert("RGB")).astype(int)
    ys, xs = np.nonzero(_mask(rgb, plan.TOP_RGB))
    key = fig.legend_box
    inside = ~((xs >= key[0]) & (xs <= key[2]) & (ys >= key[1]) & (ys <= key[3]))
    marked = np.array([xs[inside].mean(), ys[inside].mean()])
    (mid_px,) = fig.to_px(top_mid[None, :])
    (centre_px,) = fig.to_px(mapped.mean(axis=0)[None, :])
    away = (marked - mid_px) @ (mid_px - centre_px) / np.linalg.norm(mid_px - centre_px)
    assert 10 < away < 80  # beyond the top edge, near it
    assert (
        np.linalg.norm(
            marked - mid_px - away * (mid_px - centre_px) / np.linalg.norm(mid_px - centre_px)
        )
        < 40
    )  # at the edge's middle


def test_a_board_larger_than_the_travel_is_said_to_fit_no_offset(rng, tmp_path, capsys):
    """A 40 mm board on a machine with 30 mm of Y travel: moving it cannot help, and the
    warning says so with both spans, instead of "check offset_mm and [envelope]"."""
    import tomli_w

    job = make_job(tmp_path, rng, optimize=True)
    table = load_profile("grbl-3018-diamond").to_table()
    offset = table["board"]["offset_mm"]
    table["envelope"]["y_mm"] = [offset[1] - 5.0, offset[1] + 25.0]
    table["start_mm"] = [offset[0] - 5.0, offset[1] - 5.0]
    short = tmp_path / "short.toml"
    short.write_text(tomli_w.dumps(table))
    main(["toolpath", str(job), "--machine", str(short), "--force"])
    said = capsys.readouterr().out
    assert "board spans 40 mm in Y (the design's [board] height_mm)" in said
    assert "Y travel is 30 mm: no offset_mm in the profile's [board] can fit it" in said
    assert "in X" not in said and "rotation_deg" not in said  # 40 mm fits neither way
    assert "check the profile's" not in said


@pytest.mark.parametrize(
    ("size", "rotation", "said"),
    [
        ((30.0, 30.0), 0, None),
        ((300.0, 180.0), 0, None),  # exactly the 3018's travel
        ((200.0, 200.0), 0, ["200 mm in Y (the design's [board] height_mm)", "travel is 180"]),
        ((100.0, 200.0), 0, ["200 mm in Y", "rotation_deg = 90 with offset_mm = ["]),
        ((100.0, 200.0), 90, None),  # turned, its 200 mm lie along X's 300 mm
        ((250.0, 170.0), 90, ["250 mm in Y (the design's [board] width_mm)", "rotation_deg = 180"]),
        ((400.0, 200.0), 0, ["400 mm in X", "and the board spans 200 mm in Y"]),
    ],
)
def test_oversize_text_names_the_axis_the_key_and_a_turn_that_fits(size, rotation, said):
    from scratchfab.toolpath.plan import oversize_text

    table = load_profile("grbl-3018-diamond").to_table()  # travel X 300, Y 180 mm
    table["board"]["rotation_deg"] = rotation
    text = oversize_text(profile_from_mapping(table, "<p>"), size)
    if said is None:
        assert text is None
    else:
        assert text is not None and all(part in text for part in said), text
        assert ("rotation_deg" in text) is any("rotation_deg" in part for part in said)
