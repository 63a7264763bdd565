"""Algebraic loops between FMUs (issue 40): two test FMUs with direct feedthrough both ways
(tests/fmus/loop/loop_a, loop_b; tests/test_loop_fmus.py builds them), solved at each communication point where they can
save and restore their state, refused in one line naming the loop's connectors where one cannot."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from test_loop_fmus import loop_fmus

from cosim.errors import InvalidSettingError
from cosim.plant.system_plant import SystemPlant
from cosim.plant.system_structure import System
from cosim.plant.system_wiring import wire

KA, KB, C, W = 0.5, -0.8, 0.3, 2.0


@pytest.mark.parametrize(("a_version", "b_version"), [("2.0", "2.0"), ("3.0", "3.0"), ("2.0", "3.0")])
def test_a_loop_is_solved_to_1e_10_at_every_communication_point(a_version, b_version):
    """y_a = ka*(kb*y_a + c*sin(w t)) + x, so y_a = (ka*c*sin(w t) + x)/(1 - ka*kb): at the start (consistent
    initialisation) and after every step, FMI 2 and 3 mixed."""
    system = System({"a": loop_fmus(a_version)["loop_a"], "b": loop_fmus(b_version)["loop_b"]},
                    [("a.y", "b.u"), ("b.y", "a.u")])
    assert wire(system).loops == (("a.y", "b.u", "b.y", "a.u"),)
    with SystemPlant(system, dt=0.01, outputs=["a.y", "b.y", "a.x"]) as plant:
        assert plant.engine == "python" and "algebraic loop" in plant.engine_note
        first = plant.read_outputs()
        y = np.vstack([first, plant.run(np.zeros((100, 0)))])
    t = 0.01 * np.arange(101)
    expected = (KA * C * np.sin(W * t) + y[:, 2]) / (1 - KA * KB)
    assert first[0] == pytest.approx(1.0 / 1.4, abs=1e-12)  # x0 = 1 at t = 0
    assert np.max(np.abs(y[:, 0] - expected)) < 1e-10
    assert np.max(np.abs(y[:, 1] - (KB * y[:, 0] + C * np.sin(W * t)))) < 1e-10
    # the state between: x' = (u - x)/tau with u = y_b held over each step (Gauss-Seidel, extrapolated), so x follows
    # the loop's solution: x' = (kb*y_a + c sin(wt) - x)/tau; checked against scipy to the coupling's order
    from scipy.integrate import solve_ivp

    def rhs(s, x):
        ya = (KA * C * np.sin(W * s) + x[0]) / (1 - KA * KB)
        return [(KB * ya + C * np.sin(W * s) - x[0]) / 0.2]

    exact = solve_ivp(rhs, (0, 1), [1.0], t_eval=t, rtol=1e-12, atol=1e-12).y[0]
    error = np.abs(y[:, 2] - exact)  # the first step extrapolates from one point only (order 0): 1.2e-3 there
    assert np.max(error) < 2e-3 and np.max(error[50:]) < 5e-5


def test_a_loop_through_an_fmu_that_cannot_save_its_state_is_refused_in_one_line(tmp_path):
    fmus = loop_fmus("2.0")
    system = System({"a": fmus["loop_a"], "b": fmus["loop_b_nostate"]}, [("a.y", "b.u"), ("b.y", "a.u")])
    with pytest.raises(InvalidSettingError, match=r"algebraic loop through direct feedthrough: a.y -> b.u -> b.y "
                                                  r"-> a.u -> a.y; component b \(loop_b_nostate.fmu\) cannot save"):
        SystemPlant(system, dt=0.01)
    # the same from the command line: exit 2, one line, nothing written
    (tmp_path / "SystemStructure.ssd").write_text(f"""<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
  xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" version="1.0" name="loop">
 <ssd:System name="loop">
  <ssd:Elements>
   <ssd:Component name="a" source="{fmus['loop_a']}"/>
   <ssd:Component name="b" source="{fmus['loop_b_nostate']}"/>
  </ssd:Elements>
  <ssd:Connections>
   <ssd:Connection startElement="a" startConnector="y" endElement="b" endConnector="u"/>
   <ssd:Connection startElement="b" startConnector="y" endElement="a" endConnector="u"/>
  </ssd:Connections>
 </ssd:System>
</ssd:SystemStructureDescription>""")
    run = [sys.executable, "-m", "cosim.cli"]
    proc = subprocess.run([*run, "simulate", "SystemStructure.ssd", "--duration", "1", "--dt", "0.01", "-o", "x.csv"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "a.y -> b.u -> b.y -> a.u -> a.y" in proc.stderr and not (tmp_path / "x.csv").exists()
    info = subprocess.run([*run, "fmu", "info", "SystemStructure.ssd", "--json"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    assert json.loads(info.stdout)["loops"] == [["a.y", "b.u", "b.y", "a.u"]]


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_connected_fmus_initialise_together(version):
    """FMI's consistent initialisation: loop_a with ``steady=1`` starts its state at its input's value as it stands
    when it leaves Initialization Mode. Its input is loop_b's output, which the master gives it there: the state
    starts at b's initial output (kb*2 + c*sin(0), b's free input started at 2), not at the input's start value 0
    (where the connected values were set only after the FMUs had left Initialization Mode, it did)."""
    fmus = loop_fmus(version)
    system = System({"a": fmus["loop_a"], "b": fmus["loop_b"]}, [("b.y", "a.u")])
    with SystemPlant(system, dt=0.01, outputs=["a.x", "b.y"], parameters={"a.steady": 1.0, "b.c": 0.3},
                     start={"b.u": 2.0}) as plant:
        x0, yb0 = plant.get(["a.x", "b.y"])
        assert yb0 == pytest.approx(KB * 2.0) and x0 == pytest.approx(yb0)  # b.y(0) = kb*2 + c*sin(0)
        plant.reset()
        assert plant.get(["a.x"])[0] == pytest.approx(KB * 2.0)  # again after a reset
    with SystemPlant(system, dt=0.01, outputs=["a.x"], parameters={"a.steady": 0.0}) as plant:
        assert plant.get(["a.x"])[0] == 1.0  # its start value x0, without steady
