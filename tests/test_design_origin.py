"""design.toml's heading comment names the images the user gave, through reruns of it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from PIL import Image

from scratchfab.cli import main
from scratchfab.model.design import load_design


def _comment(toml: Path) -> list[str]:
    """The comment lines heading a design.toml."""
    lines = toml.read_text(encoding="utf-8").splitlines()
    return lines[: next(i for i, line in enumerate(lines) if not line.startswith("#"))]


@pytest.fixture()
def pictures(tmp_path: Path) -> list[Path]:
    out = []
    for name, value in (("sun", 230), ("moon", 90)):
        path = tmp_path / "in" / f"{name}.png"
        path.parent.mkdir(exist_ok=True)
        image = Image.new("L", (20, 20), 0)
        image.paste(value, (4, 4, 16, 16))
        image.save(path)
        out.append(path)
    return out


def test_a_rerun_from_the_jobs_design_toml_still_names_the_images_first_given(
    pictures, tmp_path, capsys
):
    job = tmp_path / "job"
    quick = [str(p) for p in pictures] + ["--board", "30x30", "--count", "60", "--resolution", "12"]
    main(["design", *quick, "--gamma", "2", "--out", str(job)])
    toml = job / "design" / "design.toml"
    first = _comment(toml)
    for picture in pictures:
        assert f"# {picture.stem}: {picture.resolve()}" in first
    assert "(fit = contain, gamma = 2, contrast = 1)," in first[1]
    assert not [line for line in first if "earlier design" in line]

    # Rerun in place (it reads its own board pictures), then from there into a second job.
    main(["design", str(toml), "--out", str(job)])
    main(["design", str(toml), "--out", str(tmp_path / "job2")])
    capsys.readouterr()
    for again in (toml, tmp_path / "job2" / "design" / "design.toml"):
        comment = _comment(again)
        design = load_design(again)
        for view, picture in zip(design.views, pictures, strict=True):
            line = comment.index(f"# {view.name}: {job / 'design' / 'board' / picture.name}")
            assert comment[line + 1] == (
                f"#   the board picture an earlier design made from {picture.resolve()} "
                "(fit = contain, gamma = 2, contrast = 1)"
            )
        # the comment's options are this run's, applied to the board picture
        assert "(fit = contain, gamma = 1, contrast = 1)," in comment[1]


def test_a_picture_named_board_without_a_design_beside_it_is_named_alone(
    pictures, tmp_path, capsys
):
    """Only a design's own board folder (a design.toml with the heading beside it) counts."""
    board = tmp_path / "elsewhere" / "board"
    board.mkdir(parents=True)
    picture = board / "sun.png"
    picture.write_bytes(pictures[0].read_bytes())
    (board.parent / "design.toml").write_text("# a note of mine\n[board]\n", encoding="utf-8")
    job = tmp_path / "job"
    main(["design", str(picture), "--board", "30x30", "--count", "40", "--resolution", "12",
          "--out", str(job)])  # fmt: skip
    capsys.readouterr()
    comment = _comment(job / "design" / "design.toml")
    assert f"# sun: {picture.resolve()}" in comment
    assert not [line for line in comment if "earlier design" in line]


def test_an_earlier_reruns_own_options_stay_in_the_chain(pictures, tmp_path, capsys):
    """A rerun that changed the board picture (gamma 2) is named after the first image: a
    design made from its board picture says both steps, not only the first one's options."""
    quick = [str(pictures[0]), "--board", "30x30", "--count", "40", "--resolution", "12"]
    first, second, third = (tmp_path / f"job{i}" for i in (1, 2, 3))
    main(["design", *quick, "--out", str(first)])
    main(["design", str(first / "design" / "design.toml"), "--gamma", "2", "--out", str(second)])
    main(["design", str(second / "design" / "design.toml"), "--out", str(third)])
    capsys.readouterr()
    comment = _comment(third / "design" / "design.toml")
    line = comment.index(f"# sun: {second / 'design' / 'board' / 'sun.png'}")
    assert comment[line + 1] == (
        f"#   the board picture an earlier design made from {pictures[0].resolve()} "
        "(fit = contain, gamma = 1, contrast = 1), then (fit = contain, gamma = 2, contrast = 1)"
    )
    # a plain rerun (gamma and contrast 1) adds no step
    main(["design", str(third / "design" / "design.toml"), "--out", str(tmp_path / "job4")])
    capsys.readouterr()
    again = _comment(tmp_path / "job4" / "design" / "design.toml")
    named = again.index(f"# sun: {third / 'design' / 'board' / 'sun.png'}")
    assert again[named + 1] == comment[line + 1]


def test_a_view_renamed_in_the_jobs_design_toml_is_headed_by_the_picture_it_has_now(
    pictures, tmp_path, capsys
):
    """A lab technician renames a view in JOB/design/design.toml and reruns in place: the
    heading names the board picture that exists after the run, under the new name, and
    still what it was first made from, through a further rerun."""
    job = tmp_path / "job"
    quick = [str(p) for p in pictures] + ["--board", "30x30", "--count", "60", "--resolution", "12"]
    main(["design", *quick, "--out", str(job)])
    toml = job / "design" / "design.toml"
    text = toml.read_text(encoding="utf-8")
    assert text.count('name = "sun"') == 1
    toml.write_text(text.replace('name = "sun"', 'name = "sol"'), encoding="utf-8")
    for _ in range(2):
        main(["design", str(toml), "--out", str(job)])
        capsys.readouterr()
        comment = _comment(toml)
        named = [line.split(": ", 1)[1] for line in comment if re.match(r"# \w+: ", line)]
        assert named and all(Path(p).is_file() for p in named), named
        board = job / "design" / "board"
        line = comment.index(f"# sol: {board / 'sol.png'}")
        assert comment[line + 1] == (
            f"#   the board picture an earlier design made from {pictures[0].resolve()} "
            "(fit = contain, gamma = 1, contrast = 1)"
        )
        assert not (board / "sun.png").exists()
        views = load_design(toml).views
        assert [(v.name, v.target) for v in views] == [
            ("sol", str(board / "sol.png")),
            ("moon", str(board / "moon.png")),
        ]


def test_a_copied_job_reruns_from_its_own_board_pictures(pictures, tmp_path, capsys):
    """A copy's design.toml names the original's pictures (SPEC 6, absolute paths); a rerun
    from the copy reads the copy's own, whether the original is gone or designed anew."""
    import shutil

    import numpy as np

    job = tmp_path / "job"
    quick = [str(p) for p in pictures] + ["--board", "30x30", "--count", "40", "--resolution", "12"]
    main(["design", *quick, "--out", str(job)])
    copy = tmp_path / "copy"
    shutil.copytree(job, copy)
    before = {v: np.load(copy / "design" / "targets" / f"{v}.npy") for v in ("sun", "moon")}

    # the original designed anew (inverted): the copy must not pick that up
    main(["design", str(job / "design" / "design.toml"), "--invert", "--out", str(job)])
    main(["design", str(copy / "design" / "design.toml"), "--out", str(copy)])
    capsys.readouterr()
    for view, target in before.items():
        assert np.array_equal(np.load(copy / "design" / "targets" / f"{view}.npy"), target,
                              equal_nan=True)  # fmt: skip
    comment = _comment(copy / "design" / "design.toml")
    assert f"# sun: {copy / 'design' / 'board' / 'sun.png'}" in comment

    # the original gone: the rerun still works from the copy's pictures
    shutil.rmtree(job)
    assert main(["design", str(copy / "design" / "design.toml"), "--out", str(copy)]) in (0, None)
    capsys.readouterr()
    for view, target in before.items():
        assert np.array_equal(np.load(copy / "design" / "targets" / f"{view}.npy"), target,
                              equal_nan=True)  # fmt: skip
