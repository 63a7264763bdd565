"""Every HTML report opens with a summary box (cosim.report.summary_box): the plant, the data, what was found with
its standard errors, the error before and after, the verdicts and the time, each where it applies, right under the
title, in a file that needs nothing beside it. The demo's, the diagnosis's and the reproduced study's boxes are
checked on their own runs in test_demo.py, test_figures.py and test_reproduce.py; the CLI's in test_readme_tour.py.
"""

import importlib.util
import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner
from loop_fixtures import StateFeedback
from matplotlib.figure import Figure
from summary_checks import summary_rows

from controllers.pid import PID
from cosim.cli import main
from cosim.loop.validation import validate
from cosim.loop.validation_report import write_validation_report
from cosim.report import Report, duration_text, summary_box, value_with_error

SPECS = ["settling_time<=1.0", "overshoot<=10%", "steady_state_error<=2e-5", "input_limit<=5000"]


def test_the_box_shows_what_applies_and_comes_first_whenever_it_is_added():
    report = Report("job", subtitle="what it did")
    report.add_table("A table", [{"a": 1.0}])
    report.add_figure("A figure", Figure(figsize=(2, 1)))
    report.add_summary(plant="servo.fmu", data="data.csv: 4515 samples",
                       effects=[{"name": "coulomb_friction", "attached_to": "omega_m", "parameters": {"Fc": 99.3412},
                                 "uncertainty": {"Fc": 0.6213}, "units": {"Fc": "N m"}, "truth": {"Fc": 100.0},
                                 "meaning": "Coulomb friction"}],
                       errors={"before": {"x": 6.41, "v": None}, "after": {"x": 0.158, "v": 1.0}},
                       error_label="free-run NRMSE %",
                       verdicts=[{"label": "PID", "passed": True, "scenarios": {"step": True, "load": True}},
                                 {"label": "MPC", "passed": False, "scenarios": {"step": True, "load": False},
                                  "note": "deadline missed"}],
                       robustness={"samples": 8, "pass_rate": 0.75, "passed": False, "text": "8 plants"},
                       seconds=83.0, timing={"diagnosis": 6.9})
    rows = summary_rows(report.render())
    assert rows[""] == "Summary 2 of 3 FAILED"  # the MPC and the pass rate
    assert list(rows)[1:] == ["Plant", "Data", "Found", "Error", "Verdicts", "Robustness", "Time"]
    assert rows["Found"].startswith("coulomb_friction on omega_m: Fc = 99.34 ± 0.62 N m (true 100 N m)")
    assert rows["Error"] == "free-run NRMSE % x v before 6.41 n/a after 0.158 1"
    assert rows["Verdicts"] == "step load verdict PID PASSED PASSED PASSED MPC PASSED FAILED FAILED deadline missed"
    assert rows["Robustness"] == "pass rate 75.0% 8 plants" and rows["Time"] == "1 min 23 s (diagnosis 6.9 s)"
    # only what applies: a diagnosis that found nothing says why, and has no verdict row
    rows = summary_rows(Report("d").render().replace("</h1>", "</h1>" + summary_box(
        effects=[], no_effect="the residual is white", seconds=0.5)))
    assert rows == {"": "Summary", "Found": "no effect found: the residual is white", "Time": "0.5 s"}


def test_numbers_read_as_a_person_writes_them():
    assert value_with_error(0.0010234, 3.1e-5, "rad/s") == "0.001023 ± 0.000031 rad/s"
    assert value_with_error(1.5, float("nan")) == "1.5" and value_with_error(12345.0, 151.0) == "12340 ± 150"
    assert [duration_text(s) for s in (0.82, 22.34, 192.0, 3900.0)] == ["0.82 s", "22.3 s", "3 min 12 s",
                                                                           "1 h 05 min"]


def test_the_validation_report_opens_with_the_verdict_per_scenario(fmu, tmp_path):
    # the fixture controller tracks the step but keeps an offset under the load torque: one passes, one fails
    verdict = validate(fmu, StateFeedback(), ["step:amp=0.01,duration=1", "disturbance:amp=500,at=0.3,duration=1"],
                       SPECS)
    path, _ = write_validation_report(verdict, tmp_path / "v.html", controller=StateFeedback(), fmu=fmu,
                                      parameters={"Bm": 50.0}, seconds=2.25)
    rows = summary_rows(path)
    assert rows[""] == "Summary FAILED"
    assert rows["Plant"] == "two_mass_servo.fmu (two_mass_servo, FMI 2.0, co-simulation); set: Bm=50"
    assert rows["Controller"].startswith("test-state-feedback, dt 0.443 ms (2257 Hz); inputs Tm;")
    step, load = (s.name for s in verdict.scenarios)
    assert rows["Verdicts"] == f"{step} {load} verdict test-state-feedback PASSED FAILED FAILED"
    assert "steady_state_error" in rows["Why it failed"] and rows["Time"] == "2.2 s"
    assert "Found" not in rows and "Error" not in rows  # a validation finds no effect


@pytest.fixture(scope="module")
def pid_file(tmp_path_factory):
    pid = PID(kp=1.5e4, ki=1.3e4, kd=6.4e3, tf=0.022, b=0.33, dt=1e-3, inputs="Tm", outputs="theta_L",
              u_min=-5000, u_max=5000)
    return pid.save(tmp_path_factory.mktemp("pid") / "pid.json")


def test_cosim_validate_report_names_the_fmu_the_settings_and_the_time(pid_file, tmp_path):
    result = CliRunner().invoke(main, ["validate", "bundled", str(pid_file), "--scenario", "step:amp=0.01,duration=1",
                                       "--set", "Fc=20", "--spec", "input_limit<=5000", "--json", "--report",
                                       str(tmp_path / "v.html")])
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["passed"] is True
    rows = summary_rows(tmp_path / "v.html")
    assert rows[""] == "Summary PASSED" and rows["Plant"].endswith("co-simulation); set: Fc=20")
    assert rows["Verdicts"].endswith("pid PASSED PASSED") and rows["Time"].endswith(" s")


def test_the_readme_shows_the_top_of_every_report_and_the_script_shoots_down_to_the_first_section():
    root = Path(__file__).resolve().parents[1]
    shown = re.findall(r"\(docs/screenshots/([\w.]+\.png)\)", (root / "README.md").read_text(encoding="utf-8"))
    assert {"report_top.png", "diagnosis_top.png", "validation_top.png", "reproduce_top.png"} <= set(shown)
    for name in shown:
        assert (root / "docs" / "screenshots" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    spec = importlib.util.spec_from_file_location("make_screenshots", root / "docs" / "make_screenshots.py")
    shots = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(shots)
    assert {name for kind in shots.SHOTS.values() for name, *_ in kind} == set(shown)
    report = Report("job")
    report.add_table("First section", [{"a": 1}])
    report.add_summary(seconds=1.0)
    page = shots.section_page(report.render(), root, None, shots.FIRST_SECTION)
    assert "#shot-h1, #shot-h1 ~ * { display: none }" in page and '<h2 id="shot-h1">First section' in page
