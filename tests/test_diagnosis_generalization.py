"""A 10-record slice of the diagnosis generalisation benchmark, against the issue's thresholds.

Records 0-9 of benchmarks/independent_plants.py (an independent scipy simulator), shortened to at most
1000 samples (4-5 s at 200-240 Hz; CI time), run through the default command lines as subprocesses, path (a)
``cosim diagnose DATA ...`` and path (b) ``cosim identify`` then ``cosim diagnose --model``, and scored as
benchmarks/bench_diagnosis_generalization.py scores them: named right first >= 90 %, false claims <= 5 %,
median parameter error <= 10 %, no accepted effect raising the held-out error, median time <= 10 s.
A failing assertion prints the whole table: which effects fail and how.
"""

import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))  # benchmarks/ is not a package
import bench_diagnosis_generalization as bench  # noqa: E402

RECORDS = list(range(10))  # 20 until issue 15 needed the CI time: the full benchmark is in benchmarks/
MAX_SAMPLES = 1000


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    """Path (a) on the slice, run once for the tests below (path (b) in the benchmark: CI time)."""
    data_dir = tmp_path_factory.mktemp("generalization_records")
    cosim = shutil.which("cosim", path=str(Path(sys.executable).parent)) or "cosim"
    return bench.run(RECORDS, out=data_dir / "result", data_dir=data_dir, max_samples=MAX_SAMPLES, paths=("a",),
                     cosim=cosim, jobs=1, timeout=300.0, progress=False, write=False)


@pytest.mark.slow
def test_every_record_is_diagnosed_without_error(result):
    """Whatever it names, the default command ends normally on every record (exit 0, its JSON written)."""
    assert result["summary"]["a"]["overall"]["records"] == len(RECORDS)
    failures = [(row["index"], f) for row in result["rows"] for f in row["failures"]]
    assert not failures, failures


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue 13: the thresholds are not met yet (see "
                                       "benchmarks/results/diagnosis_generalization.md)")
def test_default_diagnosis_generalises(result):
    overall = result["summary"]["a"]["overall"]
    failed = [key for key, met in overall["pass"].items() if not met]
    assert not failed, f"path (a) misses the issue's thresholds {failed}:\n{bench.markdown(result)}"
