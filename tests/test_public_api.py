"""What users import keeps working across the move into rooms.

``tests/data/api_before_rooms.json`` lists every module's ``__all__`` as it was before the move (written by
that version). Every name of ``cosim`` and ``controllers`` still imports from there; every old module path
still imports, with a :class:`~cosim.errors.CosimDeprecationWarning` naming the new place, and gives the same
objects as the room that holds them now.
"""

from __future__ import annotations

import importlib
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
