"""Which states are derived velocities (``cosim.data.derived_velocities``): the diagnosis fits the others only,
also when ``--derive VEL=POS`` names the velocity."""

from __future__ import annotations

import numpy as np
import pytest

from cosim.cli._data_options import derive_option, read_records
from cosim.data import Trajectory
from cosim.data.datafile import derived_velocities
from cosim.diagnose._free_run import measured_states
from cosim.identify.model import IdentifiedModel


@pytest.fixture
def csv(tmp_path):
    t = np.arange(400) * 0.01
    path = tmp_path / "run.csv"
    np.savetxt(path, np.column_stack([t, np.sin(t), np.cos(3 * t)]), delimiter=",", header="time,theta,u",
               comments="")
    return path


@pytest.mark.parametrize("derive, velocity", [("theta", "theta_dot"), ("omega=theta", "omega")])
def test_a_derived_velocity_is_no_measurement_under_either_name(csv, derive, velocity):
    [record] = read_records([str(csv)], states=["theta", velocity], inputs=["u"], derive=derive_option(derive),
                            time=None)
    assert derived_velocities(record) == {velocity: "theta"}
    model = IdentifiedModel(states=("theta", velocity), inputs=("u",), terms=(velocity, "u"),
                            coef=np.array([[1.0, 0.0], [0.0, 1.0]]))
    assert measured_states(model, [record], None) == ("theta",)
    # a noise level given for it makes it a measurement again
    assert measured_states(model, [record], {velocity: 0.01}) is None
    np.testing.assert_allclose(record[velocity][50:350], np.cos(record.time[50:350]), atol=1e-3)


def test_a_record_that_derived_nothing_has_no_derived_velocity():
    t = np.arange(5) * 0.1
    assert derived_velocities(Trajectory.from_arrays(t, {"x": t})) == {}
