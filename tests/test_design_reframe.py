"""A design.toml edited and run again: its views frame the new board, and a rerun that changed
nothing optimize depends on says nothing of the optimized layout."""

from __future__ import annotations

import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scratchfab.cli import main
from scratchfab.fileio import file_sha256
from scratchfab.model.design import load_design
from scratchfab.model.job import JobLayout, design_digest

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "scratchfab" / "data" / "demo"
QUICK = [str(DEMO / "sun.png"), "--board", "30x30", "--resolution", "16x16", "--count", "40"]
WARNING = re.compile(
    r"warning: view '(\w+)' sees (\d+) % of the ([\d.]+) x ([\d.]+) mm board "
    r"\(fov_deg = ([\d.]+)\), so it shows only that part of its picture; to frame the whole "
    r'board, set views\[(\d+)\] fov_deg = "auto" in (\S+) \(([\d.]+) degrees here\)'
)


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    main(args)
    return capsys.readouterr().out


def _basis(view) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float]:
    """SPEC section 2's pinhole: position, f, r, u, tx, ty."""
    pos = np.asarray(view.position_mm, float)
    f = np.asarray(view.look_at_mm, float) - pos
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(view.up, float))
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    ty = math.tan(math.radians(float(view.fov_deg)) / 2)
    return pos, f, r, u, ty * view.resolution[0] / view.resolution[1], ty


def _corners_in_frame(view, board) -> bool:
    """Whether all four board corners project inside the frame (then the whole board does)."""
    pos, f, r, u, tx, ty = _basis(view)
    hw, hh = board.width_mm / 2, board.height_mm / 2
    for x, y in ((-hw, -hh), (hw, -hh), (hw, hh), (-hw, hh)):
        rel = np.array([x, y, 0.0]) - pos
        depth = rel @ f
        if depth <= 0 or abs(rel @ r) / depth > tx or abs(rel @ u) / depth > ty:
            return False
    return True


def _share_seen(view, board) -> float:
    """The board's area inside the frame's footprint on z = 0, exactly: the four corner rays
    of the frame meet the board plane in a quadrilateral, clipped to the board."""
    pos, f, r, u, tx, ty = _basis(view)
    quad = []
    for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        d = f + sx * tx * r + sy * ty * u
        assert d[2] < 0  # the frame's corners all look down at the board plane
        quad.append(pos[:2] - pos[2] / d[2] * d[:2])
    hw, hh = board.width_mm / 2, board.height_mm / 2
    poly = quad
    # Sutherland-Hodgman against x >= -hw, x <= hw, y >= -hh, y <= hh
    for axis, limit, sign in ((0, -hw, 1), (0, hw, -1), (1, -hh, 1), (1, hh, -1)):
        out = []
        for a, b in zip(poly, poly[1:] + poly[:1], strict=True):
            ina, inb = sign * (a[axis] - limit) >= 0, sign * (b[axis] - limit) >= 0
            if ina:
                out.append(a)
            if ina != inb:
                t = (limit - a[axis]) / (b[axis] - a[axis])
                out.append(a + t * (b - a))
        poly = out
    xs, ys = np.array([p[0] for p in poly]), np.array([p[1] for p in poly])
    area = 0.5 * abs(np.sum(xs * np.roll(ys, -1) - np.roll(xs, -1) * ys))
    return area / (board.width_mm * board.height_mm)


def _edit(path: Path, **keys: str) -> None:
    """Set top-level ``key = value`` lines of a TOML file (the first of each)."""
    text = path.read_text()
    for key, value in keys.items():
        text, n = re.subn(rf"(?m)^{key} = .*$", f"{key} = {value}", text, count=1)
        assert n == 1, key
    path.write_text(text)


def _as_optimized(job: Path) -> JobLayout:
    """The job as optimize leaves it: its layout and the record of the design it was made from."""
    layout = JobLayout(job)
    layout.optimize_dir.mkdir(exist_ok=True)
    shutil.copy(layout.design.initial_scratches, layout.optimized_scratches)
    layout.optimize_summary.write_text(json.dumps({"design_sha256": design_digest(job)}))
    return layout


def test_a_quick_form_board_made_larger_is_framed_whole(tmp_path, capsys):
    """The quick form's auto fov stays "auto" (its number a comment): a rerun after [board]
    grows frames the whole new board, as four corners projected through the camera show."""
    job = tmp_path / "job"
    _run(["design", *QUICK, "--out", str(job)], capsys)
    file = job / "design" / "design.toml"
    before = load_design(file)
    said = re.findall(
        r'(?m)^fov_deg = "auto"  # ([\d.e+-]+) degrees on this 30 x 30 mm board$', file.read_text()
    )
    assert [float(x) for x in said] == [v.fov for v in before.views]
    _edit(file, width_mm="60.0")
    out = _run(["design", str(file), "--out", str(job)], capsys)
    assert "warning: view" not in out
    after = load_design(file)
    assert after.board.width_mm == 60.0
    for view in after.views:
        assert _corners_in_frame(view, after.board)
        # the old frame would have missed part of it
        old = next(v for v in before.views if v.name == view.name)
        assert not _corners_in_frame(old, after.board)
        assert _share_seen(old, after.board) < 0.9
    assert "degrees on this 60 x 30 mm board" in file.read_text()


def test_a_numeric_fov_that_misses_part_of_the_board_is_warned_with_the_fix(tmp_path, capsys):
    """A number kept from the smaller board (a design.toml written before "auto" was kept)
    warns, naming the view, the share it sees and the fov "auto" gives; doing so frames it."""
    job = tmp_path / "job"
    _run(["design", *QUICK, "--out", str(job)], capsys)
    file = job / "design" / "design.toml"
    old_fov = load_design(file).views[0].fov
    _edit(file, fov_deg=repr(old_fov), width_mm="50.0", height_mm="45.0")
    out = _run(["design", str(file), "--out", str(job)], capsys)
    found = WARNING.search(out)
    assert found, out
    name, share, width, height, fov, index, source, auto = found.groups()
    edited = load_design(file)
    view = edited.views[int(index)]
    assert (name, float(width), float(height), source) == ("sun", 50.0, 45.0, str(file))
    assert float(fov) == pytest.approx(old_fov, rel=1e-5) == view.fov
    assert abs(int(share) - 100 * _share_seen(view, edited.board)) <= 1
    assert not _corners_in_frame(view, edited.board)
    # what it says to do
    text = file.read_text()
    file.write_text(re.sub(r"(?m)^fov_deg = .*$", 'fov_deg = "auto"', text))
    out = _run(["design", str(file), "--out", str(job)], capsys)
    assert "warning: view" not in out
    framed = load_design(file).views[0]
    assert _corners_in_frame(framed, edited.board)
    assert framed.fov == pytest.approx(float(auto), rel=1e-5)


def test_a_frame_that_sees_the_whole_board_is_not_warned(tmp_path, capsys):
    """A numeric fov wider than the board needs says nothing, and stays a number."""
    job = tmp_path / "job"
    _run(["design", *QUICK, "--out", str(job)], capsys)
    file = job / "design" / "design.toml"
    fov = load_design(file).views[0].fov
    _edit(file, fov_deg=repr(fov * 1.5))
    assert "warning: view" not in _run(["design", str(file), "--out", str(job)], capsys)
    assert f"fov_deg = {fov * 1.5!r}\n" in file.read_text()  # a number of one's own stays


def test_a_rerun_that_changes_nothing_optimize_uses_says_nothing_of_the_layout(tmp_path, capsys):
    """From the first design's file, then from the job's own design.toml (comments and paths
    rewritten), then with a comment edited: no note; a key that matters: the note."""
    a = np.zeros((24, 24), np.uint8)
    a[:, :12] = 255
    Image.fromarray(a).save(tmp_path / "a.png")
    scene = tmp_path / "scene.toml"
    scene.write_text(
        "[board]\nwidth_mm = 30.0\nheight_mm = 30.0\nmargin_mm = 1.0\n"
        "[light]\nposition_mm = [0.0, 187.3, 463.6]\n"
        "[scratch]\ncount = 40\nmin_length_mm = 1.0\nmax_length_mm = 5.0\n"
        '[[views]]\nname = "a"\ntarget = "a.png"\nazimuth_deg = 0.0\nelevation_deg = 0.0\n'
        'distance_mm = 500.0\nfov_deg = "auto"\nresolution = [16, 16]\n'
    )
    job = tmp_path / "job"
    _run(["design", str(scene), "--out", str(job)], capsys)
    layout = _as_optimized(job)
    file = layout.design.design_toml
    first = file.read_text()
    out = _run(["design", str(file), "--out", str(job)], capsys)
    assert file.read_text() != first  # the heading comment now names the earlier design
    assert "note:" not in out
    file.write_text("# my notes\n" + file.read_text())
    assert "note:" not in _run(["design", str(file), "--out", str(job)], capsys)
    _edit(file, roughness="0.08")
    out = _run(["design", str(file), "--out", str(job)], capsys)
    assert f"note: {layout.optimized_scratches} (and any toolpath or G-code made from it)" in out


def test_a_record_of_the_design_files_bytes_still_matches_an_unchanged_design(tmp_path, capsys):
    """optimize/summary.json written before records design.toml's bytes: an unchanged file
    is still current there, and a changed one is not."""
    from scratchfab.model.job import design_changed_since_optimize

    job = tmp_path / "job"
    _run(["design", *QUICK, "--out", str(job)], capsys)
    layout = _as_optimized(job)
    file = layout.design.design_toml
    digests = {p.name: file_sha256(p) for p in layout.design.digested}
    layout.optimize_summary.write_text(json.dumps({"design_sha256": digests}))
    assert design_changed_since_optimize(job) == []
    _edit(file, f0="0.5")
    assert design_changed_since_optimize(job) == ["design/design.toml"]


def test_a_frame_no_fov_can_widen_to_the_board_says_to_move_the_camera(tmp_path, capsys):
    """A camera low over a tall board has part of it behind: "auto" fails there too (the
    design says so when given it), so the warning says to move the camera instead."""
    job = tmp_path / "job"
    _run(["design", *QUICK, "--out", str(job)], capsys)
    file = tmp_path / "low.toml"
    shutil.copy(job / "design" / "design.toml", file)
    text = file.read_text()
    text = re.sub(
        r"(?m)^(position_mm = \[0\.0, 0\.0, .*\])$", "position_mm = [0.0, -60.0, 5.0]", text
    )
    file.write_text(text)
    _edit(file, height_mm="200.0", fov_deg="60.0")
    view = load_design(file).views[0]
    assert view.position_mm == (0.0, -60.0, 5.0)
    corners = [(x, y, 0.0) for x in (-15.0, 15.0) for y in (-100.0, 100.0)]
    behind = [
        c for c in corners if np.dot(np.subtract(c, view.position_mm), (0.0, 60.0, -5.0)) <= 0
    ]
    assert behind  # worked out here: the board's lower corners lie behind the camera
    with pytest.raises(SystemExit):
        main(["design", str(file), "--out", str(tmp_path / "low")])
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if "warning: view 'sun' sees" in x)
    assert 'fov_deg = "auto"' not in line, line
    assert "part of the board lies behind the camera" in line
    assert (
        f"move views[0]'s camera farther from the board (its position_mm or distance_mm in {file})"
    ) in line
    # what it no longer says: "auto" is refused from there
    _edit(file, fov_deg='"auto"')
    with pytest.raises(SystemExit):
        main(["design", str(file), "--out", str(tmp_path / "low")])
    assert "the board is not in front of the camera" in capsys.readouterr().err
