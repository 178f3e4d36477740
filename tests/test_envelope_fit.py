"""A board the machine cannot reach whole: `toolpath` refuses it, names what fits, --force plans a part.

Boards x machines through the CLI: a board that fits as placed, one that fits once moved
(the offset_mm the refusal names is checked against a brute-force search over offsets,
placed by the profile's convention written out here afresh), one that fits only turned,
and one larger than the travel.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from conftest import cli_said
from PIL import Image

from scratchfab.machine.profile import load_profile
from scratchfab.toolpath import Toolpath

#: Per origin corner: where the turned board's x and y extents start, as fractions of its
#: width and height back from offset_mm (lower-left: the board lies up and right of it).
_BACK = {
    "lower-left": (0.0, 0.0),
    "lower-right": (1.0, 0.0),
    "upper-left": (0.0, 1.0),
    "upper-right": (1.0, 1.0),
    "center": (0.5, 0.5),
}


def board_box(table: dict, size: tuple[float, float], offsets: np.ndarray) -> np.ndarray:
    """(N, 2, 2): [[xmin, ymin], [xmax, ymax]] of the board at each of (N, 2) ``offsets``.

    Per docs/files.md: the board turned, then its ``origin`` corner at offset_mm.
    """
    w, h = size
    if table["board"]["rotation_deg"] % 180 == 90:
        w, h = h, w
    bx, by = _BACK[table["board"]["origin"]]
    lo = np.asarray(offsets, dtype=np.float64) - [bx * w, by * h]
    return np.stack([lo, lo + [w, h]], axis=1)


def brute_force_offsets(table: dict, size: tuple[float, float]) -> np.ndarray:
    """Every offset_mm on a 1 mm grid that puts the whole board inside the envelope.

    Kept half a unit of the G-code's last digit inside, as the planner keeps the strokes,
    where the board is that much smaller than the travel; else on its edges.
    """
    found = _brute_force(table, size, 0.5 * 10.0 ** -table["gcode"]["decimals"])
    return found if len(found) else _brute_force(table, size, 0.0)


def _brute_force(table: dict, size: tuple[float, float], slack: float) -> np.ndarray:
    env = table["envelope"]
    xs = np.arange(math.floor(env["x_mm"][0]) - 400, math.ceil(env["x_mm"][1]) + 401)
    ys = np.arange(math.floor(env["y_mm"][0]) - 400, math.ceil(env["y_mm"][1]) + 401)
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2).astype(float)
    box = board_box(table, size, grid)
    lo = np.array([env["x_mm"][0], env["y_mm"][0]]) + slack
    hi = np.array([env["x_mm"][1], env["y_mm"][1]]) - slack
    inside = np.all(box[:, 0] >= lo, axis=1) & np.all(box[:, 1] <= hi, axis=1)
    return grid[inside]


def machine(name: str) -> dict:
    """A profile table: a bundled one, or the 3018 with its board's centre placed, turned."""
    if name == "centred-turned":
        table = load_profile("grbl-3018-diamond").to_table()
        table["envelope"]["x_mm"] = [-200.0, 0.0]
        table["envelope"]["y_mm"] = [-120.0, 0.0]
        table["board"].update(origin="center", rotation_deg=90, offset_mm=[-20.0, -20.0])
        return table
    return load_profile(name).to_table()


def write_profile(folder: Path, table: dict, name: str = "my.toml") -> Path:
    path = folder / name
    path.write_text(tomli_w.dumps(table))
    return path


@pytest.fixture(scope="module")
def picture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("picture") / "g.png"
    ramp = np.linspace(60, 250, 48).astype(np.uint8)  # light enough to scratch everywhere
    Image.fromarray(np.tile(ramp, (32, 1))).save(path)
    return path


def design_job(folder: Path, picture: Path, size: tuple[float, float], capsys) -> Path:
    """A quick-form design of ``size``, as a maker starts (no optimize: toolpath takes it)."""
    job = folder / "job"
    code, said = cli_said(
        ["design", str(picture), "--board", f"{size[0]:g}x{size[1]:g}", "--out", str(job)]
        + ["--count", "300", "--seed", "1", "--fit", "cover"],
        capsys,
    )
    assert code == 0, said
    return job


def offsets_said(text: str) -> list[tuple[float, float]]:
    return [
        (float(x), float(y)) for x, y in re.findall(r"offset_mm = \[(-?[\d.]+), (-?[\d.]+)\]", text)
    ]


def toolpath(job: Path, profile: Path, capsys, *more: str) -> tuple[int, str]:
    return cli_said(
        ["toolpath", str(job), "--machine", str(profile), "--passes", "0", *more], capsys
    )


def assert_all_cut(job: Path) -> None:
    stats = Toolpath.load(job / "toolpath" / "toolpath.json").stats
    assert stats["outside_count"] == 0 and stats["clipped_count"] == 0, stats


CASES = [
    # (machine, board W x H, what the maker meets)
    ("grbl-3018-diamond", (100.0, 100.0), "fits"),
    ("grbl-3018-diamond", (250.0, 160.0), "moved"),  # the maker's: [-220, -150] overhangs
    ("grbl-3018-diamond", (100.0, 200.0), "turned"),  # 200 mm > Y's 180 mm; fits along X
    ("grbl-3018-diamond", (320.0, 200.0), "too big"),  # the maker's first board
    ("grbl-plotter-scribe", (290.0, 150.0), "moved"),  # at (20, 20) it reaches X 310
    ("grbl-plotter-scribe", (300.0, 200.0), "moved"),  # the whole travel, from (0, 0)
    ("grbl-plotter-scribe", (120.0, 80.0), "fits"),
    ("centred-turned", (100.0, 150.0), "moved"),  # turned: 150 along X, centre at (-20, -20)
    ("centred-turned", (130.0, 150.0), "too big"),  # turned: 130 along Y's 120
]


@pytest.mark.parametrize(("name", "size", "expect"), CASES)
def test_boards_on_machines(tmp_path, picture, capsys, name, size, expect):
    table = machine(name)
    profile = write_profile(tmp_path, table)
    job = design_job(tmp_path, picture, size, capsys)
    out = job / "toolpath"
    travel = (
        table["envelope"]["x_mm"][1] - table["envelope"]["x_mm"][0],
        table["envelope"]["y_mm"][1] - table["envelope"]["y_mm"][0],
    )
    fits_here = brute_force_offsets(table, size)
    current = np.array(table["board"]["offset_mm"], dtype=np.float64)
    code, said = toolpath(job, profile, capsys)
    assert "Traceback" not in said
    if expect == "fits":
        assert code == 0 and "warning: machine" not in said, said
        assert_all_cut(job)
        return
    # Refused: exit 2, the profile file, the board, the travel; nothing written.
    assert code == 2, said
    assert f"({profile})" in said and f"whole {size[0]:g} x {size[1]:g} mm board" in said
    assert f"travel is {travel[0]:g} x {travel[1]:g} mm" in said
    assert "give --force" in said and "nothing written" in said
    assert not out.exists() or not any(out.iterdir())
    if expect == "moved":
        assert len(fits_here), "the case should fit once moved"
        (offset,) = offsets_said(said)
        # The one nearest the profile's among those the brute force finds.
        nearest = fits_here[np.argmin(np.linalg.norm(fits_here - current, axis=1))]
        assert offset == tuple(nearest)
        fixed = {**table, "board": {**table["board"], "offset_mm": list(offset)}}
    elif expect == "turned":
        assert not len(fits_here)
        assert f"make the board at most {travel[0]:g} x {travel[1]:g} mm" in said
        rotation = int(re.search(r"rotation_deg = (\d+)", said).group(1))
        (offset,) = offsets_said(said)
        turned = {**table, "board": {**table["board"], "rotation_deg": rotation}}
        fits_turned = brute_force_offsets(turned, size)
        nearest = fits_turned[np.argmin(np.linalg.norm(fits_turned - current, axis=1))]
        assert rotation % 180 != table["board"]["rotation_deg"] % 180
        assert offset == tuple(nearest)
        fixed = {**turned, "board": {**turned["board"], "offset_mm": list(offset)}}
    else:
        assert not len(fits_here) and not offsets_said(said)
        most = travel if table["board"]["rotation_deg"] % 180 == 0 else travel[::-1]
        assert f"make the board at most {most[0]:g} x {most[1]:g} mm" in said
        return
    # The change the refusal names cuts the whole board.
    code, said = toolpath(job, write_profile(tmp_path, fixed, "fixed.toml"), capsys)
    assert code == 0 and "warning: machine" not in said, said
    assert_all_cut(job)


def test_force_plans_the_part_export_repeats_it_and_nothing_leaves_the_envelope(
    tmp_path, picture, capsys
):
    table = machine("grbl-3018-diamond")
    profile = write_profile(tmp_path, table)
    job = design_job(tmp_path, picture, (250.0, 160.0), capsys)
    code, said = toolpath(job, profile, capsys, "--force")
    assert code == 0 and "warning: machine" in said and "offset_mm = [" in said
    stats = Toolpath.load(job / "toolpath" / "toolpath.json").stats
    lost = f"{stats['outside_count']} of {stats['input_count']} scratches lie outside"
    assert stats["outside_count"] > 0 and lost in said
    code, said = cli_said(["export", str(job), "--format", "gcode"], capsys)
    assert code == 0 and "holds a partial board" in said and lost in said
    gcode = (job / "export" / "board.gcode").read_text()
    assert f"(PARTIAL BOARD: {stats['outside_count']} of {stats['input_count']} " in gcode
    env = table["envelope"]
    for axis, (lo, hi) in (("X", env["x_mm"]), ("Y", env["y_mm"])):
        values = [float(v) for v in re.findall(rf"^[^(].*?{axis}(-?[\d.]+)", gcode, re.M)]
        assert values and lo <= min(values) and max(values) <= hi


def test_a_refusal_leaves_an_earlier_toolpath_as_it_was(tmp_path, picture, capsys):
    table = machine("grbl-3018-diamond")
    job = design_job(tmp_path, picture, (250.0, 160.0), capsys)
    good = {**table, "board": {**table["board"], "offset_mm": [-260.0, -170.0]}}
    code, said = toolpath(job, write_profile(tmp_path, good, "good.toml"), capsys)
    assert code == 0, said
    before = {p.name: p.read_bytes() for p in (job / "toolpath").iterdir()}
    code, said = toolpath(job, write_profile(tmp_path, table), capsys)
    assert code == 2 and "nothing written" in said
    assert {p.name: p.read_bytes() for p in (job / "toolpath").iterdir()} == before


def test_a_board_wholly_off_the_envelope_names_an_offset_that_fits(tmp_path, picture, capsys):
    table = machine("grbl-plotter-scribe")
    table["board"]["offset_mm"] = [500.0, -400.0]
    job = design_job(tmp_path, picture, (100.0, 80.0), capsys)
    code, said = toolpath(job, write_profile(tmp_path, table), capsys, "--force")
    assert code == 2 and "lies wholly outside" in said, said
    (offset,) = offsets_said(said)
    fits = brute_force_offsets(table, (100.0, 80.0))
    nearest = fits[np.argmin(np.linalg.norm(fits - [500.0, -400.0], axis=1))]
    assert offset == tuple(nearest)


@pytest.mark.parametrize("origin", sorted(_BACK))
@pytest.mark.parametrize("rotation", [0, 90, 180, 270])
def test_fitting_offset_follows_every_origin_and_turn(origin, rotation):
    from scratchfab.machine.profile import profile_from_mapping

    table = machine("grbl-3018-diamond")  # X -300..0, Y -180..0
    table["board"].update(origin=origin, rotation_deg=rotation, offset_mm=[37.5, -412.25])
    size = (170.0, 120.0)  # fits either way round
    got = profile_from_mapping(table, "<p>").fitting_offset(size)
    fits = brute_force_offsets(table, size)
    nearest = fits[np.argmin(np.linalg.norm(fits - [37.5, -412.25], axis=1))]
    assert got == tuple(nearest)
    # Too long for Y when turned so that its 200 mm lie along Y; never for X.
    long = profile_from_mapping(table, "<p>").fitting_offset((100.0, 200.0))
    assert (
        (long is None)
        is (rotation % 180 == 0)
        is (not len(brute_force_offsets(table, (100.0, 200.0))))
    )


def test_advice_for_a_bundled_profile_says_to_copy_it_and_for_a_file_does_not(tmp_path):
    """The bundled file lives in the package: the advice says where the change must go."""
    from scratchfab.bundled import bundled_dir
    from scratchfab.machine.profile import load_profile
    from scratchfab.toolpath.plan import fit_advice

    bundled = load_profile("grbl-3018-diamond")
    source = bundled_dir("machine_profiles") / "grbl-3018-diamond.toml"
    mine = tmp_path / "my-3018.toml"
    mine.write_text(source.read_text())
    for board in ((250.0, 160.0), (400.0, 100.0)):  # needs an offset; larger than the travel
        said = fit_advice(bundled, board)
        assert f"is a bundled profile: copy {source} to a file of your own" in said
        assert "give that file as --machine" in said
        assert "bundled profile" not in fit_advice(load_profile(mine), board)


def test_a_stroke_ending_on_the_envelopes_edge_is_not_counted_as_clipped():
    """A board as large as the travel: a stroke that ends on the envelope's edge is kept
    half a written digit inside it (rounding), which is no clipping by the envelope."""
    from dataclasses import replace

    from scratchfab.machine.profile import load_profile
    from scratchfab.model.design import Board
    from scratchfab.model.scratches import ScratchSet
    from scratchfab.toolpath.order import OrderOptions
    from scratchfab.toolpath.plan import plan_toolpath

    profile = load_profile("grbl-plotter-scribe")
    profile = replace(profile, board=replace(profile.board, offset_mm=(0.0, 0.0)))
    width = profile.envelope.x_mm[1] - profile.envelope.x_mm[0]
    height = profile.envelope.y_mm[1] - profile.envelope.y_mm[0]
    end = width / 2  # the board's right edge, on the envelope's
    scratches = ScratchSet(
        np.array([[end - 10.0, 0.0], [end - 30.0, 5.0]]),
        np.array([[end, 0.0], [end + 5.0, 5.0]]),  # the second crosses it: clipped
        np.full(2, 0.1),
        np.full(2, 0.01),
    )
    board = Board(width_mm=width, height_mm=height, margin_mm=0.0)
    planned = plan_toolpath(scratches, board, profile, None, OrderOptions(passes=0, kicks=0))
    assert planned.stats["outside_count"] == 0
    assert planned.stats["clipped_count"] == 1
    assert planned.strokes[:, :, 0].max() <= profile.envelope.x_mm[1]
