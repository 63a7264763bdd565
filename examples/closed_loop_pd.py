"""A PD position loop on the load angle of the bundled servo FMU, stepped from Python at 2257 Hz.

The law is Tm = Kp*(ref - theta_L) - Kd*omega_m, limited to the drive's rated torque, with Coulomb friction
switched on in the FMU. The script asserts that the load reaches the reference (within the friction-induced
offset Fc/Kp) and prints the figures.

Run:  python examples/closed_loop_pd.py [--json]
"""

from __future__ import annotations

import json
import sys

import numpy as np

from cosim import FmuPlant, build_fmu

DT = 1 / 2257
REF = 0.01          # rad: a 36 arcmin step of the load
KP, KD = 2.0e5, 2.5e4
TMAX = 5000.0       # N m, the drive's rated peak torque (the FMU's declared max of Tm)
FC = 100.0          # N m of Coulomb friction on the motor


def main() -> dict:
    with FmuPlant(build_fmu(), dt=DT, parameters={"Fc": FC}) as plant:
        y = plant.read_outputs()
        theta_l, torque = [], []
        for _ in range(3 * 2257):
            tm = float(np.clip(KP * (REF - y[2]) - KD * y[1], -TMAX, TMAX))
            y = plant.step([tm, 0.0])
            theta_l.append(y[2])
            torque.append(tm)
    theta_l = np.array(theta_l)
    final_error = REF - theta_l[-1]
    settled = np.flatnonzero(np.abs(theta_l - REF) > 0.02 * REF)
    result = {
        "final_error_rad": float(final_error),
        "friction_offset_bound_rad": FC / KP,
        "settling_time_2pct_s": float((settled[-1] + 1) * DT) if settled.size else 0.0,
        "overshoot_pct": float(100 * max(0.0, theta_l.max() - REF) / REF),
        "peak_torque": float(np.max(np.abs(torque))),
    }
    # a P law leaves at most Fc/Kp of offset against Coulomb friction
    assert abs(final_error) <= 1.05 * FC / KP, result
    assert result["settling_time_2pct_s"] < 1.0 and result["overshoot_pct"] < 5.0, result
    return result


if __name__ == "__main__":
    figures = main()
    print(json.dumps(figures) if "--json" in sys.argv else "\n".join(f"{k}: {v:.6g}" for k, v in figures.items()))
