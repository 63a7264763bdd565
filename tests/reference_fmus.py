"""The Modelica Association's Reference FMUs, built from their source in ../shared/fmus/reference-fmus with cmake,
once, into cosim's cache folder (``$COSIM_CACHE_DIR/reference-fmus/fmi<N>-<source hash>``), for the tests that
check cosim as an importer of FMUs nobody here wrote.

The build follows ../shared/fmus/README.md: ``cmake -S SRC -B BUILD -DFMI_VERSION=N -DCMAKE_BUILD_TYPE=Release
-DCMAKE_C_FLAGS=-Wno-error=stringop-truncation`` then ``cmake --build BUILD``; the FMUs land in BUILD/fmus. The
tests take an unoptimised build (``-O0``: 6 s of compiling instead of 14 for FMI 3; cosim and fmpy then run the
same binary, so the comparisons do not depend on it); benchmarks/bench_step.py asks for the Release build. A
build goes to a temporary folder renamed into place when complete, so a crash leaves no half-built set. cmake is
the system's, else the ``cmake`` PyPI package's (a test dependency).
"""

from __future__ import annotations

import fcntl
import functools
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

SOURCE = Path(__file__).resolve().parents[2] / "shared" / "fmus" / "reference-fmus"
NAMES = {2: ("BouncingBall", "Dahlquist", "Feedthrough", "Resource", "Stair", "VanDerPol"),
         3: ("BouncingBall", "Clocks", "Dahlquist", "Feedthrough", "Resource", "Roberts", "Stair", "StateSpace",
             "VanDerPol")}


def _cmake() -> str:
    found = shutil.which("cmake")
    if found:
        return found
    try:
        import cmake  # the PyPI package ships the binary

        return str(Path(cmake.CMAKE_BIN_DIR) / "cmake")
    except ImportError:
        pytest.fail("no cmake: install the test extra (pip install -e '.[test]') or the system's cmake")


def _source_hash() -> str:
    """A hash of the source tree's file names, sizes and modification times (what a rebuild depends on)."""
    digest = hashlib.sha256()
    for path in sorted(p for p in SOURCE.rglob("*") if p.is_file() and p.suffix in (".c", ".h", ".xml", ".txt")):
        stat = path.stat()
        digest.update(f"{path.relative_to(SOURCE)}:{stat.st_size}:{int(stat.st_mtime)}".encode())
    return digest.hexdigest()[:12]


@functools.cache  # once per process: the tests ask for the set once each
def reference_fmus(fmi_version: int, *, optimized: bool = False) -> dict[str, Path]:
    """Name -> path of the Reference FMUs of `fmi_version` (2 or 3), built once and cached (`optimized`: the
    Release build, as the README of ../shared/fmus builds them; else -O0, quicker to compile)."""
    if not SOURCE.is_dir():
        pytest.fail(f"the Reference FMUs' source is not at {SOURCE} (see ../shared/fmus/README.md)")
    cache = Path(os.environ.get("COSIM_CACHE_DIR") or Path.home() / ".cache" / "cosim") / "reference-fmus"
    target = cache / f"fmi{fmi_version}-{'release' if optimized else 'o0'}-{_source_hash()}"
    cache.mkdir(parents=True, exist_ok=True)
    # one build for all the xdist workers: the others wait on the lock, then find the set built
    with open(cache / f".fmi{fmi_version}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not all((target / f"{name}.fmu").is_file() for name in NAMES[fmi_version]):
            _build(fmi_version, cache, target, optimized)
    return {name: target / f"{name}.fmu" for name in NAMES[fmi_version]}


def _build(fmi_version: int, cache: Path, target: Path, optimized: bool) -> None:
    """Configure and build the set with cmake in a temporary folder, renamed to `target` when complete."""
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        build = Path(tmp) / "build"
        cmake = _cmake()
        for command in ([cmake, "-S", str(SOURCE), "-B", str(build), f"-DFMI_VERSION={fmi_version}",
                         "-DCMAKE_BUILD_TYPE=" + ("Release" if optimized else ""),
                         "-DCMAKE_C_FLAGS=-Wno-error=stringop-truncation" + ("" if optimized else " -O0")],
                        [cmake, "--build", str(build), "-j2"]):
            done = subprocess.run(command, capture_output=True, text=True, timeout=600)
            if done.returncode:
                pytest.fail(f"building the Reference FMUs failed: {' '.join(command)}\n{done.stderr[-3000:]}")
        staged = Path(tmp) / "fmus"
        staged.mkdir()
        for name in NAMES[fmi_version]:
            shutil.copy2(build / "fmus" / f"{name}.fmu", staged / f"{name}.fmu")
        shutil.rmtree(target, ignore_errors=True)
        staged.rename(target)
