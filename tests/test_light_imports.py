"""``import cosim`` and ``cosim --help`` load only what they need: the heavy libraries are imported on first use.

Each case runs a fresh interpreter (the test session itself has imported everything long ago) and lists which of
the heavy libraries ended up in its ``sys.modules``.
"""

from __future__ import annotations

import json
import subprocess
import sys

#: Libraries that take from a tenth of a second to seconds to import; the rooms import them when used.
HEAVY = ("pandas", "scipy.optimize", "casadi", "pysindy", "control", "matplotlib", "dask")


def heavy_modules_after(code: str) -> list[str]:
    """The libraries of :data:`HEAVY` that a fresh interpreter has imported after running `code`."""
    probe = f"{code}\nimport json, sys\nprint(json.dumps(sorted(m for m in {HEAVY!r} if m in sys.modules)))\n"
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.splitlines()[-1])


def test_import_cosim_loads_no_heavy_library():
    assert heavy_modules_after("import cosim") == []


def test_the_command_line_help_loads_no_heavy_library():
    code = "\n".join([
        "from cosim.cli import main",
        "try:",
        "    main(['--help'], standalone_mode=False)",
        "except SystemExit as exc:",
        "    assert not exc.code, exc",
    ])
    assert heavy_modules_after(code) == []


def test_a_heavy_library_is_imported_when_used():
    # the probe sees a library once cosim needs it: building a multisine refines its peak with scipy.optimize
    code = "import cosim\ncosim.signals.multisine(0.1, band=(1.0, 10.0))"
    assert heavy_modules_after(code) == ["scipy.optimize"]
