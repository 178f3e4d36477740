"""Mitsuba scenes of one view: the board, the design's light and the SPEC's camera.

The sensor reproduces SPEC section 2 pixel for pixel: a pinhole at the view's position
looking at ``look_at`` with ``up``, vertical field of view ``fov`` (``fov_axis = "y"``, so
tx = ty W / H), film row 0 at the top and column 0 at the left (Mitsuba's camera frame
has +x to the left, which puts the image's left edge on the SPEC's -r side), and a box
reconstruction filter of radius 1/2 so every sample lands in exactly its own pixel and a
pixel is the plain average of the radiance over its own square.

Renders are bit-reproducible: :func:`render_view` evaluates each sample's radiance in
Dr.Jit (lanes are independent, so the thread count does not matter) and sums a pixel's
samples in float64 in a fixed order, where ``mi.render`` adds them into the film with
atomic float32 additions whose order depends on the thread schedule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from scratchfab.backend import BackendName, array_module
from scratchfab.model.design import Design, View
from scratchfab.model.scratches import ScratchSet

#: The sampler: multi-jittered stratification of the pixel (best of Mitsuba's at thin bands).
SAMPLER = "multijitter"
#: Most samples one kernel launch of :func:`render_view` evaluates (4 bytes each are kept
#: until summed); more samples per pixel are taken in passes, as Mitsuba's
#: ``samples_per_pass`` does.
MAX_WAVEFRONT = 1 << 24


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


def samples_per_pass(pixels: int, spp: int, limit: int = MAX_WAVEFRONT) -> int:
    """The largest divisor of ``spp`` whose pass of ``pixels`` samples each fits ``limit``."""
    best = 1
    for d in range(1, math.isqrt(spp) + 1):
        if spp % d == 0:
            for c in (d, spp // d):
                if pixels * c <= limit:
                    best = max(best, c)
    return best


def render_view(scene: Any, spp: int, seed: int, max_wavefront: int = MAX_WAVEFRONT) -> np.ndarray:
    """Render the scene's sensor like ``mi.render(scene, spp=spp, seed=seed)``, reproducibly.

    The image of :func:`render_view_spread` (see there).
    """
    return render_view_spread(scene, spp, seed, max_wavefront)[0]


def render_view_spread(
    scene: Any, spp: int, seed: int, max_wavefront: int = MAX_WAVEFRONT
) -> tuple[np.ndarray, np.ndarray]:
    """Render the scene's sensor like ``mi.render(scene, spp=spp, seed=seed)``, reproducibly.

    The samples (positions, rays, sampler state) are Mitsuba's own, so the image is
    ``mi.render``'s up to rounding: each pixel is the float64 mean of its samples'
    luminance, summed in a fixed order. Passes of ``samples_per_pass`` samples per pixel
    keep a launch within ``max_wavefront`` samples (the sampler's stratification spans
    all passes).

    Args:
        scene: A loaded Mitsuba scene with a sampling integrator and a box-filtered film.
        spp: Samples per pixel (rounded up as the sampler asks, as ``mi.render`` does).
        seed: The sampler's seed.
        max_wavefront: Most samples per kernel launch.

    Returns:
        (H, W) float64 image, and (H, W) the variance of one sample about its pixel's mean
        (unbiased; 0 with one sample): the spread of a render without stratification,
        that verify holds its own against to tell how the noise falls with ``spp``.
    """
    import drjit as dr
    import mitsuba as mi

    sensor = scene.sensors()[0]
    film = sensor.film()
    if not film.rfilter().is_box_filter() or film.sample_border():
        raise ValueError("render_view needs a box filter and sample_border = false")
    width, height = (int(v) for v in film.crop_size())
    pixels = width * height
    sampler = sensor.sampler().clone()
    sampler.set_sample_count(spp)
    spp = sampler.sample_count()  # the multi-jitter sampler rounds up to its grid
    per_pass = samples_per_pass(pixels, spp, max_wavefront)
    sampler.set_samples_per_wavefront(per_pass)
    sampler.seed(seed, pixels * per_pass)
    integrator = scene.integrator()

    idx = dr.arange(mi.UInt32, pixels * per_pass) // dr.opaque(mi.UInt32, per_pass)
    row = idx // width
    ox, oy = (int(v) for v in film.crop_offset())
    pos = mi.Vector2f(mi.Float(idx - row * width + ox), mi.Float(row + oy))
    scale = mi.ScalarVector2f(1.0 / width, 1.0 / height)
    shift = mi.ScalarVector2f(-ox / width, -oy / height)
    total = np.zeros(pixels, dtype=np.float64)
    squares = np.zeros(pixels, dtype=np.float64)
    passes = spp // per_pass
    with dr.suspend_grad():
        for k in range(passes):
            sample_pos = dr.fma(pos + sampler.next_2d(), scale, shift)
            aperture = mi.Point2f(0.5)
            if sensor.needs_aperture_sample():
                aperture = sampler.next_2d()
            time = mi.Float(sensor.shutter_open())
            if sensor.shutter_open_time() > 0:
                time += sampler.next_1d() * sensor.shutter_open_time()
            wavelength = sampler.next_1d() if mi.is_spectral else mi.Float(0.0)
            ray, weight = sensor.sample_ray_differential(time, wavelength, sample_pos, aperture)
            ray.scale_differential(1.0 / math.sqrt(spp))
            value, _, _ = integrator.sample(scene, sampler, ray, sensor.get_medium())
            value = weight * value
            lum = mi.luminance(value) if mi.is_rgb else value[0]
            if k + 1 < passes:
                sampler.advance()
                sampler.schedule_state()
            dr.eval(lum)
            samples = np.asarray(lum, dtype=np.float32).reshape(pixels, per_pass)
            total += samples.sum(axis=1, dtype=np.float64)
            squares += np.einsum("ij,ij->i", samples, samples, dtype=np.float64)
    mean = total / spp
    spread = np.maximum(squares - spp * mean * mean, 0.0) / max(1, spp - 1)
    return mean.reshape(height, width), spread.reshape(height, width)


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
