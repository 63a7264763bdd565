"""The controller stage end to end: FMU data -> SINDYc model -> PID and MPC designed on it -> validated on the FMU.

The specs are the telescope specs of cosim.loop.validation without the timing ones (timing is measured in
benchmarks/, never asserted in tests): a 0.01 rad load-angle step settles into 2 % within 1 s with at most
10 % overshoot and at most 2e-5 rad (4 arcsec) steady-state error, and a 500 N m load-torque step is
rejected without offset, torque within the rated 5000 N m, with and without Coulomb friction in the FMU.
"""

import pytest

from controllers.base import controller_from_json
from controllers.mpc import MPC
from controllers.pid import tune_pid
from cosim import simulate
from cosim.export import to_statespace
from cosim.identify.sindyc import SINDYc
from cosim.loop.validation import disturbance_step, setpoint_step, validate
from cosim.study.cases import STUDY_SETTINGS
from cosim.study.paper import STATES, STUDY_DT

SPECS = ["settling_time<=1.0", "overshoot<=10%", "steady_state_error<=2e-5", "input_limit<=5000",
         "constraint_violations<=0"]
SCENARIOS = [setpoint_step(0.01, at=0.05, duration=2.0), disturbance_step(500.0, at=0.3, duration=2.0)]
LIMITS = {"u_min": -5000.0, "u_max": 5000.0}


@pytest.fixture(scope="module")
def identified(fmu):
    """A linear SINDYc model from 4 s of FMU data: a 1-40 Hz multisine torque from rest, 5 % measurement noise.

    (The study's protocol - a square wave from a 4 rad initial twist - leaves the torque gain 30 % low to 120 %
    high at 5 % noise: the free oscillation dwarfs the excitation. A broadband excitation from rest pins it.)
    """
    traj = simulate(fmu, {"Tm": "multisine:amp=1000,fmin=1,fmax=40"}, duration=round(4.0 / STUDY_DT) * STUDY_DT,
                    dt=STUDY_DT).with_noise(0.05, seed=1)
    model = SINDYc(**STUDY_SETTINGS).fit(traj, states=list(STATES), inputs=["Tm"]).model_
    return to_statespace(model)


@pytest.fixture(scope="module")
def controllers(identified):
    pid = tune_pid(identified, dt=STUDY_DT, input="Tm", tracked="theta_L", velocity="omega_m", **LIMITS)
    mpc = MPC(identified, dt=STUDY_DT, horizon=20, inputs=["Tm"], outputs=["theta_m", "theta_L"],
              tracked=["theta_L"], **LIMITS)
    return {"pid": pid, "mpc": mpc}


@pytest.mark.slow
@pytest.mark.parametrize("friction", [0.0, 100.0])
@pytest.mark.parametrize("kind", ["pid", "mpc"])
def test_designed_on_the_identified_model_meets_the_specs_on_the_fmu(fmu, controllers, kind, friction):
    controller = controllers[kind]
    verdict = validate(fmu, controller, SCENARIOS, SPECS, parameters={"Fc": friction})
    verdict.assert_passed()
    step, load = verdict.results
    assert step.status == load.status == "completed" and not step.events
    # the design model predicts the FMU loop closely where the FMU has no effect the model lacks
    if friction == 0.0:
        assert step.metrics["model_discrepancy_pct"] < 2.0


@pytest.mark.slow
def test_mpc_has_no_offset_under_friction_where_the_model_has_no_friction(fmu, controllers):
    verdict = validate(fmu, controllers["mpc"], setpoint_step(0.01, duration=2.0), ["steady_state_error<=1e-7"],
                       parameters={"Fc": 100.0})
    verdict.assert_passed()


def test_saved_controllers_behave_identically(fmu, controllers, tmp_path):
    for kind, controller in controllers.items():
        again = controller_from_json(controller.to_json())
        first = validate(fmu, controller, setpoint_step(0.01, duration=0.3), ["input_limit<=5000"], model=None)
        second = validate(fmu, again, setpoint_step(0.01, duration=0.3), ["input_limit<=5000"], model=None)
        assert (first.results[0].fmu["Tm"] == second.results[0].fmu["Tm"]).all(), kind


def test_infeasible_mpc_in_closed_loop_falls_back_then_stops_with_time_and_reason(fmu, identified):
    from cosim.loop.closed_loop import closed_loop

    # a hard bound on the motor speed that a 20 kN m load torque (4x the rated motor torque) must break
    mpc = MPC(identified, dt=STUDY_DT, horizon=20, inputs=["Tm"], outputs=["theta_m", "theta_L"],
              tracked=["theta_L"], state_bounds={"omega_m": (-0.05, 0.05)}, hard_state_bounds=True,
              max_fallbacks=10, **LIMITS)
    res = closed_loop(mpc, fmu, duration=0.5, reference=0.0, disturbance={"TL": lambda t: 2e4 * (t >= 0.1)})
    assert res.status == "stopped"
    infeasible = [e for e in res.events if e["kind"] == "infeasible"]
    assert len(infeasible) == 10 and all(e["time"] >= 0.1 for e in infeasible)
    stop = res.events[-1]
    assert stop["kind"] == "controller_error" and "infeasible" in stop["message"]
    assert res.stopped_at == pytest.approx(infeasible[-1]["time"] + STUDY_DT, abs=1.5 * STUDY_DT)
    assert len(res.fmu) > 0.1 / STUDY_DT  # the trajectory up to the stop is kept


@pytest.mark.slow
def test_example_script_asserts_its_own_result():
    import runpy
    from pathlib import Path

    figures = runpy.run_path(str(Path(__file__).parents[1] / "examples" / "design_and_validate.py"))["main"]()
    assert set(figures) == {"pid", "mpc"} and figures["mpc"]["settling_time_s"] <= 1.0
