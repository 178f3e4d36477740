"""Files that ship inside the package (``scratchfab/data/<kind>/<name>.toml``), found by name.

A command that takes a file also takes a bundled file's name: ``--machine grbl-3018-diamond``,
``scratchfab run demo``. A value ending in ``.toml`` or holding a path separator always
names a file.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from scratchfab.errors import ConfigError

#: What one bundled file of each kind is called in messages.
_NOUN = {"machine_profiles": "profile", "pipelines": "pipeline"}


def bundled_dir(kind: str) -> Path:
    """The folder of the bundled files of one kind (``machine_profiles``, ``pipelines``)."""
    return Path(str(resources.files("scratchfab") / "data" / kind))


def bundled_names(kind: str) -> list[str]:
    """Names of the bundled files of one kind, sorted."""
    folder = bundled_dir(kind)
    if not folder.is_dir():
        return []
    return sorted(p.stem for p in folder.glob("*.toml"))


def bundled_name(kind: str, path: str | Path) -> str | None:
    """The name of the bundled file of ``kind`` that ``path`` is, else None (another file)."""
    file = Path(path)
    try:
        shipped = file.suffix == ".toml" and file.resolve().parent == bundled_dir(kind).resolve()
    except OSError:
        return None
    return file.stem if shipped else None


def names_a_file(ref: str) -> bool:
    """Whether a value names a file (else a bundled file's name)."""
    return ref.endswith(".toml") or "/" in ref or "\\" in ref


def is_file(path: Path) -> bool:
    """``path.is_file()``, False also for a name the file system refuses (too long)."""
    try:
        return path.is_file()
    except OSError:
        return False


def find_bundled(kind: str, ref: str | Path, what: str) -> Path:
    """The file a value names: a bundled file's name first, else a path.

    Args:
        kind: The bundled folder (``machine_profiles``, ``pipelines``).
        ref: The value as given.
        what: What the value names, for the error (``machine``, ``pipeline``).

    Raises:
        ConfigError: A name that is neither bundled nor a file, listing the bundled names.
    """
    text = str(ref)
    path = Path(text)
    if names_a_file(text):
        return path
    bundled = bundled_dir(kind) / f"{text}.toml"
    if is_file(bundled):
        return bundled
    if is_file(path):
        return path
    names = ", ".join(bundled_names(kind)) or "none"
    raise ConfigError(
        f"{what} '{text}': not a bundled {_NOUN.get(kind, 'file')} (bundled: {names}) nor a file"
    )
