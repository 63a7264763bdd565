"""Shared by every test: the bundled FMUs, built once per session, and an order that keeps every core busy.

The suite runs under pytest-xdist (``python -m pytest -n auto``, the README's command) with ``--dist loadfile``
(pyproject.toml): a test file runs on one worker, so a module fixture (the EMPS diagnosis, the demo: a minute and
twenty seconds) is computed once, not once per worker. The files holding ``slow`` tests are handed out first, so
that no worker starts a minute-long file while the others have nothing left to do. (``--dist loadgroup`` would
group finer, but pytest 9.2 broke it silently: pytest-dev/pytest-xdist#1386.)
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from cosim import build_fmu


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    # stable sort by file: the files with slow tests first; each file's tests stay together and in order
    slow_files = {item.path for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.path not in slow_files)


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
