"""Dr.Jit backend selection, with a clear error where the CPU backend cannot run.

Dr.Jit's LLVM (CPU) backend loads a shared libLLVM at run time. Versions before 16 are
refused or crash on kernels with min/max, so we look for 16 or newer ourselves, point
Dr.Jit at it through ``DRJIT_LIBLLVM_PATH``, and fail with the fix spelled out otherwise.
"""

from __future__ import annotations

import glob
import os
import re
import sys
from types import ModuleType
from typing import Any, Literal

import numpy as np

from scratchfab.errors import BackendError

BackendName = Literal["llvm", "cuda"]
MIN_LLVM_MAJOR = 16
_LIB_DIRS = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib64",
    "/usr/lib",
    "/usr/local/lib",
    "/opt/homebrew/opt/llvm/lib",
    "/usr/local/opt/llvm/lib",
    r"C:\Program Files\LLVM\bin",
)
_LIB_PATTERNS = ("libLLVM*.so*", "libLLVM*.dylib", "LLVM-C.dll")
_FIXES = {
    "linux": "install one (Debian/Ubuntu: `sudo apt-get install libllvm19`; "
    "in a checkout, `bash scripts/setup.sh` does this)",
    "darwin": "`brew install llvm`",
    "win32": "install LLVM (github.com/llvm/llvm-project/releases) and set "
    "DRJIT_LIBLLVM_PATH to its bin\\LLVM-C.dll",
}


def llvm_fix(platform: str | None = None) -> str:
    """What to do when Dr.Jit's CPU backend finds no libLLVM, for this operating system."""
    how = _FIXES.get(sys.platform if platform is None else platform, _FIXES["linux"])
    return (
        f"Dr.Jit's CPU backend needs a shared libLLVM {MIN_LLVM_MAJOR} or newer: {how}, "
        "or set DRJIT_LIBLLVM_PATH to such a library"
    )


def _llvm_major(path: str) -> int | None:
    match = re.search(r"libLLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
    return int(match.group(1)) if match else None


def find_libllvm() -> str | None:
    """The newest shared libLLVM >= 16 on this machine, else one without a version, or None.

    A macOS or Windows name without a version (Homebrew's ``libLLVM.dylib``, ``LLVM-C.dll``)
    is taken only when no named version >= 16 is found; a Linux ``libLLVM.so`` without one
    may be an old LLVM, which crashes Dr.Jit, so it is never taken.
    """
    best: tuple[int, str] | None = None
    unversioned: str | None = None
    for folder in _LIB_DIRS:
        for pattern in _LIB_PATTERNS:
            for path in sorted(glob.glob(os.path.join(folder, pattern))):
                major = _llvm_major(path)
                if major is None:
                    if path.endswith((".dylib", ".dll")):
                        unversioned = unversioned or path
                elif major >= MIN_LLVM_MAJOR and (best is None or major > best[0]):
                    best = (major, path)
    return best[1] if best else unversioned


def ensure_llvm_path() -> None:
    """Point Dr.Jit at a usable libLLVM before it is first used, or raise BackendError.

    Off Linux, where LLVM lives in fewer known places, a library not found here is left
    to Dr.Jit's own search (:func:`array_module` still fails cleanly if that finds none).
    """
    configured = os.environ.get("DRJIT_LIBLLVM_PATH")
    if configured:
        if not os.path.exists(configured):
            raise BackendError(f"DRJIT_LIBLLVM_PATH={configured} does not exist. {llvm_fix()}")
        major = _llvm_major(configured)
        if major is not None and major < MIN_LLVM_MAJOR:
            raise BackendError(f"DRJIT_LIBLLVM_PATH={configured} is LLVM {major}. {llvm_fix()}")
        return
    found = find_libllvm()
    if found is not None:
        os.environ["DRJIT_LIBLLVM_PATH"] = found
    elif sys.platform.startswith("linux"):
        raise BackendError(f"no usable libLLVM found. {llvm_fix()}")


def array_module(backend: BackendName = "llvm") -> ModuleType:
    """The Dr.Jit AD array namespace of ``backend`` (``drjit.llvm.ad`` or ``drjit.cuda.ad``).

    Raises:
        BackendError: When the backend cannot run here, with the fix, or is no backend.
    """
    if backend not in ("llvm", "cuda"):
        raise BackendError(f"unknown backend {backend!r}: expected 'llvm' (CPU) or 'cuda' (GPU)")
    if backend == "llvm":
        ensure_llvm_path()
    import drjit as dr

    jit_backend = dr.JitBackend.LLVM if backend == "llvm" else dr.JitBackend.CUDA
    if not dr.has_backend(jit_backend):
        if backend == "cuda":
            raise BackendError(
                "the CUDA backend needs an NVIDIA GPU and driver; use --backend llvm"
            )
        raise BackendError(f"Dr.Jit could not start its LLVM backend. {llvm_fix()}")
    import importlib

    return importlib.import_module(f"drjit.{backend}.ad")


def backend_available(backend: BackendName) -> bool:
    """Whether :func:`array_module` can start ``backend`` here."""
    try:
        array_module(backend)
    except BackendError:
        return False
    return True


def jit_array(T: type, values: Any, dtype: Any = np.float64) -> Any:
    """A Dr.Jit array of type ``T`` from numpy data copied to a 64-byte aligned buffer.

    Dr.Jit reads numpy memory in place and compiles the pointer's alignment into the
    kernel, so arrays from plain numpy allocations make the same kernel hash differently
    from run to run and defeat the kernel cache (a recompile of the renderer costs tens
    of seconds). Aligned copies keep the kernels identical.
    """
    src = np.ascontiguousarray(values, dtype=dtype).ravel()
    buf = np.empty(src.nbytes + 64, dtype=np.uint8)
    start = (-buf.ctypes.data) % 64
    out = buf[start : start + src.nbytes].view(src.dtype)
    out[:] = src
    return T(out)
