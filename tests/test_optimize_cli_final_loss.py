"""`optimize`'s closing line says which loss it gives, and log.csv bears both out.

A progress line shows the loss its step started from (log.csv's row of the step before);
the closing line gives the final layout's, evaluated after the last step (and pruning),
log.csv's last row. The reference is log.csv and summary.json as the stage wrote them.
"""

from __future__ import annotations

import csv
import json
import re

from conftest import cli_said, write_pipeline

from scratchfab.pipeline.config import load_pipeline
from scratchfab.pipeline.runner import run_pipeline


def test_the_closing_loss_is_named_and_the_progress_lines_loss_is_the_step_start(tmp_path, capsys):
    path = write_pipeline(tmp_path)
    job = tmp_path / "job"
    run_pipeline(load_pipeline(path), job, until="design")
    code, said = cli_said(
        ["optimize", str(job), "--iterations", "5", "--prune", "0.2", "--seed", "1"], capsys
    )
    assert code == 0, said
    with (job / "optimize" / "log.csv").open() as handle:
        rows = {int(float(r["iteration"])): float(r["loss"]) for r in csv.DictReader(handle)}
    summary = json.loads((job / "optimize" / "summary.json").read_text())
    prune = summary["prune"]
    assert prune["removed"] > 0 and prune["loss_after"] > prune["loss_before"]
    # The last progress line: 5 steps done, the loss step 5 started from (row 4).
    last = re.findall(r"\] 5/5 loss (\d+\.\d+)", said)
    assert last == [f"{rows[4]:.5f}"], said
    # The closing line: the final layout's loss (row 5), after the last step and pruning.
    assert summary["loss"] == prune["loss_after"]
    assert f"{rows[5]:.5f}" == f"{summary['loss']:.5f}"  # log.csv keeps 6 digits
    closing = [line for line in said.splitlines() if line.startswith("5 iterations")]
    assert len(closing) == 1, said
    assert closing[0].startswith(
        f"5 iterations (done), loss {rows[5]:.5f} after the last step and pruning "
    ), closing
    assert "progress line" in closing[0] and "started from" in closing[0]
    # The pruning line says what pruning cost in loss.
    assert f"loss {prune['loss_before']:.5f} -> {prune['loss_after']:.5f}" in said, said
