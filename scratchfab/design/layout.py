"""The initial scratch layout: blue-noise scratches that already show each target.

Each view gets a share of ``scratch.count`` proportional to its target's energy on the
board. Scratch centres are importance-sampled from the target's brightness (as the
board shows it to that view) and thinned to blue noise by weighted sample elimination
(Yuksel, "Sample Elimination for Generating Poisson Disk Sample Sets", 2015) with a
radius that follows the local density. Each scratch is turned so that its profile's
normals contain the view's half-vector at its centre (across-direction parallel to
h_xy, see :mod:`scratchfab.design.feasibility`).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Mapping
from dataclasses import replace

import numpy as np
from scipy import ndimage, sparse
from scipy.spatial import cKDTree

from scratchfab.console import Say
from scratchfab.design.feasibility import (
    across_directions,
    board_points,
    half_vectors,
    lobe_deg,
    tilt_deg,
)
from scratchfab.design.targets import bilinear, sample_board
from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.model.camera import Camera
from scratchfab.model.design import Board, Design, View
from scratchfab.model.scratches import ScratchSet
from scratchfab.render.profile import steepest_wall_deg

#: Candidates drawn per kept scratch before elimination.
CANDIDATES_PER_SAMPLE = 4
#: Exponent of the elimination weight (1 - d / 2r)^alpha (Yuksel 2015 uses 8).
ELIMINATION_ALPHA = 8.0
#: Density grid points along the board's long side.
DENSITY_GRID = 256
#: Grid points :func:`expected_length` draws strokes at, a batch.
EXPECTED_CHUNK = 8192
#: A view laying at least this many scratches gets a line of its own before it starts
#: (100000 take about 12 s on one core).
PROGRESS_COUNT = 20_000
#: Half-cell steps :func:`_bright_run` tests at once before dropping finished centres.
_RUN_CHUNK = 8


def sample_view_target(target: np.ndarray, view: View, points: np.ndarray) -> np.ndarray:
    """Brightness the view's target asks for at board points (..., 2), bilinear; 0 off the image."""
    camera = Camera.from_view(view)
    p3 = np.concatenate([points, np.zeros(points.shape[:-1] + (1,))], axis=-1)
    st, in_front = camera.project(p3)
    img = np.where(np.isfinite(target), target, 0.0)
    H, W = img.shape
    u = st[..., 0] - 0.5
    v = st[..., 1] - 0.5
    inside = (
        in_front & (st[..., 0] >= 0) & (st[..., 0] <= W) & (st[..., 1] >= 0) & (st[..., 1] <= H)
    )
    return np.where(inside, bilinear(img, u, v), 0.0)


def split_count(total: int, weights: np.ndarray) -> np.ndarray:
    """Integers proportional to ``weights`` that sum to ``total`` (largest remainder)."""
    w = np.asarray(weights, dtype=np.float64)
    if w.sum() <= 0:
        w = np.ones_like(w)
    share = total * w / w.sum()
    counts = np.floor(share).astype(np.int64)
    rest = total - int(counts.sum())
    order = np.argsort(-(share - counts), kind="stable")
    counts[order[:rest]] += 1
    return counts


def eliminate(points: np.ndarray, radius: np.ndarray, keep: int) -> np.ndarray:
    """Weighted sample elimination down to ``keep`` points (indices of the kept ones).

    Args:
        points: (M, 2) candidates.
        radius: (M,) local Poisson-disk radius of each candidate.
        keep: How many to keep.

    Returns:
        Sorted indices of the kept candidates.
    """
    m = len(points)
    if keep >= m:
        return np.arange(m)
    tree = cKDTree(points)
    neighbours = tree.query_ball_point(points, 2.0 * radius)
    lengths = np.fromiter((len(n) for n in neighbours), dtype=np.int64, count=m)
    rows = np.repeat(np.arange(m), lengths)
    cols = np.fromiter((j for n in neighbours for j in n), dtype=np.int64, count=int(lengths.sum()))
    off = rows != cols
    rows, cols = rows[off], cols[off]
    dist = np.linalg.norm(points[rows] - points[cols], axis=1)
    w = (1.0 - dist / (2.0 * radius[rows])) ** ELIMINATION_ALPHA
    # weight[i] = sum over neighbours j of w_ij; removing j lowers every i that counts j.
    by_removed = sparse.csr_matrix((w, (cols, rows)), shape=(m, m))
    # Plain Python lists and floats: the loop below is scalar work, where numpy scalars
    # would make every heap comparison slow.
    weight: list[float] = np.bincount(rows, weights=w, minlength=m).tolist()
    indptr: list[int] = by_removed.indptr.tolist()
    indices: list[int] = by_removed.indices.tolist()
    data: list[float] = by_removed.data.tolist()
    alive = [True] * m
    # One entry per live candidate, keyed (-weight, index) as the weight was when it was
    # pushed. Weights only fall, so a stored key never ranks a candidate lower than its
    # weight now: an entry on top whose key is current is the heaviest candidate (ties:
    # the lowest index), and one that is not is pushed back with its weight now. Each
    # removal then costs one pop plus the few stale entries that reach the top, instead
    # of a push per neighbour on a heap that grows to millions of stale entries.
    heap = [(-weight[i], i) for i in range(m)]
    heapq.heapify(heap)
    pop, replace_top = heapq.heappop, heapq.heapreplace
    remaining = m
    while remaining > keep:
        neg, j = heap[0]
        if -neg != weight[j]:
            replace_top(heap, (-weight[j], j))
            continue
        pop(heap)
        alive[j] = False
        remaining -= 1
        for k in range(indptr[j], indptr[j + 1]):
            i = indices[k]
            if alive[i]:
                weight[i] -= data[k]
    return np.flatnonzero(np.asarray(alive))


def _length_of(brightness: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Scratch length for a relative brightness in [0, 1]: brighter places get longer strokes."""
    return lo + (hi - lo) * np.clip(brightness, 0.0, 1.0)


def _room(centre: np.ndarray, direction: np.ndarray, box: tuple[float, float]) -> np.ndarray:
    """How far each centre can go along ``direction`` before leaving |x| <= X, |y| <= Y."""
    room = np.full(len(centre), np.inf)
    for axis, bound in enumerate(box):
        d = direction[:, axis]
        gap = np.where(d > 0, bound - centre[:, axis], bound + centre[:, axis])
        with np.errstate(divide="ignore", invalid="ignore"):
            room = np.minimum(room, np.where(np.abs(d) > 1e-12, gap / np.abs(d), np.inf))
    return np.maximum(room - 1e-9, 0.0)


def _bright_run(
    grid: np.ndarray, board: Board, centre: np.ndarray, direction: np.ndarray, limit: np.ndarray
) -> np.ndarray:
    """Distance from each centre along ``direction`` while the grid stays at least half as bright.

    Steps of half a cell are walked in chunks; a centre stops once it meets a dark cell or
    passes its ``limit``, which caps the result.
    """
    rows, cols = grid.shape
    hw, hh = board.half_extent
    step = 0.5 * min(board.width_mm / cols, board.height_mm / rows)
    steps = np.arange(1, int(np.ceil(limit.max() / step)) + 2) * step
    c0 = np.clip(((centre[:, 0] + hw) / board.width_mm * cols).astype(np.intp), 0, cols - 1)
    r0 = np.clip(((hh - centre[:, 1]) / board.height_mm * rows).astype(np.intp), 0, rows - 1)
    flat = grid.ravel()
    half_bright = 0.5 * flat[r0 * cols + c0]
    run = np.array(limit, dtype=float)
    # only centres with a dark cell within reach (a step past the longest limit) walk
    reach = limit.max() + step
    size = [
        2 * (int(np.ceil(reach / (board.height_mm / rows))) + 2) + 1,
        2 * (int(np.ceil(reach / (board.width_mm / cols))) + 2) + 1,
    ]
    darkest = ndimage.minimum_filter(grid, size=size, mode="nearest").ravel()
    todo = np.flatnonzero((limit > 0) & (darkest[r0 * cols + c0] < half_bright))
    for start in range(0, len(steps), _RUN_CHUNK):
        if todo.size == 0:
            break
        chunk = steps[start : start + _RUN_CHUNK]
        x = centre[todo, 0, None] + chunk * direction[todo, 0, None]
        y = centre[todo, 1, None] + chunk * direction[todo, 1, None]
        c = np.clip(((x + hw) / board.width_mm * cols).astype(np.intp), 0, cols - 1)
        r = np.clip(((hh - y) / board.height_mm * rows).astype(np.intp), 0, rows - 1)
        dark = flat[r * cols + c] < half_bright[todo, None]
        hit = dark.any(axis=1)
        first = start + dark.argmax(axis=1)[hit]
        bright = np.where(first > 0, steps[np.maximum(first - 1, 0)], 0.0)
        run[todo[hit]] = np.minimum(bright, limit[todo[hit]])
        todo = todo[~hit & (chunk[-1] < limit[todo])]
    return run


def check_targets(design: Design, targets: Mapping[str, np.ndarray]) -> None:
    """Refuse targets that name none of the design's views or do not fit their view.

    Raises:
        ScratchfabError: Naming the views expected, or the view and both sizes (W x H).
    """
    views = [v for v in design.views if v.name in targets]
    if not views:
        raise ScratchfabError(
            f"{design.source}: the targets name none of the views "
            f"({', '.join(v.name for v in design.views)}); got {', '.join(map(str, targets))}"
        )
    for view in views:
        shape = np.shape(targets[view.name])
        if shape != (view.height, view.width):
            size = "x".join(map(str, shape[::-1])) if len(shape) == 2 else f"shape {shape}"
            raise ScratchfabError(
                f"target of view '{view.name}' is {size}, the view is "
                f"{view.width}x{view.height} pixels (a target is in the view's camera pixels, "
                "see scratchfab.design.targets.warp_to_view)"
            )


def view_densities(
    design: Design, targets: Mapping[str, np.ndarray]
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Board grid points and, per view, the brightness to show there (0 where unreachable).

    Only points whose centre region leaves room for a ``min_length_mm`` scratch inside
    the margin in every direction count, so every sampled centre can take a scratch.

    Raises:
        ScratchfabError: As :func:`check_targets`.
    """
    check_targets(design, targets)
    return _densities(
        design, list(targets), lambda view, pts: sample_view_target(targets[view.name], view, pts)
    )


def board_densities(
    design: Design, boards: Mapping[str, np.ndarray]
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """As :func:`view_densities` from board-space images, before they are warped to the views.

    Args:
        design: The resolved design.
        boards: View name -> its target as a board-space image
            (:func:`scratchfab.design.targets.board_image`).
    """
    return _densities(
        design, list(boards), lambda view, pts: sample_board(boards[view.name], design.board, pts)
    )


def _densities(
    design: Design, names: list[str], sample: Callable[[View, np.ndarray], np.ndarray]
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Board grid points and the brightness ``sample(view, points)`` of the views named."""
    pts = board_points(design.board, DENSITY_GRID)
    usable = np.all(np.abs(pts) <= _inner_box(design), axis=-1)
    reach = steepest_wall_deg(design.scratch.width_mm, design.scratch.depth_mm) + lobe_deg(
        design.board.roughness
    )
    out: dict[str, np.ndarray] = {}
    for view in design.views:
        if view.name not in names:
            continue
        b = sample(view, pts)
        lit = tilt_deg(half_vectors(design, view, pts)) <= reach
        out[view.name] = np.where(usable & lit, np.clip(b, 0.0, None), 0.0)
    return pts, out


def initial_layout(
    design: Design,
    targets: Mapping[str, np.ndarray],
    seed: int,
    progress: Say = lambda _: None,
) -> ScratchSet:
    """Place exactly ``design.scratch.count`` scratches that show each target in its view.

    Args:
        design: The resolved design.
        targets: View name -> (H, W) target in that view's camera pixels (NaN off the
            board), as :func:`scratchfab.design.targets.view_targets` returns.
        seed: Seed of the random generator.
        progress: Called with a line before each view that lays many scratches.

    Returns:
        The layout (the views' scratches one after the other, see
        :func:`layout_by_view`); all lie inside ``board.margin_mm`` with lengths in
        ``[min_length_mm, max_length_mm]``.

    Raises:
        ScratchfabError: The targets name none of the views or one is not (H, W) of its
            view (:func:`check_targets`); ``min_length_mm`` does not fit the margin.
    """
    parts = list(layout_by_view(design, targets, seed, progress).values())
    return ScratchSet(
        np.concatenate([p.p0 for p in parts]),
        np.concatenate([p.p1 for p in parts]),
        np.concatenate([p.width for p in parts]),
        np.concatenate([p.depth for p in parts]),
    )


def layout_by_view(
    design: Design,
    targets: Mapping[str, np.ndarray],
    seed: int,
    progress: Say = lambda _: None,
) -> dict[str, ScratchSet]:
    """The initial layout split by the view each scratch is turned for.

    Args:
        design: The resolved design.
        targets: View name -> (H, W) target in that view's camera pixels (NaN off the
            board), as :func:`scratchfab.design.targets.view_targets` returns.
        seed: Seed of the random generator.
        progress: Called with a line before each view that lays at least
            :data:`PROGRESS_COUNT` scratches.

    Returns:
        View name -> its scratches (possibly none); ``count`` scratches in all.
    """
    if seed is None:  # numpy would draw fresh entropy: another layout each run
        raise ValueError("seed: expected a whole number (the same seed lays the same layout)")
    rng = np.random.default_rng(seed)
    tool = design.scratch
    hw, hh = design.board.half_extent
    if min(hw, hh) - design.board.margin_mm <= tool.min_length_mm / 2:
        raise ConfigError(
            f"{design.source}: scratch.min_length_mm ({tool.min_length_mm:g}) does not fit "
            f"inside the board's margin ({design.board.margin_mm:g} mm)"
        )
    pts, dens = view_densities(design, targets)
    dens, counts = _shares(design, pts, dens)
    inner = _inner_box(design)
    rows, cols = pts.shape[:2]
    cell = np.array([design.board.width_mm / cols, design.board.height_mm / rows])
    cell_area = float(cell[0] * cell[1])
    out: dict[str, ScratchSet] = {}
    for name, n in counts.items():
        if n == 0:
            out[name] = ScratchSet.from_arrays(
                np.zeros((0, 2)), np.zeros((0, 2)), tool.width_mm, tool.depth_mm
            )
            continue
        view = design.view(name)
        rel, q = _centre_weights(dens[name].ravel(), design)
        prob = q / q.sum()
        m = CANDIDATES_PER_SAMPLE * int(n)
        if n >= PROGRESS_COUNT:
            progress(f"  laying {n} scratches for '{name}' (thinning {m} candidates) ...")
        idx = rng.choice(len(prob), size=m, p=prob)
        cand = pts.reshape(-1, 2)[idx] + (rng.random((m, 2)) - 0.5) * cell
        cand = np.clip(cand, -inner, inner)
        # Local point density n * prob / cell_area -> Poisson-disk radius (Yuksel's r_max).
        local = n * prob[idx] / cell_area
        radius = np.sqrt(1.0 / (2.0 * math.sqrt(3.0) * local))
        kept = eliminate(cand, radius, int(n))
        p0, p1 = _strokes(design, view, dens[name], cand[kept], rel[idx[kept]])
        out[name] = ScratchSet.from_arrays(p0, p1, tool.width_mm, tool.depth_mm)
    return out


def _strokes(
    design: Design, view: View, grid: np.ndarray, centre: np.ndarray, rel: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The ends of scratches for ``view`` at ``centre`` of relative brightness ``rel``.

    Each is turned so that its profile's normals contain the view's half-vector. Each end
    runs up to half the length, stops where the density ``grid`` turns dark (so strokes
    do not bleed past edges), but never makes the scratch shorter than min_length;
    centres lie min_length/2 inside the margin, so that always fits.
    """
    tool = design.scratch
    hw, hh = design.board.half_extent
    box = (hw - design.board.margin_mm, hh - design.board.margin_mm)
    across = across_directions(half_vectors(design, view, centre))
    along = np.stack([-across[:, 1], across[:, 0]], axis=1)
    half = _length_of(rel, tool.min_length_mm, tool.max_length_mm) / 2
    ends = []
    for sign in (-1.0, 1.0):
        room = _room(centre, sign * along, box)
        run = _bright_run(grid, design.board, centre, sign * along, np.minimum(half, room))
        ends.append(np.minimum(room, np.maximum(tool.min_length_mm / 2, np.minimum(half, run))))
    return centre - ends[0][:, None] * along, centre + ends[1][:, None] * along


def _inner_box(design: Design) -> np.ndarray:
    """Half extents (x, y) of the box scratch centres keep to: min_length_mm / 2 inside the margin."""
    hw, hh = design.board.half_extent
    inset = design.board.margin_mm + design.scratch.min_length_mm / 2
    return np.array([hw - inset, hh - inset])


def _shares(
    design: Design, pts: np.ndarray, dens: dict[str, np.ndarray]
) -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """Each view's centre density and scratch count (shares of ``count`` by the energy).

    With nothing bright anywhere, the density is flat over the box of :func:`_inner_box`.
    """
    names = list(dens)
    energy = np.array([dens[n].sum() for n in names])
    if energy.sum() <= 0:
        flat = np.all(np.abs(pts) <= _inner_box(design), axis=-1).astype(float)
        dens = {n: flat for n in names}
        energy = np.ones(len(names))
    counts = split_count(design.scratch.count, energy)
    return dens, {n: int(c) for n, c in zip(names, counts, strict=True)}


def _centre_weights(b: np.ndarray, design: Design) -> tuple[np.ndarray, np.ndarray]:
    """Relative brightness and centre weight at grid points of brightness ``b`` (some > 0).

    Centre density proportional to brightness / length: the lit area per board area
    (scratch count x length x width) then follows the target's brightness.
    """
    tool = design.scratch
    rel = b / b.max()
    length = _length_of(rel, tool.min_length_mm, tool.max_length_mm)
    return rel, np.where(b > 0, rel / length, 0.0)


def expected_length(design: Design, pts: np.ndarray, dens: dict[str, np.ndarray]) -> float:
    """The total length (mm) :func:`layout_by_view` draws, expected, from the densities.

    The layout draws a view's centres with probability proportional to
    :func:`_centre_weights` (before the jitter within a grid cell and the thinning to
    blue noise) and gives each the stroke :func:`_strokes` draws there, so the mean
    length of a view's scratches is that of the strokes at the grid points, weighed so.

    Args:
        design: The resolved design.
        pts: The density grid (:func:`view_densities` or :func:`board_densities`).
        dens: View name -> density on that grid.
    """
    return length_by_count(design, pts, dens)(design.scratch.count)


def length_by_count(
    design: Design, pts: np.ndarray, dens: dict[str, np.ndarray]
) -> Callable[[int], float]:
    """:func:`expected_length` as a function of ``[scratch] count``.

    The count only shares the scratches among the views; each view's strokes are drawn
    once, the first time a count gives it scratches.
    """
    tool = design.scratch
    inner = _inner_box(design)
    drawn: dict[str, tuple[float, float]] = {}

    def view_drawn(name: str, grid: np.ndarray) -> tuple[float, float]:
        """The view's weighed sum of stroke lengths over the grid, and the weights' sum."""
        rel, q = _centre_weights(grid.ravel(), design)
        at = np.flatnonzero(q > 0)
        total = 0.0
        for part in np.array_split(at, -(-len(at) // EXPECTED_CHUNK)):
            centre = np.clip(pts.reshape(-1, 2)[part], -inner, inner)
            p0, p1 = _strokes(design, design.view(name), grid, centre, rel[part])
            total += float(q[part] @ np.linalg.norm(p1 - p0, axis=1))
        return total, float(q[at].sum())

    def length(count: int) -> float:
        shared, counts = _shares(replace(design, scratch=replace(tool, count=count)), pts, dens)
        total = 0.0
        for name, n in counts.items():
            if n == 0:
                continue
            if name not in drawn:
                drawn[name] = view_drawn(name, shared[name])
            lengths, weight = drawn[name]
            total += n * lengths / weight
        return total

    return length


def longest_for_length(
    design: Design, pts: np.ndarray, dens: dict[str, np.ndarray], total_mm: float
) -> float | None:
    """The largest ``max_length_mm`` (in 0.1 mm) whose :func:`expected_length` keeps to ``total_mm``.

    None when even ``max_length_mm = min_length_mm`` exceeds it (the count must fall).
    """
    tool = design.scratch

    def total(longest: float) -> float:
        tried = replace(design, scratch=replace(tool, max_length_mm=longest))
        return expected_length(tried, pts, dens)

    # candidates min_length_mm, then whole tenths of a millimetre up to max_length_mm
    tenths = np.arange(
        math.floor(tool.min_length_mm * 10) + 1, math.floor(tool.max_length_mm * 10) + 1
    )
    candidates = [tool.min_length_mm, *(float(t) / 10 for t in tenths)]
    if total(candidates[0]) > total_mm:
        return None
    lo, hi = 0, len(candidates)  # candidates[lo] fits; the first that does not is <= hi
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if total(candidates[mid]) <= total_mm else (lo, mid)
    return candidates[lo]
