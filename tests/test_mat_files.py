"""Issue 38, items 3, 4 and 6: trajectories as MATLAB ``.mat`` files, a file's matrix columns driving an FMU, and
one rule for a file's time column.

* ``cosim simulate -o run.mat`` (``Trajectory.write``) writes ``time`` and one variable per signal, names made
  MATLAB identifiers (``mass.s`` -> ``mass_s``), the real names, units, roles and meta in a char variable:
  ``scipy.io.loadmat`` reads every signal exactly, and cosim reads it all back (``Trajectory.read``,
  ``load_data``, ``--input-file``, ``cosim identify``);
* ``--input-file rig.mat --input "Tm=data[:,1]"`` drives the FMU from a matrix's column exactly as the CSV whose
  Tm it holds;
* ``time_column``: ``t`` when a file has one and no ``time``, else ``time``, for CSV, Parquet and ``.mat`` alike.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.io
from click.testing import CliRunner

from cosim.cli import main as cli
from cosim.data import Trajectory, file_variables, load_data, time_column
from cosim.data._trajectory_mat import HEADER
from cosim.errors import UnknownVariableError
from cosim.plant.build import build_fmu

SLIDING = Path(__file__).parent / "fmus" / "sliding_mass"


def run(*args: str) -> str:
    done = CliRunner().invoke(cli, list(args))
    assert done.exit_code == 0, done.output
    return done.stdout


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    """The sliding mass (FMI 3) driven by a force file, recorded by name (mass.s, der(mass.v)) as CSV and .mat."""
    folder = tmp_path_factory.mktemp("mat")
    t = np.round(np.arange(301) * 0.01, 12)
    pd.DataFrame({"t": t, "extForce": 6.0 * np.sign(np.sin(2.1 * t + 0.2))}).to_csv(folder / "force.csv", index=False)
    fmu = build_fmu(source=SLIDING, fmi_version="3.0")
    for out in ("run.csv", "run.mat"):
        run("simulate", str(fmu), "--input-file", str(folder / "force.csv"), "--record", "mass.s,mass.v,der(mass.v)",
            "-o", str(folder / out))
    return folder


def test_loadmat_reads_every_signal_exactly(runs):
    table = pd.read_csv(runs / "run.csv")  # a CSV reads back exactly (tests/test_trajectory.py)
    data = scipy.io.loadmat(runs / "run.mat")
    names = {"time": "time", "extForce": "extForce", "mass_s": "mass.s", "mass_v": "mass.v",
             "der_mass_v": "der(mass.v)"}
    assert sorted(k for k in data if not k.startswith("__")) == sorted([*names, HEADER])
    for matlab, column in names.items():
        assert data[matlab].shape == (len(table), 1) and data[matlab].dtype == np.float64, matlab
        np.testing.assert_array_equal(data[matlab][:, 0], table[column].to_numpy(), err_msg=matlab)
    header = json.loads(str(data[HEADER][0]))
    assert header["names"]["der_mass_v"] == "der(mass.v)" and header["units"]["mass.s"] == "m"
    assert header["roles"] == {"extForce": "input", "mass.s": "state", "mass.v": "state", "der(mass.v)": "output"}


def test_whole_numbers_stay_whole_and_names_stay_unique(tmp_path):
    """An FMU's integer column is written as int64; names that would meet get _2, keywords and names from a digit x."""
    big = 2**53
    traj = Trajectory.from_arrays([0.0, 1.0], {"n": [big, -3], "mass.s": [0.5, 0.25], "mass_s": [1.0, 2.0],
                                               "end": [0.0, 1.0], "2x": [3.0, 4.0]},
                                  meta={"types": {"n": "Int64"}})
    data = scipy.io.loadmat(traj.write(tmp_path / "r.mat"))
    assert data["n"].dtype == np.int64 and int(data["n"][0, 0]) == big
    assert {"mass_s", "mass_s_2", "xEnd", "x_2x"} <= set(data)
    np.testing.assert_array_equal(data["mass_s_2"][:, 0], [0.5, 0.25])
    back = Trajectory.read(tmp_path / "r.mat")
    assert back.names == traj.names and back.meta == traj.meta
    assert list(tmp_path.iterdir()) == [tmp_path / "r.mat"]  # written through a temporary file, renamed


def test_cosim_reads_its_mat_back_everywhere(runs, tmp_path):
    """Trajectory.read, load_data, data info and a replay through --input-file: the real names, units, roles."""
    csv, mat = Trajectory.read(runs / "run.csv"), Trajectory.read(runs / "run.mat")
    assert mat == csv
    loaded = load_data(runs / "run.mat", excitation=False)
    assert loaded.names == csv.names and loaded.units == csv.units and loaded.roles == csv.roles
    np.testing.assert_array_equal(loaded.values, csv.values)
    assert file_variables(runs / "run.mat") == ["time", "extForce", "mass.s", "mass.v", "der(mass.v)"]
    info = json.loads(run("data", "info", str(runs / "run.mat"), "--json"))
    assert [s["name"] for s in info["signals"]] == list(csv.names)
    fmu = build_fmu(source=SLIDING, fmi_version="3.0")
    out = run("simulate", str(fmu), "--input-file", str(runs / "run.mat"), "--record", "mass.s,mass.v,der(mass.v)",
              "-o", str(tmp_path / "again.mat"))
    assert "inputs extForce from run.mat" in out
    assert Trajectory.read(tmp_path / "again.mat").values.tolist() == csv.values.tolist()


def test_cosim_identify_reads_a_mat(fmu, tmp_path):
    """The bundled servo recorded to .mat and identified from it: the same model as from the CSV of that run."""
    args = ["--input", "Tm=multisine:amp=1000,fmin=1,fmax=40", "--duration", "1128/2257", "--dt", "1/2257"]
    run("simulate", "bundled", *args, "-o", str(tmp_path / "d.mat"))
    Trajectory.read(tmp_path / "d.mat").write(tmp_path / "d.csv")
    models = []
    for data in ("d.mat", "d.csv"):
        run("identify", str(tmp_path / data), "--state", "theta_m,omega_m,theta_L,omega_L", "--input", "Tm", "-o",
            str(tmp_path / f"{data}.json"))
        models.append(json.loads((tmp_path / f"{data}.json").read_text()))
    assert models[0]["coef"] == models[1]["coef"] and models[0]["inputs"] == ["Tm"]


def test_a_mat_matrix_column_drives_the_fmu_as_the_csv_did(fmu, tmp_path):
    """`--input-file rig.mat --input "Tm=data[:,1]"` (column 1 of the matrix `data`, 0-based) reproduces the run
    driven by the CSV whose Tm that column holds, exactly; an expression of the file's variables works alike."""
    n, dt = 1129, 1 / 2257
    t = np.arange(n) * dt
    tm = 800.0 * np.sign(np.sin(2 * np.pi * 7.0 * t)) + 200.0 * np.sin(2 * np.pi * 31.0 * t)
    pd.DataFrame({"time": t, "Tm": tm}).to_csv(tmp_path / "u.csv", index=False)
    scipy.io.savemat(tmp_path / "rig.mat", {"t": t[:, None], "data": np.column_stack([t, tm, tm / 35.15]),
                                            "gain": 35.15})
    run("simulate", str(fmu), "--input-file", str(tmp_path / "u.csv"), "-o", str(tmp_path / "a.csv"))
    out = run("simulate", str(fmu), "--input-file", str(tmp_path / "rig.mat"), "--input", "Tm=data[:,1]", "-o",
              str(tmp_path / "b.csv"))
    assert "inputs Tm=data[:,1] from rig.mat" in out
    a, b = pd.read_csv(tmp_path / "a.csv"), pd.read_csv(tmp_path / "b.csv")
    assert list(a.columns) == list(b.columns) == ["time", "Tm", "theta_m", "omega_m", "theta_L", "omega_L"]
    assert np.abs(b.to_numpy() - a.to_numpy()).max() <= 1e-12  # measured: 0
    run("simulate", str(fmu), "--input-file", str(tmp_path / "rig.mat"), "--time", "data[:,0]", "--input",
        "Tm=gain*data[:,2]", "--dt", "1/2257", "-o", str(tmp_path / "c.csv"))
    c = pd.read_csv(tmp_path / "c.csv")
    np.testing.assert_allclose(c["Tm"], a["Tm"], rtol=1e-13, atol=1e-10)  # 35.15*(tm/35.15): rounded once or twice
    np.testing.assert_allclose(c["theta_L"], a["theta_L"], rtol=1e-9, atol=1e-15)
    # a spec still reads as a spec with a file, and an expression without a file is refused in one line
    done = CliRunner().invoke(cli, ["simulate", str(fmu), "--input-file", str(tmp_path / "rig.mat"), "--input",
                                    "Tm=data[:,1]", "--input", "TL=step:value=100,at=0.1", "--dt", "1/2257", "--json"])
    assert done.exit_code == 0 and json.loads(done.stdout)["driven"] == ["Tm", "TL"], done.output
    bad = CliRunner().invoke(cli, ["simulate", str(fmu), "--input", "Tm=data[:,1]", "--duration", "0.1", "--dt",
                                   "0.01"])
    assert bad.exit_code == 2 and bad.stderr.count("\n") == 1, bad.output
    assert "an expression of a file's variables needs --input-file DATA" in bad.stderr
    bad = CliRunner().invoke(cli, ["simulate", str(fmu), "--input-file", str(tmp_path / "rig.mat"), "--input",
                                   "Tm=data[:,5]", "--dt", "1/2257"])
    assert bad.exit_code == 2 and "data is 1129 x 3, column index must be 0..2" in bad.stderr, bad.output


def test_one_rule_for_the_time_column(tmp_path):
    """`t` when a file has one and no `time`, else `time`: the same answer for CSV, Parquet and .mat, from
    time_column, load_data and `cosim data info` (which used to disagree on a file with both, and on Parquet)."""
    t = np.arange(12) * 0.1
    frames = {"only_t": pd.DataFrame({"t": t, "u": np.sin(t)}),
              "both": pd.DataFrame({"time": t, "t": 2 * t, "u": np.sin(t)})}
    for stem, frame in frames.items():
        expected = "t" if stem == "only_t" else "time"
        frame.to_csv(tmp_path / f"{stem}.csv", index=False)
        frame.to_parquet(tmp_path / f"{stem}.parquet", index=False)
        scipy.io.savemat(tmp_path / f"{stem}.mat", {k: v.to_numpy()[:, None] for k, v in frame.items()})
        for suffix in (".csv", ".parquet", ".mat"):
            path = tmp_path / f"{stem}{suffix}"
            assert time_column(path) == expected, path.name
            loaded = load_data(path, excitation=False)
            assert loaded.meta["data_file"]["time"] == expected and "u" in loaded.names, path.name
            info = json.loads(run("data", "info", str(path), "--json"))
            assert info["t_end"] == pytest.approx(t[-1]), path.name
    assert time_column(["u", "v"]) == "time"
    (tmp_path / "none.csv").write_text("a,b\n1,2\n")
    with pytest.raises(UnknownVariableError, match="has no time variable 't' or 'time'"):
        load_data(tmp_path / "none.csv")
    import cosim.cli.simulate as simulate_cli
    import cosim.data._measurement_files as files

    assert not hasattr(simulate_cli, "_time_of") and not hasattr(files, "_TIME_NAMES")  # the copies are gone
