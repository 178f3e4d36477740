"""Points sampled along line segments, for the neighbour searches that need a superset."""

from __future__ import annotations

import numpy as np


def sample_along(p0: np.ndarray, p1: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along each segment p0[k] -> p1[k], ends included, at most ``step`` apart.

    Every point of a segment lies within ``step / 2`` of one of its samples, which is what
    makes a radius query over the samples complete. Each segment gets at least its two ends.

    Returns:
        (points (M, 2), owner (M,)): the samples, segment by segment in order, and the
        index of the segment each belongs to.
    """
    d = p1 - p0
    length = np.hypot(d[:, 0], d[:, 1])
    counts = np.maximum(2, np.ceil(length / step).astype(np.int64) + 1)
    owner = np.repeat(np.arange(len(p0)), counts)
    first = np.cumsum(counts) - counts
    t = (np.arange(int(counts.sum())) - first[owner]) / (counts[owner] - 1)
    return p0[owner] + t[:, None] * d[owner], owner
