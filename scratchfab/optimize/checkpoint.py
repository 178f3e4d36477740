"""Atomic checkpoints of an optimization run (``JOB/optimize/checkpoint.npz``).

A checkpoint holds the raw parameters and Adam moments of every variable, the iteration,
the endpoints the current pixel pairs were found around, the state of the run's random
generator, the log rows so far, the elapsed time and a fingerprint of the settings that
shape the trajectory. It is written through :func:`scratchfab.fileio.atomic_open`, so a
kill at any moment leaves either the previous checkpoint or the new one, never a torn file.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from scratchfab.errors import ConfigError
from scratchfab.fileio import atomic_open, decode_json, load_numpy

FORMAT = 1


def save_checkpoint(
    path: Path,
    state: dict[str, np.ndarray],
    meta: dict[str, Any],
    log_rows: np.ndarray,
) -> None:
    """Write a checkpoint atomically.

    Args:
        path: The ``.npz`` file.
        state: :meth:`LayoutOptimizer.state`.
        meta: JSON-ready metadata (fingerprint, RNG state, elapsed time, column names).
        log_rows: (iterations, columns) float64 log so far.
    """
    payload = dict(state)
    payload["log_rows"] = np.asarray(log_rows, dtype=np.float64)
    payload["meta"] = np.frombuffer(
        json.dumps({"format": FORMAT, **meta}, sort_keys=True).encode("utf-8"), dtype=np.uint8
    )
    buf = io.BytesIO()
    np.savez(buf, **payload)  # type: ignore[arg-type]
    with atomic_open(path, "wb") as handle:
        handle.write(buf.getvalue())


def load_checkpoint(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any], np.ndarray]:
    """Read a checkpoint: (state, meta, log_rows).

    Raises:
        ConfigError: When the file is missing, unreadable or not a checkpoint, naming it
            (a pipeline then optimizes from the start).
    """
    if not path.exists():
        raise ConfigError(f"{path}: no checkpoint to resume from (run without --resume)")
    arrays: dict[str, np.ndarray] = load_numpy(path)
    try:
        meta = decode_json(arrays.pop("meta").tobytes().decode("utf-8"))
        log_rows = arrays.pop("log_rows")
    except (KeyError, ValueError) as exc:
        raise ConfigError(f"{path}: not a scratchfab checkpoint ({exc})") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("fingerprint", {}), dict):
        raise ConfigError(
            f"{path}: not a scratchfab checkpoint (its meta and meta.fingerprint must be "
            "JSON objects)"
        )
    if meta.get("format") != FORMAT:
        raise ConfigError(f"{path}: checkpoint format {meta.get('format')} is not {FORMAT}")
    return arrays, meta, log_rows


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint as read (:func:`read_checkpoint`), so that one reading serves a resume.

    Attributes:
        path: The ``.npz`` file.
        state: The optimizer's state (:meth:`LayoutOptimizer.state`).
        meta: Its metadata (fingerprint, RNG state, elapsed time, column names).
        log_rows: (iterations, columns) float64 log so far.
    """

    path: Path
    state: dict[str, np.ndarray]
    meta: dict[str, Any]
    log_rows: np.ndarray

    @property
    def done(self) -> int | None:
        """The steps it had done (None: its ``iteration`` is no integer scalar)."""
        step = self.state.get("iteration")
        if not isinstance(step, np.ndarray) or step.shape != () or step.dtype.kind not in "iu":
            return None
        return int(step)


def read_checkpoint(path: Path) -> Checkpoint:
    """Read a checkpoint (:func:`load_checkpoint`) as a :class:`Checkpoint`."""
    return Checkpoint(path, *load_checkpoint(path))
