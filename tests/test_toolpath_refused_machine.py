"""A re-plan for another machine that is refused: the earlier plan stays, and says so.

``toolpath JOB --machine other.toml`` refused (the board does not fit that machine)
leaves JOB/toolpath as it was, planned for the earlier profile; the refusal names that
profile, and ``export`` names the profile it writes for, so that the earlier plan is
not taken for one made for the other machine.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import tomli_w
from conftest import cli_said, make_design

from scratchfab.machine.profile import load_profile
from scratchfab.model.scratches import ScratchSet

BUNDLED = "grbl-3018-diamond"


def make_job(folder: Path) -> Path:
    """A 40 mm design and 30 scratches of it (seeded), no optimize."""
    job = folder / "job"
    design = make_design()
    design.save(job / "design" / "design.toml")
    rng = np.random.default_rng(7)
    p0 = rng.uniform(-15.0, 15.0, (30, 2))
    p1 = p0 + rng.uniform(1.0, 4.0, (30, 2))
    ScratchSet.from_arrays(p0, p1, 0.1, 0.01).save(job / "design" / "scratches.csv", design.scratch)
    return job


def profile_file(folder: Path, name: str, **board: object) -> Path:
    """The bundled profile, renamed, its board placed by ``board``; written to a file."""
    table = load_profile(BUNDLED).to_table()
    table["name"] = name
    table["board"].update(board)
    path = folder / f"{name}.toml"
    path.write_text(tomli_w.dumps(table))
    return path


def test_a_refused_plan_names_the_plan_it_keeps_and_export_names_its_machine(tmp_path, capsys):
    job = make_job(tmp_path)
    plan = job / "toolpath" / "toolpath.json"
    code, said = cli_said(["toolpath", str(job), "--machine", BUNDLED], capsys)
    assert code == 0, said
    before = {p.name: p.read_bytes() for p in plan.parent.iterdir()}
    planned = load_profile(BUNDLED).name
    # The 40 mm board's lower-left corner 20 mm short of X 0 (the envelope's edge).
    other = profile_file(tmp_path, "other", offset_mm=[-20.0, -150.0])
    code, said = cli_said(["toolpath", str(job), "--machine", str(other)], capsys)
    assert code == 2 and "nothing written" in said, said
    assert {p.name: p.read_bytes() for p in plan.parent.iterdir()} == before
    kept = f"{plan} keeps its earlier plan, for machine '{planned}' ({BUNDLED}), not for 'other'"
    assert kept in said and "export writes that plan" in said, said
    # export writes it, and says for which machine.
    code, said = cli_said(["export", str(job), "--format", "gcode"], capsys)
    assert code == 0, said
    wrote = f"wrote {job / 'export' / 'board.gcode'} for machine '{planned}' ({BUNDLED}), "
    assert wrote + "from the design's initial layout (not optimized):" in said
    # Asked for the other machine, export refuses: it places the board elsewhere.
    code, said = cli_said(["export", str(job), "-f", "gcode", "--machine", str(other)], capsys)
    assert code != 0 and "places or cuts the board otherwise" in said, said
    # A profile that places the board as planned (other feeds, say) is named with the plan's.
    same = profile_file(tmp_path, "same", offset_mm=list(load_profile(BUNDLED).board.offset_mm))
    code, said = cli_said(["export", str(job), "-f", "svg", "--machine", str(same)], capsys)
    assert code == 0, said
    assert f"for machine 'same' ({same}), planned for machine '{planned}' ({BUNDLED}), " in said


def test_a_refusal_says_nothing_of_a_plan_for_the_same_settings_or_of_none(tmp_path, capsys):
    job = make_job(tmp_path)
    other = profile_file(tmp_path, "other", offset_mm=[-20.0, -150.0])
    code, said = cli_said(["toolpath", str(job), "--machine", str(other)], capsys)
    assert code == 2 and "nothing written" in said and "earlier plan" not in said, said
    code, said = cli_said(["toolpath", str(job), "--machine", str(other), "--force"], capsys)
    assert code == 0, said
    # Planned (a part) for these very settings: export's own checks apply, no word here.
    code, said = cli_said(["toolpath", str(job), "--machine", str(other)], capsys)
    assert code == 2 and "earlier plan" not in said, said
