"""Pinhole cameras and pixel footprints on the board plane (SPEC section 2)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scratchfab.model.design import View


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera in the SPEC's convention.

    Attributes:
        position: (3,) camera centre in mm.
        forward: (3,) unit f = normalize(look_at - position).
        right: (3,) unit r = normalize(f x up).
        up: (3,) unit u = r x f.
        tan_x: tx = ty * W / H.
        tan_y: ty = tan(fov / 2).
        width: W in pixels.
        height: H in pixels.
    """

    position: np.ndarray
    forward: np.ndarray
    right: np.ndarray
    up: np.ndarray
    tan_x: float
    tan_y: float
    width: int
    height: int

    @classmethod
    def from_view(cls, view: View) -> Camera:
        """The camera of a resolved view."""
        pos = view.camera_position
        fwd = np.asarray(view.look_at_mm, dtype=np.float64) - pos
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, np.asarray(view.up, dtype=np.float64))
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        ty = math.tan(math.radians(view.fov) / 2)
        tx = ty * view.width / view.height
        return cls(pos, fwd, right, up, tx, ty, view.width, view.height)

    def directions(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Unnormalised ray directions (..., 3) through image-plane points (s, t)."""
        s = np.asarray(s, dtype=np.float64)[..., None]
        t = np.asarray(t, dtype=np.float64)[..., None]
        return (
            self.forward
            + (2 * s / self.width - 1) * self.tan_x * self.right
            + (1 - 2 * t / self.height) * self.tan_y * self.up
        )

    def board_hits(self, s: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where rays through (s, t) meet z = 0.

        Returns:
            (points (..., 2) in mm, valid (...) bool): invalid where the ray does not
            go down toward the board (its hit would be behind the camera).
        """
        d = self.directions(s, t)
        dz = d[..., 2]
        valid = dz < -1e-12
        lam = np.where(valid, -self.position[2] / np.where(valid, dz, -1.0), 0.0)
        pts = self.position[:2] + lam[..., None] * d[..., :2]
        return pts, valid

    def corner_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Board hits of the (H+1, W+1) pixel-corner grid: (points, valid)."""
        t, s = np.meshgrid(
            np.arange(self.height + 1, dtype=np.float64),
            np.arange(self.width + 1, dtype=np.float64),
            indexing="ij",
        )
        return self.board_hits(s, t)

    def center_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Board hits of the (H, W) pixel centres: (points, valid)."""
        t, s = np.meshgrid(
            np.arange(self.height, dtype=np.float64) + 0.5,
            np.arange(self.width, dtype=np.float64) + 0.5,
            indexing="ij",
        )
        return self.board_hits(s, t)

    def footprints(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel footprints on the board.

        Returns:
            (quads (H, W, 4, 2), valid (H, W)): the corners of pixel (i, j) in the order
            (i, j), (i, j+1), (i+1, j+1), (i+1, j) of the image plane, which is
            counter-clockwise on the board for a camera in front of it (z > 0) with an
            upright image; valid where all four corner rays meet the board.
        """
        pts, ok = self.corner_grid()
        quads = np.stack([pts[:-1, :-1], pts[1:, :-1], pts[1:, 1:], pts[:-1, 1:]], axis=2)
        valid = ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, 1:] & ok[1:, :-1]
        return quads, valid

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Image-plane coordinates (s, t) of world points (..., 3); inverse of :meth:`directions`.

        Returns:
            (st (..., 2), in_front (...) bool).
        """
        rel = np.asarray(points, dtype=np.float64) - self.position
        depth = rel @ self.forward
        in_front = depth > 1e-12
        safe = np.where(in_front, depth, 1.0)
        x = (rel @ self.right) / safe / self.tan_x
        y = (rel @ self.up) / safe / self.tan_y
        s = (x + 1) * self.width / 2
        t = (1 - y) * self.height / 2
        return np.stack([s, t], axis=-1), in_front


def polygon_area(quads: np.ndarray) -> np.ndarray:
    """Signed shoelace area of polygons (..., K, 2) (positive when counter-clockwise)."""
    x = quads[..., 0]
    y = quads[..., 1]
    return 0.5 * np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1)
