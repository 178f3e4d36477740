"""design says where to stand and where the light goes, in report.html's words, and
warns of targets that will show poorly (mostly bright) or refuses ones that show nothing
(black)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import cli_run, design_sun_and_moon
from PIL import Image

from scratchfab.bundled import bundled_dir
from scratchfab.design.stage import BRIGHT_TARGET_MEAN, load_source
from scratchfab.design.stand import place, side, stand_lines, stand_text
from scratchfab.model.design import design_from_mapping, load_design, position_from_polar

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "scratchfab" / "data" / "demo"
DEMO_TOML = bundled_dir("pipelines") / "demo.toml"


@pytest.mark.parametrize(
    ("polar", "subject", "said"),
    [
        ((0.0, 0.0, 500.0), "the board’s front", "straight in front of the board, level with "
         "its centre, 50 cm away"),
        ((0.4, -0.4, 504.0), "the board’s front", "straight in front of the board, level with "
         "its centre, 50 cm away"),
        ((-30.0, 10.0, 800.0), "the board’s front", "30° to the left of the board’s front, "
         "10° above its centre, 80 cm away"),
        ((45.2, -20.0, 1234.0), "the board", "45° to the right of the board, 20° below its "
         "centre, 123 cm away"),
        ((0.0, 22.0, 500.0), "the board", "straight in front of the board, 22° above its "
         "centre, 50 cm away"),
    ],
)  # fmt: skip
def test_place_words_a_point_in_front_of_the_board(polar, subject, said):
    assert place(position_from_polar(*polar), subject) == said


def test_side_rounds_to_whole_degrees():
    assert side(0.49) == side(-0.49) == "straight in front"
    assert side(-0.51) == "1° to the left" and side(21.6) == "22° to the right"


def _demo_design():
    design, _ = load_source(DEMO_TOML)
    return design


def test_stand_text_is_what_the_report_says_for_the_demo():
    """The report's "Where to stand" list holds each view's text (as it stood when moved)."""
    from scratchfab.pipeline import report

    design = _demo_design()
    section = report._stand_section(design, {})
    for view in design.views:
        assert f"<b>{view.name}</b>: {stand_text(design, view)}.</li>" in section
    # The demo's file: cameras 22° left and right, level, 500 mm; light 22° up, 500 mm.
    sun, house = design.views
    light = "light straight in front of the board, 22° above its centre, 50 cm away"
    assert stand_text(design, sun) == (
        f"stand 22° to the left of the board’s front, level with its centre, 50 cm away; {light}"
    )
    assert stand_text(design, house, light=False) == (
        "stand 22° to the right of the board’s front, level with its centre, 50 cm away"
    )


def test_stand_lines_name_the_light_once_when_shared_else_per_view(tmp_path):
    design = _demo_design()
    lines = stand_lines(design)
    assert lines[0].startswith("where to stand (angles from the board’s front")
    assert lines[1:] == [
        f"  sun: {stand_text(design, design.views[0], light=False)}",
        f"  house: {stand_text(design, design.views[1], light=False)}",
        "  the light: straight in front of the board, 22° above its centre, 50 cm away",
    ]
    # A view with a light of its own: each line names its light.
    data = {
        "light": {"position_mm": [0.0, 100.0, 400.0]},
        "views": [
            {"name": "a", "position_mm": [-100.0, 0.0, 400.0], "resolution": [8, 8]},
            {
                "name": "b",
                "position_mm": [100.0, 0.0, 400.0],
                "resolution": [8, 8],
                "light_position_mm": [300.0, 0.0, 300.0],
            },
        ],
    }
    own = design_from_mapping(data, "test", tmp_path)
    lines = stand_lines(own)
    assert lines[1:] == [
        f"  a: {stand_text(own, own.views[0])}",
        f"  b: {stand_text(own, own.views[1])}",
    ]
    assert lines[2].endswith(
        "; light 45° to the right of the board, level with its centre, 42 cm away"
    )


def _board_mean(job: Path, name: str) -> float:
    """The mean linear brightness of a view's board picture, decoded here from its PNG."""
    codes = np.asarray(Image.open(job / "design" / "board" / f"{name}.png"), dtype=np.float64)
    v = codes / 65535.0
    return float(np.mean(np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)))


def test_design_prints_where_to_stand_from_its_own_design_file(tmp_path, capsys):
    job = tmp_path / "job"
    out = design_sun_and_moon(job, "50x40", 200, capsys)
    lines = out.splitlines()
    design = load_design(job / "design" / "design.toml", require_views=False)
    start = lines.index(stand_lines(design)[0])
    assert lines[start + 1 : start + 4] == stand_lines(design)[1:]
    assert lines[start + 4].startswith("design file: ")
    # The words agree with the file's camera positions, worked out here.
    for line, view in zip(lines[start + 1 : start + 3], design.views, strict=True):
        x, y, z = view.position_mm
        azimuth = math.degrees(math.atan2(x, z))
        assert line.startswith(f"  {view.name}: stand {abs(azimuth):.0f}° to the ")
        assert line.endswith(f"{math.sqrt(x * x + y * y + z * z) / 10:.0f} cm away")
        assert ("left" in line) == (azimuth < 0)
    lx, ly, lz = design.light.position_mm
    assert lines[start + 3] == (
        f"  the light: straight in front of the board, "
        f"{math.degrees(math.atan2(ly, math.hypot(lx, lz))):.0f}° above its centre, "
        f"{math.sqrt(lx * lx + ly * ly + lz * lz) / 10:.0f} cm away"
    )


def _shares(tmp_path: Path, share: float, name: str) -> Path:
    """A 100 x 80 picture whose left ``share`` of every row is white, the rest black."""
    row = (np.arange(100) < round(100 * share)).astype(np.uint8) * 255
    path = tmp_path / f"{name}.png"
    Image.fromarray(np.tile(row, (80, 1))).save(path)
    return path


def test_mostly_bright_targets_are_warned_of_and_dark_grounds_are_not(tmp_path, capsys):
    """Dark text on white warns, with its mean on the board; its inverse and the demo's not."""
    text = np.full((80, 100), 255, np.uint8)
    text[20:60, 20:30] = text[20:60, 60:70] = text[35:45, 30:60] = 0  # a black "H" on white
    Image.fromarray(text).save(tmp_path / "text.png")
    Image.fromarray(255 - text).save(tmp_path / "inverse.png")
    pictures = [
        tmp_path / "text.png",
        tmp_path / "inverse.png",
        _shares(tmp_path, 0.45, "under"),
        _shares(tmp_path, 0.55, "over"),
    ]
    job = tmp_path / "job"
    code, out, _ = cli_run(
        ["design", *map(str, pictures), "--board", "50x40", "--count", "200",
         "--resolution", "24", "--out", str(job)],
        capsys,
    )  # fmt: skip
    assert code == 0
    means = {p.stem: _board_mean(job, p.stem) for p in pictures}
    assert means["text"] > 0.8 and means["inverse"] < 0.2  # the board picture is the image
    assert means["under"] < BRIGHT_TARGET_MEAN < means["over"]
    warned = {line.split("'")[1]: line for line in out.splitlines() if "mostly bright" in line}
    assert sorted(warned) == ["over", "text"]
    for name, line in warned.items():
        assert f"mean linear brightness {means[name]:.2f} on the board" in line
        assert "bright = cut" in line and "invert a dark-on-white image" in line


def test_the_demo_targets_are_not_warned_of(tmp_path, capsys):
    code, out, _ = cli_run(
        ["design", str(DEMO_TOML), "--count", "100", "--resolution", "16", "--out",
         str(tmp_path / "job")],
        capsys,
    )  # fmt: skip
    assert code == 0 and "warning: target" not in out


def test_a_black_logo_on_a_transparent_ground_is_refused_unless_forced(tmp_path, capsys):
    logo = Image.new("RGBA", (40, 40), (0, 0, 0, 0))
    logo.paste((0, 0, 0, 255), (10, 10, 30, 30))
    logo.save(tmp_path / "logo.png")
    args = ["design", str(tmp_path / "logo.png"), str(DEMO / "sun.png"), "--board", "40x40",
            "--count", "100", "--resolution", "16", "--out", str(tmp_path / "job")]  # fmt: skip
    code, _, err = cli_run(args, capsys)
    assert code == 2 and not (tmp_path / "job").exists()
    assert err.startswith(f"error: {tmp_path / 'logo.png'}: the picture is black on the board")
    assert "make the logo white" in err and "use --force" in err
    code, out, _ = cli_run([*args, "--force"], capsys)
    assert code == 0 and "warning: target 'logo' is uniform (brightness 0.000" in out
    assert _board_mean(tmp_path / "job", "logo") == 0.0
