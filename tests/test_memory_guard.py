"""The memory guard: a simulation or an identification the machine cannot hold is refused up front, with the
figure and what to change, before anything is allocated or written."""

import subprocess
import sys
import time

import numpy as np
import pytest

from cosim.errors import InvalidSettingError
from cosim.numbers import available_memory, check_memory


def test_a_nanosecond_step_is_refused_in_under_a_second_with_no_file(tmp_path):
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "cosim.cli", "simulate", "bundled", "--dt", "1e-9",
                             "--duration", "10", "-o", str(tmp_path / "out.csv")],
                            capture_output=True, text=True, cwd=tmp_path, timeout=60)
    elapsed = time.perf_counter() - start
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: a simulation of 10,000,000,001 samples"), lines
    assert "GB" in lines[0] and "use a larger dt or a shorter duration" in lines[0]
    assert list(tmp_path.iterdir()) == []
    assert elapsed < 5.0  # the interpreter's start included; the refusal itself is instantaneous


def test_the_limit_follows_the_machine_and_can_be_set(monkeypatch):
    assert available_memory() > 0
    monkeypatch.setenv("COSIM_MEMORY_LIMIT", "1e6")
    assert available_memory() == 1_000_000
    check_memory(62_500, what="x", hint="y")  # 0.5 MB: half of the limit exactly
    with pytest.raises(InvalidSettingError, match=r"^z needs 0.000504 GB, more than 50% of the 0.001 GB .*; w$"):
        check_memory(63_000, what="z", hint="w")


def test_an_identification_too_big_for_the_machine_is_refused_before_fitting(monkeypatch):
    from cosim import SINDYc, Trajectory

    t = np.arange(2000) * 1e-3
    traj = Trajectory.from_arrays(t, {"u": np.sin(3 * t), "a": np.sin(t), "b": np.cos(t)},
                                  roles={"u": "input", "a": "state", "b": "state"})
    monkeypatch.setenv("COSIM_MEMORY_LIMIT", "1e5")
    with pytest.raises(InvalidSettingError, match="identifying .* terms on 2,000 samples needs .* decimate"):
        SINDYc().fit(traj)
