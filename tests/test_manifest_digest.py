"""Manifest.digest: a job file's digest as a stage read it and as it wrote it.

Reference: hashlib's SHA-256 of the files' bytes, taken here.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from scratchfab.pipeline.manifest import Manifest, fingerprint


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_digest_as_read_and_as_written(tmp_path: Path) -> None:
    """Each table answers for its own files; a file a stage neither read nor wrote, an
    unknown stage and a damaged entry answer None."""
    job = tmp_path / "job"
    job.mkdir()
    read, wrote = job / "in.toml", job / "out.csv"
    read.write_text("a = 1\n")
    wrote.write_text("x,y\n")
    manifest = Manifest.load(job)
    manifest.record("design", fingerprint([read], None, {}, job), ["out.csv"], 0.1, [wrote])
    before = (_sha(read), _sha(wrote))
    read.write_text("a = 2\n")  # edits since: the record keeps what the stage saw
    wrote.write_text("x,y\n1,2\n")
    again = Manifest.load(job)
    assert again.digest("design", read, "read") == before[0] != _sha(read)
    assert again.digest("design", wrote, "written") == before[1] != _sha(wrote)
    assert again.digest("design", wrote, "read") is None
    assert again.digest("design", read, "written") is None
    assert again.digest("optimize", read, "read") is None
    stages = json.loads((job / "manifest.json").read_text())["stages"]
    stages["design"]["inputs"] = ["not", "a", "table"]
    stages["design"]["written"] = "nor this"
    (job / "manifest.json").write_text(json.dumps({"stages": stages}))
    damaged = Manifest.load(job)
    assert damaged.digest("design", read, "read") is None
    assert damaged.digest("design", wrote, "written") is None
