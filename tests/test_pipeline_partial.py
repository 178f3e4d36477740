"""Which pipeline key lets the toolpath stage plan a board the machine's envelope cuts short.

``[toolpath] force`` (as ``scratchfab toolpath --force``) where given; else ``[pipeline]
force``, the design stage's override, which meant both before the partial board had a key
of its own: an older file keeps working, with a note naming the new key. References: the
plan's own statistics (scratches outside the envelope, clipped to it) and a toolpath
fingerprint as the stage recorded it before the key (no ``force``).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import write_pipeline

from scratchfab.bundled import bundled_dir
from scratchfab.errors import ScratchfabError
from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.runner import _board_overhang, _Stages, run_pipeline

OFFSET = "offset_mm = [-220.0, -150.0]"
#: The key each row adds under [toolpath], after its machine.
MACHINE = 'machine = "overhang.toml"'


def _pipeline(folder: Path, pipeline_force: bool, toolpath_force: bool | None) -> Path:
    """The tiny pipeline on a 3018 whose board hangs 15 mm past X 0 (a partial board)."""
    profile = (bundled_dir("machine_profiles") / "grbl-3018-diamond.toml").read_text()
    assert OFFSET in profile
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "overhang.toml").write_text(profile.replace(OFFSET, "offset_mm = [-15.0, -150.0]"))
    edits = {'machine = "grbl-3018-diamond"': MACHINE}
    if toolpath_force is not None:
        edits['machine = "grbl-3018-diamond"'] += f"\nforce = {str(toolpath_force).lower()}"
    if pipeline_force:
        edits['name = "tiny"'] = 'name = "tiny"\nforce = true'
    return write_pipeline(folder, edits=edits)


@pytest.fixture(scope="module")
def verified(tmp_path_factory: pytest.TempPathFactory) -> dict[bool, Path]:
    """Per ``[pipeline] force``, a job run up to verify (the stages [toolpath] leaves alone)."""
    jobs = {}
    for force in (False, True):
        folder = tmp_path_factory.mktemp(f"pipeline-force-{force}")
        path = _pipeline(folder, force, None)
        run_pipeline(load_pipeline(path), folder / "job", until="verify")
        jobs[force] = folder / "job"
    return jobs


@pytest.mark.parametrize(
    ("pipeline_force", "toolpath_force", "planned", "noted"),
    [
        (False, None, False, False),  # neither: refused, naming [toolpath] force
        (True, None, True, True),  # an older file: planned as before, with the note
        (True, False, False, False),  # the design's override alone
        (False, True, True, False),  # the partial board's own key
        (True, True, True, False),
    ],
)
def test_a_partial_board_is_planned_by_toolpath_force_else_an_older_files_pipeline_force(
    tmp_path: Path,
    verified: dict[bool, Path],
    pipeline_force: bool,
    toolpath_force: bool | None,
    planned: bool,
    noted: bool,
) -> None:
    folder = tmp_path / "pipe"
    path = _pipeline(folder, pipeline_force, toolpath_force)
    job = folder / "job"
    shutil.copytree(verified[pipeline_force], job)
    said: list[str] = []
    if not planned:
        with pytest.raises(ScratchfabError) as info:
            run_pipeline(load_pipeline(path), job, until="toolpath", say=said.append)
        assert "or give [toolpath] force = true to plan only the part it reaches" in str(info.value)
        assert not (job / "toolpath" / "toolpath.json").exists()
    else:
        run_pipeline(load_pipeline(path), job, until="toolpath", say=said.append)
        stats = json.loads((job / "toolpath" / "toolpath.json").read_text())["statistics"]
        assert stats["outside_count"] > 0 and stats["clipped_count"] > 0
    # only toolpath ran: [toolpath] is none of the earlier stages' inputs
    assert [line for line in said if line.endswith("] running")] == ["[toolpath] running"]
    notes = [line for line in said if "note: the part the machine reaches was planned" in line]
    assert len(notes) == noted
    if noted:
        assert (
            notes[0]
            .strip()
            .endswith(
                f"set [toolpath] force in {path}: true to keep planning it, false to refuse a "
                "partial board"
            )
        )


@pytest.mark.parametrize(
    ("pipeline_force", "toolpath_force", "words"),
    [
        (
            True,
            None,
            "will leave out the scratches beyond it and clip those across its edge ([pipeline] "
            "force = true, [toolpath] force not given: set it to false to refuse it)",
        ),
        (
            False,
            True,
            "will leave out the scratches beyond it and clip those across its edge ([toolpath] "
            "force = true)",
        ),
        (
            True,
            False,
            "will stop there if a scratch lies beyond it, unless [toolpath] force = true, which "
            "cuts only the part it reaches",
        ),
    ],
)
def test_the_start_warning_names_the_key_that_plans_the_part_within_reach(
    tmp_path: Path, pipeline_force: bool, toolpath_force: bool | None, words: str
) -> None:
    """Said before design runs (a run up to toolpath or later), so a person who meant only
    the design's override can stop before minutes of work."""
    warning = _board_overhang(load_pipeline(_pipeline(tmp_path, pipeline_force, toolpath_force)))
    assert warning is not None and warning.startswith("warning: the 30 x 30 mm board (corners ")
    assert words in warning


def test_a_job_planned_before_the_key_keeps_its_toolpath_and_the_key_reruns_it(
    tmp_path: Path,
) -> None:
    """The toolpath fingerprint holds ``force`` only where given, so an older job's plan stays
    current; giving ``[toolpath] force = false`` to an older file's job plans again and
    refuses its partial board."""
    path = _pipeline(tmp_path, True, None)
    job = tmp_path / "job"
    pipe = load_pipeline(path)
    before_the_key = {"passes": 50, "kicks": None, "seed": 0}  # [toolpath] as recorded then
    assert _Stages(pipe, job, print, None).inputs("toolpath")["options"] == before_the_key
    run_pipeline(pipe, job, until="toolpath", say=lambda _: None)
    said: list[str] = []
    run_pipeline(load_pipeline(path), job, until="toolpath", say=said.append)
    assert "[toolpath] up to date, skipped" in said
    refusing = _pipeline(tmp_path, True, False)
    with pytest.raises(ScratchfabError, match=r"or give \[toolpath\] force = true"):
        run_pipeline(load_pipeline(refusing), job, until="toolpath", say=lambda _: None)
