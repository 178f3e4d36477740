"""Shared fixtures. Helpers add fixtures here by appending; never rewrite the file."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from hypothesis import settings
from PIL import Image, ImageDraw

from scratchfab.backend import array_module
from scratchfab.model.design import Design, design_from_mapping

#: Heavy cases run in full only with SCRATCHFAB_FULL=1 (CI runs them reduced).
FULL = os.environ.get("SCRATCHFAB_FULL") == "1"

# Property tests draw the same examples on every run (the suite is deterministic);
# SCRATCHFAB_FULL=1 explores new random examples instead.
settings.register_profile("deterministic", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile("explore" if FULL else "deterministic")


@pytest.fixture(scope="session")
def m() -> ModuleType:
    """Dr.Jit's LLVM AD array namespace (drjit.llvm.ad)."""
    return array_module("llvm")


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator; tests take randomness only from here or their own seeds."""
    return np.random.default_rng(20231121)


def make_design(views: int = 2, resolution: int = 32, size_mm: float = 40.0) -> Design:
    """A small two-view design used across tests (left/right cameras, light above)."""
    tables = {
        "board": {"width_mm": size_mm, "height_mm": size_mm, "roughness": 0.05, "margin_mm": 1.0},
        "light": {"position_mm": [0.0, 150.0, 300.0]},
        "scratch": {
            "width_mm": 0.1,
            "depth_mm": 0.01,
            "count": 200,
            "min_length_mm": 1.0,
            "max_length_mm": 6.0,
        },
        "views": [
            {
                "name": name,
                "position_mm": [x, 0.0, 300.0],
                "fov_deg": "auto",
                "resolution": [resolution, resolution],
            }
            for name, x in [("left", -120.0), ("right", 120.0), ("top", 0.0)][:views]
        ],
    }
    return design_from_mapping(tables, "<test design>", Path("."))


@pytest.fixture
def small_design() -> Design:
    """Two views, 32x32 pixels, 40 mm board."""
    return make_design()


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def chromium_dom(page: Path, profile_dir: Path, window: str | None = None) -> str:
    """The DOM of ``page`` after its scripts ran, from Debian's headless Chromium
    (``window``: its size, e.g. ``"1200,900"``; None: Chromium's default)."""
    assert CHROMIUM is not None
    return subprocess.run(
        [
            CHROMIUM,
            *([f"--window-size={window}"] if window else []),
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            f"--user-data-dir={profile_dir}",
            "--virtual-time-budget=5000",
            "--dump-dom",
            page.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout


def check_report_in_chromium(report: Path, profile_dir: Path) -> dict[str, str]:
    """Load a report in Chromium: every image must decode; returns the metrics it shows."""
    dom = chromium_dom(report, profile_dir)
    total = re.search(r'data-total="(\d+)"', dom)
    decoded = re.search(r'data-decoded="(\d+)"', dom)
    assert total and decoded, dom[:2000]
    assert int(total.group(1)) > 0 and decoded.group(1) == total.group(1)
    return dict(re.findall(r'data-metric="([^"]+)"[^>]*>([^<]*)<', dom))


PIPELINE = """
[board]
width_mm = 30.0
height_mm = 30.0
margin_mm = 1.5

[light]
position_mm = [0.0, 187.3, 463.6]

[scratch]
count = 250
min_length_mm = 1.5
max_length_mm = 5.0

[[views]]
name = "disc"
target = "disc.png"
azimuth_deg = -22.0
elevation_deg = 0.0
distance_mm = 400.0
fov_deg = "auto"
resolution = [24, 24]

[[views]]
name = "bar"
target = "bar.png"
azimuth_deg = 22.0
elevation_deg = 0.0
distance_mm = 400.0
fov_deg = "auto"
resolution = [24, 24]

[pipeline]
name = "tiny"

[optimize]
iterations = 4

[verify]
spp = 256
min_rho = {min_rho}

[toolpath]
machine = "grbl-3018-diamond"

[export]
formats = {formats}

[stream]
port = "grblsim://?time_scale=0&$130=300&$131=180&$132=45"
"""


def write_disc_and_bar(folder: Path) -> None:
    """The two 64 x 64 targets of the tiny pipelines: a white disc and a white bar on black."""
    disc = Image.new("L", (64, 64), 0)
    ImageDraw.Draw(disc).ellipse((12, 12, 52, 52), fill=255)
    disc.save(folder / "disc.png")
    bar = Image.new("L", (64, 64), 0)
    ImageDraw.Draw(bar).rectangle((8, 26, 56, 38), fill=255)
    bar.save(folder / "bar.png")


def write_pipeline(
    folder: Path,
    min_rho: float = -1.0,
    formats: str = '["gcode", "svg"]',
    edits: dict[str, str] | None = None,
) -> Path:
    """A tiny two-view pipeline (disc and bar targets) in ``folder``, every stage in seconds.

    ``edits`` replaces text of the file (old -> new) for a variant.
    """
    folder.mkdir(parents=True, exist_ok=True)
    write_disc_and_bar(folder)
    text = PIPELINE.format(min_rho=min_rho, formats=formats)
    for old, new in (edits or {}).items():
        assert old in text, old
        text = text.replace(old, new)
    path = folder / "tiny.toml"
    path.write_text(text)
    return path


def pasted_words(command: str, cwd: Path) -> list[str]:
    """The arguments a POSIX shell hands ``scratchfab`` when a person pastes ``command``.

    ``scratchfab`` is a shell function here that prints its arguments, so a command the
    shell would expand (``$(...)``, a quote left open) shows it instead of running anything.
    """
    script = 'scratchfab() { printf "%s\\0" "$@"; }\n' + command
    done = subprocess.run(["sh", "-c", script], cwd=cwd, capture_output=True, check=True)
    assert done.stderr == b"", done.stderr
    return ["scratchfab", *done.stdout.decode().split("\0")[:-1]]


def assert_views_see_the_whole_board_and_are_feasible(design: Design) -> None:
    """Every camera of ``design`` sees the whole board, and the feasibility check finds no
    error and every view reachable on the whole board (the quick form's promise)."""
    from scratchfab.design.feasibility import check_feasibility
    from scratchfab.model.camera import Camera

    hw, hh = design.board.half_extent
    corners = np.array([[x, y, 0.0] for x in (-hw, hw) for y in (-hh, hh)])
    for view in design.views:
        st, front = Camera.from_view(view).project(corners)
        assert np.all(front)
        assert np.all((st[:, 0] > 0) & (st[:, 0] < view.width))
        assert np.all((st[:, 1] > 0) & (st[:, 1] < view.height))
    report = check_feasibility(design)
    assert report.errors == []
    assert all(v.reachable_fraction == 1.0 for v in report.views.values())


@pytest.fixture()
def white(tmp_path: Path) -> Path:
    """A 16 x 16 white PNG: a target image for the quick form."""
    path = tmp_path / "w.png"
    Image.new("L", (16, 16), 255).save(path)
    return path


def cli_run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """Run ``scratchfab ARGV``: its exit code (0: ran through), its stdout and its stderr."""
    from scratchfab.cli import main

    try:
        main(argv)
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


def cli_said(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """Run ``scratchfab ARGV``: its exit code (0: ran through) and everything it said."""
    code, out, err = cli_run(argv, capsys)
    return code, out + err


def design_sun_and_moon(
    job: Path, board: str, count: int, capsys: pytest.CaptureFixture[str]
) -> str:
    """``scratchfab design`` (quick form) on the bundled demo's sun and moon, 24 px views,
    into ``job``: what it printed (it must exit 0)."""
    from scratchfab.bundled import bundled_dir

    demo = bundled_dir("demo")
    images = [str(demo / "sun.png"), str(demo / "moon.png")]
    argv = ["design", *images, "--board", board, "--count", str(count), "--resolution", "24"]
    code, out, err = cli_run([*argv, "--out", str(job)], capsys)
    assert code == 0, err
    return out
