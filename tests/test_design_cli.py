from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import assert_views_see_the_whole_board_and_are_feasible
from PIL import Image

from scratchfab.bundled import bundled_dir
from scratchfab.cli import main
from scratchfab.design.feasibility import board_points, half_vectors, tilt_deg
from scratchfab.design.quick import TILT_SHARE, quick_design
from scratchfab.design.stage import run_design
from scratchfab.design.targets import view_targets
from scratchfab.model.design import load_design
from scratchfab.model.job import JobLayout, design_digest
from scratchfab.model.scratches import load_scratches
from scratchfab.render.profile import steepest_wall_deg

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "scratchfab" / "data" / "demo"


def _run(args, capsys):
    main(args)
    return capsys.readouterr().out


def _fail(args, capsys) -> str:
    with pytest.raises(SystemExit) as info:
        main(args)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err
    return err


def test_quick_form_writes_a_job_that_the_next_run_can_start_from(tmp_path, capsys):
    job = tmp_path / "job"
    args = [str(DEMO / "sun.png"), str(DEMO / "house.png"), "--board", "50x40"]
    out = _run(
        ["design", *args, "--count", "400", "--resolution", "40x32", "--out", str(job)], capsys
    )
    folder = job / "design"
    assert f"design file: {folder / 'design.toml'}" in out
    lines = out.splitlines()
    header = next(k for k, line in enumerate(lines) if line.startswith("design: 2 views"))
    assert header < next(k for k, line in enumerate(lines) if "loaded 2 target image" in line)
    for rel in (
        "design.toml",
        "scratches.csv",
        "feasibility.json",
        "feasibility_sun.png",
        "feasibility_house.png",
        "targets/sun.npy",
        "targets/sun.png",
        "targets/house.npy",
        "targets/house.png",
        "board/sun.png",
        "board/house.png",
    ):
        assert (folder / rel).is_file(), rel
    assert not list(job.glob(".design*"))  # no temporary folders left behind
    design = load_design(folder / "design.toml")
    assert design.board.width_mm == 50.0 and design.board.height_mm == 40.0
    assert design.scratch.count == 400
    assert [v.resolution for v in design.views] == [(40, 32), (40, 32)]
    assert all(Path(v.target).is_absolute() for v in design.views)  # type: ignore[arg-type]
    report = json.loads((folder / "feasibility.json").read_text())
    assert report["errors"] == [] and report["warnings"] == []
    layout = load_scratches(folder / "scratches.csv", design.scratch, design.board)
    assert len(layout) == 400
    # The resolved design reproduces the targets exactly (a second, independent read of
    # the board-space PNGs it points to) ...
    targets = view_targets(design)
    for name, t in targets.items():
        saved = np.load(folder / "targets" / f"{name}.npy")
        assert saved.dtype == np.float32 and saved.shape == (32, 40)
        np.testing.assert_array_equal(np.isnan(saved), np.isnan(t))
        np.testing.assert_allclose(saved, t.astype(np.float32), rtol=0, atol=0)
    # ... and a run from it gives the same job.
    job2 = tmp_path / "job2"
    _run(["design", str(folder / "design.toml"), "--out", str(job2)], capsys)
    assert (job2 / "design" / "scratches.csv").read_text() == (folder / "scratches.csv").read_text()
    for name in targets:
        np.testing.assert_array_equal(
            np.load(job2 / "design" / "targets" / f"{name}.npy"),
            np.load(folder / "targets" / f"{name}.npy"),
        )


@pytest.mark.parametrize("n", [1, 2, 3])
def test_quick_form_places_views_that_see_the_whole_board_and_are_feasible(n):
    images = [DEMO / "sun.png", DEMO / "house.png", DEMO / "sun.png"][:n]
    design = quick_design(images, (100.0, 60.0))
    names = [v.name for v in design.views]
    assert len(set(names)) == n
    assert_views_see_the_whole_board_and_are_feasible(design)


def test_quick_form_keeps_one_view_as_far_from_the_bare_board_gloss_as_two_views():
    """One camera on the normal gets the light at twice the aimed tilt: its centre half-vector
    tilts TILT_SHARE of the wall like the two-view layout's, and nowhere on the board does the
    bare board's mirror direction come closer than the two-view layout lets it (a light at the
    two-view elevation left the top edge 4.7 deg off the normal, lit by the board's gloss)."""
    one = quick_design([DEMO / "sun.png"], (100.0, 100.0))
    pts = board_points(one.board)
    two = quick_design([DEMO / "sun.png", DEMO / "house.png"], (100.0, 100.0))
    wall = float(steepest_wall_deg(one.scratch.width_mm, one.scratch.depth_mm))
    centre = tilt_deg(half_vectors(one, one.views[0], np.zeros((1, 2))))[0]
    assert centre == pytest.approx(TILT_SHARE * wall, abs=0.01)
    least_one = tilt_deg(half_vectors(one, one.views[0], pts)).min()
    least_two = min(tilt_deg(half_vectors(two, v, pts)).min() for v in two.views)
    assert least_one >= least_two


def test_a_design_rerun_over_an_optimized_job_says_what_to_rerun(tmp_path, capsys):
    """Optimize records the design's digests; a design that changes them says the optimized
    layout (and toolpath, G-code) is now the earlier design's; the same design says nothing."""
    job = tmp_path / "job"
    args = [str(DEMO / "sun.png"), "--board", "30x30", "--resolution", "16x16", "--out", str(job)]
    _run(["design", *args, "--count", "40"], capsys)
    layout = JobLayout(job)
    layout.optimize_dir.mkdir()
    shutil.copy(layout.design.initial_scratches, layout.optimized_scratches)
    layout.optimize_summary.write_text(json.dumps({"design_sha256": design_digest(job)}))
    assert "note:" not in _run(["design", *args, "--count", "40"], capsys)
    out = _run(["design", *args, "--count", "41"], capsys)
    assert (
        f"note: {layout.optimized_scratches} (and any toolpath or G-code made from it) comes "
        "from the earlier design; rerun `scratchfab optimize "
    ) in out
    assert "before toolpath and export" in out


def test_demo_pipeline_designs(tmp_path, capsys):
    job = tmp_path / "demo"
    out = _run(["design", str(bundled_dir("pipelines") / "demo.toml"), "--out", str(job)], capsys)
    assert "initial layout: 2000 scratches" in out
    design = load_design(job / "design" / "design.toml")
    assert [v.name for v in design.views] == ["sun", "house"]
    assert np.load(job / "design" / "targets" / "sun.npy").shape == (80, 80)


def _toml(tmp_path: Path, extra: str = "", target_b: str = "b.png") -> Path:
    a = np.zeros((32, 32), np.uint8)
    a[:, :16] = 255
    Image.fromarray(a).save(tmp_path / "a.png")
    Image.fromarray(a.T.copy()).save(tmp_path / "b.png")
    path = tmp_path / "scene.toml"
    views = ""
    for name, target, az in (("a", "a.png", -22.0), ("b", target_b, 22.0)):
        views += (
            f'[[views]]\nname = "{name}"\ntarget = "{target}"\nazimuth_deg = {az}\n'
            'elevation_deg = 0.0\ndistance_mm = 500.0\nfov_deg = "auto"\nresolution = [24, 24]\n'
        )
    path.write_text(
        extra + "[board]\nwidth_mm = 40.0\nheight_mm = 40.0\nmargin_mm = 1.0\n"
        "[light]\nposition_mm = [0.0, 187.3, 463.6]\n"
        "[scratch]\ncount = 150\nmin_length_mm = 1.0\nmax_length_mm = 5.0\n" + views
    )
    return path


def test_file_form_overrides_and_pipeline_options(tmp_path, capsys):
    toml = _toml(
        tmp_path, extra='[pipeline]\nfit = "cover"\nseed = 4\n[optimize]\niterations = 3\n'
    )
    res = run_design(toml, tmp_path / "j1", count=90, resolution=(20, 16), progress=lambda s: None)
    assert len(res.scratches) == 90
    assert res.targets["a"].shape == (16, 20)
    assert "fit = cover" in (res.folder / "design.toml").read_text()
    seeded = run_design(
        toml,
        tmp_path / "j2",
        seed=4,
        fit="cover",
        count=90,
        resolution=(20, 16),
        progress=lambda s: None,
    )
    np.testing.assert_array_equal(res.scratches.p0, seeded.scratches.p0)
    other_seed = run_design(toml, tmp_path / "j5", seed=0, count=90, progress=lambda s: None)
    assert not np.array_equal(other_seed.scratches.p0, seeded.scratches.p0)
    Image.fromarray(np.full((32, 32), 128, np.uint8)).save(tmp_path / "a.png")  # mid-grey
    brighter = run_design(toml, tmp_path / "j3", gamma=0.5, progress=lambda s: None)
    plain = run_design(toml, tmp_path / "j4", progress=lambda s: None)
    board = np.isfinite(plain.targets["a"])
    # gamma is an exponent on linear values: 0.5 takes sRGB 128 (linear 0.216) to 0.465
    assert np.median(plain.targets["a"][board]) == pytest.approx(0.2158, abs=0.002)
    assert np.median(brighter.targets["a"][board]) == pytest.approx(0.2158**0.5, abs=0.003)


def test_fit_contain_shows_the_whole_picture_and_cover_fills_the_board(tmp_path):
    toml = _toml(tmp_path)
    wide = np.full((32, 64), 255, np.uint8)  # 2:1 on a square board
    Image.fromarray(wide).save(tmp_path / "a.png")
    lit = {}
    for fit in ("contain", "cover"):
        res = run_design(toml, tmp_path / fit, fit=fit, count=50, progress=lambda s: None)
        board = np.asarray(Image.open(res.folder / "board" / "a.png").convert("L"), float) / 255
        lit[fit] = float(np.mean(board > 0.5))
    # contain: the picture spans the board's width and half its height, black bars above
    # and below; cover: it fills the board (the picture's sides are cropped)
    assert lit["contain"] == pytest.approx(0.5, abs=0.05)
    assert lit["cover"] == pytest.approx(1.0, abs=0.01)


def test_user_errors_are_one_line_and_keep_the_old_job(tmp_path, capsys):
    toml = _toml(tmp_path)
    job = tmp_path / "job"
    _run(["design", str(toml), "--out", str(job)], capsys)
    before = (job / "design" / "scratches.csv").read_text()
    err = _fail(["design", str(toml), "--board", "10x10", "--out", str(job)], capsys)
    assert "--board only applies to the quick form" in err
    for option, value in (("--board", "ten"), ("--resolution", "0x5")):  # usage errors
        with pytest.raises(SystemExit) as info:
            main(["design", str(DEMO / "sun.png"), option, value, "--out", str(job)])
        err = capsys.readouterr().err
        assert info.value.code == 2 and f"Invalid value for '{option}'" in err
        assert f"'{value}'" in err and "Traceback" not in err
    missing = tmp_path / "missing.toml"
    missing.write_text(toml.read_text().replace('"b.png"', '"nowhere.png"'))
    err = _fail(["design", str(missing), "--out", str(job)], capsys)
    assert "nowhere.png" in err and "not found" in err
    no_target = tmp_path / "no_target.toml"
    no_target.write_text(toml.read_text().replace('target = "b.png"\n', ""))
    err = _fail(["design", str(no_target), "--out", str(job)], capsys)
    assert "'b'" in err and "missing target" in err
    a_file = tmp_path / "occupied"
    a_file.write_text("not a folder")
    err = _fail(["design", str(toml), "--out", str(a_file / "job")], capsys)
    assert "cannot create the job folder" in err and str(a_file) in err
    # The failed runs left the earlier job as it was.
    assert (job / "design" / "scratches.csv").read_text() == before
    assert not list(job.glob(".design*"))


def test_one_pixel_and_black_images_make_a_job_when_forced(tmp_path, capsys):
    Image.new("L", (1, 1), 180).save(tmp_path / "dot.png")
    Image.new("RGB", (20, 10), (0, 0, 0)).save(tmp_path / "night.jpg")
    logo = Image.new("RGBA", (20, 20), (0, 0, 0, 0))  # a white logo on a transparent ground:
    logo.paste((255, 255, 255, 255), (5, 5, 15, 15))  # not uniform, no warning
    logo.save(tmp_path / "logo.png")
    job = tmp_path / "job"
    args = [
        "design",
        str(tmp_path / "dot.png"),
        str(tmp_path / "night.jpg"),
        str(tmp_path / "logo.png"),
        "--board",
        "30x30",
        "--count",
        "50",
        "--resolution",
        "16",
        "--out",
        str(job),
    ]
    # The black picture shows nothing: refused, naming it as typed, until forced.
    err = _fail(args, capsys)
    assert f"error: {tmp_path / 'night.jpg'}: the picture is black on the board" in err
    assert "use --force" in err and not job.exists()
    out = _run([*args, "--force"], capsys)
    assert "initial layout: 50 scratches" in out
    # The two even pictures are named, with what they read as, and the logo is not.
    assert "warning: target 'dot' is uniform (brightness 0.4" in out
    assert "warning: target 'night' is uniform (brightness 0.000" in out
    assert "transparent pixels read as black" in out and "'logo' is uniform" not in out
    dot = np.load(job / "design" / "targets" / "dot.npy")
    night = np.load(job / "design" / "targets" / "night.npy")
    board = np.isfinite(dot)
    # A 1x1 picture fills the board with its one value; a black one stays black.
    inner = dot[board][dot[board] > 0.999 * np.nanmax(dot)]
    assert inner.size > 50
    assert float(inner.mean()) == pytest.approx(((180 / 255 + 0.055) / 1.055) ** 2.4, abs=1e-4)
    assert np.nanmax(night) == 0.0
    # All scratches go to the view that has something to show.
    assert len((job / "design" / "scratches.csv").read_text().splitlines()) == 51


def test_all_black_targets_spread_the_scratches_evenly(tmp_path):
    Image.new("L", (8, 8), 0).save(tmp_path / "black.png")
    design = quick_design([tmp_path / "black.png"], (30.0, 30.0), count=40, resolution=(16, 16))
    res = run_design(design, tmp_path / "job", force=True, progress=lambda s: None)
    assert len(res.scratches) == 40
    mid = (res.scratches.p0 + res.scratches.p1) / 2
    assert (mid[:, 0] < 0).sum() > 10 and (mid[:, 0] > 0).sum() > 10


def test_missing_target_names_the_view_key_and_the_file(tmp_path, capsys):
    from scratchfab.cli import main

    design = tmp_path / "d.toml"
    design.write_text(
        "[light]\nposition_mm = [0.0, 100.0, 400.0]\n"
        '[[views]]\nname = "a"\ntarget = "nope.png"\n'
        "position_mm = [-100.0, 0.0, 400.0]\nresolution = [16, 16]\n"
    )
    with pytest.raises(SystemExit) as info:
        main(["design", str(design), "--out", str(tmp_path / "job")])
    err = capsys.readouterr().err
    assert info.value.code == 2
    assert (
        err.strip()
        == f"error: {design}: views[0].target ('a'): {tmp_path / 'nope.png'}: image file not found"
    )
    assert not (tmp_path / "job" / "design").exists()


#: ``[pipeline]`` (and later stage) mistakes: ``design FILE`` and ``run FILE`` read the
#: tables with one parser, so both refuse each one naming the file and the key.
_TABLE_MISTAKES = [
    ("[pipeline]\nseed = -1\n", "pipeline.seed: expected a value at least 0, got -1"),
    ('[pipeline]\nseed = "abc"\n', "pipeline.seed: expected an integer, got 'abc'"),
    ("[pipeline]\nseed = 1.5\n", "pipeline.seed: expected an integer, got 1.5"),
    ('[pipeline]\nforce = "no"\n', "pipeline.force: expected true or false, got 'no'"),
    ('[pipeline]\nfti = "cover"\n', "pipeline: unknown key 'fti' (did you mean 'fit'?)"),
    ('[pipeline]\nfit = "stretch"\n', "pipeline.fit: expected 'contain' or 'cover'"),
    ("pipeline = 3\n", "pipeline: expected a table, got 3"),
    ("[verify]\nsweep = 1\n", "verify.sweep: expected 0 (no sweep) or at least 2 frames"),
]


@pytest.mark.parametrize("command", [["design"], ["run", "--until", "design"]])
@pytest.mark.parametrize(("extra", "message"), _TABLE_MISTAKES)
def test_pipeline_table_mistakes_are_one_line_for_design_and_run(
    tmp_path, capsys, command, extra, message
):
    toml = _toml(tmp_path, extra=extra)
    job = tmp_path / "job"
    err = _fail([command[0], str(toml), "--out", str(job), *command[1:]], capsys)
    assert f"{toml}: {message}" in err and "Traceback" not in err
    assert not job.exists()


def test_pipeline_force_is_read_as_a_boolean(tmp_path, capsys):
    # The second view stands too far to the side: infeasible unless forced.
    steep = _toml(tmp_path).read_text().replace("azimuth_deg = 22.0", "azimuth_deg = 80.0")
    toml = tmp_path / "steep.toml"
    toml.write_text("[pipeline]\nforce = false\n" + steep)
    with pytest.raises(SystemExit) as info:
        main(["design", str(toml), "--out", str(tmp_path / "j1")])
    out, err = capsys.readouterr()
    assert info.value.code == 2 and err.startswith("error: ") and "\n" not in err.strip()
    assert "'b'" in err and "--force" in err
    assert "error" not in out  # the progress does not say it first
    assert not (tmp_path / "j1" / "design").exists()
    toml.write_text("[pipeline]\nforce = true\n" + steep)
    main(["design", str(toml), "--out", str(tmp_path / "j2")])
    assert "  error: " in capsys.readouterr().out  # forced: the progress names what it ignores
    report = json.loads((tmp_path / "j2" / "design" / "feasibility.json").read_text())
    assert any("'b'" in e for e in report["errors"])


def test_pipeline_seed_and_fit_match_the_command_line(tmp_path, capsys):
    # A second path to the same options: the table read by `run`, and the flags of `design`.
    toml = _toml(tmp_path, extra='[pipeline]\nseed = 3\nfit = "cover"\n')
    main(["run", str(toml), "--out", str(tmp_path / "run"), "--until", "design"])
    (tmp_path / "plain").mkdir()
    plain = _toml(tmp_path / "plain")
    flags = ["--seed", "3", "--fit", "cover"]
    _run(["design", str(plain), "--out", str(tmp_path / "cli"), *flags], capsys)
    _run(["design", str(plain), "--out", str(tmp_path / "default")], capsys)
    by_run = (tmp_path / "run" / "design" / "scratches.csv").read_text()
    assert by_run == (tmp_path / "cli" / "design" / "scratches.csv").read_text()
    assert by_run != (tmp_path / "default" / "design" / "scratches.csv").read_text()


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--seed", "-1"),
        ("--gamma", "0"),
        ("--gamma", "nan"),
        ("--contrast", "-1"),
        ("--board", "100"),
        ("--board", "100x0"),
        ("--board", "axb"),
        ("--resolution", "0"),
        ("--resolution", "64x0"),
        ("--resolution", "64x48.5"),
        ("--resolution", "64mm"),
    ],
)
@pytest.mark.parametrize("form", ["file", "quick"])
def test_out_of_range_options_are_usage_errors(tmp_path, capsys, option, value, form):
    inputs = [str(_toml(tmp_path))] if form == "file" else [str(DEMO / "sun.png")]
    job = tmp_path / "job"
    with pytest.raises(SystemExit) as info:
        main(["design", *inputs, "--out", str(job), option, value])
    err = capsys.readouterr().err
    assert info.value.code == 2
    assert f"Invalid value for '{option}'" in err and "Traceback" not in err
    assert not job.exists()


def test_a_path_the_console_cannot_encode_is_escaped_not_a_traceback(tmp_path):
    import os
    import subprocess
    import sys

    from PIL import Image

    for name in ("a.png", "b.png"):
        Image.new("L", (16, 16), 200).save(tmp_path / name)
    out = tmp_path / "Łódź"
    code = "import sys; from scratchfab.cli import main; main(sys.argv[1:])"
    args = [str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--out", str(out), "--force"]
    env = {**os.environ, "PYTHONIOENCODING": "cp1252"}
    done = subprocess.run(
        [sys.executable, "-c", code, "design", *args, "--count", "50", "--resolution", "16"],
        capture_output=True,
        env=env,
    )
    assert done.returncode == 0, done.stderr.decode("cp1252")
    assert b"\\u0141\xf3d\\u017a" in done.stdout  # cp1252 has the o with acute accent
    assert b"Traceback" not in done.stderr


def test_quick_form_names_views_that_every_disk_keeps_apart(tmp_path, capsys):
    """Names from file names: unique ignoring case, never a Windows device name."""
    files = []
    for name in ("Left.png", "sub/left.PNG", "nul.png", "COM1.jpg", "left_2.png"):
        path = tmp_path / name
        path.parent.mkdir(exist_ok=True)
        Image.new("L", (8, 8), 40 * len(files) + 20).save(path)
        files.append(str(path))
    design = quick_design([Path(f) for f in files], (30.0, 30.0), count=20, resolution=(8, 8))
    names = [v.name for v in design.views]
    assert names == ["Left", "left_2", "view_nul", "view_COM1", "left_2_2"]
    assert len({n.lower() for n in names}) == len(names)


def test_quick_form_errors_name_the_image_as_typed(tmp_path, capsys, monkeypatch):
    """No design file was written by the user: no ``views[i].target``, no resolved path."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "pics").mkdir()
    (tmp_path / "pics" / "broken.png").write_bytes(b"not a picture")
    Image.new("L", (8, 8), 200).save(tmp_path / "good.png")
    for images, typed, why in (
        (["good.png", "pics/broken.png"], "pics/broken.png", "not an image file Pillow can read"),
        (["nope.png"], "nope.png", "image file not found"),
    ):
        err = _fail(["design", *images, "--board", "20x20", "--out", "job"], capsys)
        assert err == f"error: {typed}: {why}"
    assert not (tmp_path / "job" / "design").exists()


def test_a_bundled_pipelines_name_designs_as_its_file(tmp_path, capsys):
    """`design demo` takes the bundled pipeline's name, as `run demo` does: the same layout
    as the file's path gives; a name that is no bundled pipeline stays an image's name."""
    by_name, by_path = tmp_path / "by-name", tmp_path / "by-path"
    _run(["design", "demo", "--out", str(by_name)], capsys)
    _run(["design", str(bundled_dir("pipelines") / "demo.toml"), "--out", str(by_path)], capsys)
    made = [JobLayout(job).design.initial_scratches.read_bytes() for job in (by_name, by_path)]
    assert made[0] == made[1] and made[0].count(b"\n") > 100
    with pytest.raises(SystemExit) as exc:
        main(["design", "no-such-pipeline", "--out", str(tmp_path / "none")])
    assert exc.value.code != 0
    assert "no-such-pipeline: image file not found" in capsys.readouterr().err
