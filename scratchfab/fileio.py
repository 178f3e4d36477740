"""Atomic file writes: a reader never sees a half-written file, a failure never loses the old one."""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import shutil
import tempfile
import tokenize
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from scratchfab.errors import ConfigError, ScratchfabError


def decode_json(text: str) -> Any:
    """``json.loads`` whose every failure on bad text is a :class:`json.JSONDecodeError`.

    Python refuses integers of over 4300 digits (a plain ValueError) and arrays nested
    too deeply (RecursionError); in a file of ours either is damage like any other.
    """
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        raise
    except (ValueError, RecursionError) as exc:
        raise json.JSONDecodeError(str(exc).split(";")[0], text, 0) from None


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# Read once at import: reading it sets the process-wide umask to 0 for a moment, which
# would race with another thread creating files (the optimizer writes from a thread).
_UMASK = _umask()


_NUL = "a path cannot hold a NUL byte, \\0"


def _reason(exc: OSError | ValueError) -> str:
    """Why a path could not be used, in words: the system's, or the NUL byte's."""
    if isinstance(exc, OSError):
        return str(exc.strerror or exc)
    return _NUL  # Python's "embedded null byte"


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "w", **kwargs: Any) -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path``; rename it over ``path`` only on success.

    Args:
        path: The final file.
        mode: ``"w"`` (text) or ``"wb"`` (binary).
        **kwargs: Passed to :func:`open` (e.g. ``newline``, ``encoding``).

    Raises:
        ScratchfabError: The folder cannot be made or the file cannot be written (one
            line naming the file); the old file is kept.
    """
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    except (OSError, ValueError) as exc:
        raise ScratchfabError(f"{target}: cannot write ({_reason(exc)})") from None
    os.close(fd)
    os.chmod(tmp_name, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the usual permissions
    try:
        if "b" not in mode:
            kwargs.setdefault("encoding", "utf-8")
        with open(tmp_name, mode, **kwargs) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, target)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        if isinstance(exc, OSError):  # a full disk, a quota, a vanished folder
            raise ScratchfabError(f"{target}: cannot write ({exc.strerror or exc})") from None
        raise


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Fill a temporary folder beside ``path``; put it in place of ``path`` only on success.

    The old folder is renamed aside first and removed after, or renamed back if the
    swap fails, so a reader finds the old folder or the new one, never a mix.

    Raises:
        ScratchfabError: The parent folder cannot be made or written, or the swap fails.
    """
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    except (OSError, ValueError) as exc:
        raise ScratchfabError(f"{target}: cannot write ({_reason(exc)})") from None
    os.chmod(tmp, 0o777 & ~_UMASK)  # mkdtemp makes 0700; give the usual permissions
    try:
        yield tmp
        old = None
        if target.exists():
            old = target.with_name(f".{target.name}.old.{os.getpid()}")
            if old.exists():
                shutil.rmtree(old)
            os.replace(target, old)
        try:
            os.replace(tmp, target)
        except BaseException:
            if old is not None:
                with contextlib.suppress(OSError):
                    os.replace(old, target)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except OSError as exc:
        raise ScratchfabError(f"{target}: cannot write ({exc.strerror or exc})") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` atomically (LF line ends)."""
    with atomic_open(path, "w", newline="\n") as handle:
        handle.write(text)


def file_sha256(path: str | os.PathLike[str], extra: bytes = b"") -> str:
    """SHA-256 of a file's bytes followed by ``extra``, hex; "missing" when there is no file."""
    file = Path(path)
    if not file.is_file():
        return "missing"
    digest = hashlib.sha256()
    with file.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    digest.update(extra)
    return digest.hexdigest()


def _readable(path: str | os.PathLike[str]) -> None:
    """Refuse a path to read that no system call takes (a NUL byte), naming it.

    Python's open raises ValueError ('embedded null byte') for it, which a reader's
    handling of its contents' ValueErrors would take for damage.
    """
    if "\0" in os.fspath(path):
        raise ConfigError(f"{path}: cannot read ({_NUL})")


def read_input(path: Path, expected: str, missing: str = "file not found") -> bytes:
    """The bytes of a user's input file, or a one-line ConfigError naming it.

    Args:
        path: The file.
        expected: What it should be, for the folder case ("a TOML file").
        missing: The message when it does not exist.
    """
    _readable(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{path}: {missing}") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, expected {expected}") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None


def json_safe(value: Any) -> Any:
    """``value`` with NaN and infinities as None and numpy scalars as Python numbers.

    JSON has no NaN; strict readers reject Python's ``NaN`` extension.
    """
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


def write_json(path: str | os.PathLike[str], data: Any) -> None:
    """Write ``data`` as strict JSON (indented, NaN as null) atomically."""
    write_text(path, json.dumps(json_safe(data), indent=2, allow_nan=False, default=str) + "\n")


def write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_open(path, "wb") as handle:
        handle.write(data)


def save_npy(path: str | os.PathLike[str], array: np.ndarray) -> None:
    """Save a numpy array to ``path`` atomically (``.npy`` format)."""
    with atomic_open(path, "wb") as handle:
        np.save(handle, array)


def save_png(path: str | os.PathLike[str], image: Any) -> None:
    """Save a Pillow image as PNG atomically."""
    with atomic_open(path, "wb") as handle:
        image.save(handle, format="PNG")


def try_lock(handle: IO[Any]) -> bool:
    """Lock an open file for this process alone, without waiting; False if another holds it.

    An advisory ``flock``: it goes with the process, so a killed one leaves none behind.
    POSIX only; elsewhere (Windows) nothing is locked and True is returned, so the
    commands still run there, without the guard against a second run or stream.

    Raises:
        ScratchfabError: The file system cannot lock (some network or FUSE mounts).
    """
    if os.name != "posix":
        return True
    import fcntl

    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except (BlockingIOError, PermissionError):
        return False
    except OSError as exc:
        raise ScratchfabError(
            f"{handle.name}: cannot lock ({exc.strerror or exc}); use a job folder on a local disk"
        ) from None
    return True


def _check_npy_header(stream: IO[bytes], available: int) -> None:
    """Refuse an ``.npy`` stream whose header promises more data than the ``available`` bytes.

    numpy allocates the array the header describes before it reads, so a damaged shape
    (a flipped digit) would ask for terabytes instead of failing on the short read.

    Raises:
        ValueError: Not an ``.npy`` header, or a shape larger than what follows it.
    """
    begin = stream.tell()
    version = np.lib.format.read_magic(stream)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(stream)
    elif version == (2, 0):
        shape, _, dtype = np.lib.format.read_array_header_2_0(stream)
    else:  # 3.0 only holds field names outside Latin-1, which no array of ours has
        raise ValueError(f"format version {version[0]}.{version[1]}, expected 1.0 or 2.0")
    need = math.prod(shape) * dtype.itemsize
    left = available - (stream.tell() - begin)
    if need > left:
        raise ValueError(
            f"Failed to read its data: the header says shape {shape} of {dtype} ({need} "
            f"bytes) but {left} bytes follow"
        )


def load_numpy(path: str | os.PathLike[str]) -> Any:
    """A ``.npy`` file's array, or a ``.npz`` file's arrays (name -> array); never a pickle.

    The suffix says which the file must be. numpy's own error for a file that is neither
    advises loading it with pickles enabled, which no user should do with our files. Each
    array's header is checked against the bytes that follow before numpy allocates it.

    Raises:
        ConfigError: One line naming the file: missing, unreadable, not a NumPy file of
            that kind, or a damaged one.
    """
    file = Path(path)
    _readable(file)
    kind = ".npz" if file.suffix.lower() == ".npz" else ".npy"
    magic = b"PK" if kind == ".npz" else b"\x93NUMPY"
    try:
        with file.open("rb") as handle:
            head = handle.read(8)
            if not head.startswith(magic):
                seen = f"it begins with {head!r}" if head else "it is empty"
                raise ConfigError(f"{file}: not a NumPy {kind} file ({seen})")
            handle.seek(0)
            if kind == ".npy":
                _check_npy_header(handle, os.fstat(handle.fileno()).st_size)
                handle.seek(0)
                return np.load(handle, allow_pickle=False)
            with zipfile.ZipFile(handle) as archive:
                for info in archive.infolist():
                    if not info.filename.endswith(".npy"):
                        raise ValueError(f"member {info.filename!r} is not an .npy array")
                    with archive.open(info) as member:
                        try:
                            _check_npy_header(member, info.file_size)
                        except ValueError as exc:
                            raise ValueError(f"member {info.filename!r}: {exc}") from None
            handle.seek(0)
            with np.load(handle, allow_pickle=False) as arrays:
                return {name: arrays[name] for name in arrays.files}
    except FileNotFoundError:
        raise ConfigError(f"{file}: file not found") from None
    except OSError as exc:
        raise ConfigError(f"{file}: cannot read ({exc.strerror or exc})") from None
    except MemoryError:
        raise ConfigError(f"{file}: NumPy {kind} file too large to load") from None
    except (
        ValueError,
        EOFError,
        SyntaxError,  # the header's Python literal
        tokenize.TokenError,
        RecursionError,
        NotImplementedError,  # a zip feature Python lacks
        zipfile.BadZipFile,
        zlib.error,
    ) as exc:
        why = (
            "a damaged header"
            if isinstance(exc, SyntaxError | tokenize.TokenError | RecursionError)
            else " ".join(str(exc).split())[:200]
        )
        raise ConfigError(f"{file}: unreadable NumPy {kind} file ({why})") from None
