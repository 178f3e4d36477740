"""What importing the CLI commands loads: the heavy libraries only where a run needs them.

Each case runs in a fresh interpreter and reads ``sys.modules``; no timing is measured.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from scratchfab.machine.profile import load_profile
from scratchfab.model.design import Board
from scratchfab.model.scratches import ScratchSet
from scratchfab.toolpath import plan_toolpath

HEAVY = ("scipy", "ezdxf", "numba", "drjit", "mitsuba")


def loaded_after(code: str, *args: str) -> set[str]:
    """The HEAVY modules in ``sys.modules`` after running ``code`` in a new interpreter."""
    report = f"import json, sys; print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))"
    run = subprocess.run(
        [sys.executable, "-c", f"{code}\n{report}", *args],
        check=True,
        capture_output=True,
        text=True,
    )
    return set(json.loads(run.stdout.splitlines()[-1]))


@pytest.mark.parametrize(
    "module",
    [
        "scratchfab.cli.export_cmd",
        "scratchfab.cli.toolpath_cmd",
        "scratchfab.cli.design_cmd",
        "scratchfab.cli.render_cmd",
        "scratchfab.export",
        "scratchfab.toolpath",
    ],
)
def test_importing_a_command_loads_none_of_the_heavy_libraries(module):
    assert loaded_after(f"import {module}") == set()


def test_the_check_sees_a_heavy_import():
    assert "scipy" in loaded_after("import scratchfab.design.stage")
    assert "ezdxf" in loaded_after("import scratchfab.export.dxf")


@pytest.fixture(scope="module")
def toolpath_file(tmp_path_factory):
    rng = np.random.default_rng(3)
    c = rng.uniform(-15, 15, (40, 2))
    u = rng.normal(size=(40, 2))
    scratches = ScratchSet.from_arrays(c - u, c + u, 0.1, 0.01)
    board = Board(width_mm=40.0, height_mm=40.0, margin_mm=1.0)
    path = tmp_path_factory.mktemp("imports") / "toolpath.json"
    plan_toolpath(scratches, board, load_profile("grbl-3018-diamond")).save(path)
    return path


@pytest.mark.parametrize(
    ("fmt", "expected"), [("gcode", set()), ("svg", set()), ("dxf", {"ezdxf"})]
)
def test_an_export_loads_only_its_own_writer(toolpath_file, fmt, expected):
    out = toolpath_file.parent / f"board.{fmt}"
    code = (
        "import sys; from scratchfab.cli import main\n"
        "try:\n"
        "    main(['export', '--toolpath', sys.argv[1], '-o', sys.argv[2]])\n"
        "except SystemExit as stop:\n"
        "    assert not stop.code, stop.code"
    )
    assert loaded_after(code, str(toolpath_file), str(out)) == expected
    assert out.stat().st_size > 0


def test_help_of_every_command_loads_none_of_the_heavy_libraries():
    code = (
        "from scratchfab.cli import main\n"
        "for name in ('export', 'toolpath', 'design', 'render'):\n"
        "    try:\n"
        "        main([name, '--help'])\n"
        "    except SystemExit as stop:\n"
        "        assert not stop.code, stop.code"
    )
    assert loaded_after(code) == set()


def core_modules() -> list[str]:
    """Every module of the package outside the click layer (``scratchfab.cli``, ``__main__``)."""
    import pkgutil

    import scratchfab

    names = [
        info.name
        for info in pkgutil.walk_packages(scratchfab.__path__, "scratchfab.")
        if not info.name.startswith(("scratchfab.cli", "scratchfab.data"))
        and info.name != "scratchfab.__main__"
    ]
    return sorted(names)


def test_no_core_module_imports_click():
    modules = core_modules()
    assert {
        "scratchfab.model.design",
        "scratchfab.machine.sender",
        "scratchfab.verify.bsdf",
    } <= set(modules)
    code = (
        "import importlib, sys\n"
        "for name in sys.argv[1:]:\n"
        "    importlib.import_module(name)\n"
        "    assert 'click' not in sys.modules, name"
    )
    subprocess.run([sys.executable, "-c", code, *modules], check=True)


def test_the_click_check_sees_a_click_import():
    code = "import sys, scratchfab.cli; assert 'click' in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)
