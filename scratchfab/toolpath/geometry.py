"""Stroke clean-up in machine coordinates: clip, drop the too short, merge duplicates."""

from __future__ import annotations

import numpy as np
import shapely

from scratchfab.segments import sample_along

# scipy (~0.2 s to import) is imported in merge_collinear, the one function that uses it:
# importing the toolpath package (the CLI's help, the exporters) does not need it.


def onto_box(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, slack: float) -> np.ndarray:
    """(N, 2) ``points`` with each coordinate at most ``slack`` beyond the box moved onto its edge.

    The box is [lo, hi] per axis. Coordinates inside it, or further out (for clipping to
    cut), stay as they are.
    """
    p = np.asarray(points, dtype=np.float64)
    p = np.where((p < lo) & (p >= lo - slack), lo, p)
    return np.where((p > hi) & (p <= hi + slack), hi, p)


def clip_strokes(
    p0: np.ndarray, p1: np.ndarray, region: shapely.Polygon
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clip segments to a convex polygon (shapely, vectorised).

    Args:
        p0: (N, 2) segment starts (machine XY, mm).
        p1: (N, 2) segment ends (machine XY, mm).
        region: A convex polygon in the same frame (the board within the envelope).

    Returns:
        (keep, q0, q1): indices of the segments that keep a piece of positive length, and
        that piece's ends, in the segment's own direction.
    """
    n = len(p0)
    if n == 0:
        empty = np.empty((0, 2))
        return np.empty(0, dtype=np.int64), empty, empty
    lines = shapely.linestrings(np.stack([p0, p1], axis=1))
    pieces = shapely.intersection(lines, region)
    is_line = shapely.get_type_id(pieces) == 1
    is_line &= ~shapely.is_empty(pieces)
    keep = np.flatnonzero(is_line)
    if len(keep) == 0:
        empty = np.empty((0, 2))
        return keep, empty, empty
    coords = shapely.get_coordinates(pieces[keep])
    counts = shapely.get_num_coordinates(pieces[keep])
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    q0 = coords[first]
    q1 = coords[first + counts - 1]
    # Shapely may return the piece reversed; restore the segment's direction.
    d = p1[keep] - p0[keep]
    flipped = np.einsum("ij,ij->i", q1 - q0, d) < 0
    q0, q1 = np.where(flipped[:, None], q1, q0), np.where(flipped[:, None], q0, q1)
    positive = np.hypot(*(q1 - q0).T) > 0
    return keep[positive], q0[positive], q1[positive]


def merge_collinear(
    p0: np.ndarray, p1: np.ndarray, tolerance: float
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Merge segments that lie on one line (within ``tolerance``) and overlap or touch.

    Two segments are duplicates when every endpoint of each lies within ``tolerance`` of
    the other's line and their extents along it overlap (or meet within ``tolerance``).
    Duplicates chain into groups; each group becomes one segment along its longest
    member's line, covering the union of the members' extents.

    Returns:
        (q0, q1, groups): the merged segments and, for each, the input indices it covers.
        Segments without duplicates come back unchanged, in input order, before the
        merged ones.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(p0)
    if n < 2:
        return p0.copy(), p1.copy(), [np.array([i]) for i in range(n)]
    d = p1 - p0
    length = np.hypot(*d.T)
    theta = np.mod(np.arctan2(d[:, 1], d[:, 0]), np.pi)
    u = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    i, j = _candidate_pairs(p0, p1, u, tolerance)
    ok = _collinear_overlap(p0, p1, u, i, j, tolerance)
    i, j = i[ok], j[ok]
    if len(i) == 0:
        return p0.copy(), p1.copy(), [np.array([k]) for k in range(n)]
    graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    sizes = np.bincount(label)
    single = sizes[label] == 1
    out0 = [p0[single]]
    out1 = [p1[single]]
    groups = [np.array([k]) for k in np.flatnonzero(single)]
    multi = np.flatnonzero(~single)
    order = multi[np.argsort(label[multi], kind="stable")]
    bounds = np.flatnonzero(np.diff(label[order])) + 1
    for members in np.split(order, bounds):
        ref = members[np.argmax(length[members])]
        base, axis = p0[ref], u[ref]
        t = np.concatenate([(p0[members] - base) @ axis, (p1[members] - base) @ axis])
        out0.append((base + t.min() * axis)[None, :])
        out1.append((base + t.max() * axis)[None, :])
        groups.append(members)
    return np.vstack(out0), np.vstack(out1), groups


def _candidate_pairs(
    p0: np.ndarray, p1: np.ndarray, u: np.ndarray, tolerance: float, step: float = 4.0
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i < j) that may be duplicates: a superset, from points sampled along each.

    Of two duplicates, one has an endpoint within ``tolerance`` of the other's line and at
    most ``tolerance`` past its extent, so within ``r`` of one of the other's points
    sampled at most ``step`` apart (ends included); and their directions differ by at
    most asin(2 tolerance / length) for either length. Endpoints and samples carry their
    direction doubled (a stroke and its reverse are one line), scaled so that the
    largest such difference spans ``r`` too; the endpoints within ``sqrt(2) r`` of each
    sample are the candidates.
    """
    from scipy.spatial import cKDTree

    n = len(p0)
    length = np.hypot(*(p1 - p0).T)
    at, seg = sample_along(p0, p1, step)
    r = float(np.hypot(tolerance, max(0.5 * step, tolerance)))
    chord = 2.0 * min(1.0, 2.0 * tolerance / max(float(length.min()), 1e-12))
    turn = (r / chord) * np.stack([u[:, 0] ** 2 - u[:, 1] ** 2, 2.0 * u[:, 0] * u[:, 1]], 1)
    samples = np.hstack([at, turn[seg]])
    ends = np.vstack([np.hstack([p0, turn]), np.hstack([p1, turn])])
    near = cKDTree(samples).sparse_distance_matrix(
        cKDTree(ends), np.sqrt(2.0) * r * (1.0 + 1e-9), output_type="ndarray"
    )
    i, j = seg[near["i"]], near["j"] % n
    i, j = np.minimum(i, j), np.maximum(i, j)
    key = np.unique(i[i != j] * n + j[i != j])
    return key // n, key % n


def _collinear_overlap(
    p0: np.ndarray,
    p1: np.ndarray,
    u: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
    tolerance: float,
) -> np.ndarray:
    """Mask of pairs (i, j) on one line within ``tolerance`` whose extents overlap."""

    def off_line(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        # Distances of b's two endpoints from a's line.
        na = np.stack([-u[a, 1], u[a, 0]], axis=1)
        d0 = np.abs(np.einsum("ij,ij->i", p0[b] - p0[a], na))
        d1 = np.abs(np.einsum("ij,ij->i", p1[b] - p0[a], na))
        return np.maximum(d0, d1)

    near = (off_line(i, j) <= tolerance) & (off_line(j, i) <= tolerance)
    ti0 = np.einsum("ij,ij->i", p0[i], u[i])
    ti1 = np.einsum("ij,ij->i", p1[i], u[i])
    tj0 = np.einsum("ij,ij->i", p0[j], u[i])
    tj1 = np.einsum("ij,ij->i", p1[j], u[i])
    lo = np.maximum(np.minimum(ti0, ti1), np.minimum(tj0, tj1))
    hi = np.minimum(np.maximum(ti0, ti1), np.maximum(tj0, tj1))
    return near & (hi >= lo - tolerance)
