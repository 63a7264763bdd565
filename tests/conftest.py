"""Shared by every test: the bundled FMUs, built once per session, and an order that keeps every core busy.

The suite runs under pytest-xdist (``python -m pytest -n auto``, the README's command) with ``--dist loadfile``
(pyproject.toml): a test file runs on one worker, so a module fixture (the EMPS diagnosis, the demo: a minute and
twenty seconds) is computed once, not once per worker. The longest files are handed out first
(:data:`FILE_SECONDS`), then the other files holding ``slow`` tests, so that no worker starts a minute-long file
while the others have nothing left to do. (``--dist loadgroup`` would group finer, but pytest 9.2 broke it
silently: pytest-dev/pytest-xdist#1386.)
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from cosim import build_fmu

#: Seconds of work of the longest files (measured 2026-11-27 with ``--durations=0`` on 2 cores, cold caches as in
#: CI): they are handed out longest first, so that the last file to start is a short one. Only the order depends
#: on these figures.
FILE_SECONDS = {"test_diagnose_benchmark_cases.py": 114, "test_diagnosis.py": 70,
                "test_diagnosis_generalization.py": 35, "test_emps.py": 43, "test_readme_tour.py": 31,
                "test_identify_multistart.py": 25, "test_diagnose_record_rate.py": 21,
                "test_diagnosis_uncovered.py": 21, "test_kinematics.py": 16, "test_derive_window.py": 14,
                "test_demo.py": 13, "test_identification.py": 12, "test_pid.py": 12,
                # builds the Reference FMUs (cmake, 15-20 s) while the other worker runs a long file, so that
                # test_reference_fmus.py finds them built instead of waiting on the build's lock
                "test_model_exchange.py": 20}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    # stable sort by file: the longest files first, then the other files with slow tests; each file's tests stay
    # together and in order
    slow_files = {item.path for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: (-FILE_SECONDS.get(item.path.name, 0), item.path not in slow_files))


@pytest.fixture(scope="session", autouse=True)
def _one_blas_thread_per_worker():
    """Under xdist every core already runs a worker: BLAS threads on top would only fight over the cores."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


@pytest.fixture(scope="session")
def fmu() -> Path:
    """The bundled two-mass servo FMU (FMI 2.0), built from its C source once (cached on disk after)."""
    return build_fmu()


@pytest.fixture(scope="session")
def fmu3() -> Path:
    """The bundled two-mass servo FMU as FMI 3.0."""
    return build_fmu(fmi_version="3.0")
