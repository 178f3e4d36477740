"""Installing scratchfab: scripts/setup.sh (and its libLLVM check, scripts/llvm.sh), the sdist."""

from __future__ import annotations

import shutil
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
    top = {p.name for p in ROOT.iterdir() if not p.name.startswith(".")}
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


# scripts/setup.sh, run in a copy of the checkout with stand-ins on PATH for the
# interpreters, the venv's python (pip), id, sudo and apt-get: nothing is installed.
SETUP_SH = ROOT / "scripts" / "setup.sh"
TOOLS = ("dirname", "cat", "sha256sum", "cut", "mkdir", "cp", "env", "touch")


def _stub(path: Path, body: str) -> Path:
    path.write_text("#!/bin/bash\n" + body, encoding="utf-8")
    path.chmod(0o755)
    return path


class Sandbox:
    """A checkout with setup.sh, a PATH of stand-ins, and a log of what they were asked."""

    def __init__(self, tmp_path: Path, uid: int = 0, llvm: bool = True):
        self.tmp, self.repo, self.bin = tmp_path, tmp_path / "repo", tmp_path / "bin"
        self.log = tmp_path / "log"
        self.lib = tmp_path / "libLLVM-19.so"  # appears when apt-get installs libllvm19
        (self.repo / "scripts").mkdir(parents=True)
        (self.repo / "scratchfab").mkdir()
        self.bin.mkdir()
        (self.repo / "scripts" / "setup.sh").write_text(SETUP_SH.read_text())
        (self.repo / "scripts" / "llvm.sh").write_text(f'have_llvm() {{ [ -e "{self.lib}" ]; }}\n')
        (self.repo / "pyproject.toml").write_text((ROOT / "pyproject.toml").read_text())
        (self.repo / "scratchfab" / "__init__.py").write_text('__version__ = "0"\n')
        if llvm:
            self.lib.write_bytes(b"")
        self.log.write_text("")
        for tool in TOOLS:
            found = shutil.which(tool)
            assert found, tool
            (self.bin / tool).symlink_to(found)
        _stub(self.bin / "id", f"echo {uid}\n")

    def venv_python(self, path: Path, ok: bool) -> Path:
        """A venv's python: logs its calls; ``-c`` (setup's health check) succeeds if ``ok``."""
        path.parent.mkdir(parents=True, exist_ok=True)
        return _stub(
            path, f'echo "venv-python $*" >>"{self.log}"\n[ "$1" != -c ] || {str(ok).lower()}\n'
        )

    def python(self, name: str, version: str | None) -> Path:
        """An interpreter on PATH reporting ``version`` (None: fails like a pyenv shim)."""
        if version is None:
            return _stub(self.bin / name, 'echo "pyenv: $0: command not found" >&2; exit 127\n')
        major, minor = map(int, version.split("."))
        template = self.venv_python(self.tmp / "templates" / name, (major, minor) >= (3, 11))
        return _stub(
            self.bin / name,
            f'if [ "$1" = -c ]; then echo {version}; exit 0; fi\n'
            f'echo "{name} $*" >>"{self.log}"\n'
            'd="${@: -1}"; mkdir -p "$d/bin"\n'
            f'cp "{template}" "$d/bin/python"\n',
        )

    def run(self, **env: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [shutil.which("bash") or "bash", str(self.repo / "scripts" / "setup.sh")],
            env={"PATH": str(self.bin), **env},
            capture_output=True,
            text=True,
            check=False,
        )

    def calls(self) -> list[str]:
        return self.log.read_text().splitlines()


PIP = ["venv-python -m pip install -q --upgrade pip", "venv-python -m pip install -q -e .[dev]"]


def test_setup_picks_the_newest_python_that_runs_and_is_3_11_or_newer(tmp_path):
    box = Sandbox(tmp_path)
    box.python("python3.13", None)  # a pyenv shim of a version that is not selected
    box.python("python3.11", "3.11")
    box.python("python3", "3.10")
    run = box.run()
    assert run.returncode == 0, run.stderr
    assert box.calls() == ["python3.11 -m venv .venv", *PIP]
    # The second run finds the stamp and asks nothing, not even the venv's python.
    again = box.run()
    assert again.returncode == 0 and again.stdout == again.stderr == ""
    assert box.calls() == ["python3.11 -m venv .venv", *PIP]


def test_setup_uses_PYTHON_when_set(tmp_path):
    box = Sandbox(tmp_path)
    box.python("python3.13", "3.13")
    chosen = box.python("py312", "3.12")
    run = box.run(PYTHON=str(chosen))
    assert run.returncode == 0, run.stderr
    assert box.calls() == ["py312 -m venv .venv", *PIP]


@pytest.mark.parametrize(
    ("pythons", "env", "found"),
    [
        ({"python3": "3.10", "python3.12": None}, {}, "python3.12 (does not run), python3 3.10"),
        ({"python3.11": "3.11", "old": "3.9"}, {"PYTHON": "old"}, "old 3.9"),
        ({}, {}, "none of python3.13 python3.12 python3.11 python3"),
    ],
)
def test_setup_without_python_3_11_says_what_it_found(tmp_path, pythons, env, found):
    box = Sandbox(tmp_path)
    for name, version in pythons.items():
        box.python(name, version)
    run = box.run(**env)
    assert run.returncode == 1
    assert run.stderr == (
        f"setup: scratchfab needs Python >= 3.11; found {found}; "
        "set PYTHON to a Python 3.11 or newer\n"
    )
    assert not (box.repo / ".venv").exists() and box.calls() == []


def test_setup_reuses_a_good_venv_and_recreates_a_bad_one(tmp_path):
    box = Sandbox(tmp_path)
    box.python("python3.12", "3.12")
    box.venv_python(box.repo / ".venv" / "bin" / "python", ok=True)
    run = box.run()
    assert run.returncode == 0, run.stderr
    assert box.calls() == [
        "venv-python -c import sys, pip; assert sys.version_info >= (3, 11)",
        *PIP,
    ]

    # A venv of Python 3.10, or one without pip, that never took the install (no stamp).
    box.log.write_text("")
    (box.repo / ".venv" / ".scratchfab-installed").unlink()
    box.venv_python(box.repo / ".venv" / "bin" / "python", ok=False)
    run = box.run()
    assert run.returncode == 0, run.stderr
    assert "setup: .venv has no working Python >= 3.11 with pip; recreating it" in run.stdout
    assert box.calls() == [
        "venv-python -c import sys, pip; assert sys.version_info >= (3, 11)",
        "python3.12 -m venv --clear .venv",
        *PIP,
    ]


LLVM_HINT = (
    "install libllvm19 (Debian/Ubuntu: sudo apt-get install libllvm19) or any shared libLLVM "
    ">= 16, set DRJIT_LIBLLVM_PATH to it if it is not in /usr/lib, and run this again\n"
)


def _apt(box: Sandbox, rc: int = 0) -> None:
    _stub(
        box.bin / "apt-get",
        f'echo "apt-get $*" >>"{box.log}"\n'
        f'[ "$1" != install ] || {{ [ {rc} -ne 0 ] || touch "{box.lib}"; exit {rc}; }}\n',
    )


def test_setup_skips_the_libllvm_step_for_an_existing_DRJIT_LIBLLVM_PATH(tmp_path):
    box = Sandbox(tmp_path, uid=1000, llvm=False)
    _apt(box)
    box.python("python3", "3.11")
    own = tmp_path / "own-libLLVM.so"
    own.write_bytes(b"")
    run = box.run(DRJIT_LIBLLVM_PATH=str(own))
    assert run.returncode == 0, run.stderr
    assert not any(call.startswith("apt-get") for call in box.calls())
    # A path that names nothing is not taken: setup goes on to look for libLLVM itself.
    run = Sandbox(tmp_path / "again", uid=1000, llvm=False).run(
        DRJIT_LIBLLVM_PATH=str(tmp_path / "missing.so")
    )
    assert run.returncode == 1 and run.stderr.endswith(LLVM_HINT)


@pytest.mark.parametrize("sudo", [None, "exit 1\n"])
def test_setup_without_root_or_sudo_prints_the_manual_libllvm_fix(tmp_path, sudo):
    box = Sandbox(tmp_path, uid=1000, llvm=False)
    _apt(box)
    if sudo is not None:  # sudo that wants a password: `sudo -n true` fails
        _stub(box.bin / "sudo", f'echo "sudo $*" >>"{box.log}"\n{sudo}')
    run = box.run()
    assert run.returncode == 1
    assert run.stderr == (
        "setup: installing libllvm19 needs root and sudo cannot run without a password; "
        + LLVM_HINT
    )
    assert box.calls() == ([] if sudo is None else ["sudo -n true"])
    assert not (box.repo / ".venv").exists()


@pytest.mark.parametrize(("uid", "rc"), [(0, 0), (0, 100), (1000, 0), (1000, 100)])
def test_setup_installs_libllvm19_with_apt_or_prints_the_fix(tmp_path, uid, rc):
    box = Sandbox(tmp_path, uid=uid, llvm=False)
    _apt(box, rc)
    _stub(box.bin / "sudo", f'echo "sudo $*" >>"{box.log}"\n[ "$1" = -n ] && shift && "$@"\n')
    box.python("python3", "3.11")
    run = box.run()
    apt = ["apt-get update -qq", "apt-get install -y -qq libllvm19"]
    if uid != 0:  # each through `sudo -n` (the install through env, which sudo would reset)
        install = "sudo -n env DEBIAN_FRONTEND=noninteractive " + apt[1]
        apt = ["sudo -n true", "sudo -n " + apt[0], apt[0], install, apt[1]]
    if rc == 0:
        assert run.returncode == 0, run.stderr
        assert box.lib.exists() and "python3 -m venv .venv" in box.calls()
    else:
        assert run.returncode == 1
        assert run.stderr == "setup: apt-get could not install libllvm19; " + LLVM_HINT
        assert not (box.repo / ".venv").exists()
    assert [c for c in box.calls() if not c.startswith(("python3", "venv-python"))] == apt


COMPILED = ROOT / "scratchfab" / "compiled.py"
# a module compiled through compiled.py, beside it
USER = """
from compiled import njit


@njit()
def twice(x):
    return 2 * x
"""


def _homeless_install(tmp_path):
    """A copy of scratchfab/compiled.py and a module compiled through it, in tmp_path/mod,
    where numba can cache neither beside the module nor in ~ (files where it wants
    folders). Returns the temporary folder the process gets and its environment."""
    import os

    (tmp_path / "mod").mkdir()
    (tmp_path / "mod" / "compiled.py").write_text(COMPILED.read_text())
    (tmp_path / "mod" / "user.py").write_text(USER)
    (tmp_path / "mod" / "__pycache__").write_bytes(b"")
    (tmp_path / "home").write_bytes(b"")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "XDG_"))}
    env.update(HOME=str(tmp_path / "home"), TMPDIR=str(tmp), PYTHONDONTWRITEBYTECODE="1")
    return tmp, env


def _import_compiled(tmp_path, env, uid):
    """Import the copy in a fresh process that takes ``uid`` for its own; returns its
    NUMBA_CACHE, NUMBA_CACHE_DIR, twice(21) and twice's cache path, as printed."""
    import sys

    code = (
        "import os, sys; uid = int(sys.argv[2]); os.getuid = lambda: uid;"
        "sys.path.insert(0, sys.argv[1]); import compiled, user;"
        "print(compiled.NUMBA_CACHE, os.environ.get('NUMBA_CACHE_DIR'));"
        "print(user.twice(21), user.twice.stats.cache_path)"
    )
    run = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "mod"), str(uid)],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    (cached, folder), (result, path) = (line.split() for line in run.stdout.splitlines())
    return cached, folder, result, path


@pytest.mark.parametrize("tmp_folder", ["private", "shared"])
def test_numba_compiles_where_it_cannot_cache_in_its_own_places(tmp_path, tmp_folder):
    """A read-only install run by a user without a home: no __pycache__, no ~/.cache.

    scratchfab.compiled falls back to a private temporary cache folder (or to none where
    that folder is someone else's), so importing and compiling through it still works.
    """
    import os

    tmp, env = _homeless_install(tmp_path)
    cache = tmp / f"scratchfab-numba-{os.getuid()}"
    if tmp_folder == "shared":  # made by someone else, or open to all: not to be trusted
        cache.mkdir(mode=0o777)
        cache.chmod(0o777)
    cached, folder, result, path = _import_compiled(tmp_path, env, os.getuid())
    assert result == "42"
    if tmp_folder == "private":
        assert (cached, folder) == ("True", str(cache))
        assert (cache.stat().st_mode & 0o777) == 0o700
        assert Path(path).is_relative_to(cache)
        assert any(cache.rglob("user.twice-*.nbi"))
    else:
        assert (cached, folder, path) == ("False", "None", "None")
        assert not any(cache.iterdir())


def test_every_compiled_scan_takes_the_cache_choice_of_scratchfab_compiled():
    """The tour search, the renderer's pair scans and the merge candidates all compile
    through scratchfab.compiled: each is cached exactly when it caches."""
    from scratchfab import compiled
    from scratchfab.optimize.loss import _compiled_scan
    from scratchfab.render.pairs import _compiled
    from scratchfab.toolpath import local_search

    scans = {
        "local_search.cut_region": local_search.cut_region,
        "local_search.improve": local_search.improve,
        "loss._scan_pairs": _compiled_scan(),
        "pairs._count_pairs": _compiled()[0],
        "pairs._write_pairs": _compiled()[1],
    }
    for name, scan in scans.items():
        assert (scan.stats.cache_path is not None) == compiled.NUMBA_CACHE, name


@pytest.mark.parametrize("case", ["someone_elses", "a_link", "the_users_own"])
def test_numba_keeps_out_of_cache_folders_it_cannot_trust(tmp_path, case):
    """Where numba cannot cache in its own places, scratchfab.compiled does not take:

    - a private-looking <tmp>/scratchfab-numba-<uid> (0700) owned by another user,
    - a link put there (even to a private folder of this user's),
    - its own folder in place of a NUMBA_CACHE_DIR the user set (unusable here):
    it compiles uncached, and nothing is written there.
    """
    import os

    tmp, env = _homeless_install(tmp_path)
    # the process below takes uid + 1 for its own (files stay the real uid's): the folder
    # this user makes here is then another user's to it
    uid = os.getuid() + (case == "someone_elses")
    cache = tmp / f"scratchfab-numba-{uid}"
    target = tmp_path / "private"
    if case == "someone_elses":
        cache.mkdir(mode=0o700)
        target = cache
    elif case == "a_link":
        target.mkdir(mode=0o700)
        cache.symlink_to(target, target_is_directory=True)
    else:
        env["NUMBA_CACHE_DIR"] = str(tmp_path / "home" / "numba")  # under a file
    cached, folder, result, path = _import_compiled(tmp_path, env, uid)
    assert (cached, result, path) == ("False", "42", "None")
    assert folder == env.get("NUMBA_CACHE_DIR", "None")
    if case == "the_users_own":
        assert not cache.exists()
    else:
        assert not any(target.iterdir())


def test_a_function_numba_cannot_cache_is_compiled_uncached():
    """A function without a cache locator (here: no source file) must not fail its import."""
    from scratchfab.compiled import njit

    namespace: dict = {}
    exec("def twice(x):\n    return 2 * x\n", namespace)  # no file: numba cannot cache it
    assert njit(namespace["twice"])(21) == 42
    assert njit()(namespace["twice"])(4) == 8
    assert njit(namespace["twice"], nogil=True)(1.5) == 3.0
