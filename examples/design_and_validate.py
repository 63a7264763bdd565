"""Identify the bundled servo from FMU data, design a PID and an MPC on the model, validate both on the FMU.

The whole controller-design workflow in one script: a 1-40 Hz multisine torque from rest (5 % noise) ->
linear SINDYc model -> python-control StateSpace -> PID (derivative action from the motor speed) and MPC
(horizon 20, |Tm| <= 5000 N m, positions measured) -> closed loop against the FMU with Coulomb friction on, a
0.01 rad load-angle step and a 500 N m load-torque step, checked against the telescope specs. The script
asserts that both controllers pass and prints their figures.

Run:  python examples/design_and_validate.py [--json]
"""

from __future__ import annotations

import json
import sys

from controllers import MPC, tune_pid
from cosim import SINDYc, build_fmu, simulate, to_statespace
from cosim.loop.validation import disturbance_step, setpoint_step, validate
from cosim.study.cases import STUDY_SETTINGS
from cosim.study.paper import STATES, STUDY_DT

SPECS = ["settling_time<=1.0", "overshoot<=10%", "steady_state_error<=2e-5", "input_limit<=5000"]
SCENARIOS = [setpoint_step(0.01, duration=2.0), disturbance_step(500.0, at=0.3, duration=2.0)]


def main() -> dict:
    fmu = build_fmu()
    data = simulate(fmu, {"Tm": "multisine:amp=1000,fmin=1,fmax=40"}, duration=round(4 / STUDY_DT) * STUDY_DT,
                    dt=STUDY_DT).with_noise(0.05, seed=0)
    model = to_statespace(SINDYc(**STUDY_SETTINGS).fit(data, states=list(STATES), inputs=["Tm"]).model_)
    controllers = {
        "pid": tune_pid(model, dt=STUDY_DT, input="Tm", tracked="theta_L", velocity="omega_m", u_min=-5000,
                        u_max=5000),
        "mpc": MPC(model, dt=STUDY_DT, horizon=20, inputs=["Tm"], outputs=["theta_m", "theta_L"],
                   tracked=["theta_L"], u_min=-5000, u_max=5000),
    }
    figures = {}
    for name, controller in controllers.items():
        verdict = validate(fmu, controller, SCENARIOS, SPECS, parameters={"Fc": 100.0})
        assert verdict.passed, verdict.reasons
        step = verdict.results[0].metrics
        figures[name] = {"settling_time_s": round(step["settling_time"], 3),
                         "overshoot_pct": round(step["overshoot_pct"], 2),
                         "steady_state_error_rad": float(f"{step['steady_state_error']:.2g}"),
                         "compute_median_us": round(verdict.solve_time_us()["median"], 1)}
    return figures


if __name__ == "__main__":
    result = main()
    print(json.dumps(result, indent=1) if "--json" in sys.argv else
          "\n".join(f"{name}: {values}" for name, values in result.items()))
