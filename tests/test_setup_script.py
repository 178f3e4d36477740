"""scripts/llvm.sh: setup's check for a shared libLLVM 16+ (Dr.Jit's CPU backend)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

LLVM_SH = Path(__file__).resolve().parents[1] / "scripts" / "llvm.sh"


def have_llvm(*dirs: Path) -> bool:
    run = subprocess.run(
        ["bash", "-c", '. "$0"; have_llvm "$@"', str(LLVM_SH), *map(str, dirs)], check=False
    )
    assert run.returncode in (0, 1)
    return run.returncode == 0


@pytest.mark.parametrize(
    ("files", "found"),
    [
        (["libLLVM-19.so"], True),
        (["libLLVM.so.19.1"], True),
        (["libLLVM-16.so.1"], True),
        (["libLLVM-20.so.1"], True),
        (["libLLVM.so.21.1"], True),
        (["libLLVM-14.so", "libLLVM-15.so.1", "libLLVM.so.15"], False),
        # Debian bookworm: old and new side by side (an older check missed 19 here and
        # ran apt-get on every `make`, failing without root).
        (["libLLVM-14.so.1", "libLLVM-15.so", "libLLVM-19.so", "libLLVM.so.19.1"], True),
        ([], False),
    ],
)
def test_have_llvm_finds_a_shared_libllvm_16_or_newer(tmp_path, files, found):
    for name in files:
        (tmp_path / name).write_bytes(b"")
    assert have_llvm(tmp_path) is found


def test_have_llvm_looks_in_every_folder_given(tmp_path):
    old, new = tmp_path / "old", tmp_path / "new"
    old.mkdir()
    new.mkdir()
    (old / "libLLVM-14.so").write_bytes(b"")
    assert not have_llvm(old)
    (new / "libLLVM-19.so").write_bytes(b"")
    assert have_llvm(old, new)


def test_python_m_scratchfab_runs_the_cli_with_the_single_sourced_version():
    import sys
    from importlib.metadata import version

    import scratchfab

    run = subprocess.run(
        [sys.executable, "-m", "scratchfab", "--version"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == f"scratchfab, version {scratchfab.__version__}"
    # pyproject's version is dynamic: the installed metadata reads scratchfab.__version__.
    assert version("scratchfab") == scratchfab.__version__
