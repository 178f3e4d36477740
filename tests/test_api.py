"""The top-level API: ``from scratchfab import *`` and the names its docstring documents.

Each case that imports runs in a fresh interpreter, so the lazy imports are seen as a
notebook sees them.
"""

from __future__ import annotations

import importlib
import json
import re
import subprocess
import sys

import pytest

import scratchfab

#: A Sphinx role naming a full dotted path in the module docstring.
ROLE = re.compile(r":(?:func|class):`~?(scratchfab(?:\.\w+)+)`")


def documented() -> dict[str, str]:
    """Each name the docstring's roles give, by its full path."""
    return {path.rsplit(".", 1)[1]: path for path in ROLE.findall(scratchfab.__doc__ or "")}


def fresh(code: str) -> object:
    """What ``code`` prints as JSON on its last line, run in a new interpreter."""
    run = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    return json.loads(run.stdout.splitlines()[-1])


def test_star_import_gives_exactly_all_with_docstrings():
    got = fresh(
        "import json\n"
        "before = set(globals())\n"
        "from scratchfab import *\n"
        "names = sorted(set(globals()) - before - {'before'})\n"
        "print(json.dumps({n: bool((globals()[n].__doc__ or '').strip()) for n in names}))"
    )
    assert isinstance(got, dict)
    assert sorted(got) == sorted(scratchfab.__all__)
    assert [name for name, has_doc in got.items() if not has_doc] == []


def test_every_name_is_the_object_its_documented_path_names():
    paths = documented()
    missing = [name for name in scratchfab.__all__ if name not in paths]
    assert missing == [], "names in __all__ the module docstring does not name by path"
    for name in scratchfab.__all__:
        module, _, attr = paths[name].rpartition(".")
        assert getattr(scratchfab, name) is getattr(importlib.import_module(module), attr)


def test_importing_scratchfab_loads_none_of_its_modules():
    loaded = fresh(
        "import json, sys, scratchfab\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith('scratchfab.') "
        "or m in ('numpy', 'scipy', 'drjit', 'mitsuba', 'numba'))))"
    )
    assert loaded == []


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no_such_name"):
        scratchfab.no_such_name  # noqa: B018
    assert set(scratchfab.__all__) <= set(dir(scratchfab))


def _type_checking_imports(module) -> dict[str, set[str]]:
    """The names each ``from M import ...`` under the module's TYPE_CHECKING block imports."""
    import ast
    from pathlib import Path

    tree = ast.parse(Path(module.__file__).read_text())
    blocks = [
        node
        for node in tree.body
        if isinstance(node, ast.If)
        and ast.unparse(node.test).endswith("TYPE_CHECKING")
        and not ast.unparse(node.test).startswith("not ")
    ]
    assert len(blocks) == 1, "one `if TYPE_CHECKING:` block of imports"
    found: dict[str, set[str]] = {}
    for node in blocks[0].body:
        assert isinstance(node, ast.ImportFrom) and node.module
        found.setdefault(node.module, set()).update(a.asname or a.name for a in node.names)
    return found


def test_the_names_mypy_sees_are_the_names_loaded_on_use():
    """mypy reads the TYPE_CHECKING imports; the runtime, the lazy table: the same names."""
    seen = _type_checking_imports(scratchfab)
    table: dict[str, set[str]] = {}
    for name, module in scratchfab._HOME.items():
        table.setdefault(module, set()).add(name)
    assert seen == table
    assert sorted(scratchfab._HOME) == sorted(scratchfab.__all__)


def test_the_toolpath_package_s_lazy_names_are_its_type_checking_imports():
    import scratchfab.toolpath as toolpath

    assert _type_checking_imports(toolpath) == {
        "scratchfab.toolpath.plan": set(toolpath._FROM_PLAN)
    }
    assert set(toolpath._FROM_PLAN) <= set(toolpath.__all__)


def test_dir_lists_the_api_and_no_helper():
    import scratchfab.toolpath as toolpath

    listed = fresh("import json, scratchfab\nprint(json.dumps(dir(scratchfab)))")
    assert isinstance(listed, list)  # a fresh import: no submodule loaded yet
    assert [n for n in listed if not n.startswith("_")] == sorted(scratchfab.__all__)
    helpers = {"Any", "TYPE_CHECKING", "importlib", "annotations", "import_module"}
    assert helpers.isdisjoint(dir(toolpath))
    assert helpers.isdisjoint(vars(scratchfab))


def test_mypy_is_not_told_every_name_exists():
    """``__getattr__`` only outside type checking: mypy would type a misspelt name as Any."""
    import ast
    from pathlib import Path

    import scratchfab.toolpath as toolpath

    for module in (scratchfab, toolpath):
        tree = ast.parse(Path(module.__file__).read_text())
        top = [n.name for n in tree.body if isinstance(n, ast.FunctionDef)]
        assert "__getattr__" not in top, module.__name__
        guarded = [
            n
            for n in tree.body
            if isinstance(n, ast.If)
            and ast.unparse(n.test).startswith("not ")
            and ast.unparse(n.test).endswith("TYPE_CHECKING")
        ]
        assert [f.name for g in guarded for f in g.body] == ["__getattr__"], module.__name__
