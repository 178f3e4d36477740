"""`scratchfab render`: outputs, the job folder, the bundled example and one-line errors."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import make_design
from PIL import Image

from scratchfab.cli import main
from scratchfab.model.design import load_design
from scratchfab.model.scratches import ScratchSet, load_scratches
from scratchfab.render.layout import EXPOSURE_KEY, read_render_layout, write_render_layout
from scratchfab.render.renderer import render_scratches

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "pipelines" / "example"


def run(argv: list[str]) -> int:
    try:
        main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    return 0


def write_inputs(folder: Path, rng: np.random.Generator, n: int = 40) -> tuple[Path, Path]:
    design = make_design(resolution=16)
    folder.mkdir(parents=True, exist_ok=True)
    design_file = folder / "design.toml"
    design.save(design_file)
    c = rng.uniform(-15, 15, (n, 2))
    d = rng.uniform(-2, 2, (n, 2))
    ScratchSet.from_arrays(c - d, c + d, rng.uniform(0.05, 0.2, n), 0.01).save(
        folder / "scratches.csv", design.scratch
    )
    return design_file, folder / "scratches.csv"


def test_render_writes_layout_equal_to_library(tmp_path, rng, capsys):
    design_file, scratch_file = write_inputs(tmp_path / "in", rng)
    out = tmp_path / "out"
    code = run(
        [
            "render",
            "--design",
            str(design_file),
            "--scratches",
            str(scratch_file),
            "--out",
            str(out),
        ]
    )
    assert code == 0
    assert "view left" in capsys.readouterr().out  # progress per view
    assert sorted(p.name for p in out.iterdir()) == [
        "left.npy",
        "left.png",
        "right.npy",
        "right.png",
    ]
    design = load_design(design_file)
    expected = render_scratches(design, load_scratches(scratch_file, design.scratch))
    got = read_render_layout(out)
    for name, img in expected.items():
        assert got[name].dtype == np.float32 and got[name].shape == (16, 16)
        np.testing.assert_array_equal(got[name], img)


def test_preview_follows_the_documented_tone_map(tmp_path, rng):
    img = rng.gamma(0.5, 1e-6, (12, 20)).astype(np.float32)
    img[0, 0] = np.nan
    write_render_layout(tmp_path, {"v": img})
    png = Image.open(tmp_path / "v.png")
    assert png.mode == "L" and png.size == (20, 12)
    e = float(png.text[EXPOSURE_KEY])
    positive = img[np.isfinite(img) & (img > 0)].astype(np.float64)
    assert e == pytest.approx(np.percentile(positive, 99.5), rel=1e-12)
    grey = np.asarray(png, dtype=np.float64)
    finite = np.nan_to_num(img.astype(np.float64), nan=0.0)
    # IEC 61966-2-1, written out here independently of scratchfab.render.tonemap
    x = np.clip(finite / e, 0, 1)
    want = np.round(255 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055))
    assert np.abs(grey - want).max() <= 1 and np.mean(grey == want) > 0.98  # rounding ties
    assert grey[0, 0] == 0
    # and back: the preview gives radiance to within 8-bit quantisation below white
    below = finite < e
    v = grey / 255
    back = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4) * e
    assert np.all(np.abs(back - finite)[below] <= 0.02 * e)


def test_render_job_prefers_the_optimized_layout(tmp_path, rng):
    job = tmp_path / "job"
    write_inputs(job / "design", rng)
    assert run(["render", str(job)]) == 0
    first = read_render_layout(job / "render")
    (job / "optimize").mkdir()
    ScratchSet.from_arrays([[-5.0, 0.0]], [[5.0, 1.0]], 0.1, 0.01).save(
        job / "optimize" / "scratches.csv"
    )
    assert run(["render", str(job), "--out", str(tmp_path / "other")]) == 0
    second = read_render_layout(tmp_path / "other")
    assert not np.array_equal(first["left"], second["left"])
    design = load_design(job / "design" / "design.toml")
    want = render_scratches(
        design, load_scratches(job / "optimize" / "scratches.csv", design.scratch)
    )
    np.testing.assert_array_equal(second["left"], want["left"])


def test_bundled_example_renders(tmp_path):
    """The README's interim main job, exactly as `make demo` runs it (relative paths)."""
    out = tmp_path / "job-example"
    code = run(
        [
            "render",
            "--design",
            str(EXAMPLE / "design.toml"),
            "--scratches",
            str(EXAMPLE / "scratches.csv"),
            "--out",
            str(out),
        ]
    )
    assert code == 0
    images = read_render_layout(out)
    assert set(images) == {"left", "right"}
    scratches = load_scratches(
        EXAMPLE / "scratches.csv", load_design(EXAMPLE / "design.toml").scratch
    )
    assert 200 <= len(scratches) <= 1000
    # each view shows its own shape: its brightest pixels differ from the other view's
    left, right = images["left"], images["right"][:, ::-1]
    top_left = left > np.percentile(left, 97)
    top_right = right > np.percentile(right, 97)
    assert np.count_nonzero(top_left & top_right) < 0.3 * np.count_nonzero(top_left)


def test_example_script_is_reproducible(tmp_path):
    copy = tmp_path / "example"
    shutil.copytree(EXAMPLE, copy)
    (copy / "scratches.csv").unlink()
    import runpy

    runpy.run_path(str(copy / "make_example.py"), run_name="__main__")
    assert (copy / "scratches.csv").read_text() == (EXAMPLE / "scratches.csv").read_text()
    assert (copy / "design.toml").read_text() == (EXAMPLE / "design.toml").read_text()


BAD_SCRATCHES = [
    ("x0,y0,x1,y1\n1,2,3\n", "line 2: expected 4 values"),
    ("x0,y0,x1,y1\n1,2,1,2\n", "line 2: scratch has zero length"),
    ("x0,y0,x1,y1\n0,0,1,1\n1,2,30,4\n", "line 3: scratch leaves the board"),
    ("x0,y0,x1,y1\n0,0,nan,1\n", "column x1: expected a finite number"),
    ("x0,y0,x1,y1,width,depth\n0,0,1,1,0.1,-1\n", "column depth: expected a positive size"),
    ("x0,y0,x1,y2\n0,0,1,1\n", "missing y1"),
]


@pytest.mark.parametrize(("text", "message"), BAD_SCRATCHES)
def test_bad_scratch_file_is_one_line_and_writes_nothing(tmp_path, rng, capsys, text, message):
    design_file, scratch_file = write_inputs(tmp_path / "in", rng)
    scratch_file.write_text(text)
    out = tmp_path / "out"
    code = run(
        [
            "render",
            "--design",
            str(design_file),
            "--scratches",
            str(scratch_file),
            "--out",
            str(out),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code != 0
    assert err.count("\n") == 0 and err.startswith("error: ")
    assert str(scratch_file) in err and message in err
    assert "Traceback" not in err
    assert not out.exists()


def test_bad_design_and_usage_errors(tmp_path, rng, capsys):
    design_file, scratch_file = write_inputs(tmp_path / "in", rng)
    text = design_file.read_text().replace("roughness", "roughnes")
    design_file.write_text(text)
    cases = [
        (
            [
                "render",
                "--design",
                str(design_file),
                "--scratches",
                str(scratch_file),
                "--out",
                str(tmp_path / "o"),
            ],
            ["roughnes", "did you mean 'roughness'", str(design_file)],
        ),
        (
            [
                "render",
                "--design",
                str(tmp_path / "none.toml"),
                "--scratches",
                str(scratch_file),
                "--out",
                str(tmp_path / "o"),
            ],
            ["none.toml: file not found"],
        ),
        (["render", str(tmp_path / "nojob")], ["nojob: job folder not found"]),
        (["render", str(tmp_path)], ["design.toml: file not found"]),
        (["render", "--design", str(design_file)], ["give JOB, or all of"]),
        (["render", str(tmp_path), "--design", str(design_file)], ["not both"]),
    ]
    for argv, parts in cases:
        code = run(argv)
        err = capsys.readouterr().err.strip()
        assert code != 0, argv
        assert err.count("\n") == 0, err
        for part in parts:
            assert part in err, (argv, err)
    assert not (tmp_path / "o").exists()


def test_cuda_backend_renders_or_says_why(tmp_path, rng, capsys):
    import drjit as dr

    design_file, scratch_file = write_inputs(tmp_path / "in", rng)
    args = ["render", "--design", str(design_file), "--scratches", str(scratch_file), "--out"]
    code = run([*args, str(tmp_path / "cuda"), "--backend", "cuda"])
    err = capsys.readouterr().err.strip()
    if not dr.has_backend(dr.JitBackend.CUDA):
        assert code != 0 and err.count("\n") == 0 and "--backend llvm" in err
        assert not (tmp_path / "cuda").exists()
        return
    assert code == 0
    assert run([*args, str(tmp_path / "llvm")]) == 0
    a, b = read_render_layout(tmp_path / "cuda"), read_render_layout(tmp_path / "llvm")
    for name in a:
        np.testing.assert_allclose(a[name], b[name], rtol=1e-5, atol=1e-6 * b[name].max())


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda d: None, "{d}: render folder not found"),
        (lambda d: d.mkdir(), "{d}: no <view>.npy images in this folder"),
        (
            lambda d: _put(d, b"garbage"),
            "{d}/a.npy: not a NumPy .npy file (it begins with b'garbage')",
        ),
        (lambda d: _put(d, b""), "{d}/a.npy: not a NumPy .npy file (it is empty)"),
        (
            lambda d: _put(d, _npy(np.zeros(3))),
            "{d}/a.npy: expected a 2-D float image, got float64 (3,)",
        ),
        (
            lambda d: _put(d, _npy(np.zeros((2, 2), int))),
            "{d}/a.npy: expected a 2-D float image, got int64",
        ),
        (
            lambda d: _put(d, _npy(np.zeros(4))[:-8]),
            "{d}/a.npy: unreadable NumPy .npy file (Failed to read",
        ),
    ],
    ids=["missing", "empty folder", "garbage", "empty file", "1-D", "integers", "truncated"],
)
def test_render_folder_errors_are_one_line_naming_the_file(tmp_path, make, message):
    from scratchfab.errors import ConfigError

    folder = tmp_path / "renders"
    make(folder)
    with pytest.raises(ConfigError) as exc:
        read_render_layout(folder)
    text = str(exc.value)
    assert text.startswith(message.format(d=folder)) and "\n" not in text
    assert "allow_pickle" not in text


def _npy(array: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _put(folder: Path, data: bytes) -> None:
    folder.mkdir()
    (folder / "a.npy").write_bytes(data)


# ---------------------------------------------------------------- the command line as a whole


def test_help_lists_every_command_and_each_resolves(capsys):
    import re

    import click

    from scratchfab.cli import COMMANDS, cli

    # click (standalone_mode=False) returns --help's exit code instead of raising.
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    listed = re.findall(r"^  (\S+)  +(.+)$", out.split("\nCommands:\n")[1], re.MULTILINE)
    assert [name for name, _ in listed] == list(COMMANDS)
    ctx = click.Context(cli)
    for name, text in listed:
        command = cli.get_command(ctx, name)
        assert isinstance(command, click.Command) and command.name == name
        assert text == COMMANDS[name][2]
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("scratchfab, version ")
