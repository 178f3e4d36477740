"""scratchfab as a library: a notebook's walk from a dict to G-code, without the CLI.

The walk runs in a fresh interpreter at a tiny size, so it also catches a core module
that imports click or writes to stdout/stderr. The other tests pin the errors a library
user meets for arrays of the wrong shape.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scratchfab.backend import array_module
from scratchfab.design.layout import initial_layout
from scratchfab.design.targets import fit_to_board, warp_to_view
from scratchfab.errors import ScratchfabError
from scratchfab.machine.profile import load_profile
from scratchfab.model.design import design_from_mapping
from scratchfab.model.scratches import ScratchSet
from scratchfab.optimize.optimizer import Settings
from scratchfab.toolpath import plan_toolpath

TABLES = {
    "board": {"width_mm": 30.0, "height_mm": 30.0, "margin_mm": 1.5},
    "light": {"position_mm": [0.0, 187.3, 463.6]},
    "scratch": {"count": 120, "min_length_mm": 1.5, "max_length_mm": 5.0},
    "views": [
        {
            "name": name,
            "azimuth_deg": azimuth,
            "elevation_deg": 0.0,
            "distance_mm": 400.0,
            "fov_deg": "auto",
            "resolution": [16, 16],
        }
        for name, azimuth in (("disc", -22.0), ("bar", 22.0))
    ],
}

WALK = f"""
import io, json, sys, tempfile
from contextlib import redirect_stdout
from pathlib import Path
import numpy as np
from scratchfab.backend import array_module
from scratchfab.design.layout import initial_layout
from scratchfab.design.targets import fit_to_board, warp_to_view
from scratchfab.export import export
from scratchfab.export.dxf import dxf_text
from scratchfab.export.gcode import gcode_lines, gcode_text
from scratchfab.export.svg import svg_text
from scratchfab.machine.profile import load_profile
from scratchfab.machine.stream_job import StreamCallbacks, StreamRequest, stream_file
from scratchfab.model.design import design_from_mapping
from scratchfab.model.scratches import ScratchSet
from scratchfab.optimize.optimizer import LayoutOptimizer, Settings
from scratchfab.optimize.options import OptimizeOptions
from scratchfab.render.renderer import render_scratches
from scratchfab.toolpath import plan_toolpath

design = design_from_mapping({TABLES!r}, "<notebook>", Path("."))
yy, xx = np.mgrid[0:48, 0:48]
pictures = {{
    "disc": ((xx - 24) ** 2 + (yy - 24) ** 2 < 15**2).astype(float),
    "bar": ((yy > 19) & (yy < 29) & (xx > 6) & (xx < 42)).astype(float),
}}
targets = {{
    v.name: warp_to_view(fit_to_board(pictures[v.name], design.board), design.board, v)
    for v in design.views
}}
layout = initial_layout(design, targets, seed=0)
lr = OptimizeOptions().learning_rates()
opt = LayoutOptimizer(design, targets, layout, Settings(lr=lr), array_module("llvm"))
losses = [opt.step().loss for _ in range(3)]
board = opt.scratches()
images = render_scratches(design, board)
profile = load_profile("grbl-3018-diamond")
toolpath = plan_toolpath(board, design.board, profile, design.scratch)
text = "\\n".join(gcode_lines(toolpath)) + "\\n"
folder = Path(sys.argv[1])
sizes = {{ext: export(toolpath, None, folder / f"board.{{ext}}")["bytes"]
         for ext in ("gcode", "svg", "dxf")}}
said = []
request = StreamRequest(
    gcode=folder / "board.gcode",
    port="grblsim://?time_scale=0&$130=300&$131=180&$132=45",
    machine=profile,
)
stream_file(request, StreamCallbacks(lambda p: None, said.append, lambda: "stop", lambda _: True))
result = {{
    "click": "click" in sys.modules,
    "layout": len(layout),
    "count": design.scratch.count,
    "losses": losses,
    "images": {{k: [list(v.shape), float(np.nanmax(v))] for k, v in images.items()}},
    "strokes": len(toolpath),
    "text_matches_file": [
        text == gcode_text(toolpath) == (folder / "board.gcode").read_text(),
        svg_text(toolpath) == (folder / "board.svg").read_text(),
        dxf_text(toolpath) == (folder / "board.dxf").read_text(),
    ],
    "sizes": sizes,
    "done": said[-1],
}}
sys.__stdout__.write("RESULT " + json.dumps(result))
"""


def test_a_notebook_walk_needs_no_cli_and_prints_nothing(tmp_path):
    run = subprocess.run(
        [sys.executable, "-c", WALK, str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stderr == ""
    assert run.stdout.startswith("RESULT "), run.stdout[:2000]
    result = json.loads(run.stdout.removeprefix("RESULT "))
    assert not result["click"]
    assert result["layout"] == result["count"]
    assert result["losses"][-1] < result["losses"][0]
    for view in TABLES["views"]:
        shape, peak = result["images"][view["name"]]
        assert shape == view["resolution"][::-1] and peak > 0
    assert 0 < result["strokes"] <= result["layout"]
    assert result["text_matches_file"] == [True, True, True]
    assert all(size > 0 for size in result["sizes"].values())
    assert result["done"].startswith("done:")
    assert (tmp_path / "board.gcode.journal.jsonl").is_file()


@pytest.fixture(scope="module")
def design():
    return design_from_mapping(TABLES, "<notebook>", Path("."))


@pytest.mark.parametrize(
    ("p0", "p1", "width"),
    [
        (np.zeros((2, 6)), np.ones((2, 6)), 0.1),  # x row and y row: transposed
        (np.zeros((4, 3)), np.ones((4, 3)), 0.1),  # 3-D points
        (np.zeros((4, 2)), np.ones((3, 2)), 0.1),  # different counts
        (np.zeros((4, 2)), np.ones((4, 2)), [0.1, 0.2]),  # widths for 2 of 4
    ],
)
def test_scratch_arrays_of_the_wrong_shape_are_refused(p0, p1, width):
    with pytest.raises(ValueError, match=r"\(N, 2\)|width"):
        ScratchSet.from_arrays(p0, p1, width, 0.01)


def test_scratch_arrays_accept_lists_and_one_point():
    one = ScratchSet.from_arrays([1.0, 2.0], [3.0, 4.0], 0.1, 0.01)
    assert one.p0.tolist() == [[1.0, 2.0]] and one.p1.tolist() == [[3.0, 4.0]]
    rows = ScratchSet.from_arrays([[0, 0], [1, 1]], [[2, 2], [3, 3]], [0.1, 0.2], 0.01)
    assert rows.width.tolist() == [0.1, 0.2] and rows.depth.tolist() == [0.01, 0.01]


def test_initial_layout_names_the_views_it_expected(design):
    with pytest.raises(ScratchfabError, match="disc, bar"):
        initial_layout(design, {"left": np.ones((16, 16))}, seed=0)


def test_initial_layout_refuses_a_target_of_another_size(design):
    with pytest.raises(ScratchfabError, match=r"disc.*8x8.*16x16"):
        initial_layout(design, {"disc": np.ones((8, 8))}, seed=0)


@pytest.mark.parametrize("shape", [(10, 10, 3), (10,)])
def test_board_images_must_be_2d(design, shape):
    with pytest.raises(ValueError, match=r"\(h, w\)"):
        fit_to_board(np.ones(shape), design.board)
    with pytest.raises(ValueError, match=r"\(rows, cols\)"):
        warp_to_view(np.ones(shape), design.board, design.views[0])


@pytest.mark.parametrize("where", ["p0", "p1"])
def test_plan_toolpath_names_a_scratch_that_is_not_finite(design, where):
    p0 = np.array([[0.0, 0.0], [1.0, 1.0], [-2.0, 3.0]])
    p1 = p0 + 2.0
    (p0 if where == "p0" else p1)[1, 0] = np.nan
    scratches = ScratchSet.from_arrays(p0, p1, 0.1, 0.01)
    with pytest.raises(ScratchfabError, match="scratch 2 "):
        plan_toolpath(scratches, design.board, load_profile("grbl-3018-diamond"))


@pytest.mark.parametrize(
    ("p0", "p1"),
    [
        (np.zeros((2, 6)), np.ones((2, 6))),  # x row and y row: transposed
        (np.zeros((4, 3)), np.ones((4, 3))),
        (np.zeros((4, 2)), np.ones((3, 2))),
    ],
)
def test_order_strokes_refuses_arrays_of_the_wrong_shape(p0, p1):
    from scratchfab.toolpath import order_strokes

    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        order_strokes(p0, p1, (0.0, 0.0))


@pytest.mark.parametrize(
    ("start", "message"),
    [
        ((0.0, 0.0, 0.0), r"start: expected one finite \(x, y\) in mm, got \(0\.0, 0\.0, 0\.0\)"),
        ([[0.0, 0.0]], r"start: expected one finite \(x, y\)"),
        ((math.nan, 0.0), r"start: expected one finite \(x, y\) in mm, got \(nan, 0\.0\)"),
        ((0.0, -math.inf), r"start: expected one finite"),
        (None, r"start: expected one finite \(x, y\) in mm, got None"),
        ("ab", r"start: expected numbers in mm, got 'ab'"),
    ],
)
def test_order_strokes_refuses_a_start_that_is_not_one_point(start, message):
    from scratchfab.toolpath import order_strokes

    p0 = np.array([[0.0, 0.0], [5.0, 5.0]])
    with pytest.raises(ValueError, match=f"^{message}"):
        order_strokes(p0, p0 + 1.0, start)


@pytest.mark.parametrize("end", ["p0", "p1"])
def test_order_strokes_names_the_first_stroke_that_is_not_finite(end):
    from scratchfab.toolpath import order_strokes

    arrays = {"p0": np.zeros((6, 2)), "p1": np.ones((6, 2))}
    arrays[end][2, 1] = math.nan
    arrays[end][4, 0] = math.inf
    with pytest.raises(ValueError, match=r"^p0 and p1: stroke 2 is not finite .*, nor are 1 more$"):
        order_strokes(arrays["p0"], arrays["p1"], (0.0, 0.0))


@pytest.mark.parametrize(
    ("column", "value"), [("p0", np.nan), ("p1", np.inf), ("width", 0.0), ("depth", np.nan)]
)
def test_render_names_a_scratch_it_cannot_draw(design, column, value):
    from scratchfab.render.renderer import render_scratches

    rng = np.random.default_rng(5)
    c = rng.uniform(-10, 10, (6, 2))
    arrays = {"p0": c - 1.0, "p1": c + 1.0, "width": np.full(6, 0.1), "depth": np.full(6, 0.01)}
    arrays[column][4] = value
    scratches = ScratchSet(**arrays)
    with pytest.raises(ScratchfabError, match=r"scratch 5 \(line 6\)"):
        render_scratches(design, scratches)


@pytest.mark.parametrize("data", [[], "board", None])
def test_design_from_something_else_than_tables_names_the_source(data):
    with pytest.raises(ScratchfabError, match="<notebook>: expected tables"):
        design_from_mapping(data, "<notebook>", Path("."))


@pytest.mark.parametrize(
    ("targets", "cross", "message"),
    [
        ({"disc": np.ones((8, 8))}, None, r"targets: disc: the image has shape \(8, 8\)"),
        ({"left": np.ones((16, 16))}, None, "targets: left names no view"),
        (None, {("disc", "left"): np.ones((16, 16))}, r"cross: \(disc, left\) names no view"),
        (None, {("bar", "disc"): np.ones((16, 8))}, r"cross: \(bar, disc\): the image"),
    ],
)
def test_verify_refuses_targets_of_other_views_before_rendering(
    design, tmp_path, targets, cross, message
):
    from scratchfab.verify.verify import VerifySettings, run_verify

    scratches = ScratchSet.from_arrays([[-5.0, 0.0]], [[5.0, 1.0]], 0.1, 0.01)
    out = tmp_path / "verify"
    with pytest.raises(ScratchfabError, match=message):
        run_verify(design, scratches, out, VerifySettings(spp=4), targets=targets, cross=cross)
    assert not out.exists()


@pytest.mark.parametrize("value", [0.0, -1.0, np.nan, np.inf])
def test_a_preview_needs_a_positive_exposure(value):
    from scratchfab.render.layout import png_bytes

    with pytest.raises(ValueError, match="exposure_value"):
        png_bytes(np.ones((4, 4)), value)


@pytest.mark.parametrize("scale", [255.0, -1.0, np.nan])
def test_a_picture_is_linear_luminance_in_0_1(design, scale):
    picture = np.ones((10, 10))
    picture[3, 4] = scale
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        fit_to_board(picture, design.board)


def test_a_scratch_set_takes_lists_as_float64_arrays():
    s = ScratchSet([[0, 0], [1, 2]], [[3, 4], [4, 6]], [0.1, 0.2], [0.01, 0.02])
    assert s.p1.dtype == np.float64 and s.p1.tolist() == [[3.0, 4.0], [4.0, 6.0]]
    assert s.lengths.tolist() == [5.0, 5.0]
    same = np.zeros((2, 2))
    assert ScratchSet(same, same, np.ones(2), np.ones(2)).p0 is same
    with pytest.raises(ValueError, match=r"\(2,\), got shapes \(\) and \(2,\)"):
        ScratchSet(same, same, 0.1, np.ones(2))


def bounded_fields():
    """(class, field, a value outside its bounds) for each bounded design/profile/optimize field."""
    from dataclasses import fields

    from scratchfab.machine.profile import Feeds, GcodeFormat, Motion, Serial, Tool, ToolControl
    from scratchfab.model.design import Board, Light, ScratchTool, View
    from scratchfab.optimize.options import OptimizeOptions

    cases = []
    for cls in (
        Board,
        Light,
        ScratchTool,
        View,
        Feeds,
        Motion,
        Tool,
        ToolControl,
        Serial,
        GcodeFormat,
        OptimizeOptions,
    ):
        for f in fields(cls):
            meta = f.metadata
            if not meta:
                continue
            if meta.get("gt") is not None:
                bad = meta["gt"]
            elif meta.get("ge") is not None:
                bad = meta["ge"] - 1.0
            else:
                bad = meta["le"] * 2.0
            cases.append((cls, f.name, bad))
    return cases


VALID = {
    "Board": {},
    "Light": {"position_mm": (0.0, 100.0, 400.0)},
    "ScratchTool": {},
    "View": {"name": "v", "position_mm": (0.0, 0.0, 400.0)},
    "Feeds": {},
    "Motion": {},
    "Tool": {"width_mm": 0.1, "depth_mm": 0.01},
    "ToolControl": {},
    "Serial": {},
    "GcodeFormat": {},
    "OptimizeOptions": {},
}


@pytest.mark.parametrize(("cls", "name", "bad"), bounded_fields())
def test_a_table_built_in_code_meets_the_files_bounds(cls, name, bad):
    """The bounds of spec() hold for a table built in code, not only for a file's."""
    kwargs = dict(VALID[cls.__name__])
    default = kwargs.get(name, getattr(cls, name, None))
    kwargs[name] = tuple(bad for _ in default) if isinstance(default, tuple) else bad
    with pytest.raises(ValueError, match=rf"{cls.__name__}\.{name}: expected a value"):
        cls(**kwargs)
    cls(**VALID[cls.__name__])


@pytest.mark.parametrize(
    ("look_at", "distance", "azimuth", "refused"),
    [
        ([0.0, 0.0, 10.0], 1e6, 0.0, True),  # z = 1e6 + 10
        ([-1.0, 0.0, 0.0], 1e6, -90.0, True),  # x = -1e6 - 1
        ([0.0, 0.0, 0.0], 1e6, 0.0, False),  # z = 1e6 exactly: the bound's edge
        ([0.0, 0.0, -10.0], 1e6, 0.0, False),
    ],
)
def test_a_polar_camera_beyond_the_coordinates_names_the_polar_keys(
    look_at, distance, azimuth, refused
):
    """Each key within its own bounds, the camera they place may lie beyond +-1e6 mm: the
    message names the keys the file has (azimuth/elevation/distance, look_at_mm), not the
    View's position_mm that it lacks; a camera on the bound itself is a camera."""
    from scratchfab.errors import ConfigError

    view = {
        "name": "far",
        "azimuth_deg": azimuth,
        "elevation_deg": 0.0,
        "distance_mm": distance,
        "look_at_mm": look_at,
        "fov_deg": 1.0,
        "resolution": [8, 8],
    }
    data = {**TABLES, "views": [view]}
    if not refused:
        design = design_from_mapping(data, "far.toml", Path("."))
        assert max(abs(c) for c in design.views[0].position_mm) == pytest.approx(1e6, abs=10)
        return
    with pytest.raises(ConfigError) as exc:
        design_from_mapping(data, "far.toml", Path("."))
    text = str(exc.value)
    assert text.startswith("far.toml: views[0]: ") and "\n" not in text
    assert "distance_mm" in text and "look_at_mm" in text and "position_mm" not in text


@pytest.mark.parametrize("damage", ["resolution", "bytes"])
def test_verify_job_names_a_stale_or_damaged_target_file(tmp_path, capsys, damage):
    """``verify-render JOB`` reads JOB/design/targets/<view>.npy: one that no longer fits
    its view (the design's resolution edited after `design`) or is not a NumPy file is
    named by its path, through the CLI as one line, before any rendering (before: a line
    without the file, or numpy's traceback)."""
    import re

    from conftest import make_design
    from test_optimize_helpers import make_job

    import scratchfab.cli as cli

    job = make_job(tmp_path / "job", make_design(resolution=24, size_mm=30.0), count=20)
    target = job / "design" / "targets" / "left.npy"
    if damage == "resolution":
        toml = job / "design" / "design.toml"
        text = toml.read_text()
        edited = re.sub(r"resolution = \[\s*24,\s*24,?\s*\]", "resolution = [32, 32]", text)
        assert edited != text
        toml.write_text(edited)
    else:
        target.write_bytes(b"\x93NUMPY\x01\x00garbage")
    with pytest.raises(SystemExit) as exc:
        cli.main(["verify-render", str(job), "--spp", "2", "--out", str(tmp_path / "v")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"error: {target}: ") and "Traceback" not in "".join(err)
    assert not (tmp_path / "v").exists()  # refused before anything was rendered or written


def test_a_single_image_path_is_not_read_as_a_list_of_views(tmp_path):
    """``quick_design("a.png")`` once made one view per character of the path."""
    from scratchfab.design.quick import quick_design

    for path in ("/tmp/disc.png", tmp_path / "disc.png"):
        with pytest.raises(ScratchfabError, match=r"expected a list of image paths.*pass \["):
            quick_design(path, (40.0, 40.0))  # type: ignore[arg-type]


def test_an_unknown_backend_is_named_as_such():
    from scratchfab.errors import BackendError

    with pytest.raises(BackendError, match=r"unknown backend 'cpu': expected 'llvm'"):
        array_module("cpu")  # type: ignore[arg-type]


def test_initial_layout_needs_a_seed(design):
    targets = {v.name: np.ones((v.height, v.width)) for v in design.views}
    with pytest.raises(ValueError, match="seed"):
        initial_layout(design, targets, seed=None)  # type: ignore[arg-type]
    first, again = (initial_layout(design, targets, seed=3) for _ in range(2))
    assert np.array_equal(first.p0, again.p0) and np.array_equal(first.p1, again.p1)


def test_settings_of_the_options_are_the_stages():
    """``Settings.of`` gives a loop what the optimize stage gives it: each field from its
    option, the schedule the options make unless one is given."""
    from scratchfab.optimize.options import OptimizeOptions, StepSchedule

    options = OptimizeOptions(iterations=30, refresh_every=5, space="perceptual",
                              merge_weight=0.5, lr_schedule="linear")  # fmt: skip
    settings = Settings.of(options)
    assert settings.lr == options.learning_rates() and settings.refresh_every == 5
    assert settings.space == "perceptual" and settings.merge_weight == 0.5
    assert settings.schedule == options.schedule() and settings.schedule is not None
    longer = StepSchedule("linear", 4.0, 1.0, 60)
    assert Settings.of(options, longer).schedule == longer
    assert Settings.of(OptimizeOptions(lr_schedule="constant")).schedule is None
