"""The bare board's glint, left out of the optimizer's image error.

Where a view's half-vector tilts less than the design check's glint limit
(:func:`scratchfab.design.feasibility.glint_limit_deg`) the polished board mirrors the
light into the view brighter than any scratch can shine there: scratches only darken
those pixels, so no layout shows the image on them. Counted in the image error, a glint
on a few per cent of the board holds most of a view's light, sets the exposure s_k
(SPEC section 7) and leaves the rest of the image dim and flat. The optimizer therefore
leaves the glinting pixels out of both s_k and E_k: their target mask is 0, as off the
board. The mask depends on the design alone (camera, light, tool, roughness), so a run
and its resume compute the same one. Verify still counts every pixel.

Measured on a maker's case, the demo on a 200 x 200 mm board (3.6 % of it glints, holding
79 % of the bare board's light; the demo's 2000 scratches and 300 steps): outside the
glint rho rose from 0.13 / 0.08 to 0.24 / 0.19 (sun / house), and to 0.88 / 0.89 from
0.83 / 0.81 where the half-vector tilts 10 degrees or more; Mitsuba's figures over the
whole view barely move (rho -0.07 / -0.11 to -0.06 / -0.10, PSNR 7.4 / 6.5 dB): the glint
still outshines the image. Past the limit the glint fades over a few lobe widths: up to
about twice the limit (8 % of that board) the bare board still gives about half of a
pixel's light against sparse scratches, which holds rho there down; a mask at 8 degrees
instead raised rho past 10 degrees to 0.95 / 0.94 but lowered it from 8 to 10 degrees
(0.82 / 0.55 to 0.54 / 0.26) and past the limit as a whole (0.24 / 0.19 to 0.21 / 0.16);
a 150 mm board lit lower (5.4 % glints) traded alike (past 10 degrees 0.94 / 0.95 to
0.98 / 0.99, from 6 to 8 degrees 0.57 / 0.20 to 0.28 / 0.01). With ten times the
scratches (20000, the quick form's 0.5 per mm^2, about half the board grooved) the band
shows its image at this limit (rho 0.92 / 0.62 from 6 to 8 degrees, 0.99 from 8 to 10)
and a mask at 8 degrees mostly lost it (0.29 / 0.12 from 6 to 8; past the limit 0.94 /
0.92 fell to 0.83 / 0.73). The band is a sparse layout's: the limit stays where no
layout can help. The demo has no glint: its layout stays bit for bit the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scratchfab import figures
from scratchfab.design.feasibility import GLINT, tilt_deg
from scratchfab.render.renderer import ViewRenderer

#: The outline around the pixels where the bare board glints, in every picture of a view
#: (the feasibility map's glint colour).
GLINT_RGB: figures.RGB = GLINT
#: What the outline means, in a picture's key or caption.
GLINT_KEY = "the bare board glints: no scratch shows the image"


def glints(h: np.ndarray, limit_deg: float) -> np.ndarray:
    """Where the bare board glints: unit half-vectors ``h`` (..., 3) tilted below the limit."""
    return np.asarray(tilt_deg(h) < limit_deg)


@dataclass(frozen=True)
class ViewGlint:
    """One view's glint on its camera pixels.

    Attributes:
        name: The view.
        mask: (H, W) bool, the pixels on the board whose half-vector glints.
        board_share: Their share of the board area the view sees.
        light_share: Their share of the bare board's light in the view.
    """

    name: str
    mask: np.ndarray
    board_share: float
    light_share: float

    def check_shape(self, shape: tuple[int, ...], what: str) -> None:
        """Raise ValueError naming the view unless ``shape`` is the mask's (``what`` has it)."""
        if tuple(shape) != self.mask.shape:
            raise ValueError(
                f"view '{self.name}': glint mask {self.mask.shape} and {what} {tuple(shape)} differ"
            )

    def left_out(self, image: np.ndarray) -> np.ndarray:
        """``image`` of the view (H, W) with NaN where the board glints, as off the board."""
        self.check_shape(image.shape, "image")
        return np.where(self.mask, np.nan, image)

    def note(self) -> str:
        """A line for the user; empty without glint."""
        if not self.mask.any():
            return ""
        if self.board_share >= 1.0:
            return (
                f"view '{self.name}': the bare board glints on all of the board; its pixels "
                "are left out of the image error, so nothing optimizes this view (verify "
                "still counts them)."
            )
        return (
            f"view '{self.name}': the bare board glints on {100 * self.board_share:.1f}% of "
            f"the board ({100 * self.light_share:.0f}% of its light in this view); those "
            "pixels are left out of the image error (verify still counts them)."
        )


def view_glint(renderer: ViewRenderer, limit_deg: float) -> ViewGlint:
    """The glint of one view on its camera pixels (at their centres' half-vectors).

    Args:
        renderer: The view's renderer (its half-vectors, footprints and bare board).
        limit_deg: :func:`scratchfab.design.feasibility.design_glint_deg`.
    """
    area_on_board = renderer.area_on_board
    bare = renderer.factor * area_on_board * renderer.d_flat  # the render without scratches
    on = area_on_board > 0
    mask = glints(renderer.half_vector, limit_deg) & on
    area = float(area_on_board[on].sum())
    light = float(bare[on].sum())
    return ViewGlint(
        renderer.view.name,
        mask,
        float(area_on_board[mask].sum()) / area if area > 0 else 0.0,
        float(bare[mask].sum()) / light if light > 0 else 0.0,
    )


def outline_glint(picture: np.ndarray, glint: ViewGlint | None, factor: int) -> ViewGlint | None:
    """Outline ``glint``'s pixels on a picture of its view in :data:`GLINT_RGB`, in place.

    The outline is the glint region's inner edge (:func:`scratchfab.figures.outline_cells`),
    so the pixels inside keep their colours.

    Args:
        picture: 8-bit RGB (H * factor, W * factor, 3): the view's (H, W) pixels enlarged.
        glint: The view's glint; None or an empty mask draws nothing.
        factor: The enlargement.

    Returns:
        The glint drawn, or None where there is none.

    Raises:
        ValueError: The glint's mask is not the picture's pixels.
    """
    if glint is None:
        return None
    rows, cols = picture.shape[0] // factor, picture.shape[1] // factor
    exact = picture.shape[:2] == (rows * factor, cols * factor)
    glint.check_shape((rows, cols) if exact else picture.shape[:2], f"picture (enlarged {factor}x)")
    if not glint.mask.any():
        return None
    figures.outline_cells(picture, figures.enlarge(glint.mask, factor), GLINT_RGB)
    return glint
