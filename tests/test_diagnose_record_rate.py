"""A long record is searched at a lower rate and its findings refitted at the record's own (``_analysis_rate``):
an effect the refit moves out of what the plant can have is dropped there too, as within the rounds."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest


@pytest.mark.slow
def test_a_delay_refitted_to_a_lead_at_the_record_rate_is_dropped(tmp_path):
    """Record 64 of benchmarks/independent_plants.py at 20 000 samples (a mass with Stribeck friction under a
    PID, 4 kHz): the search at a lower rate accepts a delay, and the refit at 4 kHz moved its taps to a centroid
    of -5.06 samples, which was reported as the finding. It is dropped and said so."""
    from click.testing import CliRunner

    from cosim.cli import main

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))  # benchmarks/ is not a package
    import independent_plants as ip

    record = ip.make_record(64, max_samples=20000)
    folder = record.write(tmp_path / "record")
    out = tmp_path / "after.json"
    result = CliRunner().invoke(main, ["diagnose", str(folder / "train.csv"), "--state", ",".join(
        record.cli["states"]), "--input", record.cli["input"], "--json", "-o", str(out)], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert not any(e["name"] == "delay" for e in report["effects"])
    dropped = [e for e in report["rejected"] if e["name"] == "delay"]
    assert dropped and all(e["parameters"]["delay_samples"] <= 0.0 for e in dropped)
    assert "dropped" in report["message"]
