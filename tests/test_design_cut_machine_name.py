"""The cut line names the machine one way, whether ``design`` or ``run`` made the layout.

The quick form passed the bundled name (``'grbl-3018-diamond'``), ``run`` the loaded
profile (``'GRBL 3018 engraver, diamond drag bit'``). Both now say the profile's name and,
in brackets, the bundled name or the file, as export's line does. The reference is the
profile file itself.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import replace

import tomli_w
from conftest import cli_run
from cut_said import cut_sentence

from scratchfab.bundled import bundled_dir
from scratchfab.design.stage import run_design
from scratchfab.pipeline.config import load_pipeline
from scratchfab.toolpath.inputs import planned_for
from scratchfab.toolpath.plan import Toolpath

DEMO = bundled_dir("demo")
PROFILE = bundled_dir("machine_profiles") / "grbl-3018-diamond.toml"


def _machine(lines: list[str]) -> str:
    cut = cut_sentence(lines)
    named = re.search(r" on (machine '.*?' \([^;)]*);", cut)
    assert named, cut
    return named.group(1)


def test_design_and_run_name_the_machine_alike(tmp_path, capsys):
    name = tomllib.loads(PROFILE.read_text(encoding="utf-8"))["name"]
    expected = f"machine '{name}' ({PROFILE.stem}"
    code, out, _ = cli_run(
        ["design", str(DEMO / "sun.png"), "--board", "40x30", "--count", "40",
         "--resolution", "16", "--out", str(tmp_path / "a")],
        capsys,
    )  # fmt: skip
    assert code == 0, out
    assert _machine(out.splitlines()) == expected
    pipe = load_pipeline(bundled_dir("pipelines") / "demo.toml")
    design = replace(pipe.design, source=str(pipe.path))
    design = replace(design, scratch=replace(design.scratch, count=40))
    said: list[str] = []
    run_design(design, tmp_path / "b", resolution=None, progress=said.append, machine=pipe.profile)
    assert pipe.profile.name == name
    assert _machine(said) == expected


def test_design_and_toolpath_name_a_profile_file_alike(tmp_path, capsys):
    """A profile file of the user's: design's cut line and a toolpath planned for it (as
    toolpath and export name it) say the same, the file's own name and its path; the cut
    line says it times the layout before optimize."""
    table = tomllib.loads(PROFILE.read_text(encoding="utf-8"))
    table["name"] = "my engraver"
    mine = tmp_path / "machines" / "mine.toml"
    mine.parent.mkdir()
    mine.write_text(tomli_w.dumps(table), encoding="utf-8")
    job = tmp_path / "job"
    said: list[str] = []
    design_file = tmp_path / "design.toml"
    pipe = load_pipeline(bundled_dir("pipelines") / "demo.toml")
    design = replace(pipe.design, scratch=replace(pipe.design.scratch, count=40))
    design.save(design_file)
    run_design(design_file, job, resolution=(16, 16), progress=said.append, machine=str(mine))
    expected = f"machine 'my engraver' ({mine}"
    assert _machine(said) == expected
    cut = cut_sentence(said)
    assert "this initial layout, before optimize" in cut, cut
    code, out, _ = cli_run(["toolpath", str(job), "--machine", str(mine)], capsys)
    assert code == 0, out
    planned = planned_for(Toolpath.load(job / "toolpath" / "toolpath.json"))
    assert planned == expected + ")"


def test_design_machine_option_times_the_cut_on_that_machine(tmp_path, capsys):
    """The quick form's ``--machine`` (a plotter owner's finding: design timed a plotter job
    on the 3018): the line names that profile and differs from the 3018's (that the time is
    toolpath's estimate is test_design_cut_cost's), and a typo is refused before anything
    is written."""
    plotter = bundled_dir("machine_profiles") / "grbl-plotter-scribe.toml"
    name = tomllib.loads(plotter.read_text(encoding="utf-8"))["name"]
    quick = [str(DEMO / "sun.png"), "--board", "40x30", "--count", "40", "--resolution", "16"]
    lines = {}
    for machine in ("grbl-plotter-scribe", "grbl-3018-diamond"):
        code, out, err = cli_run(
            ["design", *quick, "--machine", machine, "--out", str(tmp_path / machine)], capsys
        )
        assert code == 0, err
        lines[machine] = cut_sentence(out.splitlines())
    assert _machine([lines["grbl-plotter-scribe"]]) == f"machine '{name}' ({plotter.stem}"
    assert lines["grbl-plotter-scribe"] != lines["grbl-3018-diamond"]

    code, out, err = cli_run(
        ["design", *quick, "--machine", "grbl-plotter-scrib", "--out", str(tmp_path / "typo")],
        capsys,
    )
    assert code != 0
    assert "grbl-plotter-scrib" in err and "Traceback" not in err
    assert not (tmp_path / "typo").exists()
