"""numba compilation of the package's compiled scans, with one choice of cache for all.

numba caches compiled code in NUMBA_CACHE_DIR, beside the module or in the user's cache
folder; where none is writable (a read-only install run by a user without a home)
``cache=True`` fails on import. Compiling the local search takes about 9 s, so such a
user's cache goes to ``<tmp>/scratchfab-numba-<uid>``, a folder of theirs alone; failing
that, to none. Importing this module loads numba (about 0.2-0.7 s): the renderer's pair
scan and the merge candidates import it on first use, not with the package.
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Callable
from typing import Any

import numba


def _probe() -> None:
    """Nothing: decorated to ask numba whether it can cache this package's functions."""


def _numba_can_cache() -> bool:
    try:
        numba.njit(cache=True)(_probe)
    except RuntimeError:  # "cannot cache function '_probe': no locator available"
        return False
    return True


def _numba_cache() -> bool:
    """Whether numba can cache compiled functions, in a private temporary folder if need be."""
    if _numba_can_cache():
        return True
    if os.environ.get("NUMBA_CACHE_DIR") or not hasattr(os, "getuid"):
        return False
    folder = os.path.join(tempfile.gettempdir(), f"scratchfab-numba-{os.getuid()}")
    try:
        os.makedirs(folder, mode=0o700, exist_ok=True)
        info = os.lstat(folder)
    except OSError:
        return False
    if not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid() or info.st_mode & 0o077:
        return False  # someone else's: code loaded from it could not be trusted
    os.environ["NUMBA_CACHE_DIR"] = folder
    numba.core.config.reload_config()
    return _numba_can_cache()


#: Whether numba caches the package's compiled functions.
NUMBA_CACHE = _numba_cache()


def njit(function: Callable[..., Any] | None = None, **options: Any) -> Any:
    """``numba.njit`` with the package's cache choice: ``njit(f, nogil=True)`` or ``@njit()``.

    A function numba cannot cache where this module can (its own folder not writable, or
    no source file) is compiled uncached rather than failing its module's import.
    """
    if function is None:
        return lambda f: njit(f, **options)
    try:
        return numba.njit(function, cache=NUMBA_CACHE, **options)
    except RuntimeError:  # "cannot cache function ...: no locator available"
        return numba.njit(function, cache=False, **options)
