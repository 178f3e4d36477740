"""The job manifest: which stage ran on which inputs, so unchanged stages are skipped.

``JOB/manifest.json`` records, per stage, a fingerprint of its inputs (the contents of
the files it reads, and its options) and the outputs it wrote. A stage is up to date
when its fingerprint matches and its outputs exist; the runner
(:mod:`scratchfab.pipeline.runner`) decides what else reruns.

Nothing in a fingerprint names where a file lies on this computer: files of the job are
keyed by their path inside the job, the user's own files (target images, the machine
profile) by the role the pipeline gives them. A job, its project folder or scratchfab
itself can be moved, copied or renamed without losing a finished stage, and a file
whose bytes change is still seen.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from scratchfab.fileio import decode_json, file_sha256, write_text
from scratchfab.machine.sender_journal import timestamp

MANIFEST_NAME = "manifest.json"

FINGERPRINT_FORMAT = 2
"""Recorded in every fingerprint. Format 1 (no ``format`` key) keyed the user's files by
absolute path and mixed their modification times into the digests."""

Legacy = Callable[[Any], bool]
"""Whether a stage's inputs as recorded in format 1 describe its inputs now."""


def file_digest(path: Path, with_mtime: bool = False) -> str:
    """SHA-256 of a file's bytes (and its mtime when ``with_mtime``); "missing" if absent.

    ``with_mtime`` is how format 1 digested the user's own files; only
    :func:`matches_format_1` still asks for it.
    """
    stamp = str(path.stat().st_mtime_ns).encode() if with_mtime and path.is_file() else b""
    return file_sha256(path, stamp)


# What file browsers leave in folders of pictures (Windows Explorer, macOS Finder on
# a USB stick): no stage reads them; hidden names are listed by their dot.
_BROWSER_FILES = frozenset({"thumbs.db", "ehthumbs.db", "desktop.ini", "icon\r"})


def _read_by_a_stage(relative: Path) -> bool:
    """False for hidden names, hidden folders and file browsers' files (see ``_files_under``)."""
    if any(part.startswith(".") for part in relative.parts):
        return False
    return relative.name.lower() not in _BROWSER_FILES


def _files_under(path: Path) -> list[Path]:
    """``path``, or the files under it that a stage may read.

    Left out: hidden names and folders (scratch space such as ``atomic_open``'s
    ``.<name>.*.tmp``, a copy may drop them) and the files a file browser adds when the
    job is looked at on a USB stick (``Thumbs.db``, ``desktop.ini``), so that looking at
    a job does not rerun it.
    """
    if not path.is_dir():
        return [path]
    return sorted(
        p for p in path.rglob("*") if p.is_file() and _read_by_a_stage(p.relative_to(path))
    )


def _key(path: Path, root: Path | None) -> str:
    """A job file as recorded: relative to the job folder when inside it, else absolute."""
    if root is not None:
        for inner, outer in ((path, root), (path.resolve(), root.resolve())):
            try:
                return inner.relative_to(outer).as_posix()
            except ValueError:
                pass
    return str(path.resolve())


def _jsonable(options: Mapping[str, Any] | None) -> Any:
    return json.loads(json.dumps(options or {}, default=str))


def fingerprint(
    files: Iterable[Path],
    sources: Mapping[str, Path] | None = None,
    options: Mapping[str, Any] | None = None,
    root: Path | None = None,
) -> dict[str, Any]:
    """The inputs of a stage as a JSON-able record.

    Args:
        files: Files (or folders, taken whole) written by earlier stages, keyed by their
            path in the job folder ``root``, so a job that is moved or named by another
            path is still recognised.
        sources: The user's own files (targets, the machine profile) by their role in
            the pipeline (``target:<view>``, ``machine``): where they lie does not count,
            their bytes do.
        options: The stage's options.
        root: The job folder.
    """
    record: dict[str, str] = {}
    for item in files:
        for f in _files_under(Path(item)):
            record[_key(f, root)] = file_digest(f)
    for role, path in (sources or {}).items():
        record[role] = file_digest(Path(path))
    return {"format": FINGERPRINT_FORMAT, "files": record, "options": _jsonable(options)}


def is_format_1(inputs: Any) -> bool:
    """Whether a recorded fingerprint predates :data:`FINGERPRINT_FORMAT` 2."""
    return isinstance(inputs, dict) and "format" not in inputs


def matches_format_1(
    recorded: Any,
    files: Iterable[Path],
    sources: Mapping[str, Path],
    options: Mapping[str, Any] | None,
    root: Path,
) -> bool:
    """Whether ``recorded``, a format-1 fingerprint, describes these inputs now.

    Format 1 recorded the job's files as :func:`fingerprint` does, and the user's files
    under their absolute paths with digests of bytes and modification time. Those are
    compared by digest, whatever path they were recorded under, so a project folder
    moved with its files' times kept still matches; ``options`` are the stage's options
    as format 1 recorded them.
    """
    if not is_format_1(recorded) or not isinstance(recorded.get("files"), dict):
        return False
    old: dict[str, Any] = recorded["files"]
    now = fingerprint(files, None, None, root)["files"]
    if any(old.get(key) != digest for key, digest in now.items()):
        return False
    rest = {digest for key, digest in old.items() if key not in now}
    stamped = {file_digest(Path(p), with_mtime=True) for p in sources.values()}
    return rest == stamped and recorded.get("options") == _jsonable(options)


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

    def _same_inputs(
        self, entry: Mapping[str, Any], inputs: Mapping[str, Any], legacy: Legacy | None
    ) -> bool:
        recorded = entry.get("inputs")
        if recorded == inputs:
            return True
        return legacy is not None and is_format_1(recorded) and legacy(recorded)

    def is_current(
        self, stage: str, inputs: Mapping[str, Any], legacy: Legacy | None = None
    ) -> bool:
        """True when ``stage`` last succeeded on exactly ``inputs`` and its outputs exist.

        An entry recorded in format 1 counts when ``legacy`` says it describes the same
        inputs; it is then recorded again as ``inputs`` (the manifest is saved).
        """
        entry = self.stages.get(stage)
        if not entry or entry.get("status") != "done":
            return False
        if not self._same_inputs(entry, inputs, legacy):
            return False
        try:
            if not all((self.job / out).exists() for out in entry.get("outputs", [])):
                return False
        except OSError:  # a name too long for the file system: not an output of ours
            return False
        if entry.get("inputs") != inputs:
            entry["inputs"] = dict(inputs)
            self.save()
        return True

    def recorded_in_format_1(self, stage: str) -> bool:
        """Whether ``stage``'s entry holds a fingerprint in format 1 (an earlier scratchfab)."""
        return is_format_1((self.stages.get(stage) or {}).get("inputs"))

    def record(
        self,
        stage: str,
        inputs: Mapping[str, Any],
        outputs: Iterable[str],
        seconds: float,
        written: Iterable[Path] = (),
    ) -> None:
        """Mark ``stage`` done on ``inputs`` with its outputs (relative to the job).

        ``written``: job files whose digest as the stage wrote them is kept
        (:meth:`digest`), so that an edit by hand can be told from the stage's own.
        """
        self.stages[stage] = {
            "status": "done",
            "inputs": dict(inputs),
            "outputs": sorted(outputs),
            "seconds": round(seconds, 3),
            "finished": timestamp(),
        }
        if digests := {_key(f, self.job): file_digest(f) for f in written}:
            self.stages[stage]["written"] = digests
        self.save()

    def start(self, stage: str, inputs: Mapping[str, Any]) -> None:
        """Mark ``stage`` as running on ``inputs``, so a kill leaves it not done.

        Its ``started`` time is kept while it fails or is interrupted, so a reader can tell
        this run's output (a stream's journal session) from an earlier run's.
        """
        self.stages[stage] = {"status": "running", "inputs": dict(inputs), "started": timestamp()}
        self.save()

    def _started(self, stage: str) -> dict[str, str]:
        """``{"started": time}`` of a stage :meth:`start` marked running, else ``{}``."""
        entry = self.stages.get(stage) or {}
        started = entry.get("started") if entry.get("status") == "running" else None
        return {"started": started} if isinstance(started, str) else {}

    def interrupt(self, stage: str, inputs: Mapping[str, Any], reason: str) -> None:
        """Mark ``stage`` as stopped by the person on ``inputs``, its work so far saved."""
        self.stages[stage] = {
            "status": "interrupted",
            "inputs": dict(inputs),
            "reason": reason,
            **self._started(stage),
        }
        self.save()

    def digest(self, stage: str, file: Path, table: Literal["read", "written"]) -> str | None:
        """The digest of the job's ``file`` as ``stage`` last read or wrote it.

        Args:
            stage: The stage.
            file: A job file.
            table: ``"read"``: as its inputs recorded it; ``"written"``: as :meth:`record`
                kept what it wrote.

        Returns:
            The digest; None where the entry does not hold it.
        """
        entry = self.stages.get(stage) or {}
        if table == "read":
            inputs = entry.get("inputs")
            entry = inputs if isinstance(inputs, dict) else {}
        files = entry.get("files" if table == "read" else "written")
        return files.get(_key(file, self.job)) if isinstance(files, dict) else None

    def stopped(self, stage: str) -> bool:
        """True when ``stage`` last started and did not finish, whatever its inputs."""
        return (self.stages.get(stage) or {}).get("status") in ("running", "interrupted")

    def invalidate(self, stage: str, reason: str) -> None:
        """Mark ``stage`` as not done (it failed or its inputs changed)."""
        self.stages[stage] = {"status": "failed", "reason": reason, **self._started(stage)}
        self.save()
