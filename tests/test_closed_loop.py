"""The closed loop against the real bundled FMU: results, the model run, timing, and what happens on failure."""

import numpy as np
import pytest
from loop_fixtures import DT, StateFeedback, true_model

from controllers.base import DesignModel
from cosim.errors import InvalidSettingError, UnknownVariableError
from cosim.loop.closed_loop import ModelPlant, closed_loop
from cosim.plant.fmu_plant import FmuPlant
from cosim.study.paper import STATES


def test_tracks_a_step_and_matches_the_design_model(fmu):
    res = closed_loop(StateFeedback(), fmu, duration=1.5, reference=lambda t: 0.01 * (t >= 0.1))
    assert res.status == "completed" and not res.events
    assert len(res.fmu) == round(1.5 / DT) + 1 and res.model is not None
    assert res.fmu["theta_L"][-1] == pytest.approx(0.01, rel=1e-3)
    assert res.metrics["settling_time"] < 1.0
    # the FMU (RK4, 10 substeps) and the exact ZOH model run the same closed loop: they agree to ~1e-7
    assert res.metrics["model_discrepancy_pct"] < 1e-4
    assert res.metrics["constraint_violations"] == 0
    assert res.metrics["realtime_factor"] > 1.0
    assert np.all(res.compute_time > 0)
    summary = res.to_dict()
    assert summary["status"] == "completed" and summary["solve_time_us"]["p99"] > 0


def test_disturbance_and_effect_reach_the_fmu_only_where_asked(fmu):
    res = closed_loop(StateFeedback(), fmu, duration=1.0, reference=0.0,
                      disturbance={"TL": lambda t: 800.0 * (t >= 0.5)}, parameters={"Fc": 50.0})
    tl = res.fmu["TL"]
    assert np.all(tl[res.fmu.time < 0.5 - 1e-9] == 0) and np.all(tl[res.fmu.time >= 0.5] == 800.0)
    assert res.metrics["peak_error"] > 1e-6  # the load torque moved the load
    # the design model has TL as an input: it saw the same disturbance, but no friction
    assert res.model["TL"][-1] == 800.0


def test_controller_that_raises_stops_the_loop_and_keeps_the_trajectory(fmu):
    res = closed_loop(StateFeedback(fail_at=0.25), fmu, duration=1.0, reference=0.01, model=None)
    assert res.status == "stopped"
    assert res.stopped_at == pytest.approx(0.25, abs=DT)
    assert len(res.fmu) == round(0.25 / DT) + 1 or abs(res.fmu.time[-1] - 0.25) <= DT
    event = res.events[-1]
    assert event["kind"] == "controller_error" and "solver exploded" in event["message"]
    assert event["time"] == pytest.approx(0.25, abs=DT)
    held = closed_loop(StateFeedback(fail_at=0.25), fmu, duration=0.5, reference=0.01, model=None,
                       on_controller_error="hold")
    failing = np.count_nonzero(held.fmu.time[:-1] >= 0.25)
    assert held.status == "completed" and len(held.events) == 1
    assert f"{failing} calls failed" in held.events[0]["message"]
    assert np.all(held.fmu["Tm"][held.fmu.time >= 0.25] == held.fmu["Tm"][-failing - 2])  # the last good input


def test_non_finite_controller_output_stops_before_reaching_the_plant(fmu):
    res = closed_loop(StateFeedback(nan_at=0.1), fmu, duration=0.5, reference=0.01, model=None)
    assert res.status == "stopped" and "non-finite" in res.events[-1]["message"]
    assert np.all(np.isfinite(res.fmu["theta_L"]))


def test_plant_failure_mid_run_is_reported_with_its_time(fmu):
    res = closed_loop(StateFeedback(), fmu, duration=5.0, reference=0.0, parameters={"Bm": -2e5},
                      start={"omega_m": 1.0}, model=None)
    assert res.status == "stopped"
    assert res.events[-1]["kind"] == "plant_error" and "diverged" in res.events[-1]["message"]
    assert 0 < res.stopped_at < 5.0
    assert np.all(np.isfinite(res.fmu["theta_m"]))


def test_deadline_misses_are_counted(fmu):
    res = closed_loop(StateFeedback(slow_every=50), fmu, duration=0.2, reference=0.0, model=None)
    n = round(0.2 / DT)
    assert res.metrics["deadline_misses"] >= n // 50
    assert res.metrics["deadline_miss_rate"] == pytest.approx(res.metrics["deadline_misses"] / n)


def test_input_limit_violations_are_counted(fmu):
    res = closed_loop(StateFeedback(overshoot_limits=True), fmu, duration=0.3, reference=0.05, model=None)
    over = np.count_nonzero(np.abs(res.fmu["Tm"][:-1]) > 5000)
    assert over > 0 and res.metrics["constraint_violations"] == over


def test_open_plant_must_step_at_the_controller_rate(fmu):
    with FmuPlant(fmu, dt=1e-3) as plant, pytest.raises(InvalidSettingError, match="controller's dt"):
        closed_loop(StateFeedback(), plant, duration=0.1)
    with FmuPlant(fmu, dt=DT) as plant:  # an open plant is reset and can be reused
        first = closed_loop(StateFeedback(), plant, duration=0.2, reference=0.01, model=None)
        again = closed_loop(StateFeedback(), plant, duration=0.2, reference=0.01, model=None)
    np.testing.assert_array_equal(first.fmu["theta_L"], again.fmu["theta_L"])


def test_bad_names_and_signals_are_refused(fmu):
    with pytest.raises(UnknownVariableError, match="the loop drives Tm, Tx .*has no input named 'Tx'"):
        closed_loop(StateFeedback(), fmu, duration=0.1, disturbance={"Tx": 1.0})
    with pytest.raises(InvalidSettingError, match="driven by the controller"):
        closed_loop(StateFeedback(), fmu, duration=0.1, disturbance={"Tm": 1.0})
    with pytest.raises(InvalidSettingError, match="samples"):
        closed_loop(StateFeedback(), fmu, duration=0.1, reference=np.zeros(7))
    with pytest.raises(InvalidSettingError, match="duration"):
        closed_loop(StateFeedback(), fmu, duration=-1)


def test_model_plant_steps_like_the_discrete_model():
    model = DesignModel.from_statespace(true_model(), dt=DT)
    plant = ModelPlant(model, dt=DT, inputs=["Tm", "TL"], outputs=list(STATES), x0={"theta_L": 0.1})
    y = plant.step([100.0, 0.0])
    x0 = np.array([0.0, 0.0, 0.1, 0.0])
    np.testing.assert_allclose(y, model.A @ x0 + model.B @ [100.0, 0.0], rtol=1e-12)


def test_model_run_notes_what_the_model_cannot_do(fmu):
    partial = StateFeedback()
    sys = true_model()
    partial.design_model = DesignModel.from_statespace(sys[[0, 2], :], dt=DT)  # positions only
    res = closed_loop(partial, fmu, duration=0.2, reference=0.01)
    assert res.model is None and any("lacks a measured output" in note for note in res.notes)
    no_tl = StateFeedback()
    no_tl.design_model = DesignModel.from_statespace(sys[:, 0], dt=DT)  # no TL input
    res = closed_loop(no_tl, fmu, duration=0.2, reference=0.01, disturbance={"TL": 100.0})
    assert res.model is not None and any("no input TL" in note for note in res.notes)
    assert res.metrics["model_discrepancy_rms"] > 0
