"""`cosim identify --library polynomial --degree 3` on the Reference FMU VanDerPol finds its equations.

The Modelica Association's VanDerPol (``x0' = x1``, ``x1' = mu (1 - x0^2) x1 - x0``, mu = 1) integrates with
forward Euler at the 0.01 s communication step, so its samples are Euler's, not the continuous flow's. With the
default options (threshold "auto", output-error refinement) and a cubic library the identification must keep
the four true terms and no other, each coefficient within 2 % of the equations', and the model's free run
from an initial state the record never visited must follow the FMU within 1 % NRMSE over 20 s (the model is
simulated by cosim, RK4; the FMU by its own Euler: the refined coefficients absorb most of the difference). Both
FMI 2.0 and FMI 3.0 builds; everything through the CLI on a CSV written by `cosim simulate`.

The 1 % holds from states near the limit cycle; from states far from it a continuous four-term model cannot
carry the Euler step's own dynamics: 1.2-2.7 % from (0.5, 0.5), (0.1, 0), (3, 0) or (0, -3), whatever record
it is trained on (the exact coefficients give 6-12 % everywhere).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

sys.path.insert(0, str(Path(__file__).parent))
from reference_fmus import reference_fmus  # noqa: E402

import cosim  # noqa: E402
from cosim.cli import main  # noqa: E402
from cosim.identify.metrics import nrmse_fit_pct  # noqa: E402
from cosim.identify.model import IdentifiedModel  # noqa: E402

TRUE = {"x0": {"x1": 1.0}, "x1": {"x0": -1.0, "x1": 1.0, "x0**2*x1": -1.0}}
DT = 0.01


def cli(*args: str) -> str:
    result = CliRunner().invoke(main, list(args), catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return result.stdout


@pytest.mark.parametrize("version", [2, 3])
def test_default_identify_finds_the_vanderpol_equations(tmp_path, version):
    fmu = reference_fmus(version)["VanDerPol"]
    data, model_file = tmp_path / "vdp.csv", tmp_path / "model.json"
    cli("simulate", str(fmu), "--duration", "20", "--dt", str(DT), "--start", "x0=2", "--start", "x1=0",
        "-o", str(data))
    out = json.loads(cli("identify", str(data), "--state", "x0,x1", "--library", "polynomial", "--degree", "3",
                         "-o", str(model_file), "--json"))
    model = IdentifiedModel.load(model_file)
    kept = {(s, t): float(model.coef[i, j]) for i, s in enumerate(model.states)
            for j, t in enumerate(model.terms) if model.coef[i, j] != 0.0}
    assert set(kept) == {(s, t) for s, row in TRUE.items() for t in row}, out["equations"]
    for (s, t), value in kept.items():
        assert abs(value - TRUE[s][t]) <= 0.02 * abs(TRUE[s][t]), (s, t, value)

    start = {"x0": -1.0, "x1": 1.0}  # inside the limit cycle, a phase the record (from (2, 0)) starts nowhere near
    fmu_run = cosim.simulate(fmu, duration=20.0, dt=DT, start=start)
    measured = np.column_stack([np.asarray(fmu_run[s]) for s in model.states])
    sim = model.simulate([start[s] for s in model.states], n_steps=len(measured) - 1, dt=DT)
    assert sim.status == "ok"
    nrmse = 100.0 - np.asarray(nrmse_fit_pct(measured, sim.states))
    assert np.all(nrmse < 1.0), nrmse
