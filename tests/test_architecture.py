"""The house's rules (docs/architecture.md): imports flow one way between rooms, no circles, no module over
600 lines, every package shipped. Each check is also shown failing on a deliberately bad copy of the code.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("cosim", "controllers")
MAX_LINES = 600


def lint_imports(project: Path) -> subprocess.CompletedProcess:
    """import-linter on `project` (its pyproject.toml's contracts), in a fresh interpreter importing from there."""
    code = ("import sys; from importlinter.cli import lint_imports; "
            "sys.exit(lint_imports(config_filename='pyproject.toml', no_cache=True, no_logo=True))")
    return subprocess.run([sys.executable, "-c", code], cwd=project, capture_output=True, text=True, timeout=300,
                          env={"PYTHONPATH": str(project), "PATH": "", "PYTHONDONTWRITEBYTECODE": "1"})


def oversized_modules(root: Path, limit: int = MAX_LINES) -> dict[str, int]:
    """Python modules under `root`'s packages with more than `limit` lines, by path."""
    sizes = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            lines = len(path.read_text(encoding="utf-8").splitlines())
            if lines > limit:
                sizes[str(path.relative_to(root))] = lines
    return sizes


@pytest.fixture(scope="module")
def copy_of_project(tmp_path_factory) -> Path:
    """The packages and pyproject.toml copied, for deliberately bad changes."""
    target = tmp_path_factory.mktemp("project")
    shutil.copy(ROOT / "pyproject.toml", target / "pyproject.toml")
    for package in PACKAGES:
        shutil.copytree(ROOT / package, target / package, ignore=shutil.ignore_patterns("__pycache__"))
    return target


def test_imports_follow_the_rooms_arrows_without_circles():
    result = lint_imports(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    contracts = (ROOT / "pyproject.toml").read_text(encoding="utf-8").count("[[tool.importlinter.contracts]]")
    assert f"Contracts: {contracts} kept, 0 broken." in result.stdout


def lint_after_appending(project: Path, module: str, text: str) -> subprocess.CompletedProcess:
    """import-linter on `project` with `text` appended to `module` (a path inside it), which is then restored."""
    path = project / module
    original = path.read_text()
    path.write_text(original + text)
    try:
        return lint_imports(project)
    finally:
        path.write_text(original)


def test_an_upward_import_breaks_the_layers_contract(copy_of_project):
    result = lint_after_appending(copy_of_project, "cosim/plant/build.py",
                                  "\nfrom ..loop.closed_loop import closed_loop  # noqa\n")
    assert result.returncode == 1, result.stdout
    assert "cosim.plant is not allowed to import cosim.loop" in result.stdout


def test_a_circle_inside_a_room_breaks_the_acyclic_contract(copy_of_project):
    # trajectory is imported by simulation; the reverse import closes a circle inside the data room
    result = lint_after_appending(copy_of_project, "cosim/data/trajectory.py",
                                  "\n\ndef _circle():\n    from .simulation import simulate  # noqa\n")
    assert result.returncode == 1, result.stdout
    assert "No cycles are allowed in cosim.data" in result.stdout


def test_no_module_is_over_600_lines():
    assert oversized_modules(ROOT) == {}


def test_the_size_check_finds_a_long_module(copy_of_project):
    long_module = copy_of_project / "cosim" / "data" / "long.py"
    long_module.write_text("x = 1\n" * (MAX_LINES + 1))
    try:
        assert oversized_modules(copy_of_project) == {"cosim/data/long.py": MAX_LINES + 1}
    finally:
        long_module.unlink()


def test_every_package_is_listed_for_the_wheel():
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    listed = set(re.findall(r'"([a-z_.]+)"', re.search(r"packages = \[(.*?)\]", text, re.S).group(1)))
    on_disk = {".".join(p.parent.relative_to(ROOT).parts) for package in PACKAGES
               for p in (ROOT / package).rglob("__init__.py")}
    assert on_disk - listed == set()
