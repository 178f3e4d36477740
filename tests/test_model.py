from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from scratchfab.errors import ConfigError
from scratchfab.model.camera import Camera, polygon_area
from scratchfab.model.design import design_from_mapping, load_design
from scratchfab.model.scratches import ScratchSet, load_scratches

BASE = {
    "board": {"width_mm": 100.0, "height_mm": 80.0},
    "light": {"position_mm": [0.0, 300.0, 500.0]},
    "views": [{"name": "left", "position_mm": [-180.0, 0.0, 500.0], "resolution": [64, 48]}],
}


def _with(path: str, value):
    import copy

    data = copy.deepcopy(BASE)
    node = data
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[int(k)] if k.isdigit() else node[k]
    node[keys[-1]] = value
    return data


BAD_DESIGNS = [
    (_with("board.widht_mm", 1.0), "unknown key 'widht_mm' (did you mean 'width_mm'?)"),
    (_with("board.width_mm", -1.0), "board.width_mm: expected a value greater than 0"),
    (_with("board.width_mm", "wide"), "board.width_mm: expected a number"),
    (_with("board.width_mm", float("nan")), "board.width_mm: expected a finite number"),
    (_with("board.roughness", 0.0), "board.roughness: expected a value in [0.005, 1]"),
    (_with("board.roughness", 0.004), "board.roughness: expected a value in [0.005, 1]"),
    (_with("board.roughness", 1.5), "board.roughness: expected a value in [0.005, 1]"),
    (_with("light.position_mm", [0.0, 1.0, 0.0]), "in front of the board (z > 0)"),
    (_with("views.0.position_mm", [0.0, 1.0, -5.0]), "camera must be in front of the board"),
    (_with("views.0.fov_deg", 170.0), "fov_deg must be in (0, 170)"),
    (_with("views.0.fov_deg", 0.0), "fov_deg must be in (0, 170)"),
    (_with("views", [{"name": "a", "position_mm": [0, 0, 1.0]}] * 2), "duplicate view name 'a'"),
    (_with("views.0.resolution", [64]), "views[0].resolution: expected a list of 2"),
    ({"board": {}, "views": BASE["views"]}, "missing required table [light]"),
    (_with("views.0.name", "a/b"), "not file-name safe"),
    (_with("views.0.name", "NUL"), "not a Windows device name"),
    (_with("views.0.name", "com3.left"), "not a Windows device name"),
    (
        _with("views", [{"name": n, "position_mm": [0, 0, 1.0]} for n in ("Left", "left")]),
        "duplicate view name 'left' (names that differ only in case",
    ),
    (_with("views.0.resolution", [400000, 400000]), "resolution must be two integers in 1..16384"),
    ({**BASE, "scratch": {"count": 10**11}}, "scratch.count: expected a value in (0, 10000000]"),
]


@pytest.mark.parametrize(("data", "message"), BAD_DESIGNS)
def test_design_errors_name_file_and_key(data, message):
    with pytest.raises(ConfigError) as info:
        design_from_mapping(data, "scene.toml", Path("."))
    text = str(info.value)
    assert text.startswith("scene.toml:")
    assert message in text
    assert "\n" not in text


def test_design_roundtrip_and_polar_view(tmp_path):
    data = _with(
        "views",
        [
            {
                "name": "v",
                "azimuth_deg": 30.0,
                "elevation_deg": 10.0,
                "distance_mm": 400.0,
                "fov_deg": "auto",
                "target": "cat.png",
                "resolution": [64, 48],
            }
        ],
    )
    design = design_from_mapping(data, "scene.toml", tmp_path)
    view = design.views[0]
    az, el = math.radians(30), math.radians(10)
    assert np.allclose(
        view.position_mm,
        [400 * math.cos(el) * math.sin(az), 400 * math.sin(el), 400 * math.cos(el) * math.cos(az)],
    )
    assert 0 < view.fov < 170
    out = tmp_path / "resolved.toml"
    design.save(out)
    again = load_design(out)
    assert again.views[0].position_mm == pytest.approx(view.position_mm)
    assert again.target_path(again.views[0]) == tmp_path / "cat.png"
    # auto fov: every board corner inside the frame, and not by much
    cam = Camera.from_view(view)
    corners = np.array([[sx * 50, sy * 40, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    st, front = cam.project(corners)
    assert front.all()
    assert (st[:, 0] >= 0).all() and (st[:, 0] <= 64).all()
    assert (st[:, 1] >= 0).all() and (st[:, 1] <= 48).all()
    reach = max(np.abs(st[:, 0] - 32).max() / 32, np.abs(st[:, 1] - 24).max() / 24)
    assert reach == pytest.approx(1 / 1.08, rel=1e-9)  # the outermost corner: 8% margin


def test_camera_matches_spec_and_footprints_tile(small_design):
    view = small_design.views[0]
    cam = Camera.from_view(view)
    # Ray through the image centre goes along f; project() inverts directions().
    d = cam.directions(np.array(view.width / 2), np.array(view.height / 2))
    assert np.allclose(d, cam.forward)
    pts, valid = cam.center_grid()
    assert valid.all()
    st, _ = cam.project(np.concatenate([pts, np.zeros(pts.shape[:-1] + (1,))], axis=-1))
    j, i = np.mgrid[0 : view.height, 0 : view.width]
    assert np.allclose(st[..., 0], i + 0.5) and np.allclose(st[..., 1], j + 0.5)
    quads, qvalid = cam.footprints()
    area = polygon_area(quads)
    assert qvalid.all() and (area > 0).all()  # counter-clockwise on the board
    # Footprints tile the image of the frame: total area equals the frame's quadrilateral.
    corner_pts, _ = cam.corner_grid()
    frame = np.stack([corner_pts[0, 0], corner_pts[-1, 0], corner_pts[-1, -1], corner_pts[0, -1]])
    assert area.sum() == pytest.approx(polygon_area(frame), rel=1e-9)
    # Image top edge is +y on the board, left edge -x (SPEC section 5).
    assert pts[0, 0, 1] > pts[-1, 0, 1] and pts[0, 0, 0] < pts[0, -1, 0]


BAD_ROWS = [
    ("x0,y0,x1,y1\n1,2,3\n", "line 2: expected 4 values, got 3"),
    ("x0,y0,x1,y1\n1,2,1,2\n", "line 2: scratch has zero length"),
    ("x0,y0,x1,y1\n0,0,1,nan\n", "line 2: column y1: expected a finite number"),
    ("x0,y0,x1,y1\n0,0,1,abc\n", "line 2: column y1: expected a number, got 'abc'"),
    ("x0,y0,x1,y1\n0,0,1,1\n0,0,60,0\n", "line 3: scratch leaves the board"),
    ("x0,y0,x1,y1,width,depth\n0,0,1,1,-0.1,0.01\n", "column width: expected a positive size"),
    ("x0,y0,x2,y1\n", "header must be x0,y0,x1,y1"),
    ("", "empty file"),
]


@pytest.mark.parametrize(("text", "message"), BAD_ROWS)
def test_scratch_csv_errors(tmp_path, small_design, text, message):
    path = tmp_path / "s.csv"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_scratches(path, small_design.scratch, small_design.board)
    assert str(info.value).startswith(str(path))
    assert message in str(info.value)


def test_design_toml_writes_each_point_on_one_line_and_reads_back_the_same(tmp_path, monkeypatch):
    """A point reads as a person writes it, ``[x, y, z]``, and every value reads back as
    tomli_w's own (one item per line) text of the same design reads."""
    import tomllib

    import scratchfab.model.design as design_module

    data = _with("light", {"position_mm": [-0.0, 1e-7, 123456.789012345], "intensity": 1.0})
    design = design_from_mapping(data, "scene.toml", tmp_path)
    text = design.to_toml()
    points = [line for line in text.splitlines() if line.startswith(("position_mm", "up ="))]
    assert len(points) >= 3 and all(p.endswith("]") and p.count(",") == 2 for p in points)
    monkeypatch.setattr(design_module, "_numbers_on_one_line", lambda t: t)
    spread = design.to_toml()
    assert "position_mm = [\n" in spread  # what tomli_w writes
    assert tomllib.loads(text) == tomllib.loads(spread)
    assert tomllib.loads(text)["light"]["position_mm"] == [-0.0, 1e-7, 123456.789012345]


def test_scratch_csv_roundtrip(tmp_path, small_design, rng):
    p0 = rng.uniform(-10, 10, (20, 2))
    s = ScratchSet.from_arrays(p0, p0 + 1.5, rng.uniform(0.05, 0.2, 20), 0.01)
    s.save(tmp_path / "s.csv", small_design.scratch)
    back = load_scratches(tmp_path / "s.csv", small_design.scratch, small_design.board)
    for a, b in [(s.p0, back.p0), (s.p1, back.p1), (s.width, back.width), (s.depth, back.depth)]:
        assert np.array_equal(a, b)


def test_atomic_write_gives_the_usual_permissions_and_keeps_the_old_file(tmp_path):
    import os

    from scratchfab.fileio import atomic_open, write_text

    mask = os.umask(0)
    os.umask(mask)
    write_text(tmp_path / "b.txt", "old")
    assert (tmp_path / "b.txt").stat().st_mode & 0o777 == 0o666 & ~mask  # not mkstemp's 0600
    with pytest.raises(RuntimeError), atomic_open(tmp_path / "b.txt") as handle:
        handle.write("half")
        raise RuntimeError("writer failed")
    assert (tmp_path / "b.txt").read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["b.txt"]  # no temporary file left


def test_full_disk_is_one_line_naming_the_file_and_keeps_the_old_one(tmp_path, monkeypatch):
    import errno
    import os

    from scratchfab.errors import ScratchfabError
    from scratchfab.fileio import atomic_folder, write_text

    write_text(tmp_path / "b.txt", "old")
    with atomic_folder(tmp_path / "stage") as new:
        write_text(new / "a.txt", "old")

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(ScratchfabError) as info:
        write_text(tmp_path / "b.txt", "new")
    assert str(info.value) == f"{tmp_path / 'b.txt'}: cannot write (No space left on device)"
    with pytest.raises(ScratchfabError) as info, atomic_folder(tmp_path / "stage") as new:
        (new / "a.txt").write_text("new")  # a write that is not through write_text
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert str(info.value) == f"{tmp_path / 'stage'}: cannot write (No space left on device)"
    assert (tmp_path / "b.txt").read_text() == "old"
    assert (tmp_path / "stage" / "a.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.txt", "stage"]  # no temporaries


def test_atomic_folder_gives_the_usual_permissions_and_keeps_the_old_folder(tmp_path):
    import os

    from scratchfab.fileio import atomic_folder, write_text

    mask = os.umask(0)
    os.umask(mask)
    with atomic_folder(tmp_path / "stage") as new:
        write_text(new / "a.txt", "old")
    assert (tmp_path / "stage").stat().st_mode & 0o777 == 0o777 & ~mask  # not mkdtemp's 0700
    with pytest.raises(RuntimeError), atomic_folder(tmp_path / "stage") as new:
        write_text(new / "a.txt", "half")
        raise RuntimeError("writer failed")
    assert (tmp_path / "stage" / "a.txt").read_text() == "old"
    with atomic_folder(tmp_path / "stage") as new:
        write_text(new / "b.txt", "new")
    assert sorted(p.name for p in (tmp_path / "stage").iterdir()) == ["b.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["stage"]  # nothing temporary left


def test_try_lock_refuses_a_file_another_process_holds_until_it_ends(tmp_path):
    import subprocess
    import sys

    from scratchfab.fileio import try_lock

    path = tmp_path / "lock"
    path.touch()
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import fcntl, sys; h = open(sys.argv[1], 'a'); "
            "fcntl.flock(h, fcntl.LOCK_EX); print('held', flush=True); sys.stdin.read()",
            str(path),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        with open(path, "a") as handle:
            assert not try_lock(handle)
    finally:
        holder.communicate("")  # the holder exits; its lock goes with it
    with open(path, "a") as handle:
        assert try_lock(handle)
        with open(path, "a") as second:
            assert not try_lock(second)  # a second handle, even in this process


def test_files_saved_with_a_byte_order_mark_read_as_without(tmp_path, small_design):
    """Excel's "CSV UTF-8" and older Notepad start a file with a BOM; it is not a character."""
    from scratchfab.model.schema import load_toml

    rows = "x0,y0,x1,y1\n0,0,3,0\n1,1,1,4\n"
    (tmp_path / "plain.csv").write_text(rows, encoding="utf-8")
    (tmp_path / "bom.csv").write_text(rows, encoding="utf-8-sig")
    plain = load_scratches(tmp_path / "plain.csv", small_design.scratch, small_design.board)
    bom = load_scratches(tmp_path / "bom.csv", small_design.scratch, small_design.board)
    assert np.array_equal(plain.p0, bom.p0) and np.array_equal(plain.p1, bom.p1)
    assert (tmp_path / "bom.csv").read_bytes().startswith(b"\xef\xbb\xbf")
    (tmp_path / "bom.toml").write_text("[board]\nwidth_mm = 50.0\n", encoding="utf-8-sig")
    assert load_toml(tmp_path / "bom.toml") == {"board": {"width_mm": 50.0}}


def test_try_lock_on_a_file_system_that_cannot_lock_says_so(tmp_path, monkeypatch):
    import errno
    import fcntl

    from scratchfab.errors import ScratchfabError
    from scratchfab.fileio import try_lock

    def no_locks(fd, operation):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    with open(tmp_path / "lock", "a") as handle:
        with pytest.raises(ScratchfabError, match="cannot lock .No locks available.; use a job"):
            try_lock(handle)


# A design file as a person writes it; each case below edits it (old -> new) or replaces it.
SCENE = """\
[board]
width_mm = 30.0
height_mm = 30.0
margin_mm = 1.5

[light]
position_mm = [0.0, 187.3, 463.6]

[scratch]
count = 50
min_length_mm = 1.5
max_length_mm = 5.0

[[views]]
name = "a"
azimuth_deg = -22.0
elevation_deg = 0.0
distance_mm = 400.0
fov_deg = "auto"
resolution = [16, 16]
"""
POLAR = "azimuth_deg = -22.0\nelevation_deg = 0.0\ndistance_mm = 400.0\n"
NESTED = "[design]\n" + SCENE.replace("[board]", "[design.board]").replace(
    "[light]", "[design.light]"
).replace("[scratch]", "[design.scratch]").replace("[[views]]", "[[design.views]]")

SCENE_ERRORS = [
    # (id, file bytes, expected fragment after "<file>: ")
    ("invalid toml", SCENE + "\n[oops\n", "invalid TOML: Expected ']' at the end of a table"),
    ("latin-1", (SCENE + "# caf\xe9\n").encode("latin-1"), "not a UTF-8 text file, expected TOML"),
    (
        "[design]",
        NESTED,
        "put board, light, scratch and views at the top level, not under [design]",
    ),
    ("no views", SCENE.split("[[views]]")[0], "views: at least one [[views]] table is required"),
    (
        "position and polar",
        SCENE.replace(POLAR, POLAR + "position_mm = [0.0, 0.0, 400.0]\n"),
        "views[0]: view 'a': give either position_mm or azimuth/elevation/distance, not both",
    ),
    (
        "look_at == position",
        SCENE.replace(POLAR, "position_mm = [0.0, 0.0, 400.0]\nlook_at_mm = [0.0, 0.0, 400.0]\n"),
        "views[0]: view 'a': look_at_mm equals position_mm",
    ),
    (
        "up along the view",
        SCENE.replace(POLAR, "position_mm = [0.0, 0.0, 400.0]\nup = [0.0, 0.0, 1.0]\n"),
        "views[0]: view 'a': up is parallel to the viewing direction",
    ),
    (
        "view's light behind",
        SCENE + "light_position_mm = [0.0, 0.0, -10.0]\n",
        "views[0]: view 'a': light_position_mm must be in front of the board (z > 0), got z = -10.0",
    ),
    (
        "min > max length",
        SCENE.replace("min_length_mm = 1.5", "min_length_mm = 6.0"),
        "scratch: min_length_mm (6.0) is larger than max_length_mm (5.0)",
    ),
]


@pytest.mark.parametrize(
    ("content", "fragment"), [c[1:] for c in SCENE_ERRORS], ids=[c[0] for c in SCENE_ERRORS]
)
def test_design_file_errors_are_one_line_naming_file_and_key(tmp_path, content, fragment):
    path = tmp_path / "scene.toml"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    with pytest.raises(ConfigError) as info:
        load_design(path)
    text = str(info.value)
    assert text.startswith(f"{path}: {fragment}") and "\n" not in text


def test_invalid_toml_names_the_line(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(SCENE_ERRORS[0][1])
    line = path.read_text().splitlines().index("[oops") + 1
    with pytest.raises(ConfigError, match=rf"\(at line {line}, column \d+\)$"):
        load_design(path)


@pytest.mark.parametrize("case", ["invalid toml", "latin-1", "[design]", "up along the view"])
def test_design_cli_turns_file_errors_into_one_line_and_exit_2(tmp_path, capsys, case):
    from scratchfab.cli import main

    _, content, fragment = next(c for c in SCENE_ERRORS if c[0] == case)
    path = tmp_path / "scene.toml"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    job = tmp_path / "job"
    with pytest.raises(SystemExit) as exc:
        main(["design", str(path), "--out", str(job)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {path}: {fragment}")
    assert not job.exists()


def test_the_unedited_scene_loads(tmp_path):
    """The cases above fail for their edit alone."""
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    design = load_design(path)
    assert [v.name for v in design.views] == ["a"] and design.scratch.min_length_mm == 1.5


@pytest.mark.parametrize("name", ["sun\n", "sun\r\n", "\nsun", "su\nn"])
def test_a_view_name_with_a_newline_is_refused_in_one_line(tmp_path, name):
    with pytest.raises(ConfigError) as info:
        design_from_mapping(_with("views.0.name", name), "scene.toml", Path("."))
    text = str(info.value)
    assert text.startswith("scene.toml:") and "not file-name safe" in text
    assert "\n" not in text and repr(name) in text
    # the same from a file, as a person writes it
    import tomli_w

    file = tmp_path / "scene.toml"
    file.write_text(tomli_w.dumps(_with("views.0.name", name)))
    with pytest.raises(ConfigError) as info:
        load_design(file)
    assert str(info.value).startswith(str(file)) and "\n" not in str(info.value)


def test_design_toml_round_trips_a_target_path_with_a_newline(tmp_path):
    import tomllib

    from PIL import Image

    from scratchfab.design.stage import run_design

    # A folder name that, written raw into the header comment, would add a key.
    folder = tmp_path / "in\nx = 1\n[extra]\n"
    folder.mkdir()
    target = folder / "sun\n.png"
    Image.fromarray(np.tile(np.arange(32, dtype=np.uint8) * 8, (32, 1))).save(target)
    data = {
        "board": {"width_mm": 40.0, "height_mm": 40.0, "margin_mm": 1.0},
        "light": {"position_mm": [0.0, 150.0, 300.0]},
        "scratch": {"count": 40, "min_length_mm": 1.0, "max_length_mm": 5.0},
        "views": [
            {
                "name": "sun",
                "position_mm": [0.0, 40.0, 300.0],
                "fov_deg": "auto",
                "resolution": [16, 16],
                "target": str(target),
            }
        ],
    }
    design = design_from_mapping(data, "<test>", tmp_path)
    result = run_design(design, tmp_path / "job", progress=lambda s: None)
    text = (result.folder / "design.toml").read_text(encoding="utf-8")
    parsed = tomllib.loads(text)  # a second reader
    header = [line for line in text.splitlines() if line.startswith("#")]
    assert len(header) == 3 + 1  # one comment line per view, none broken
    assert header[-1] == "# sun: " + str(target).replace("\n", "\\n")
    body = "\n".join(line for line in text.splitlines() if not line.startswith("#"))
    assert tomllib.loads(body) == parsed  # the comment adds no value
    assert set(parsed) == {"board", "light", "scratch", "views"}
    assert parsed["views"][0]["name"] == "sun"
    assert parsed["views"][0]["target"] == str(result.folder / "board" / "sun.png")
    assert parsed["board"]["width_mm"] == 40.0 and parsed["scratch"]["count"] == 40
    again = load_design(result.folder / "design.toml")
    assert again.views[0].position_mm == pytest.approx(design.views[0].position_mm)
