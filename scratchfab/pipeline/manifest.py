"""The job manifest: which stage ran on which inputs, so unchanged stages are skipped.

``JOB/manifest.json`` records, per stage, a fingerprint of its inputs (file contents,
plus modification times for the user's own source files such as target images) and
options, and the outputs it wrote. A stage is up to date when its fingerprint matches
and its outputs exist; the runner (:mod:`scratchfab.pipeline.runner`) decides what else
reruns.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from scratchfab.fileio import decode_json, file_sha256, write_text

MANIFEST_NAME = "manifest.json"


def file_digest(path: Path, with_mtime: bool = False) -> str:
    """SHA-256 of a file's bytes (and its mtime when ``with_mtime``); "missing" if absent."""
    stamp = str(path.stat().st_mtime_ns).encode() if with_mtime and path.is_file() else b""
    return file_sha256(path, stamp)


def _files_under(path: Path) -> list[Path]:
    if path.is_dir():
        return sorted(p for p in path.rglob("*") if p.is_file() and not p.name.startswith("."))
    return [path]


def _key(path: Path, root: Path | None) -> str:
    """A path as recorded: relative to the job folder when inside it, else absolute."""
    if root is not None:
        try:
            return path.resolve().relative_to(root.resolve()).as_posix()
        except ValueError:
            pass
    return str(path.resolve())


def fingerprint(
    files: Iterable[Path],
    sources: Iterable[Path] = (),
    options: Mapping[str, Any] | None = None,
    root: Path | None = None,
) -> dict[str, Any]:
    """The inputs of a stage as a JSON-able record.

    Args:
        files: Files (or folders, taken whole) written by earlier stages: content only.
        sources: The user's own files (targets, profiles): content and modification time,
            so that touching one counts as a change.
        options: The stage's options.
        root: The job folder: files inside it are recorded relative to it, so a job that
            is moved or named by another path is still recognised.
    """
    record: dict[str, str] = {}
    for item in files:
        for f in _files_under(Path(item)):
            record[_key(f, root)] = file_digest(f)
    for item in sources:
        for f in _files_under(Path(item)):
            record[_key(f, root)] = file_digest(f, with_mtime=True)
    return {"files": record, "options": json.loads(json.dumps(options or {}, default=str))}


def _entry_ok(entry: Any) -> bool:
    """Whether a stage's manifest entry has the shape :class:`Manifest` writes."""
    if not isinstance(entry, dict) or not isinstance(entry.get("status", ""), str):
        return False
    outputs = entry.get("outputs", [])
    return isinstance(outputs, list) and all(isinstance(out, str) for out in outputs)


@dataclass
class Manifest:
    """The manifest of one job folder."""

    job: Path
    stages: dict[str, dict[str, Any]] = field(default_factory=dict)

    @classmethod
    def load(cls, job: Path) -> Manifest:
        """Read ``JOB/manifest.json`` (an empty manifest when absent or unreadable)."""
        path = job / MANIFEST_NAME
        try:
            data = decode_json(path.read_text(encoding="utf-8"))
            stages = data.get("stages", {}) if isinstance(data, dict) else {}
        except (OSError, ValueError):
            stages = {}
        if not isinstance(stages, dict):
            stages = {}
        # An entry not as :meth:`record` and its siblings write it is dropped: that stage
        # is then not done and reruns, as when the whole file is unreadable.
        return cls(job, {k: v for k, v in stages.items() if _entry_ok(v)})

    def save(self) -> None:
        """Write the manifest atomically."""
        write_text(
            self.job / MANIFEST_NAME,
            json.dumps({"stages": self.stages}, indent=2, sort_keys=True) + "\n",
        )

    def is_current(self, stage: str, inputs: Mapping[str, Any]) -> bool:
        """True when ``stage`` last succeeded on exactly ``inputs`` and its outputs exist."""
        entry = self.stages.get(stage)
        if not entry or entry.get("status") != "done" or entry.get("inputs") != inputs:
            return False
        try:
            return all((self.job / out).exists() for out in entry.get("outputs", []))
        except OSError:  # a name too long for the file system: not an output of ours
            return False

    def record(
        self, stage: str, inputs: Mapping[str, Any], outputs: Iterable[str], seconds: float
    ) -> None:
        """Mark ``stage`` done on ``inputs`` with its outputs (relative to the job)."""
        self.stages[stage] = {
            "status": "done",
            "inputs": dict(inputs),
            "outputs": sorted(outputs),
            "seconds": round(seconds, 3),
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
        }
        self.save()

    def start(self, stage: str, inputs: Mapping[str, Any]) -> None:
        """Mark ``stage`` as running on ``inputs``, so a kill leaves it not done."""
        self.stages[stage] = {"status": "running", "inputs": dict(inputs)}
        self.save()

    def interrupt(self, stage: str, inputs: Mapping[str, Any], reason: str) -> None:
        """Mark ``stage`` as stopped by the person on ``inputs``, its work so far saved."""
        self.stages[stage] = {"status": "interrupted", "inputs": dict(inputs), "reason": reason}
        self.save()

    def unfinished(self, stage: str, inputs: Mapping[str, Any]) -> bool:
        """True when ``stage`` last started on exactly ``inputs`` and did not finish."""
        entry = self.stages.get(stage) or {}
        return entry.get("status") in ("running", "interrupted") and entry.get("inputs") == inputs

    def invalidate(self, stage: str, reason: str) -> None:
        """Mark ``stage`` as not done (it failed or its inputs changed)."""
        self.stages[stage] = {"status": "failed", "reason": reason}
        self.save()
