"""A board exactly as large as the machine's travel: strokes on its edge are cut, not dropped.

With ``margin_mm = 0`` a scratch may lie on the board's edge, which is then the envelope's
edge. The expected machine coordinates are written out here from the profile's
convention (docs/files.md: the board turned, its origin corner at offset_mm), and the
G-code is read back with the test interpreter: every written coordinate inside the
envelope, the edge strokes on the edge.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomli_w
from conftest import cli_said
from gcode_interp import cuts, interpret

from scratchfab.export.gcode import gcode_lines
from scratchfab.machine.profile import load_profile, profile_from_mapping
from scratchfab.model.design import Board, ScratchTool, design_from_mapping
from scratchfab.model.scratches import ScratchSet, load_scratches
from scratchfab.toolpath import Toolpath, plan_toolpath
from scratchfab.toolpath.plan import fit_advice, partial_text


def travel_sized(name: str) -> tuple[dict, tuple[float, float]]:
    """A profile table whose travel the board fills exactly, and that board's size."""
    table = load_profile("grbl-3018-diamond").to_table()  # X -300..0, Y -180..0
    if name == "lower-left":
        table["board"].update(origin="lower-left", rotation_deg=0, offset_mm=[-300.0, -180.0])
        return table, (300.0, 180.0)
    # Turned a quarter, its centre placed: 200 mm along X, 120 mm along Y.
    table["envelope"].update(x_mm=[-200.0, 0.0], y_mm=[-120.0, 0.0])
    table["board"].update(origin="center", rotation_deg=90, offset_mm=[-100.0, -60.0])
    return table, (120.0, 200.0)


def on_machine(name: str, points: np.ndarray) -> np.ndarray:
    """Board points (centred, +y up) to machine XY, by each profile's convention."""
    x, y = points[:, 0], points[:, 1]
    if name == "lower-left":  # the lower-left corner (-150, -90) at (-300, -180)
        return np.stack([x - 150.0, y - 90.0], axis=1)
    # a quarter turn counter-clockwise, (x, y) -> (-y, x), then the centre at (-100, -60)
    return np.stack([-y - 100.0, x - 60.0], axis=1)


def edge_scratches(size: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Scratches on all four edges, two from corners, one inside (none collinear)."""
    hw, hh = size[0] / 2, size[1] / 2
    rows = [
        [-hw + 10, -hh, hw - 10, -hh],  # bottom edge
        [hw - 5, hh, -hw + 5, hh],  # top edge
        [-hw, -hh + 5, -hw, hh - 5],  # left edge
        [hw, 20.0, hw, -20.0],  # right edge
        [-hw, -hh, -hw + 30, -hh + 20],  # from a corner
        [hw, hh, hw - 25, hh - 25],  # from the opposite corner
        [0.0, 0.0, 10.0, 5.0],
    ]
    data = np.array(rows, dtype=np.float64)
    return data[:, :2], data[:, 2:]


def same_segments(got: np.ndarray, want: np.ndarray, tol: float) -> bool:
    """Whether the (N, 2, 2) segments are the same set, either direction, within ``tol``."""
    if len(got) != len(want):
        return False
    left = list(range(len(want)))
    for seg in got:
        for k in left:
            if min(np.abs(seg - want[k]).max(), np.abs(seg[::-1] - want[k]).max()) <= tol:
                left.remove(k)
                break
        else:
            return False
    return True


def write_job(folder: Path, size: tuple[float, float]) -> tuple[Path, Path]:
    """A design of ``size`` with margin_mm = 0 and the scratch CSV of :func:`edge_scratches`."""
    tables = {
        "board": {"width_mm": size[0], "height_mm": size[1], "roughness": 0.05, "margin_mm": 0.0},
        "light": {"position_mm": [0.0, 150.0, 300.0]},
        "scratch": {"width_mm": 0.1, "depth_mm": 0.01, "count": 7},
        "views": [
            {"name": "front", "position_mm": [0.0, 0.0, 400.0], "fov_deg": "auto"},
        ],
    }
    design = design_from_mapping(tables, "<edge design>", folder)
    design_file = folder / "design.toml"
    design.save(design_file)
    p0, p1 = edge_scratches(size)
    scratch_file = folder / "scratches.csv"
    ScratchSet.from_arrays(p0, p1, 0.1, 0.01).save(scratch_file, design.scratch)
    return design_file, scratch_file


@pytest.mark.parametrize("name", ["lower-left", "turned-centred"])
def test_a_board_as_large_as_the_travel_is_cut_whole_edges_included(tmp_path, capsys, name):
    table, size = travel_sized(name)
    profile = tmp_path / "travel.toml"
    profile.write_text(tomli_w.dumps(table))
    design_file, scratch_file = write_job(tmp_path, size)
    out = tmp_path / "toolpath"
    code, said = cli_said(
        ["toolpath", "--scratches", str(scratch_file), "--design", str(design_file)]
        + ["--out", str(out), "--machine", str(profile), "--passes", "0"],
        capsys,
    )
    assert code == 0 and "warning" not in said and "offset_mm" not in said, said
    tp = Toolpath.load(out / "toolpath.json")
    stats = tp.stats
    assert (stats["outside_count"], stats["clipped_count"], stats["count"]) == (0, 0, 7), stats
    p0, p1 = edge_scratches(size)
    want = np.stack([on_machine(name, p0), on_machine(name, p1)], axis=1)
    assert same_segments(tp.strokes, want, 1e-9)
    env = table["envelope"]
    lo = np.array([env["x_mm"][0], env["y_mm"][0]])
    hi = np.array([env["x_mm"][1], env["y_mm"][1]])
    assert np.all(tp.strokes >= lo) and np.all(tp.strokes <= hi)
    # The G-code cuts the same strokes, each written coordinate inside the envelope.
    export = tmp_path / "board.gcode"
    code, said = cli_said(
        ["export", "--toolpath", str(out / "toolpath.json"), "-o", str(export)], capsys
    )
    assert code == 0, said
    run = interpret(export.read_text())
    cut, _ = cuts(run, table["z"]["engrave_mm"] + 1e-6)
    written = np.array([[m.start[:2], m.end[:2]] for m in cut])
    assert same_segments(written, want, 0.5e-3)
    xy = np.array([p[:2] for m in run.moves for p in (m.start, m.end) if not np.isnan(p[0])])
    assert np.all(xy >= lo) and np.all(xy <= hi)
    # The edge strokes run on the edges themselves.
    for axis in range(2):
        assert np.any(written[..., axis] == lo[axis]) and np.any(written[..., axis] == hi[axis])


def test_an_end_within_half_a_written_digit_of_the_edge_is_kept_on_it():
    table, size = travel_sized("lower-left")
    table["gcode"]["decimals"] = 1  # half a written digit: 0.05 mm
    table["tool"]["tolerance_mm"] = 0.05
    profile = profile_from_mapping(table, "<travel>")
    board = Board(width_mm=size[0], height_mm=size[1], margin_mm=0.0)
    # Top edge y = 90 on the board, y = 0 on the machine: one end 0.04 mm beyond it, one
    # 0.06 mm (the G-code would write it 0.1 mm outside: clipped).
    p0 = np.array([[-50.0, 80.0], [50.0, 80.0]])
    p1 = np.array([[-50.0, 90.04], [50.0, 90.06]])
    tp = plan_toolpath(ScratchSet.from_arrays(p0, p1, 0.1, 0.01), board, profile)
    assert (tp.stats["outside_count"], tp.stats["clipped_count"]) == (0, 1), tp.stats
    want = np.array([[[-200.0, -10.0], [-200.0, 0.0]], [[-100.0, -10.0], [-100.0, 0.0]]])
    assert same_segments(tp.strokes, want, 1e-9)
    ys = [float(w[1:]) for line in gcode_lines(tp) for w in line.split() if w[0] == "Y"]
    assert max(ys) == 0.0


def test_the_advice_never_names_the_offset_already_in_use():
    table, size = travel_sized("lower-left")
    profile = profile_from_mapping(table, "<travel>")
    board = Board(width_mm=size[0], height_mm=size[1], margin_mm=0.0)
    # Planned in memory (a scratch file is checked against the board): one scratch runs
    # 20 mm off the board's right edge, so off the envelope too.
    p0 = np.array([[0.0, 0.0], [140.0, 0.0]])
    p1 = np.array([[10.0, 0.0], [170.0, 0.0]])
    tp = plan_toolpath(ScratchSet.from_arrays(p0, p1, 0.1, 0.01), board, profile)
    assert partial_text(tp.stats) is not None
    advice = fit_advice(profile, size)
    assert "set the profile's [board] offset_mm" not in advice, advice
    assert "offset_mm = [-300, -180] already puts the whole board inside" in advice
    # Moved off its place by 1 mm, the advice names the place.
    table["board"]["offset_mm"] = [-299.0, -180.0]
    moved = fit_advice(profile_from_mapping(table, "<moved>"), size)
    assert "set the profile's [board] offset_mm = [-300, -180]" in moved, moved


def test_an_end_the_scratch_file_may_hold_beyond_the_edge_is_kept_at_six_decimals(tmp_path):
    """A scratch file's end may lie up to its on-board tolerance (1e-6 mm) beyond the board.

    With six decimals half a written digit is 5e-7 mm, less than that: such an end must
    still be moved onto the edge (the envelope's, here), not clipped as if the envelope
    cut the board short.
    """
    table, size = travel_sized("lower-left")
    table["gcode"]["decimals"] = 6
    profile = profile_from_mapping(table, "<travel>")
    board = Board(width_mm=size[0], height_mm=size[1], margin_mm=0.0)
    tool = ScratchTool()
    # Top edge y = 90 on the board (machine y = 0), right edge x = 150 (machine x = 0):
    # 9e-7 mm beyond each, within the file's tolerance, beyond half a written digit.
    beyond = 9e-7
    assert profile.envelope_slack_mm < beyond
    p0 = np.array([[-50.0, 80.0], [140.0, 0.0]])
    p1 = np.array([[-50.0, 90.0 + beyond], [150.0 + beyond, 0.0]])
    file = tmp_path / "scratches.csv"
    ScratchSet.from_arrays(p0, p1, tool.width_mm, tool.depth_mm).save(file, tool)
    scratches = load_scratches(file, tool, board)  # the file is on the board as read
    tp = plan_toolpath(scratches, board, profile)
    assert (tp.stats["outside_count"], tp.stats["clipped_count"]) == (0, 0), tp.stats
    assert partial_text(tp.stats) is None
    want = np.array([[[-200.0, -10.0], [-200.0, 0.0]], [[-10.0, -90.0], [0.0, -90.0]]])
    assert same_segments(tp.strokes, want, 1e-12)
