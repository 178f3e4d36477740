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
