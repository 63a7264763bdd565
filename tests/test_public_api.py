"""What users import keeps working across the move into rooms.

``tests/data/api_before_rooms.json`` lists every module's ``__all__`` as it was before the move (written by
that version). Every name of ``cosim`` and ``controllers`` still imports from there; every old module path
still imports, with a :class:`~cosim.errors.CosimDeprecationWarning` naming the new place, and gives the same
objects as the room that holds them now.
"""

from __future__ import annotations

import ast
import importlib
import importlib.resources
import json
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from cosim.errors import CosimDeprecationWarning

BEFORE = json.loads((Path(__file__).parent / "data" / "api_before_rooms.json").read_text())["modules"]
TOP_LEVEL = ("cosim", "controllers")


@pytest.mark.parametrize("package", TOP_LEVEL)
def test_every_top_level_name_still_imports(package):
    module = importlib.import_module(package)
    missing = [name for name in BEFORE[package] if not hasattr(module, name)]
    assert missing == []
    assert set(BEFORE[package]) <= set(module.__all__)


OLD_PATHS = sorted(m for m in BEFORE if m not in TOP_LEVEL)


@pytest.mark.parametrize("old", OLD_PATHS)
def test_every_old_module_path_still_imports_its_names(old):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = importlib.import_module(old)
        values = {name: getattr(module, name) for name in BEFORE[old]}
    assert len(values) == len(BEFORE[old])
    assert set(BEFORE[old]) <= set(module.__all__)  # so `from old.path import *` still works
    moved = [w for w in caught if issubclass(w.category, CosimDeprecationWarning)]
    if module.__name__ != old or not hasattr(module, "__file__"):  # a path that moved (not a room's own name)
        assert moved, f"no deprecation warning for {old}"
        assert "has moved: import from cosim." in str(moved[0].message) or "controllers." in str(moved[0].message)
    for name, value in values.items():
        if isinstance(value, type) or callable(value):
            home = importlib.import_module(value.__module__) if hasattr(value, "__module__") else module
            assert getattr(home, getattr(value, "__name__", name), value) is value


def test_the_warning_points_at_the_importing_line(tmp_path):
    script = tmp_path / "user_script.py"
    script.write_text("from cosim.diagnosis import diagnose\n")
    result = subprocess.run([sys.executable, "-W", "always::DeprecationWarning", str(script)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert f"{script}:1: CosimDeprecationWarning: cosim.diagnosis has moved" in result.stderr


def test_export_is_the_function_and_the_room():
    import cosim
    import cosim.export

    assert callable(cosim.export)
    assert cosim.export.to_statespace is cosim.to_statespace
    from cosim import export

    assert callable(export)


# ------------------------------------------------------------------------------ for IDEs and type checkers
INIT = Path(__file__).parents[1] / "cosim" / "__init__.py"


def _type_checking_imports() -> dict[str, str]:
    """Name -> absolute module of each import in the ``if TYPE_CHECKING:`` block of cosim/__init__.py."""
    tree = ast.parse(INIT.read_text(encoding="utf-8"))
    blocks = [node for node in tree.body if isinstance(node, ast.If) and isinstance(node.test, ast.Name)
              and node.test.id == "TYPE_CHECKING"]
    assert len(blocks) == 1, "cosim/__init__.py has no `if TYPE_CHECKING:` block at module level"
    imports = {}
    for node in blocks[0].body:
        assert isinstance(node, ast.ImportFrom) and node.level == 1, ast.unparse(node)
        for alias in node.names:
            # `X as X`: the explicit re-export that strict checkers (mypy --no-implicit-reexport, pyright) want
            assert alias.asname == alias.name, ast.unparse(node)
            imports[alias.name] = f"cosim.{node.module}"
    return imports


def _runtime_imports() -> set[str]:
    """Names that cosim/__init__.py binds with a module-level import, run at ``import cosim``."""
    tree = ast.parse(INIT.read_text(encoding="utf-8"))
    return {alias.asname or alias.name for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))
            for alias in node.names}


def test_every_public_name_is_visible_to_type_checkers():
    import cosim

    static = _type_checking_imports()
    # what `import cosim` does not import (the lazy names) is exactly what the TYPE_CHECKING block imports
    assert set(cosim.__all__) - _runtime_imports() == set(static) == set(cosim._LAZY)
    assert set(static) <= set(cosim.__all__)


@pytest.mark.parametrize("name", sorted(_type_checking_imports()))
def test_the_type_checking_imports_are_what_runs(name):
    import cosim

    module = _type_checking_imports()[name]
    expected = getattr(importlib.import_module(module), name)
    value = getattr(cosim, name)
    # cosim.export is also a room: once imported, Python binds the name to the (callable) module
    assert value is expected or getattr(value, name, None) is expected


def test_every_public_name_resolves():
    import cosim

    assert [name for name in cosim.__all__ if getattr(cosim, name, None) is None] == []


def test_the_type_checking_block_imports_nothing_at_runtime():
    code = ("import json, sys, cosim\n"
            "print(json.dumps(sorted(m for m in sys.modules if m.split('.')[:2] in ([\"cosim\", r] for r in "
            "('identify', 'export', 'diagnose', 'loop', 'study')))))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == []


# ------------------------------------------------------------------------------------------------ py.typed
@pytest.mark.parametrize("package", TOP_LEVEL)
def test_the_packages_are_marked_typed(package):
    marker = importlib.resources.files(package) / "py.typed"
    assert marker.is_file() and marker.read_text() == ""


def test_the_typed_markers_go_into_the_wheel():
    tomllib = pytest.importorskip("tomllib")
    config = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text(encoding="utf-8"))
    package_data = config["tool"]["setuptools"]["package-data"]
    assert all("py.typed" in package_data.get(package, []) for package in TOP_LEVEL), package_data
