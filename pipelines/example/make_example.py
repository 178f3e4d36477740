"""Make the bundled example: a small two-view design and a few hundred scratches.

Run from the repository root: ``python pipelines/example/make_example.py``. It is seeded,
so it rewrites the same ``design.toml`` and ``scratches.csv`` every time.

The layout is hand-made, not optimized: scratches inside a disc are turned so that their
walls reflect the light toward the ``left`` camera (the scratch runs perpendicular to the
horizontal part of that view's half-vector), scratches inside a square ring are turned
for the ``right`` camera. Rendered with ``scratchfab render``, the left view shows a
bright disc, the right view a bright square.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scratchfab.model.design import load_design
from scratchfab.model.scratches import ScratchSet
from scratchfab.render.profile import steepest_wall_deg

HERE = Path(__file__).resolve().parent
SEED = 20240611
COUNT = 800

DESIGN = """\
# The bundled example board (pipelines/example/make_example.py writes this file).
[board]
width_mm = 60.0
height_mm = 60.0
roughness = 0.05
f0 = 0.91
margin_mm = 2.0

[light]
position_mm = [0.0, 300.0, 500.0]
intensity = 1.0

[scratch]
width_mm = 0.1
depth_mm = 0.015
count = 800
min_length_mm = 2.0
max_length_mm = 6.0

[[views]]
name = "left"
position_mm = [-180.0, 0.0, 500.0]
fov_deg = "auto"
resolution = [128, 128]

[[views]]
name = "right"
position_mm = [180.0, 0.0, 500.0]
fov_deg = "auto"
resolution = [128, 128]
"""


def half_vector_xy(camera: np.ndarray, light: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Horizontal part (N, 2) of the half-vector at board points (N, 2), and its tilt."""
    p3 = np.concatenate([points, np.zeros((len(points), 1))], axis=1)
    wi = light - p3
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = camera - p3
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    return h


def main() -> None:
    """Write design.toml and scratches.csv beside this script."""
    (HERE / "design.toml").write_text(DESIGN, encoding="utf-8")
    design = load_design(HERE / "design.toml")
    rng = np.random.default_rng(SEED)
    hw, hh = design.board.half_extent
    inner = hw - design.board.margin_mm - design.scratch.max_length_mm / 2

    centres: list[np.ndarray] = []
    owners: list[int] = []
    while len(centres) < COUNT:
        c = rng.uniform(-inner, inner, 2)
        in_disc = np.hypot(c[0] + 10.0, c[1] - 9.0) < 13.0
        box = max(abs(c[0] - 9.0), abs(c[1] + 9.0))
        in_ring = 8.0 < box < 15.0
        if in_disc != in_ring:
            centres.append(c)
            owners.append(0 if in_disc else 1)
    c = np.asarray(centres)
    owner = np.asarray(owners)

    light = np.asarray(design.light.position_mm)
    h = np.empty((COUNT, 3))
    for k, view in enumerate(design.views):
        sel = owner == k
        h[sel] = half_vector_xy(view.camera_position, light, c[sel])
    tilt = np.degrees(np.arctan2(np.hypot(h[:, 0], h[:, 1]), h[:, 2]))
    wall = float(steepest_wall_deg(design.scratch.width_mm, design.scratch.depth_mm))
    if tilt.max() >= wall:
        raise SystemExit(f"the tool's walls ({wall:.1f} deg) are too flat for {tilt.max():.1f} deg")
    # A wall tilted toward h must face across the scratch: run along h's horizontal normal.
    along = np.stack([-h[:, 1], h[:, 0]], axis=1)
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    length = rng.uniform(design.scratch.min_length_mm, design.scratch.max_length_mm, COUNT)
    p0 = c - 0.5 * length[:, None] * along
    p1 = c + 0.5 * length[:, None] * along
    scratches = ScratchSet.from_arrays(
        np.round(p0, 4), np.round(p1, 4), design.scratch.width_mm, design.scratch.depth_mm
    )
    scratches.save(HERE / "scratches.csv", design.scratch)
    print(f"wrote {HERE / 'design.toml'} and {HERE / 'scratches.csv'} ({COUNT} scratches)")


if __name__ == "__main__":
    main()
