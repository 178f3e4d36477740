"""A walking viewer: cameras along a path through and around the design views, as a GIF.

The path runs in spherical coordinates about the board centre (azimuth from +z toward
+x, elevation toward +y, distance), through the design views in order of azimuth, and
goes on beyond the first and last view by a fraction of the whole span (at that view's
distance), so the animation shows each image appear, hold near its own view and fade;
it stops short of that where it would turn past 80 degrees from the board's normal (or
the outermost view), so that it stays in front of the board.
A frame that would lie beyond the design's coordinate limit (:data:`MAX_MM` on an axis,
possible only for views near it) is drawn in to it along its direction.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw

from scratchfab.design.images import linear_to_srgb
from scratchfab.figures import TEXT_PX, enlarge, font, text_size
from scratchfab.model.design import (
    MAX_MM,
    Design,
    View,
    polar_from_position,
    position_from_polar,
)

#: Beyond the outermost views the path goes on by this fraction of the views' span.
EXTEND = 0.5
#: Azimuth span (degrees) of a sweep around a single view or views on one spot.
MIN_SPAN_DEG = 30.0
#: Frames are rendered at most this many pixels along their longer side.
MAX_SIDE = 192
#: Percentile of the positive pixels of all frames that maps to white.
WHITE_PERCENTILE = 99.5
#: GIF frames are enlarged by a whole factor to at least this many pixels wide.
GIF_MIN_WIDTH = 240
#: Milliseconds each frame shows, and the frames nearest a design view.
FRAME_MS = 120
HOLD_MS = 1000
#: Grey of the label strip under each GIF frame, and its padding in pixels.
LABEL_BACKGROUND = 235
LABEL_PAD = 6


@dataclass(frozen=True)
class SweepFrame:
    """One camera of the sweep.

    Attributes:
        view: The frame's camera (named ``frameNNN``, carrying its light).
        param: Position along the path in degrees of arc from its start.
    """

    view: View
    param: float


def _polar(p: np.ndarray) -> np.ndarray:
    """(azimuth, elevation in radians, distance) of a camera about the board's centre."""
    az, el, dist = polar_from_position((float(p[0]), float(p[1]), float(p[2])))
    return np.array([math.radians(az), math.radians(el), dist])


def _cartesian(az: float, el: float, dist: float) -> tuple[float, float, float]:
    return position_from_polar(math.degrees(az), math.degrees(el), dist)


def _within_bounds(position: tuple[float, float, float]) -> tuple[float, float, float]:
    """``position`` drawn in toward the board's centre until no coordinate exceeds MAX_MM."""
    p = np.asarray(position, dtype=np.float64)
    p = np.clip(p * min(1.0, MAX_MM / float(np.abs(p).max())), -MAX_MM, MAX_MM)
    return float(p[0]), float(p[1]), float(p[2])


def _room(end: np.ndarray, step: np.ndarray, limits: np.ndarray) -> float:
    """How far the walk may go on from ``end`` by ``step`` before it passes ``limits``.

    Args:
        end: (azimuth, elevation) in radians.
        step: Their change per degree of arc.
        limits: Their largest magnitudes.

    Returns:
        Degrees of arc, 0 when one is already past its limit.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(step != 0, (np.sign(step) * limits - end) / step, np.inf)
    return max(0.0, float(room.min()))


def sweep_path(design: Design, frames: int) -> tuple[list[SweepFrame], dict[str, float]]:
    """The sweep's cameras and each design view's position along the path.

    Args:
        design: The design; its views (and their lights) are the path's knots.
        frames: Number of cameras, at least 2.

    Returns:
        (frames, {view name: param}) with params in degrees of arc along the path.
    """
    views = sorted(design.views, key=lambda v: (_polar(v.camera_position)[0], v.name))
    knots = np.array([_polar(v.camera_position) for v in views])
    fovs = np.array([v.fov for v in views])
    lights = np.array([design.light_for(v) for v in views])
    steps = np.hypot(np.diff(knots[:, 0]), np.diff(knots[:, 1]))
    params = np.concatenate([[0.0], np.cumsum(np.degrees(steps))])
    span = params[-1]
    own = params  # each view's place along the walk, before the part ahead of the first
    if span < 1e-6:
        # One spot: sweep the azimuth across it, half the minimum span each way.
        knots, fovs, lights, params = knots[:1], fovs[:1], lights[:1], params[:1]
        own = np.zeros(len(views))
        first = last = np.array([math.radians(1.0), 0.0, 0.0])
        ext = MIN_SPAN_DEG / 2
    else:
        # Extend linearly along the end segments' directions, at the end views' distances
        # (a change of distance carried on could put the camera behind the board). An end
        # segment is the first or last of any length: views may share a camera, lit
        # otherwise, and one of none has no direction.
        moved = np.flatnonzero(steps > 0)
        first, last = (
            (knots[k + 1] - knots[k]) / (params[k + 1] - params[k]) * [1, 1, 0]
            for k in (moved[0], moved[-1])
        )
        ext = EXTEND * span
    # In front of the board: each end goes on until the azimuth is 80 degrees (1.4 rad)
    # from the board's normal (or the outermost view's), or the elevation 80 degrees,
    # so that every frame shows the board from a place of its own.
    limits = np.array([max(1.4, *np.abs(knots[:, 0])), 1.4])
    before = min(ext, _room(knots[0, :2], -first[:2], limits))
    after = min(ext, _room(knots[-1, :2], last[:2], limits))
    knots = np.vstack([knots[0] - before * first, knots, knots[-1] + after * last])
    fovs = np.concatenate([fovs[:1], fovs, fovs[-1:]])
    lights = np.vstack([lights[:1], lights, lights[-1:]])
    params = np.concatenate([[-before], params, [params[-1] + after]]) + before
    view_params = {v.name: float(p + before) for v, p in zip(views, own, strict=True)}
    lo, hi = 0.0, float(params[-1])
    res = views[0].resolution
    scale = min(1.0, MAX_SIDE / max(res))
    resolution = (max(1, round(res[0] * scale)), max(1, round(res[1] * scale)))
    out = []
    for i, t in enumerate(np.linspace(lo, hi, max(frames, 2))):
        az, el, dist = (float(np.interp(t, params, knots[:, k])) for k in range(3))
        el = float(np.clip(el, -1.4, 1.4))  # near a view above 80 degrees too
        lx, ly, lz = (float(np.interp(t, params, lights[:, k])) for k in range(3))
        view = View(
            name=f"frame{i:03d}",
            position_mm=_within_bounds(_cartesian(az, el, dist)),
            fov_deg=float(np.interp(t, params, fovs)),
            resolution=resolution,
            light_position_mm=(lx, ly, lz) if lz > 0 else None,
        )
        out.append(SweepFrame(view, float(t)))
    return out, view_params


def nearest_frames(frames: list[SweepFrame], view_params: dict[str, float]) -> dict[str, int]:
    """Index of the frame nearest each design view along the path."""
    params = np.array([f.param for f in frames])
    return {name: int(np.argmin(np.abs(params - p))) for name, p in view_params.items()}


def frame_labels(frames: list[SweepFrame], nearest: dict[str, int]) -> list[str]:
    """Each frame's caption: its camera's azimuth and elevation, then ``view: NAME``.

    The second line appears only on the frame nearest that design view.
    """
    out = []
    for i, frame in enumerate(frames):
        az, el, _ = _polar(np.asarray(frame.view.position_mm, dtype=np.float64))
        text = f"azimuth {math.degrees(az):+.0f}\u00b0  elevation {math.degrees(el):+.0f}\u00b0"
        names = sorted(name for name, k in nearest.items() if k == i)
        out.append(text + ("\nview: " + ", ".join(names) if names else ""))
    return out


def ping_pong(count: int) -> list[int]:
    """Frame order forward then back without repeating either end: 0..n-1, n-2..1."""
    return list(range(count)) + list(range(count - 2, 0, -1))


def _scale_factor(width: int, text_width: int) -> int:
    return max(1, math.ceil(max(GIF_MIN_WIDTH, text_width + 2 * LABEL_PAD) / width))


def gif_bytes(
    images: list[np.ndarray],
    labels: list[str] | None = None,
    hold: set[int] | frozenset[int] = frozenset(),
) -> bytes:
    """An endlessly looping grey GIF of linear images with one common exposure.

    The frames play forward then back (:func:`ping_pong`), each enlarged by a whole
    factor (nearest neighbour) to at least ``GIF_MIN_WIDTH`` px wide, with its label
    (dark text) in a light strip below the picture. Frames in ``hold`` (the design
    views' nearest) show for ``HOLD_MS``, the others for ``FRAME_MS``.
    """
    stack = [np.nan_to_num(np.asarray(im, dtype=np.float64), nan=0.0) for im in images]
    positive = np.concatenate([im[im > 0] for im in stack]) if stack else np.zeros(0)
    white = float(np.percentile(positive, WHITE_PERCENTILE)) if positive.size else 1.0
    white = white if white > 0 else 1.0
    texts = labels if labels is not None else [""] * len(stack)
    size = TEXT_PX
    text_w = max((text_size(t, size)[0] for t in texts if t), default=0)
    lines = max((t.count("\n") + 1 for t in texts if t), default=0)
    height, width = stack[0].shape
    factor = _scale_factor(width, text_w)
    strip = lines * (size + 3) + 2 * LABEL_PAD if lines else 0
    frames = []
    for im, text in zip(stack, texts, strict=True):
        enc = np.round(linear_to_srgb(np.clip(im / white, 0.0, 1.0)) * 255).astype(np.uint8)
        big = enlarge(enc, factor)
        frame = Image.new("L", (width * factor, height * factor + strip), LABEL_BACKGROUND)
        frame.paste(Image.fromarray(big, mode="L"), (0, 0))
        if text:
            ImageDraw.Draw(frame).multiline_text(
                (LABEL_PAD, height * factor + LABEL_PAD), text, fill=0, font=font(size), spacing=3
            )
        frames.append(frame)
    order = ping_pong(len(frames)) if len(frames) > 1 else [0]
    durations = [HOLD_MS if i in hold else FRAME_MS for i in order]
    buf = io.BytesIO()
    frames[order[0]].save(
        buf,
        format="GIF",
        save_all=True,
        append_images=[frames[i] for i in order[1:]],
        duration=durations,
        loop=0,
        optimize=False,
    )
    return buf.getvalue()


def sweep_gif(images: list[np.ndarray], frames: list[SweepFrame], nearest: dict[str, int]) -> bytes:
    """The sweep's GIF: labelled frames that hold at the design views' nearest ones."""
    return gif_bytes(images, frame_labels(frames, nearest), set(nearest.values()))
