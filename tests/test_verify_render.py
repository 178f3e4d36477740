"""verify-render end to end: agreement with the analytic render, sweep, jitter, gate, CLI."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import FULL
from PIL import Image, ImageSequence

from scratchfab.cli import main
from scratchfab.design.targets import board_image, warp_to_view
from scratchfab.metrics import pearson
from scratchfab.model.design import Design, design_from_mapping, load_design
from scratchfab.model.scratches import ScratchSet
from scratchfab.render.layout import write_render_layout
from scratchfab.render.renderer import render_scratches
from scratchfab.verify.jitter import Tolerance, jitter_scratches
from scratchfab.verify.scene import render_view, samples_per_pass, scene_dict, use_variant
from scratchfab.verify.sweep import sweep_path
from scratchfab.verify.verify import (
    DEFAULT_SPP,
    BoardRenderer,
    VerifySettings,
    design_targets,
    relative_l2,
    run_verify,
)

SIZE = 12.0  # 12 mm at 32 px: footprints of ~0.4 mm, about four scratch widths


def two_view_tables(resolution: int = 32, targets: dict[str, str] | None = None) -> dict:
    views = []
    for name, x in (("left", -120.0), ("right", 120.0)):
        view = {
            "name": name,
            "position_mm": [x, 0.0, 300.0],
            "fov_deg": "auto",
            "resolution": [resolution, resolution],
        }
        if targets:
            view["target"] = targets[name]
        views.append(view)
    return {
        "board": {"width_mm": SIZE, "height_mm": SIZE, "roughness": 0.05, "margin_mm": 0.5},
        "light": {"position_mm": [0.0, 150.0, 300.0]},
        "scratch": {"width_mm": 0.1, "depth_mm": 0.01, "min_length_mm": 0.5},
        "views": views,
    }


def two_view_design(resolution: int = 32, base: Path = Path("."), targets=None) -> Design:
    return design_from_mapping(two_view_tables(resolution, targets), "<test>", base)


def lit_scratches(
    design: Design,
    centres: np.ndarray,
    view_index: np.ndarray,
    rng: np.random.Generator,
    spread_deg: float = 8.0,
    lengths: tuple[float, float] = (1.0, 4.0),
) -> ScratchSet:
    """Scratches whose walls face the half-vector of their view (so they light there)."""
    p0, p1 = [], []
    for c, k in zip(centres, view_index, strict=True):
        view = design.views[int(k)]
        c3 = np.array([c[0], c[1], 0.0])
        wi = design.light_for(view) - c3
        wo = view.camera_position - c3
        h = wi / np.linalg.norm(wi) + wo / np.linalg.norm(wo)
        angle = math.atan2(h[1], h[0]) + math.pi / 2 + math.radians(rng.normal(0, spread_deg))
        half = 0.5 * rng.uniform(*lengths)
        u = half * np.array([math.cos(angle), math.sin(angle)])
        p0.append(c - u)
        p1.append(c + u)
    lim = SIZE / 2 - 0.5
    return ScratchSet.from_arrays(
        np.clip(p0, -lim, lim), np.clip(p1, -lim, lim), design.scratch.width_mm, 0.01
    )


def seeded_board(design: Design, n: int, seed: int) -> ScratchSet:
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-SIZE / 2 + 1, SIZE / 2 - 1, (n, 2))
    return lit_scratches(design, centres, rng.integers(0, len(design.views), n), rng)


def half_board(design: Design, n: int, seed: int) -> ScratchSet:
    """View 0 sees the left half lit, view 1 the top half."""
    rng = np.random.default_rng(seed)
    lim = SIZE / 2 - 1
    left = np.column_stack([rng.uniform(-lim, 0, n), rng.uniform(-lim, lim, n)])
    top = np.column_stack([rng.uniform(-lim, lim, n), rng.uniform(0, lim, n)])
    return lit_scratches(
        design, np.vstack([left, top]), np.repeat([0, 1], n), rng, lengths=(0.5, 1.5)
    )


def write_targets(folder: Path) -> dict[str, str]:
    folder.mkdir(parents=True, exist_ok=True)
    left = np.zeros((64, 64), np.uint8)
    left[:, :32] = 255
    top = np.zeros((64, 64), np.uint8)
    top[:32, :] = 255
    Image.fromarray(left).save(folder / "left.png")
    Image.fromarray(top).save(folder / "top.png")
    return {"left": "left.png", "right": "top.png"}


@pytest.fixture(scope="module")
def half_job(tmp_path_factory):
    """A design file with targets and the half/half board as a CSV."""
    root = tmp_path_factory.mktemp("verify")
    names = write_targets(root)
    design = two_view_design(base=root, targets=names)
    design_file = root / "design.toml"
    design.save(design_file)
    scratches = half_board(design, 140, seed=3)
    scratch_file = root / "scratches.csv"
    scratches.save(scratch_file, design.scratch)
    return root, load_design(design_file), scratches, design_file, scratch_file


def test_verify_agrees_with_the_analytic_render_within_noise():
    """The acceptance bound: relative L2 <= 2 % at the default spp, consistent with the noise."""
    design = two_view_design()
    scratches = seeded_board(design, 90, seed=11)
    analytic = render_scratches(design, scratches)
    renderer = BoardRenderer(design, scratches)
    for i, view in enumerate(design.views):
        result = renderer.render(view, DEFAULT_SPP, seed=i)
        ref = analytic[view.name]
        assert (ref > 0.2 * ref.max()).sum() > 30  # a board that shows something
        err = relative_l2(result.image, ref)
        assert 0 < result.noise < 0.02
        assert err <= 0.02, (view.name, err, result.noise)
        # The noise estimate accounts for the error: neither far below nor far above it.
        assert 0.5 * result.noise < err
        # What is left beyond the noise is the model difference (h varies over a pixel).
        assert math.sqrt(max(err**2 - result.noise**2, 0.0)) < 0.01


def test_single_scratch_lights_exactly_the_pixels_render_lights():
    design = two_view_design()
    rng = np.random.default_rng(2)
    scratch = lit_scratches(
        design, np.array([[1.3, -0.7]]), np.array([0]), rng, spread_deg=0.0, lengths=(3, 3)
    )
    analytic = render_scratches(design, scratch)["left"]
    image = BoardRenderer(design, scratch).render(design.views[0], DEFAULT_SPP).image
    peak = analytic.max()
    lit_a = analytic > 0.05 * peak
    lit_v = image > 0.05 * peak
    clear = (analytic < 0.03 * peak) | (analytic > 0.08 * peak)
    assert 4 <= lit_a.sum() < 40
    np.testing.assert_array_equal(lit_a[clear], lit_v[clear])
    assert np.unravel_index(np.argmax(image), image.shape) == np.unravel_index(
        np.argmax(analytic), analytic.shape
    )
    jj, ii = np.mgrid[: image.shape[0], : image.shape[1]]

    def centroid(img):
        w = np.where(img > 0.05 * peak, img, 0.0)
        return np.array([(w * ii).sum(), (w * jj).sum()]) / w.sum()

    assert np.linalg.norm(centroid(image) - centroid(analytic)) < 0.05


def test_sweep_frames_nearest_each_view_show_that_views_image(half_job, tmp_path):
    root, design, scratches, _, _ = half_job
    targets, cross = design_targets(design)
    frames_n = 8
    said: list[str] = []
    metrics = run_verify(
        design,
        scratches,
        tmp_path / "out",
        VerifySettings(spp=256, sweep=frames_n),
        targets=targets,
        cross=cross,
        progress=said.append,
    )
    # progress names each view's place and the sweep's frames, with the time left
    views = [line for line in said if line.startswith("verify ") and " px, " in line]
    assert [v.split(" ")[2] for v in views] == ["(1/2):", "(2/2):"]
    assert views[-1].endswith("views left about 00:00")
    sweeps = [line for line in said if line.startswith("sweep: ")]
    assert sweeps[-1] == f"sweep: {frames_n}/{frames_n} frames, eta 00:00" and len(sweeps) == 2
    path, view_params = sweep_path(design, frames_n)
    frames = sweep_pictures(tmp_path / "out" / "sweep.gif", path)
    assert len(frames) == frames_n == metrics["sweep"]["frames"]
    boards = {
        "left": board_image(root / "left.png", design.board),
        "right": board_image(root / "top.png", design.board),
    }
    nearest = metrics["sweep"]["nearest_frame"]
    assert set(nearest) == {"left", "right"} and nearest["left"] != nearest["right"]
    durations = [
        f.info["duration"]
        for f in ImageSequence.Iterator(Image.open(tmp_path / "out" / "sweep.gif"))
    ]
    held = {k for k, d in enumerate(durations[:frames_n]) if d > min(durations)}
    assert held == set(nearest.values())  # the design views' frames hold longer
    for name, index in nearest.items():
        assert path[index].view.position_mm != design.view(name).position_mm  # not the view
    for name, corr in frame_correlations(frames, path, nearest, boards, design.board).items():
        assert max(corr, key=corr.get) == name, (name, corr)
        assert corr[name] > 0.5


def test_jitter_reports_metric_drops_that_grow_with_the_tolerance(half_job, tmp_path):
    _, design, scratches, _, _ = half_job
    targets, cross = design_targets(design)
    drops = {}
    for label, tol in (
        ("tiny", Tolerance(position_mm=1e-6, angle_deg=1e-6, depth_fraction=1e-6)),
        ("coarse", Tolerance(position_mm=1.0, angle_deg=15.0, depth_fraction=0.5)),
    ):
        metrics = run_verify(
            design,
            scratches,
            tmp_path / label,
            VerifySettings(spp=512, jitter=tol),
            targets=targets,
            cross=cross,
        )
        jit = metrics["jitter"]
        assert jit["tolerance"]["position_mm"] == tol.position_mm
        drops[label] = [jit["views"][v]["rho_drop"] for v in ("left", "right")]
    assert max(abs(d) for d in drops["tiny"]) < 0.02
    assert min(drops["coarse"]) > 0.1


def test_jitter_moves_scratches_by_the_tolerance():
    rng = np.random.default_rng(0)
    base = ScratchSet.from_arrays(
        rng.uniform(-5, 5, (4000, 2)), rng.uniform(-5, 5, (4000, 2)), 0.1, 0.01
    )
    tol = Tolerance(position_mm=0.02, angle_deg=0.5, depth_fraction=0.1)
    moved = jitter_scratches(base, tol, np.random.default_rng(1))
    shift = 0.5 * (moved.p0 + moved.p1) - 0.5 * (base.p0 + base.p1)
    assert np.std(shift) == pytest.approx(0.02, rel=0.05)
    np.testing.assert_allclose(moved.lengths, base.lengths, rtol=1e-12)
    a0 = np.arctan2(*(base.p1 - base.p0).T[::-1])
    a1 = np.arctan2(*(moved.p1 - moved.p0).T[::-1])
    turn = np.angle(np.exp(1j * (a1 - a0)))
    assert np.degrees(np.std(turn)) == pytest.approx(0.5, rel=0.05)
    assert np.std(moved.depth / base.depth) == pytest.approx(0.1, rel=0.05)


def test_cli_writes_the_render_layout_and_metrics(half_job, tmp_path):
    _, design, scratches, design_file, scratch_file = half_job
    out = tmp_path / "v"
    targets, _ = design_targets(design)
    main(
        [
            "verify-render",
            "--design",
            str(design_file),
            "--scratches",
            str(scratch_file),
            "--out",
            str(out),
            "--spp",
            "1024",
        ]
    )
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["names"] == ["left", "right"]
    analytic = render_scratches(design, scratches)
    for name in ("left", "right"):
        img = np.load(out / f"{name}.npy")
        assert img.dtype == np.float32 and img.shape == (32, 32)
        assert Image.open(out / f"{name}.png").size == (32, 32)
        v = metrics["views"][name]
        assert v["spp"] >= 1024 and v["seconds"] > 0 and 0 < v["noise"] < 0.05
        assert v["rel_l2"] == pytest.approx(relative_l2(img, analytic[name]), rel=1e-5)
        rho_analytic = pearson(analytic[name], targets[name])
        assert v["rho"] > 0.3 and abs(v["rho"] - rho_analytic) < 0.03
        assert math.isfinite(v["psnr"])
        other = "right" if name == "left" else "left"
        assert set(v["crosstalk"]) == {other}
    assert metrics["crosstalk_matrix"][0][0] is None
    assert metrics["crosstalk_matrix"][0][1] == metrics["views"]["left"]["crosstalk"]["right"]


def test_min_rho_gate_fails_after_writing_everything(half_job, tmp_path, capsys):
    _, _, _, design_file, scratch_file = half_job
    out = tmp_path / "gate"
    args = ["verify-render", "--design", str(design_file), "--scratches", str(scratch_file)]
    with pytest.raises(SystemExit) as exc:
        main([*args, "--out", str(out), "--spp", "64", "--min-rho", "0.99999"])
    assert exc.value.code == 3
    said = capsys.readouterr()
    err = said.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: view ") and "--min-rho" in err[0]
    metrics = json.loads((out / "metrics.json").read_text())
    # The progress line and the gate show a rho alike: rounded down (truncated) to the
    # gate's 5 decimals, never rounded up to reach it.
    worst = min(("left", "right"), key=lambda n: metrics["views"][n]["rho"])
    for name in ("left", "right"):
        rho = metrics["views"][name]["rho"]
        assert 0 < rho < 0.99999
        shown = f"{rho:.12f}"[:7]
        assert f"verify {name}: relative L2 vs render " in said.out
        assert f", rho vs target {shown}" in said.out
        if name == worst:
            assert f"view {name} looks like its target only to rho {shown}, below" in err[0]
    gate = metrics["gate"]
    assert gate == {
        "min_rho": 0.99999,
        "passed": False,
        "failing": ["left", "right"],
        "unchecked": [],
    }
    main([*args, "--out", str(tmp_path / "pass"), "--spp", "64", "--min-rho", "0.3"])
    assert json.loads((tmp_path / "pass" / "metrics.json").read_text())["gate"]["passed"]


def test_job_mode_compares_with_the_optimize_renders(half_job, tmp_path, capsys, monkeypatch):
    _, design, scratches, _, _ = half_job
    job = tmp_path / "job"
    design.save(job / "design" / "design.toml")
    scratches.save(job / "optimize" / "scratches.csv", design.scratch)
    analytic = render_scratches(design, scratches)
    write_render_layout(job / "optimize" / "renders", analytic)
    targets, _ = design_targets(design)
    for name, t in targets.items():
        (job / "design" / "targets").mkdir(parents=True, exist_ok=True)
        np.save(job / "design" / "targets" / f"{name}.npy", t.astype(np.float32))
    main(["verify-render", str(job), "--spp", "256"])
    metrics = json.loads((job / "verify" / "metrics.json").read_text())
    # named inside the job (a copied job names its own renders); from outside it, absolute
    assert metrics["comparison"] == "optimize/renders"
    for name in ("left", "right"):
        img = np.load(job / "verify" / f"{name}.npy")
        assert metrics["views"][name]["rel_l2"] == pytest.approx(
            relative_l2(img, analytic[name]), rel=1e-5
        )
        assert "crosstalk" in metrics["views"][name]
    for out, named in (
        (job / "verify" / "again", "optimize/renders"),
        (tmp_path / "elsewhere", str(job / "optimize" / "renders")),
    ):
        main(["verify-render", str(job), "--spp", "4", "--out", str(out)])
        assert json.loads((out / "metrics.json").read_text())["comparison"] == named
    # renders of other views (the design's resolution changed since optimize) are not the
    # board's: a fresh analytic render, not an error naming "optimize/renders", which is
    # relative to the job and not to where the command runs
    # The progress line names the renders as they are found from where the command runs
    # (a job named relative to another folder), not job-relative.
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    capsys.readouterr()
    main(["verify-render", "../job", "--spp", "4", "--out", str(tmp_path / "o2")])
    (line,) = [s for s in capsys.readouterr().out.splitlines() if "verifying" in s]
    scratch_named, renders_named = re.fullmatch(
        r"verifying (\S+) \(\d+ scratches\) against the optimizer's renders in (\S+)", line
    ).groups()
    assert (cwd / scratch_named).resolve() == (job / "optimize" / "scratches.csv").resolve()
    assert (cwd / renders_named).resolve() == (job / "optimize" / "renders").resolve()
    np.save(job / "optimize" / "renders" / "left.npy", np.zeros((4, 4), np.float32))
    main(["verify-render", str(job), "--spp", "4"])
    assert "scratches) against a fresh analytic render" in capsys.readouterr().out
    metrics = json.loads((job / "verify" / "metrics.json").read_text())
    assert metrics["comparison"] == "render_scratches"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["{tmp}/nope"], "job folder not found"),
        (["{tmp}", "--design", "{design}"], "not both"),
        (["--design", "{design}", "--scratches", "{csv}"], "--out DIR"),
        (
            ["--design", "{design}", "--scratches", "{csv}", "--out", "{tmp}/o", "--sweep", "1"],
            "--sweep",
        ),
        (["--design", "{design}", "--scratches", "{bad}", "--out", "{tmp}/o"], "line 3"),
        (
            ["--design", "{design}", "--scratches", "{csv}", "--out", "{tmp}/o", "--machine", "x"],
            "--jitter",
        ),
        (
            [
                "--design",
                "{design}",
                "--scratches",
                "{csv}",
                "--out",
                "{tmp}/o",
                "--jitter",
                "--machine",
                "nosuch",
            ],
            "machine 'nosuch'",
        ),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(half_job, tmp_path, capsys, args, message):
    _, _, _, design_file, scratch_file = half_job
    bad = tmp_path / "bad.csv"
    bad.write_text("x0,y0,x1,y1\n0,0,1,1\n0,0,zero,1\n")
    fill = {"tmp": tmp_path, "design": design_file, "csv": scratch_file, "bad": bad}
    with pytest.raises(SystemExit) as exc:
        main(["verify-render", *[a.format(**fill) for a in args]])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--max-noise", "nan"], "'--max-noise': 'nan' is not a finite number"),
        (["--sky", "--sky-strength", "nan"], "'--sky-strength': 'nan' is not a finite"),
        (["--sky", "--sun", "nan", "0", "1"], "'--sun': 'nan' is not a finite number"),
        (["--sky", "--sun", "0", "inf", "1"], "'--sun': 'inf' is not a finite number"),
        (["--sky", "--sun", "0", "0", "0"], "--sun: expected three finite numbers, not all zero"),
        (["--sky", "--sun", "0.3", "-0.2", "1"], "--sun: the sun must be above the horizon (y > 0"),
        (["--min-rho", "nan"], "'--min-rho': 'nan' is not a finite number"),
    ],
)
def test_option_values_that_are_not_finite_numbers_are_refused(
    half_job, tmp_path, capsys, args, message
):
    _, _, _, design_file, scratch_file = half_job
    files = ["--design", str(design_file), "--scratches", str(scratch_file)]
    with pytest.raises(SystemExit) as exc:
        main(["verify-render", *files, "--out", str(tmp_path / "o"), *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"spp": 1}, "spp: expected at least 2"),
        ({"sweep": 1}, "sweep: expected 0 (no sweep) or at least 2 frames, got 1"),
        ({"min_rho": 1.5}, "min_rho: expected -1 to 1, got 1.5"),
        ({"max_noise": 0.0}, "max_noise: expected a number > 0"),
        ({"max_noise": float("nan")}, "max_noise: expected a number > 0"),
        ({"sky": {"sun_direction": (0.0, 0.0, 0.0)}}, "sun_direction: expected three finite"),
        ({"sky": {"sun_direction": (1.0, 0.0, 1.0)}}, "sun_direction: the sun must be above"),
        ({"sky": {"sun_direction": (0.0, float("inf"), 1.0)}}, "sun_direction: expected"),
        ({"sky": {"strength": 0.0}}, "strength: expected a finite number > 0"),
        ({"sky": {"turbidity": 12.0}}, "turbidity: expected 1 (clear) to 10"),
    ],
)
def test_verify_settings_refuse_what_the_cli_refuses(kwargs, message):
    """Library callers get the checks the CLI and pipeline files get, as ValueError."""
    from scratchfab.verify.scene import Sky

    with pytest.raises(ValueError, match=re.escape(message)):
        sky = kwargs.get("sky")
        VerifySettings(**{**kwargs, "sky": Sky(**sky) if sky else None})
    assert VerifySettings(spp=2, sweep=2, min_rho=-1, max_noise=1e-3, sky=Sky()).sweep == 2


def test_cuda_backend_without_a_gpu_is_a_clear_error(half_job, tmp_path, capsys):
    import drjit as dr

    if dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("a CUDA GPU is present")
    _, _, _, design_file, scratch_file = half_job
    args = ["--design", str(design_file), "--scratches", str(scratch_file)]
    with pytest.raises(SystemExit) as exc:
        main(["verify-render", *args, "--out", str(tmp_path / "o"), "--variant", "cuda"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "CUDA" in err[0] and "--backend llvm" in err[0]
    assert not (tmp_path / "o").exists()


def sweep_pictures(gif_path: Path, path: list) -> list[np.ndarray]:
    """The rendered pictures of a sweep GIF, in path order.

    The GIF plays the N frames forward then back (2N - 2 frames), each picture enlarged
    by a whole factor above a label strip: the first N, shrunk back, are the renders.
    """
    gif = Image.open(gif_path)
    n = len(path)
    assert gif.n_frames == 2 * n - 2
    w, h = path[0].view.resolution
    factor = gif.width // w
    assert gif.width == factor * w and gif.height > factor * h
    out = [
        np.asarray(f.convert("L"), dtype=np.float64)[: h * factor : factor, ::factor]
        for f in ImageSequence.Iterator(gif)
    ]
    for k in range(1, n - 1):
        assert np.array_equal(out[k], out[2 * n - 2 - k])  # played back in reverse
    return out[:n]


def frame_correlations(frames, path, nearest, boards, board):
    """For each design view, its nearest frame's correlation with every view's image."""
    out = {}
    for name, index in nearest.items():
        view = path[index].view
        out[name] = {
            j: pearson(frames[index], warp_to_view(img, board, view)) for j, img in boards.items()
        }
    return out


@pytest.mark.slow
def test_demo_job_verifies_within_two_percent_and_its_sweep_shows_each_image(tmp_path):
    """The bundled demo end to end (design's initial layout): acceptance on a real design."""
    from scratchfab.bundled import bundled_dir

    job = tmp_path / "job"
    main(["design", str(bundled_dir("pipelines") / "demo.toml"), "--out", str(job)])
    spp = DEFAULT_SPP if FULL else 4096
    frames_n = 8
    main(["verify-render", str(job), "--spp", str(spp), "--sweep", str(frames_n)])
    metrics = json.loads((job / "verify" / "metrics.json").read_text())
    assert metrics["comparison"] == "render_scratches"
    for name, v in metrics["views"].items():
        assert v["rel_l2"] <= 0.02, (name, v["rel_l2"], v["noise"])
        assert v["rho"] > 0.8
    design = load_design(job / "design" / "design.toml")
    path, _ = sweep_path(design, frames_n)
    frames = sweep_pictures(job / "verify" / "sweep.gif", path)
    boards = {v.name: board_image(design.target_path(v), design.board) for v in design.views}
    nearest = metrics["sweep"]["nearest_frame"]
    for name, corr in frame_correlations(frames, path, nearest, boards, design.board).items():
        assert max(corr, key=corr.get) == name, (name, corr)
        assert corr[name] > 0.5


def test_tolerance_from_a_profile_name_or_a_loaded_profile():
    from scratchfab.machine.profile import load_profile

    profile = load_profile("grbl-3018-diamond")
    by_name = Tolerance.from_profile("grbl-3018-diamond")
    loaded = Tolerance.from_profile("grbl-3018-diamond", profile)
    assert by_name.position_mm == loaded.position_mm == profile.tool.tolerance_mm
    # The report names the profile as the user did, not the installed file's path.
    assert by_name.source == loaded.source == "grbl-3018-diamond"


def test_sky_writes_its_render_layout_and_metrics(half_job, tmp_path, capsys):
    _, design, _, design_file, scratch_file = half_job
    out = tmp_path / "v"
    main(
        [
            "verify-render",
            "--design",
            str(design_file),
            "--scratches",
            str(scratch_file),
            "--out",
            str(out),
            "--spp",
            "16",
            "--sky",
            "--sun",
            "0.2",
            "0.9",
            "0.4",
            "--sky-strength",
            "2",
        ]
    )
    captured = capsys.readouterr()
    said = captured.out + captured.err
    metrics = json.loads((out / "metrics.json").read_text())
    sky = metrics["sky"]
    assert sky["folder"] == "sky" and sky["strength"] == 2.0 and sky["seconds"] > 0
    sun = np.array(sky["sun_direction"])
    np.testing.assert_allclose(
        sun / np.linalg.norm(sun), np.array([0.2, 0.9, 0.4]) / math.hypot(0.2, 0.9, 0.4)
    )
    targets, _ = design_targets(design)
    for name in ("left", "right"):
        img = np.load(out / "sky" / f"{name}.npy")
        assert img.dtype == np.float32 and img.shape == (32, 32)
        assert Image.open(out / "sky" / f"{name}.png").size == (32, 32)
        assert re.search(rf"sky {name}: \d+\.\d s, noise \d+\.\d\d %", said)
        # The metrics are those of the pictures on disk, and the sky lights the board
        # otherwise than the design's lamp does.
        assert sky["views"][name]["rho"] == pytest.approx(pearson(img, targets[name]), abs=1e-6)
        lamp = np.load(out / f"{name}.npy")
        assert np.isfinite(img).any() and not np.allclose(img, lamp, equal_nan=True)


def test_one_view_sweep_turns_the_azimuth_across_that_view():
    from scratchfab.verify.sweep import MIN_SPAN_DEG, nearest_frames

    tables = two_view_tables(resolution=16)
    tables["views"] = [{**tables["views"][0], "position_mm": [-120.0, 60.0, 300.0]}]
    design = design_from_mapping(tables, "<test>", Path("."))
    (view,) = design.views
    frames, view_params = sweep_path(design, 5)
    assert view_params == {"left": MIN_SPAN_DEG / 2}
    assert nearest_frames(frames, view_params) == {"left": 2}
    pos = np.array([f.view.position_mm for f in frames])
    np.testing.assert_allclose(pos[2], view.camera_position, atol=1e-9)
    # Same height and distance throughout; the azimuth (from +z toward +x) steps evenly
    # across the span, centred on the view's own.
    np.testing.assert_allclose(pos[:, 1], 60.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(pos, axis=1), math.hypot(120, 60, 300), rtol=1e-12)
    azimuth = np.degrees(np.arctan2(pos[:, 0], pos[:, 2]))
    centre = math.degrees(math.atan2(-120.0, 300.0))
    np.testing.assert_allclose(azimuth, centre + np.linspace(-0.5, 0.5, 5) * MIN_SPAN_DEG)
    for f in frames:
        assert f.view.fov == pytest.approx(view.fov)
        np.testing.assert_allclose(design.light_for(f.view), design.light_for(view))


@pytest.fixture
def thread_count():
    """Set Dr.Jit's CPU thread count inside a test; the old count comes back afterwards."""
    import drjit as dr

    before = dr.thread_count()
    yield dr.set_thread_count
    dr.set_thread_count(before)


@pytest.mark.parametrize("passes", [1, 3])
def test_render_view_is_mitsubas_render_without_its_thread_dependent_rounding(
    half_job, thread_count, passes
):
    """Mitsuba's own samples, summed in a fixed order: equal to ``mi.render`` up to float32
    rounding, and bit for bit the same whatever the thread count.

    132 samples per pixel (an 11 x 12 multi-jitter grid) put some pixels' samples in two
    work blocks of Dr.Jit's thread pool, where the film's atomic adds race.
    """
    _, design, scratches, _, _ = half_job
    mi = use_variant("llvm")
    view = design.views[0]
    spp = 132
    tables = scene_dict(design, scratches, view, spp)
    if passes > 1:
        tables["integrator"]["samples_per_pass"] = spp // passes
    scene = mi.load_dict(tables)
    thread_count(1)
    single = render_view(scene, spp, seed=5, max_wavefront=view.width * view.height * spp // passes)
    reference = np.array(mi.render(scene, spp=spp, seed=5), np.float64).reshape(single.shape)
    thread_count(2)
    for _ in range(3):
        again = render_view(
            scene, spp, seed=5, max_wavefront=view.width * view.height * spp // passes
        )
        assert again.tobytes() == single.tobytes()
    assert single.shape == (view.height, view.width) and single.max() > 0
    assert np.abs(single - reference).max() <= 1e-5 * reference.max()
    other_seed = render_view(scene, spp, seed=6)
    assert np.abs(other_seed - reference).max() > 1e-3 * reference.max()


def test_samples_per_pass_is_the_largest_divisor_that_fits():
    for pixels, spp, limit in [(6400, 2048, 1 << 24), (6400, 132, 6400 * 40), (7, 97, 100)]:
        per_pass = samples_per_pass(pixels, spp, limit)
        fits = [d for d in range(1, spp + 1) if spp % d == 0 and pixels * d <= limit]
        assert per_pass == max(fits, default=1)


def test_verify_outputs_are_byte_identical_across_runs_and_thread_counts(
    half_job, tmp_path, thread_count
):
    """SPEC's determinism: the same board and seed give the same files (bar timings)."""
    _, design, scratches, _, _ = half_job
    targets, cross = design_targets(design)
    settings = VerifySettings(spp=264, seed=4)
    outs = []
    for i, threads in enumerate((2, 1, 2)):
        thread_count(threads)
        out = tmp_path / f"run{i}"
        run_verify(design, scratches, out, settings, targets=targets, cross=cross)
        outs.append(out)
    names = sorted(str(p.relative_to(outs[0])) for p in outs[0].rglob("*") if p.is_file())
    assert {"left.npy", "left.png", "diff/left.png", "metrics.json"} <= set(names)

    def without_timings(value):
        if isinstance(value, dict):
            return {
                k: without_timings(v)
                for k, v in value.items()
                if k not in ("seconds", "seconds_per_spp")
            }
        return value

    for out in outs[1:]:
        assert sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()) == names
        for name in names:
            if name == "metrics.json":
                first = without_timings(json.loads((outs[0] / name).read_text()))
                assert without_timings(json.loads((out / name).read_text())) == first
            else:
                assert (out / name).read_bytes() == (outs[0] / name).read_bytes(), name


@pytest.mark.parametrize(
    ("near", "far"),
    [
        ([-120.0, 0.0, 300.0], [600.0, 0.0, 1500.0]),  # 300 -> 1500 mm would go below 0
        ([-5e5, 0.0, 5e5], [9e5, 1e5, 9e5]),  # near the coordinate limit: the frames are not
    ],
)
def test_sweep_frames_go_on_past_the_end_views_at_their_distance_within_bounds(near, far):
    """Two views: the walk is the straight line between their (azimuth, elevation), going
    on half its length past each end; its distance changes linearly between the views
    and stays the end view's past them (carried on, 300 -> 1500 mm put the first frame
    behind the board). A frame beyond MAX_MM on an axis is drawn in along its direction
    to it (a ValueError from View's bounds before)."""
    from scratchfab.model.design import MAX_MM

    tables = two_view_tables(resolution=16)
    tables["views"][0]["position_mm"], tables["views"][1]["position_mm"] = near, far
    design = design_from_mapping(tables, "<test>", Path("."))
    frames, view_params = sweep_path(design, 41)
    ends = np.array([near, far])
    az = np.arctan2(ends[:, 0], ends[:, 2])
    el = np.arctan2(ends[:, 1], np.hypot(ends[:, 0], ends[:, 2]))
    dist = np.linalg.norm(ends, axis=1)
    span = math.degrees(math.hypot(az[1] - az[0], el[1] - el[0]))
    # half the span past each view, or up to 80 degrees of azimuth (first reached here:
    # the views turn outward, their elevations small)
    turn = max(1.4, *np.abs(az))
    before, after = (min(0.5, (turn - abs(a)) / (az[1] - az[0])) for a in az)
    assert view_params == pytest.approx({"left": before * span, "right": (before + 1) * span})
    t = np.array([f.param for f in frames])
    np.testing.assert_allclose(t, np.linspace(0.0, (before + 1 + after) * span, 41))
    x = t / span - before  # 0 at the first view, 1 at the second
    a, e = az[0] + x * (az[1] - az[0]), el[0] + x * (el[1] - el[0])
    d = dist[0] + np.clip(x, 0, 1) * (dist[1] - dist[0])
    want = d[:, None] * np.stack([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)], 1)
    want *= np.minimum(1.0, MAX_MM / np.abs(want).max(axis=1))[:, None]
    got = np.array([f.view.position_mm for f in frames])
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * MAX_MM)
    assert np.abs(got).max() <= MAX_MM and got[:, 2].min() > 0
    assert (np.abs(got).max(axis=1) == MAX_MM).any() == (near[0] == -5e5)


@pytest.mark.parametrize("shared", [0, 1])
def test_sweep_through_views_that_share_a_camera_goes_on_past_the_ends(shared):
    """Two views at one camera (lit otherwise) and a third elsewhere: the walk goes on past
    each end along the segment between the two cameras (its first or last segment of no
    length gave 0/0 and NaN cameras, a ValueError from View's bounds)."""
    from scratchfab.verify.sweep import nearest_frames

    tables = two_view_tables(resolution=16)
    twin = {**tables["views"][shared], "name": "twin", "light_position_mm": [0.0, -150, 300]}
    tables["views"].append(twin)
    design = design_from_mapping(tables, "<test>", Path("."))
    frames, view_params = sweep_path(design, 41)
    pos = np.array([f.view.position_mm for f in frames])
    # the two cameras as in test_sweep_frames_go_on_past_the_end_views_at_their_distance:
    # +-21.8 degrees apart, the walk half that span past each
    span = 2 * math.degrees(math.atan2(120.0, 300.0))
    az = np.degrees(np.arctan2(pos[:, 0], pos[:, 2]))
    np.testing.assert_allclose(az, np.linspace(-span, span, 41), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(pos, axis=1), math.hypot(120.0, 300.0))
    near = nearest_frames(frames, view_params)
    assert near["twin"] == near[("left", "right")[shared]]
    assert (near["left"], near["right"]) == (10, 30)


@pytest.mark.parametrize("azimuth", [60.0, 85.0])
def test_sweep_frames_stay_in_front_of_the_board(azimuth):
    """Views far to the sides: the walk past them turns no farther than 80 degrees from the
    board's normal (the outermost view's azimuth if more), as the elevation does; carried
    on, views at +-60 degrees put the first and last frames at +-120, behind the board.
    Its frames spread evenly up to there (clipped, a third of them stood still at +-80)."""
    tables = two_view_tables(resolution=16)
    a = math.radians(azimuth)
    tables["views"][0]["position_mm"] = [-300 * math.sin(a), 0.0, 300 * math.cos(a)]
    tables["views"][1]["position_mm"] = [300 * math.sin(a), 0.0, 300 * math.cos(a)]
    design = design_from_mapping(tables, "<test>", Path("."))
    frames, view_params = sweep_path(design, 41)
    pos = np.array([f.view.position_mm for f in frames])
    got = np.degrees(np.arctan2(pos[:, 0], pos[:, 2]))
    turn = min(max(math.degrees(1.4), azimuth), 2 * azimuth)  # half the span past a view
    np.testing.assert_allclose(got, np.linspace(-turn, turn, 41), atol=1e-9)
    assert view_params == pytest.approx({"left": turn - azimuth, "right": turn + azimuth})
    assert pos[:, 2].min() > 0
    np.testing.assert_allclose(np.linalg.norm(pos, axis=1), 300.0)


def test_sweep_frames_spread_evenly_up_to_80_degrees_of_elevation():
    """Views 50 degrees below and above the board's normal: the walk goes on to 80 degrees
    past each (clipped, the frames from 80 to 100 degrees stood still at 80)."""
    tables = two_view_tables(resolution=16)
    for view, sign in zip(tables["views"], (-1, 1), strict=True):
        el = math.radians(sign * 50.0)
        view["position_mm"] = [0.0, 300 * math.sin(el), 300 * math.cos(el)]
    design = design_from_mapping(tables, "<test>", Path("."))
    frames, _ = sweep_path(design, 21)
    pos = np.array([f.view.position_mm for f in frames])
    got = np.degrees(np.arctan2(pos[:, 1], np.hypot(pos[:, 0], pos[:, 2])))
    top = math.degrees(1.4)
    np.testing.assert_allclose(got, np.linspace(-top, top, 21), atol=1e-9)


def test_a_failed_gate_never_shows_rho_rounded_up_to_the_gate():
    """0.7996 is below a gate of 0.8: shown to 3 decimals it must not read 0.800."""
    from scratchfab.verify.verify import VerifyGateError

    text = str(VerifyGateError("right", 0.7996, 0.8, 1, 2, Path("m.json")))
    assert text.startswith(
        "view right looks like its target only to rho 0.799, below --min-rho 0.8"
    )
    assert "rho -0.101," in str(VerifyGateError("left", -0.1003, 0.8, 1, 2, Path("m.json")))
