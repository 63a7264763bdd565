"""`cosim identify` and `cosim reproduce paper` from the command line, on FMU data."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from summary_checks import summary_rows

from cosim.cli import main
from cosim.identify.model import IdentifiedModel
from cosim.study.paper import STATES, STUDY_TABLE1, two_mass_matrices


def run(*args: str):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


@pytest.fixture(scope="module")
def fmu_data(tmp_path_factory):
    path = tmp_path_factory.mktemp("identify") / "data.csv"
    result = run("simulate", "bundled", "--input", "Tm=sine:amp=500,freq=5", "--duration", "3", "--dt", "1/2257",
                 "--start", "theta_m=-2", "--start", "theta_L=2", "--start", "omega_L=1", "-o", str(path))
    assert result.exit_code == 0, result.stderr
    return path


def test_identify_recovers_the_true_coefficients(fmu_data, tmp_path):
    out = tmp_path / "model.json"
    result = run("identify", str(fmu_data), "--state", ",".join(STATES), "--input", "Tm", "--no-refine",
                 "-o", str(out), "--json")
    assert result.exit_code == 0, result.stderr
    payload = json.loads(result.stdout)
    assert all(payload["fit"]["r2"][s] > 0.9999 for s in STATES), payload["fit"]
    model = IdentifiedModel.load(out)
    a, b = two_mass_matrices()
    got_a, got_b, _ = model.linear_matrices()
    np.testing.assert_allclose(got_a, a, rtol=5e-3, atol=5e-3 * np.abs(a).max())
    assert got_b[1, 0] == pytest.approx(b[1, 0], rel=5e-3)


def test_identify_prints_equations(fmu_data):
    result = run("identify", str(fmu_data), "--state", ",".join(STATES), "--input", "Tm", "--no-refine")
    assert result.exit_code == 0
    assert "theta_m' = " in result.stdout and "free-run fit" in result.stdout


@pytest.mark.parametrize("args,fragment", [
    (["--state", "theta_m,nope", "--input", "Tm"], "nope"),
    (["--state", ",".join(STATES), "--input", "Tm", "--threshold", "abc"], "--threshold"),
    (["--state", ",".join(STATES), "--input", "Tm", "--differentiation", "magic"], "magic"),
])
def test_identify_bad_input(fmu_data, args, fragment):
    result = run("identify", str(fmu_data), *args)
    assert result.exit_code != 0
    line = result.stderr.strip()
    assert line.startswith("error: ") and "\n" not in line and fragment in line, line


@pytest.mark.slow
def test_reproduce_paper_json_and_files(tmp_path):
    out = tmp_path / "repro"
    result = run("reproduce", "paper", "--seeds", "1", "--noise", "0,0.3", "--excitation", "sine", "--workers", "1",
                 "--out", str(out), "--no-progress", "--json")
    assert result.exit_code == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["noise_levels"] == [0.0, 0.3]
    for state in STATES:
        assert len(summary["r2"][state]) == 2 and len(summary["max_dev_pct"][state]) == 2
        assert summary["r2"][state][1] >= 0.99
        assert summary["max_dev_pct"][state][1] < STUDY_TABLE1[0.3][state]
    for name in ("table1.csv", "r2_vs_noise.csv", "r2_vs_noise.png", "square_vs_sine.csv", "coefficients.csv",
                 "report.html"):
        assert (out / name).stat().st_size > 0, name
    assert "Table 1" in (out / "report.html").read_text()
    rows = summary_rows(out / "report.html")  # the headline first: the cases, the deviation beside Table 1, verdicts
    assert rows["Data"].startswith("2 cases: sine excitation × noise 0 %, 30 % × 1 seed(s); 10 s each")
    study, ours = (row.split() for row in rows["Error"].split(" the study (Table 1) ")[1].split(" cosim "))
    assert [float(v) for v in study] == [float(f"{STUDY_TABLE1[0.3][s]:.3g}") for s in STATES]
    assert [float(v) for v in ours] == pytest.approx([summary["max_dev_pct"][s][1] for s in STATES], rel=5e-3)
    assert "R² ≥ 0.99 up to 30 % noise (the study's claim) PASSED PASSED PASSED" in rows["Verdicts"]
