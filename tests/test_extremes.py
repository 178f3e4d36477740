"""Valid but extreme designs through the whole pipeline (design -> ... -> export).

Each case is a design at an edge of what the schema accepts (grazing or normal views,
a light touching the board or a kilometre away, a 3 mm board and one at the machine's
envelope, a thin strip, one view and many, one scratch, bounds of roughness, f0 and the
dent, uniform and one-pixel targets, thin images, extreme seeds). The pipeline runs with
two optimizer steps and a cheap verify, and every output must stay sane:

* every array, CSV, JSON and G-code finite (targets NaN exactly off the board);
* the analytic render never brighter than a facet aimed at the half-vector allows,
  I F(wi . h) D_max m / (4 |l - c|^2 wo_z), with D_max = 1 / (pi alpha^2) the GGX peak
  and m = 1 + (area of the scratches near the footprint) / |P| the overlap allowance
  (SPEC section 4 sums overlapping scratches as if each were alone);
* the analytic render of a few scratches agrees with the brute-force reference
  (tests/reference_render.py) in that geometry;
* scratches inside the board's margin, strokes and G-code moves inside the envelope.
"""

from __future__ import annotations

import copy
import math
import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tomli_w
from conftest import FULL, write_disc_and_bar
from gcode_interp import interpret
from PIL import Image
from reference_render import reference_render

from scratchfab.errors import ConfigError
from scratchfab.model.design import design_from_mapping, load_design
from scratchfab.model.scratches import ScratchSet, load_scratches
from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.runner import run_pipeline
from scratchfab.render.renderer import render_scratches
from scratchfab.toolpath import Toolpath

BASE: dict[str, Any] = {
    "board": {"width_mm": 30.0, "height_mm": 30.0, "margin_mm": 1.5},
    "light": {"position_mm": [0.0, 187.3, 463.6]},
    "scratch": {"count": 120, "min_length_mm": 1.5, "max_length_mm": 5.0},
    "views": [
        {
            "name": "disc",
            "target": "disc.png",
            "azimuth_deg": -22.0,
            "elevation_deg": 0.0,
            "distance_mm": 400.0,
            "fov_deg": "auto",
            "resolution": [20, 20],
        },
        {
            "name": "bar",
            "target": "bar.png",
            "azimuth_deg": 22.0,
            "elevation_deg": 0.0,
            "distance_mm": 400.0,
            "fov_deg": "auto",
            "resolution": [20, 20],
        },
    ],
    "pipeline": {"name": "extreme"},
    "optimize": {"iterations": 2},
    "verify": {"spp": 16, "min_rho": -1.0},
    "toolpath": {"machine": "grbl-3018-diamond", "passes": 2, "kicks": 0},
    "export": {"formats": ["gcode", "dxf", "svg"]},
}

Mutate = Callable[[dict[str, Any]], object]


def _targets(folder: Path) -> None:
    """The target pictures the cases name (64 x 64 unless said)."""
    write_disc_and_bar(folder)
    Image.new("L", (64, 64), 0).save(folder / "black.png")
    Image.new("L", (64, 64), 255).save(folder / "white.png")
    dot = Image.new("L", (64, 64), 0)
    dot.putpixel((31, 31), 255)
    dot.save(folder / "dot.png")
    Image.new("L", (1, 1), 255).save(folder / "pixel.png")
    Image.new("L", (400, 3), 128).save(folder / "strip.png")


def _views(data: dict[str, Any], index: int | None = None, **keys: Any) -> None:
    for i, view in enumerate(data["views"]):
        if index is None or i == index:
            if "position_mm" in keys:
                for key in ("azimuth_deg", "elevation_deg", "distance_mm"):
                    view.pop(key, None)
            view.update(keys)


def _profile(folder: Path, **tool: float) -> str:
    """The bundled 3018 profile with other [tool] values (a design must match its tool)."""
    text = (Path(__file__).parents[1] / "machine_profiles/grbl-3018-diamond.toml").read_text()
    for key, value in tool.items():
        text = re.sub(rf"^{key} = .*$", f"{key} = {value!r}", text, count=1, flags=re.M)
    path = folder / "tool.toml"
    path.write_text(text)
    return str(path)


def _case(name: str, mutate: Mutate, slow: bool = False) -> Any:
    """A case; a slow one runs only design and optimize unless SCRATCHFAB_FULL=1."""
    return pytest.param(mutate, slow, id=name, marks=[pytest.mark.slow] if slow else [])


def _force(data: dict[str, Any]) -> None:
    data["pipeline"]["force"] = True


CASES = [
    _case("baseline", lambda d: None),
    # light: almost in the board's plane (forced: no view can be lit), touching it, far
    _case(
        "light_grazing",
        lambda d: (_force(d), d["light"].update(position_mm=[0.0, 500.0, 0.5])),
    ),
    _case(
        "light_touching",
        lambda d: (_force(d), d["light"].update(position_mm=[0.0, 0.0, 1e-3])),
    ),
    _case("light_far", lambda d: d["light"].update(position_mm=[0.0, 5e5, 8.6e5]), slow=True),
    # views: grazing (forced), straight above, at the light's mirror direction (forced)
    _case(
        "views_grazing",
        lambda d: (_force(d), _views(d, 0, elevation_deg=80.0), _views(d, 1, azimuth_deg=85.0)),
    ),
    _case("view_normal", lambda d: _views(d, 0, azimuth_deg=0.0), slow=True),
    _case(
        "view_mirror",
        lambda d: (_force(d), _views(d, 0, position_mm=[0.0, -187.3, 463.6])),
    ),
    _case(
        "views_same_azimuth",
        lambda d: (_force(d), _views(d, 1, azimuth_deg=-22.0)),
        slow=True,
    ),
    _case("views_close", lambda d: _views(d, None, distance_mm=20.0), slow=True),
    _case("views_far", lambda d: _views(d, None, distance_mm=9e5), slow=True),
    # boards: 3 mm, the 3018's whole envelope (220 x 150), a 100 x 3 mm strip
    _case(
        "board_3mm",
        lambda d: (
            d["board"].update(width_mm=3.0, height_mm=3.0, margin_mm=0.1),
            d["scratch"].update(count=12, min_length_mm=0.5, max_length_mm=1.0),
        ),
    ),
    _case(
        "board_envelope",
        lambda d: (
            d["board"].update(width_mm=220.0, height_mm=150.0),
            d["scratch"].update(max_length_mm=12.0),
        ),
    ),
    _case(
        "board_strip",
        lambda d: (
            d["board"].update(width_mm=100.0, height_mm=3.0, margin_mm=0.2),
            d["scratch"].update(count=60, min_length_mm=1.0, max_length_mm=2.0),
            _views(d, None, resolution=[64, 8]),
        ),
    ),
    _case("one_view", lambda d: d.update(views=d["views"][:1])),
    _case(
        "nine_views",
        lambda d: (
            _force(d),
            d.update(
                views=[
                    dict(
                        d["views"][0],
                        name=f"v{k}",
                        azimuth_deg=-24.0 + 16.0 * (k % 3),
                        elevation_deg=-16.0 + 16.0 * (k // 3),
                        resolution=[8, 8],
                    )
                    for k in range(9)
                ]
            ),
        ),
        slow=True,
    ),
    _case("one_scratch", lambda d: d["scratch"].update(count=1)),
    # surface and dent at their bounds
    _case("roughness_min", lambda d: d["board"].update(roughness=0.005)),
    _case("roughness_near_1", lambda d: (_force(d), d["board"].update(roughness=0.9999))),
    _case("f0_zero", lambda d: d["board"].update(f0=0.0)),
    _case("f0_one", lambda d: d["board"].update(f0=1.0), slow=True),
    _case("margin_zero", lambda d: d["board"].update(margin_mm=0.0), slow=True),
    _case(
        "dent_deepest",
        lambda d: (
            d["scratch"].update(depth_mm=3.0),
            d["toolpath"].update(machine=_profile(d["_folder"], depth_mm=3.0)),
        ),
    ),
    _case(
        "dent_narrow",
        lambda d: (
            d["scratch"].update(width_mm=0.001, depth_mm=0.0001),
            d["toolpath"].update(machine=_profile(d["_folder"], width_mm=0.001, depth_mm=0.0001)),
        ),
    ),
    # targets
    _case("targets_black", lambda d: (_force(d), _views(d, None, target="black.png"))),
    _case("targets_white", lambda d: _views(d, None, target="white.png"), slow=True),
    _case(
        "targets_dot_and_1px",
        lambda d: (_views(d, 0, target="dot.png"), _views(d, 1, target="pixel.png")),
    ),
    _case("target_3px_tall", lambda d: _views(d, 0, target="strip.png"), slow=True),
    # images: one pixel, thin, odd aspect with fov "auto"
    _case("resolution_1x1", lambda d: _views(d, None, resolution=[1, 1])),
    _case(
        "resolution_thin",
        lambda d: (_views(d, 0, resolution=[96, 4]), _views(d, 1, resolution=[4, 96])),
    ),
    # seeds at 0 (baseline) and the top of the 32-bit range, and beyond where allowed
    _case(
        "seeds_max",
        lambda d: [
            d[t].update(seed=2**32 - 1) for t in ("pipeline", "optimize", "verify", "toolpath")
        ],
    ),
    _case(
        "seeds_64bit",
        lambda d: [d[t].update(seed=2**63) for t in ("pipeline", "optimize", "verify")],
        slow=True,
    ),
    _case("intensity_tiny", lambda d: d["light"].update(intensity=1e-6), slow=True),
    _case("intensity_huge", lambda d: d["light"].update(intensity=1e6)),
    _case("plotter", lambda d: d["toolpath"].update(machine="grbl-plotter-scribe"), slow=True),
]


def _write_case(folder: Path, mutate: Mutate) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    _targets(folder)
    data = copy.deepcopy(BASE)
    data["_folder"] = folder
    mutate(data)
    del data["_folder"]
    path = folder / "case.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def _assert_files_finite(job: Path) -> None:
    """No NaN or infinity in any output (targets: NaN exactly where the pixel is off the board)."""
    for file in job.rglob("*.npy"):
        a = np.load(file)
        if file.parent.name == "targets":
            on = ~np.isnan(a)
            assert on.any(), f"{file}: no board pixel"
            assert np.all((a[on] >= 0) & (a[on] <= 1)), file
        else:
            assert np.all(np.isfinite(a)) and np.all(a >= 0), file
    for file in [*job.rglob("*.json"), *job.rglob("*.gcode"), *job.rglob("*.svg")]:
        assert not re.search(r"\b(nan|inf|infinity)\b", file.read_text(), re.I), file
    for file in job.rglob("*.dxf"):
        assert not re.search(r"^\s*-?(nan|inf)\s*$", file.read_text(), re.I | re.M), file
    for file in job.rglob("*.png"):
        with Image.open(file) as img:
            img.load()


def _pixel_geometry(view: Any, design: Any) -> dict[str, np.ndarray]:
    """Independent camera (tests/reference_render.py's), per pixel: footprint and shading."""
    from reference_render import _Cam

    cam = _Cam(view)
    jj, ii = np.meshgrid(
        np.arange(cam.H, dtype=np.float64), np.arange(cam.W, dtype=np.float64), indexing="ij"
    )
    corners, _, ok = cam.hit(
        np.stack([ii, ii, ii + 1, ii + 1], -1), np.stack([jj, jj + 1, jj + 1, jj], -1)
    )
    x, y = corners[..., 0], corners[..., 1]
    area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, -1) - np.roll(x, -1, -1) * y, -1))
    centre, _, _ = cam.hit(ii + 0.5, jj + 0.5)
    c3 = np.concatenate([centre, np.zeros(centre.shape[:-1] + (1,))], -1)
    to_light = design.light_for(view) - c3
    dist2 = np.sum(to_light * to_light, -1)
    wi = to_light / np.sqrt(dist2)[..., None]
    wo = cam.pos - c3
    wo /= np.linalg.norm(wo, axis=-1)[..., None]
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1)[..., None]
    f0 = design.board.f0
    fresnel = f0 + (1 - f0) * (1 - np.sum(wi * h, -1)) ** 5
    factor = design.light.intensity * fresnel / (4 * dist2 * wo[..., 2])
    return {"corners": corners, "valid": np.all(ok, -1), "area": area, "h": h, "factor": factor}


def _assert_energy_bound(design: Any, scratches: ScratchSet, images: dict[str, np.ndarray]) -> None:
    """No pixel brighter than facets aimed at its half-vector over its whole footprint."""
    p0, p1, width = scratches.p0, scratches.p1, scratches.width
    lo = np.minimum(p0, p1) - width[:, None] / 2
    hi = np.maximum(p0, p1) + width[:, None] / 2
    scratch_area = width * np.linalg.norm(p1 - p0, axis=1)
    d_max = 1 / (math.pi * design.board.roughness**2)
    for view in design.views:
        g = _pixel_geometry(view, design)
        x, y = g["corners"][..., 0], g["corners"][..., 1]
        near = np.zeros(g["area"].shape)
        for k in range(len(scratches)):
            near += scratch_area[k] * (
                (x.min(-1) <= hi[k, 0])
                & (x.max(-1) >= lo[k, 0])
                & (y.min(-1) <= hi[k, 1])
                & (y.max(-1) >= lo[k, 1])
            )
        overlap = 1 + near / np.where(g["area"] > 0, g["area"], np.inf)
        bound = np.where(g["valid"], g["factor"] * d_max * overlap, 0.0)
        image = images[view.name].astype(np.float64)
        over = image > bound * (1 + 1e-4)
        assert not over.any(), (view.name, np.argwhere(over)[:5], image[over][:5], bound[over][:5])


def _assert_matches_reference(design: Any, scratches: ScratchSet) -> None:
    """The analytic render of a few scratches against the brute-force reference."""
    few = scratches.subset(np.arange(min(6, len(scratches))))
    ours = render_scratches(design, few, "llvm")
    spp, across, step = (1024, 256, 0.002) if FULL else (256, 96, 0.005)
    ref = reference_render(design, few, samples_per_pixel=spp, across=across, along_step_mm=step)
    for view in design.views:
        mine = np.asarray(ours[view.name], dtype=np.float64)
        theirs = ref[view.name]
        peak = max(float(theirs.max()), 1e-300)
        # the reference's sampling noise: a few percent of the brightest pixel at this density
        assert np.max(np.abs(mine - theirs)) <= 0.06 * peak, (view.name, peak)
        assert abs(mine.sum() - theirs.sum()) <= 0.02 * max(theirs.sum(), 1e-300), view.name


def _assert_inside_machine(job: Path, design: Any, scratches: ScratchSet) -> None:
    hw, hh = design.board.half_extent
    reach = np.array([hw, hh]) - design.board.margin_mm + 1e-6
    for ends in (scratches.p0, scratches.p1):
        assert np.all(np.abs(ends) <= reach), "a scratch leaves the board's margin"
    if not (job / "toolpath").exists():
        return
    toolpath = Toolpath.load(job / "toolpath/toolpath.json")
    env = toolpath.profile.envelope
    strokes = toolpath.strokes.reshape(-1, 2)
    eps = 1e-9
    assert np.all((strokes[:, 0] >= env.x_mm[0] - eps) & (strokes[:, 0] <= env.x_mm[1] + eps))
    assert np.all((strokes[:, 1] >= env.y_mm[0] - eps) & (strokes[:, 1] <= env.y_mm[1] + eps))
    run = interpret((job / "export/board.gcode").read_text())
    for move in run.moves:
        for lo_hi, value in zip((env.x_mm, env.y_mm, env.z_mm), move.end, strict=True):
            assert math.isnan(value) or lo_hi[0] - 1e-3 <= value <= lo_hi[1] + 1e-3, move


@pytest.mark.parametrize(("mutate", "slow"), CASES)
def test_extreme_design_through_the_pipeline(tmp_path: Path, mutate: Mutate, slow: bool) -> None:
    """Design -> optimize -> verify -> toolpath -> export: every output finite and in bounds."""
    pipe = load_pipeline(_write_case(tmp_path, mutate))
    job = tmp_path / "job"
    whole = FULL or not slow
    began = time.perf_counter()
    run_pipeline(pipe, job, until="export" if whole else "optimize")
    seconds = time.perf_counter() - began
    # a tiny design must not take long (kernel compilation of a first run included)
    assert seconds < 30, seconds
    _assert_files_finite(job)
    design = load_design(job / "design/design.toml")
    scratches = load_scratches(job / "optimize/scratches.csv", design.scratch, design.board)
    images = {v.name: np.load(job / f"optimize/renders/{v.name}.npy") for v in design.views}
    _assert_energy_bound(design, scratches, images)
    _assert_matches_reference(design, scratches)
    _assert_inside_machine(job, design, scratches)


@pytest.mark.parametrize(
    "mutate",
    [
        (lambda d: (_force(d), _views(d, 0, elevation_deg=89.9))),
        (lambda d: d["board"].update(width_mm=100.0, height_mm=2.0, margin_mm=0.2)),
        (lambda d: _views(d, 0, resolution=[1, 48])),
    ],
    ids=["grazing_view", "strip_under_a_pixel", "one_column_image"],
)
def test_a_view_that_sees_no_board_pixel_is_refused(tmp_path: Path, mutate: Mutate) -> None:
    """Valid keys, but no pixel centre on the board: refused up front, even with force.

    It used to run through: loss 0 for that view, nothing optimized, rho 0 in the metrics.
    """
    pipe = load_pipeline(_write_case(tmp_path, mutate))
    with pytest.raises(ConfigError, match=r"views\[0\] \('disc'\): no pixel .* on the board"):
        run_pipeline(pipe, tmp_path / "job", until="design")
    assert not (tmp_path / "job/design").exists()


@pytest.mark.parametrize(
    ("light", "key"),
    [
        ({"position_mm": [0.0, 187.3, 463.6], "intensity": 1e300}, "light"),
        ({"position_mm": [0.0, 187.3, 463.6], "intensity": 1e-300}, "light"),
        ({"position_mm": [0.0, 0.0, 1e-9]}, "light"),
        ({"position_mm": [0.0, 0.0, 1e-200]}, "light"),
        ({"position_mm": [0.0, 187.3, 463.6], "intensity": 1e-6}, r"views\[1\].light_position_mm"),
    ],
    ids=["bright", "dim", "touching", "at_zero_distance", "dim_view_light"],
)
def test_a_light_whose_renders_leave_float32_is_refused(light: dict[str, Any], key: str) -> None:
    """Intensity is only bounded below by 0; renders are float32 (SPEC section 5).

    1e300 overflowed every render to inf (the optimizer then stopped with 'non-finite loss
    ... try smaller learning rates'); 1e-300 underflowed them to 0, and the whole pipeline
    ran on black renders without a word.
    """
    data = copy.deepcopy({k: BASE[k] for k in ("board", "scratch", "views")})
    data["light"] = light
    data["views"][1]["light_position_mm"] = [0.0, 9e5, 9e5]
    with pytest.raises(ConfigError, match=rf"<x>: {key}: intensity .* outside the"):
        design_from_mapping(data, "<x>", Path("."))


def test_the_light_scale_bounds_keep_renders_finite_and_nonzero(m: Any) -> None:
    """At both ends of the accepted range the analytic render is finite and not all zero."""
    from scratchfab.model.design import RADIANCE_SCALE

    for scale in RADIANCE_SCALE:
        data = copy.deepcopy({k: BASE[k] for k in ("board", "scratch", "views")})
        position = np.array([0.0, 187.3, 463.6])
        intensity = scale * 4 * float(position @ position)
        inside = 1.001 if scale < 1 else 0.999
        data["light"] = {"position_mm": position.tolist(), "intensity": intensity * inside}
        design = design_from_mapping(data, "<x>", Path("."))
        tool = design.scratch
        few = ScratchSet.from_arrays([[-5.0, 0.0]], [[5.0, 1.0]], tool.width_mm, tool.depth_mm)
        for name, image in render_scratches(design, few, "llvm").items():
            image = np.asarray(image)
            assert np.all(np.isfinite(image)) and image.max() > 0, (scale, name)
