"""EMPS, real measured data: the loader on the benchmark's files and the rigid-model baseline against the published
IDIM-LS numbers and the data's README (examples/emps.py).

The data are read from ``$COSIM_EMPS_DIR`` or ``../shared/data/emps`` beside the repository, never copied into it.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import platform
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("COSIM_EMPS_DIR") or Path(__file__).resolve().parents[2] / "shared" / "data" / "emps")
pytestmark = pytest.mark.skipif(
    not (DATA / "DATA_EMPS.mat").is_file() or not (DATA / "DATA_EMPS_PULSES.mat").is_file(),
    reason=f"EMPS data not found in {DATA} (set COSIM_EMPS_DIR to the folder with DATA_EMPS.mat and "
           "DATA_EMPS_PULSES.mat)")


@pytest.fixture(scope="module")
def emps() -> dict:
    return runpy.run_path(str(ROOT / "examples" / "emps.py"))


@pytest.fixture(scope="module")
def records(emps):
    return emps["load_emps"](DATA)


@pytest.fixture(scope="module")
def results(emps, records):
    return emps["baseline"](*records)


def test_loader_on_the_real_files(records):
    raw = scipy.io.loadmat(DATA / "DATA_EMPS_PULSES.mat")
    for traj in records:
        assert len(traj) == 24841
        assert traj.names == ("qm", "qm_dot", "qm_ddot", "force")
        assert traj.states == ("qm", "qm_dot") and traj.inputs == ("force",)
        assert traj.units == ("m", "m/s", "m/s^2", "N")
        assert traj.dt == pytest.approx(1e-3, rel=1e-12) and traj.is_uniform()
        assert traj.meta["data_file"]["time_jitter"] < 1e-7
        assert -1e-4 < traj["qm"].min() and traj["qm"].max() < 0.25  # 0 to 0.246 m
        assert traj.meta["data_file"]["scalars"]["gtau"] == pytest.approx(35.15, abs=0.01)
    test = records[1]
    np.testing.assert_array_equal(test["force"], raw["gtau"].item() * raw["vir"].ravel())
    np.testing.assert_array_equal(test["qm"], raw["qm"].ravel())
    # velocity from the band-pass: the axis moves at up to about 0.2 m/s
    assert 0.1 < np.max(np.abs(test["qm_dot"])) < 0.5


def test_pulses_can_be_added_and_are_already_in_vir(emps, records):
    train, test = records
    _, with_pulses = emps["load_emps"](DATA, add_pulses=True)
    raw = scipy.io.loadmat(DATA / "DATA_EMPS_PULSES.mat")
    np.testing.assert_allclose(with_pulses["force"] - test["force"], raw["pulses_N"].ravel().astype(float))
    coefficients = emps["fit_rigid_model"](train, coulomb=True)
    # the cross-test matches the published 5.98 % only without adding the pulses a second time
    assert emps["force_error_pct"](coefficients, test) < 6.2
    assert emps["force_error_pct"](coefficients, with_pulses) > 8.0


@pytest.mark.parametrize("model", ["coulomb", "asymmetric", "linear"])
def test_baseline_matches_the_reference(emps, results, model):
    for key, value in emps["REFERENCE"][model].items():
        assert results[model][key] == pytest.approx(value, abs=emps["TOLERANCES"][model][key]), key


def test_baseline_numbers(results):
    """The README's checks, as measured: linear ~17 % and Fv ~411, Coulomb ~4.08 %, asymmetric 3.11 %, and the
    open-loop simulation of the test record ~18 mm (linear) and ~8 mm (Coulomb)."""
    linear, coulomb, asym = results["linear"], results["coulomb"], results["asymmetric"]
    assert linear["Fc"] == 0.0 and asym["offset"] == 0.0
    assert linear["force_error_pct"] > 4 * coulomb["force_error_pct"]
    assert coulomb["force_error_pct"] > asym["force_error_pct"]
    assert linear["simulation_rms_mm"] > 2 * coulomb["simulation_rms_mm"]
    assert linear["Fv"] > 2 * coulomb["Fv"]  # the viscous term soaks up the missing Coulomb friction
    assert linear["M"] == pytest.approx(coulomb["M"], rel=0.01)


def test_model_and_coefficients_give_the_same_scores(emps, records, results):
    train, test = records
    coefficients = {k: results["coulomb"][k] for k in ("M", "Fv", "Fc", "offset")}
    model = emps["rigid_model"](coefficients, dt=train.dt)
    assert model.terms == ("qm_dot", "force", "1", "sign(qm_dot)")
    assert emps["force_error_pct"](model, train) == pytest.approx(emps["force_error_pct"](coefficients, train),
                                                                  rel=1e-9)
    linear = emps["rigid_model"]({k: results["linear"][k] for k in ("M", "Fv", "Fc", "offset")}, dt=train.dt)
    assert linear.is_linear and linear.terms == ("qm_dot", "force", "1")
    a, b, c = linear.linear_matrices()
    assert a[0, 1] == 1.0 and b[1, 0] == pytest.approx(1 / results["linear"]["M"])
    assert emps["simulation_error_mm"](linear, test) == pytest.approx(results["linear"]["simulation_rms_mm"])


def test_inverse_force_of_the_linear_model_reproduces_the_fit(emps, records, results):
    train, _ = records
    coefficients = {k: results["linear"][k] for k in ("M", "Fv", "Fc", "offset")}
    tau = emps["predicted_force"](coefficients, train)
    q, qd, qdd = emps["_bandpass"](train)
    expected = coefficients["M"] * qdd + coefficients["Fv"] * qd + coefficients["offset"]
    np.testing.assert_allclose(tau, expected, rtol=1e-9, atol=1e-9)


@pytest.fixture(scope="module")
def script(emps, tmp_path_factory):
    """The example run once as a user runs it, ``--json --report``: what it printed, returned and wrote. Its
    diagnosis of the linear model is the one the diagnosis tests below check (computed once: a minute)."""
    html = tmp_path_factory.mktemp("emps") / "emps.html"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        report = emps["main"](["--data", str(DATA), "--json", "--report", str(html), "--targets", "report"])
    return json.loads(out.getvalue()), report, html


#: Why the example's diagnosis targets are not met. Measured 2026-11-29 with the smoothing velocity held at the
#: record's reversal speed step (issue 39): Coulomb friction (Fc 22.6 N) then the asymmetry; force error 17.0 ->
#: 5.8 -> 4.6 % (target 4.1 %; the published Coulomb model 4.03 %), open-loop RMS on the test record 18.6 -> 6.5 ->
#: 7.2 mm (target 8 mm: met). The smoother switch leaves force near zero speed unexplained.
EMPS_TARGETS_MISSED = ("issue 39: the example's train force-error target is missed: 4.6 % (target 4.1; 5.8 % after "
                       "Coulomb friction); the test-record RMS target is met: 7.2 mm")


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=EMPS_TARGETS_MISSED)
def test_script_prints_json_and_asserts_its_numbers(emps, script):
    printed, report, html = script
    assert printed["before"]["Fv"] == pytest.approx(report["before"]["Fv"])
    assert [e["name"] for e in printed["effects"]][:2] == ["coulomb_friction", "viscous_asymmetry"]
    assert printed["after"]["force_error_pct"] <= 4.1 < printed["before"]["force_error_pct"]
    assert all(printed["targets"].values()), printed["targets"]
    assert "coulomb_friction" in html.read_text()
    assert set(printed["models"]) == {"linear", "coulomb", "asymmetric"}
    assert emps["check_reference"](printed["models"]) == []
    broken = json.loads(json.dumps(printed["models"]))
    broken["coulomb"]["force_error_pct"] = 9.0
    assert emps["check_reference"](broken) == ["coulomb force_error_pct: 9, reference 4.08 +- 0.15"]


@pytest.fixture(scope="module")
def diagnosed(script):
    """The script's diagnosis of the linear rigid model on the train record (diagnose_emps): the effects found
    (as DiagnosisReport.to_dict writes them), the model's figures after each, and the linear model's."""
    _, report, _ = script
    return report, report["steps"], report["before"]


@pytest.mark.slow
def test_diagnosis_names_coulomb_then_asymmetry(emps, diagnosed):
    report, steps, before = diagnosed
    effects = report["effects"]
    assert [e["name"] for e in effects][:2] == ["coulomb_friction", "viscous_asymmetry"], report["message"]
    assert effects[0]["attached_to"] == "qm_dot"
    # the asymmetry has the published sign and size (Fv+ - Fv- = -73.7 N s/m)
    assert steps[1]["Fv_asym"] == pytest.approx(-73.7 / 2, rel=0.25)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue 39: Fc 22.63 N, 11.0 % above the published 20.39 (the inverse model's "
                   "least squares): the smoothing velocity is held at the record's reversal speed step, 1.46 mm/s, "
                   "where a free fit slid below it to a value that depended on the BLAS kernel (21.7 N on one)")
def test_diagnosis_gives_the_published_coulomb_friction(emps, diagnosed):
    report, _, _ = diagnosed
    assert report["effects"][0]["parameters"]["Fc"] == pytest.approx(20.39, rel=0.10)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=EMPS_TARGETS_MISSED)
def test_diagnosis_beats_the_reference_force_error(emps, diagnosed):
    report, steps, before = diagnosed
    after = steps[-1]
    assert before["force_error_pct"] == pytest.approx(17.0, abs=0.5)
    assert after["force_error_pct"] <= emps["TARGETS"]["force_error_pct"]
    assert after["force_error_pct"] < emps["REFERENCE"]["coulomb"]["force_error_pct"]  # 4.08 %
    assert after["cross_test_force_error_pct"] < before["cross_test_force_error_pct"] / 2
    # the open-loop simulation of the validation record: from the linear model's 18.6 mm to 8 mm or less (the
    # published asymmetric model: 13.1 mm), and better than the linear model after each step
    assert before["simulation_rms_mm"] == pytest.approx(18.0, abs=1.0)
    assert after["simulation_rms_mm"] <= emps["TARGETS"]["simulation_rms_mm"]
    for step in steps:
        assert step["simulation_rms_mm"] < 0.75 * before["simulation_rms_mm"]


def test_example_script_refuses_a_missing_folder(tmp_path):
    import subprocess
    import sys

    result = subprocess.run([sys.executable, str(ROOT / "examples" / "emps.py"), "--data", str(tmp_path)],
                            capture_output=True, text=True)
    assert result.returncode != 0
    assert "Traceback" not in result.stderr and "emps:" in result.stderr


#: Issue 39: the default path's model misses the test-record target. Measured 2026-11-29 (the same under OpenBLAS
#: Haswell, SkylakeX and Sandybridge, 1 and 2 threads): Coulomb friction 20.58 N then the asymmetry, test record
#: 12.7 mm RMS (train 4.9 mm). The 5.1 mm one kernel reached before came with a cogging the others did not name.
TEST_RECORD_MISSED = ("issue 39: the default path's model simulates the test record at 12.7 mm (target 8; the "
                      "reference's asymmetric model 13.1, its Coulomb model 8.3)")


#: The issue's default path, also the README tour's EMPS line (tests/test_readme_tour.py checks they agree).
DEFAULT_PATH_OPTIONS = ("--state", "qm,qm_dot", "--derive", "qm", "--input", "force=35.15*vir")


@pytest.fixture(scope="module")
def default_path(tmp_path_factory):
    """``cosim diagnose DATA_EMPS.mat --state qm,qm_dot --derive qm --input force=35.15*vir``, nothing else: the
    effects it names (JSON) and the model it writes."""
    from click.testing import CliRunner

    from cosim.cli import main
    from cosim.identify.model import IdentifiedModel

    out = tmp_path_factory.mktemp("emps_default") / "after.json"
    result = CliRunner().invoke(main, ["diagnose", str(DATA / "DATA_EMPS.mat"), *DEFAULT_PATH_OPTIONS, "--json",
                                       "-o", str(out)])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout), IdentifiedModel.load(out)


@pytest.mark.slow
def test_default_path_names_coulomb_then_asymmetry_with_the_published_mass(default_path):
    found, model = default_path
    assert [e["name"] for e in found["effects"]][:2] == ["coulomb_friction", "viscous_asymmetry"], found["message"]
    assert found["effects"][0]["parameters"]["Fc"] == pytest.approx(20.4, rel=0.10)
    row = model.coef[model.states.index("qm_dot")]
    assert 1.0 / row[model.terms.index("force")] == pytest.approx(95.1, rel=0.05)  # the mass
    assert "qm" not in model.terms or row[model.terms.index("qm")] == 0.0  # no spring: the axis has none
    assert "qm_dot: qm" in found["dropped_terms"]


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=TEST_RECORD_MISSED)
def test_default_path_simulates_the_test_record_within_8_mm(emps, records, default_path):
    """The issue's target (published: Coulomb model 8.27 mm, linear state-space 5.53 mm, best black box 2.64 mm).
    The default path names Coulomb friction then the asymmetry: 12.7 mm."""
    _, model = default_path
    assert emps["simulation_error_mm"](model, records[1]) <= 8.0


@pytest.mark.slow
def test_default_path_simulates_the_test_record_as_well_as_the_reference_asymmetric_model(emps, records, results,
                                                                                         default_path):
    """The issue asks for the asymmetry to be named and for <= 8 mm on the test record; the reference's own
    asymmetric model (IDIM-LS fitted here: Fv+ 166.8, Fv- 240.2 N s/m, published 166.7 and 240.4) simulates the
    test record at 13.1 mm, its Coulomb model at 8.3 mm. The asymmetry lowers the train error and raises the
    test record's for the reference too. The default path's model (Coulomb friction and the asymmetry) is about as
    good on the test record (12.7 mm against 13.1) and worse on the train record (4.9 mm against 3.5, within
    1.5 times); its asymmetry, d = -40.1 N s/m, is 9 % above the reference's -36.9."""
    _, model = default_path
    reference = results["asymmetric"]
    assert reference["simulation_rms_mm"] > 8.0  # the target the issue sets, missed by the reference itself
    assert emps["simulation_error_mm"](model, records[1]) <= reference["simulation_rms_mm"] + 0.5
    assert emps["simulation_error_mm"](model, records[0]) <= 1.5 * reference["simulation_rms_mm_train"]
    d = model.coef[model.states.index("qm_dot")][model.terms.index("abs(qm_dot)")] \
        / model.coef[model.states.index("qm_dot")][model.terms.index("force")]
    assert -d == pytest.approx((reference["Fv+"] - reference["Fv-"]) / 2, rel=0.25)  # N s/m, sign: force opposes


def _blas_kernel() -> str | None:
    """The OpenBLAS kernel numpy runs on here (None without OpenBLAS)."""
    from threadpoolctl import threadpool_info

    return next((str(i.get("architecture")) for i in threadpool_info() if i.get("internal_api") == "openblas"),
                None)


@pytest.mark.slow
@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="OpenBLAS's x86-64 kernels")
def test_default_path_gives_the_same_answer_under_another_blas_kernel(default_path, tmp_path):
    """Issue 39: the effects, their order and their parameters (1e-6 relative) do not depend on the BLAS kernel.
    The default path runs again in a subprocess on another OpenBLAS kernel than this process's (Sandybridge, or
    Haswell where this process runs Sandybridge) with one BLAS thread, and must name the same."""
    found, _ = default_path
    here = (_blas_kernel() or "").lower()
    other = "Haswell" if here == "sandybridge" else "Sandybridge"
    env = {**os.environ, "OPENBLAS_CORETYPE": other, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    run = subprocess.run([sys.executable, "-c", "from cosim.cli import main; main()", "diagnose",
                          str(DATA / "DATA_EMPS.mat"), *DEFAULT_PATH_OPTIONS, "--json"],
                         capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    again = json.loads(run.stdout)
    assert [(e["name"], e["attached_to"]) for e in again["effects"]] == \
        [(e["name"], e["attached_to"]) for e in found["effects"]], (here, other, again["message"])
    for a, b in zip(found["effects"], again["effects"], strict=True):
        for name, value in a["parameters"].items():
            assert b["parameters"][name] == pytest.approx(value, rel=1e-6, abs=1e-12), (here, other, name)
