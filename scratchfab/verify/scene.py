"""Mitsuba scenes of one view: the board, the design's light and the SPEC's camera.

The sensor reproduces SPEC section 2 pixel for pixel: a pinhole at the view's position
looking at ``look_at`` with ``up``, vertical field of view ``fov`` (``fov_axis = "y"``, so
tx = ty W / H), film row 0 at the top and column 0 at the left (Mitsuba's camera frame
has +x to the left, which puts the image's left edge on the SPEC's -r side), and a box
reconstruction filter of radius 1/2 so every sample lands in exactly its own pixel and a
pixel is the plain average of the radiance over its own square.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from scratchfab.backend import BackendName, array_module
from scratchfab.model.design import Design, View
from scratchfab.model.scratches import ScratchSet

#: The sampler: multi-jittered stratification of the pixel (best of Mitsuba's at thin bands).
SAMPLER = "multijitter"


def bad_sun_direction(direction: tuple[float, ...]) -> str | None:
    """Why ``direction`` cannot point at the sun, or None.

    Three finite numbers with y > 0: y is up (the board hangs like a picture), and a sun
    at or below the horizon lights nothing (Mitsuba's sun-and-sky model only warns).
    """
    values = np.asarray(direction, dtype=np.float64)
    if not (values.shape == (3,) and np.all(np.isfinite(values)) and values.any()):
        return f"expected three finite numbers, not all zero, got {tuple(direction)}"
    if values[1] <= 0:
        return f"the sun must be above the horizon (y > 0; y is up), got {tuple(direction)}"
    return None


@dataclass(frozen=True)
class Sky:
    """Mitsuba's sun-and-sky emitter, scaled against the design's light.

    Attributes:
        sun_direction: Direction toward the sun (world, y up like the board's wall).
        strength: Sky-plus-sun irradiance on the board over the design light's
            irradiance at the board centre.
        turbidity: Haze, 1 (clear) to 10.
    """

    sun_direction: tuple[float, float, float] = (0.35, 0.8, 0.5)
    strength: float = 1.0
    turbidity: float = 3.0

    def __post_init__(self) -> None:
        if (why := bad_sun_direction(self.sun_direction)) is not None:
            raise ValueError(f"sun_direction: {why}")
        if not (np.isfinite(self.strength) and self.strength > 0):
            raise ValueError(f"strength: expected a finite number > 0, got {self.strength}")
        if not 1 <= self.turbidity <= 10:
            raise ValueError(f"turbidity: expected 1 (clear) to 10, got {self.turbidity}")


def use_variant(backend: BackendName = "llvm", color: bool = False) -> ModuleType:
    """Select Mitsuba's ``<backend>_ad_mono`` (or ``_rgb``) variant and register the plugin.

    Raises:
        BackendError: When the backend cannot run here.
    """
    array_module(backend)
    import mitsuba as mi

    mi.set_variant(f"{backend}_ad_{'rgb' if color else 'mono'}")
    from scratchfab.verify import bsdf

    bsdf.register()
    return mi


def board_bsdf(
    design: Design, scratches: ScratchSet, flat_weight: str = "signed", lobes: str = "all"
) -> dict:
    """The ``scratch_board`` BSDF of a design's board carrying ``scratches``.

    Args:
        design: Supplies the board (size, roughness, f0).
        scratches: The layout.
        flat_weight: ``"signed"`` or ``"clamped"`` flat remainder (see :mod:`.bsdf`).
        lobes: ``"all"``, ``"scratches"`` or ``"flat"``.
    """
    import mitsuba as mi

    props: dict[str, Any] = {
        "type": "scratch_board",
        "board_width": design.board.width_mm,
        "board_height": design.board.height_mm,
        "alpha": design.board.roughness,
        "f0": design.board.f0,
        "flat_weight": flat_weight,
        "lobes": lobes,
    }
    if len(scratches):
        props["p0"] = mi.TensorXf(scratches.p0.astype(np.float32))
        props["p1"] = mi.TensorXf(scratches.p1.astype(np.float32))
        props["width"] = mi.TensorXf(scratches.width.astype(np.float32))
        props["depth"] = mi.TensorXf(scratches.depth.astype(np.float32))
    return props


def sensor(view: View, spp: int, sampler: str | None = None) -> dict:
    """A perspective sensor with the view's pose, fov and pixel grid (SPEC section 2)."""
    import mitsuba as mi

    pos = view.camera_position
    dist = float(np.linalg.norm(np.asarray(view.look_at_mm) - pos))
    return {
        "type": "perspective",
        "fov_axis": "y",
        "fov": view.fov,
        "near_clip": 1e-3 * dist,
        "far_clip": 1e3 * dist,
        "to_world": mi.ScalarTransform4f().look_at(
            origin=[float(v) for v in pos],
            target=[float(v) for v in view.look_at_mm],
            up=[float(v) for v in view.up],
        ),
        "film": {
            "type": "hdrfilm",
            "width": view.width,
            "height": view.height,
            "rfilter": {"type": "box"},
            "sample_border": False,
            "pixel_format": "luminance",
            "component_format": "float32",
        },
        "sampler": {"type": sampler or SAMPLER, "sample_count": spp},
    }


def sky_emitter(design: Design, sky: Sky) -> dict:
    """The ``sunsky`` emitter scaled so its board irradiance is ``strength`` times the light's.

    The light's irradiance is taken at the board centre, I cos / r^2; the sky's is
    estimated by sampling the emitter (fixed seed) for a point facing +z.
    """
    import drjit as dr
    import mitsuba as mi

    direction = np.asarray(sky.sun_direction, dtype=np.float64)
    direction /= np.linalg.norm(direction)
    base = {
        "type": "sunsky",
        "sun_direction": [float(v) for v in direction],
        "turbidity": sky.turbidity,
        # Mitsuba's sky has its zenith at +z; the SPEC's world has +y up (the board is a
        # wall facing +z), so turn the dome. The sun direction is given in world space.
        "to_world": mi.ScalarTransform4f().rotate([1.0, 0.0, 0.0], -90.0),
    }
    emitter = mi.load_dict(base)
    # Irradiance on the board (normal +z) by emitter sampling, with a fixed seed.
    n = 1 << 16
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(7, n)
    it: Any = dr.zeros(mi.Interaction3f, n)
    it.n = mi.Vector3f(0, 0, 1)
    ds, weight = emitter.sample_direction(it, sampler.next_2d())
    lum = mi.luminance(weight)
    irradiance = float(dr.mean(lum * dr.maximum(ds.d.z, 0.0))[0])
    light = design.light
    r2 = float(np.sum(np.asarray(light.position_mm) ** 2))
    cos = light.position_mm[2] / np.sqrt(r2)
    target = sky.strength * light.intensity * cos / r2
    scale = target / max(irradiance, 1e-30)
    return base | {"sun_scale": scale, "sky_scale": scale}


def scene_dict(
    design: Design,
    scratches: ScratchSet,
    view: View,
    spp: int,
    *,
    sky: Sky | None = None,
    point_light: bool = True,
    flat_weight: str = "signed",
    bsdf: dict | None = None,
) -> dict:
    """The Mitsuba scene of one view.

    Args:
        design: Board, light and views.
        scratches: The scratch layout.
        view: The camera (and the per-view light override).
        spp: Samples per pixel.
        sky: Adds the sun-and-sky emitter (needs an RGB variant).
        point_light: Whether the design's point light is on.
        flat_weight: The plugin's overlap rule (see :mod:`.bsdf`).
        bsdf: A prebuilt board BSDF dict or object (skips rebuilding the grid).
    """
    hw, hh = design.board.half_extent
    import mitsuba as mi

    scene: dict[str, Any] = {
        "type": "scene",
        "integrator": {
            "type": "direct",
            "emitter_samples": 1,
            "bsdf_samples": 1 if sky is not None else 0,
            "hide_emitters": True,
        },
        "sensor": sensor(view, spp),
        "board": {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f().scale([hw, hh, 1.0]),
            "bsdf": bsdf if bsdf is not None else board_bsdf(design, scratches, flat_weight),
        },
    }
    if point_light:
        scene["light"] = {
            "type": "point",
            "position": [float(v) for v in design.light_for(view)],
            "intensity": {"type": "uniform", "value": design.light.intensity},
        }
    if sky is not None:
        scene["sky"] = sky_emitter(design, sky)
    return scene
