"""scripts/llvm.sh: setup's check for a shared libLLVM 16+ (Dr.Jit's CPU backend)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LLVM_SH = ROOT / "scripts" / "llvm.sh"


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


def _manifest() -> tuple[set[str], set[str]]:
    """MANIFEST.in's grafted folders and included files, plus what setuptools adds itself."""
    grafts, files = {"scratchfab"}, {"pyproject.toml", "README.md", "LICENSE", "MANIFEST.in"}
    for line in (ROOT / "MANIFEST.in").read_text(encoding="utf-8").splitlines():
        words = line.split()
        if words and words[0] == "graft":
            grafts.update(words[1:])
        elif words and words[0] == "include":
            files.update(words[1:])
    return grafts, files


def test_manifest_grafts_and_includes_name_what_exists():
    grafts, files = _manifest()
    assert "tests" in grafts
    for name in grafts:
        assert (ROOT / name).is_dir(), name
    for name in files:
        assert (ROOT / name).is_file(), name


def test_the_sdist_carries_every_local_module_and_repo_path_the_tests_use():
    """Imports of tests' own helpers and literals like ROOT / "pipelines" name carried files."""
    import ast

    grafts, files = _manifest()
    carried = grafts | files
    local = {p.stem: p for p in ROOT.glob("tests/*.py")}
    top = {p.name for p in ROOT.iterdir()}
    needed: dict[str, str] = {}
    for test in sorted(ROOT.glob("tests/*.py")):
        for node in ast.walk(ast.parse(test.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import | ast.ImportFrom):
                modules = [a.name for a in node.names] if isinstance(node, ast.Import) else []
                if isinstance(node, ast.ImportFrom) and node.module and not node.level:
                    modules = [node.module]
                for module in modules:
                    head = module.split(".")[0]
                    if head in local:
                        needed[local[head].relative_to(ROOT).parts[0]] = test.name
                    elif head in top:
                        needed[head] = test.name
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                head = node.value.split("/")[0]
                if head in top:
                    needed[head] = test.name
    assert {"tests", "pipelines", "machine_profiles", "docs"} <= set(needed)
    missing = {name: user for name, user in needed.items() if name not in carried}
    assert not missing, f"used by tests, not in MANIFEST.in: {missing}"
