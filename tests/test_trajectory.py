"""Trajectory: validation, access, noise convention, CSV/Parquet round trips, foreign files, atomic writes."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from cosim.data.trajectory import Trajectory
from cosim.errors import DataError, FmuNotFoundError, InvalidSettingError, UnknownVariableError


@pytest.fixture
def traj() -> Trajectory:
    t = np.arange(6) * 0.5
    return Trajectory.from_arrays(
        t,
        {"Tm": np.array([0.0, 1.0, 1.0, -1.0, -1.0, 0.0]), "theta_m": t**2, "omega_m": 2 * t, "y": t + 1},
        units={"Tm": "N.m", "theta_m": "rad", "omega_m": "rad/s"},
        roles={"Tm": "input", "theta_m": "state", "omega_m": "state"},
        meta={"fmu": "servo.fmu", "dt": 0.5, "parameters": {"KL": 1e6, "Fc": 0.3}, "tags": ["a", 1]},
    )


def awkward_trajectory() -> Trajectory:
    """Floats that a careless format would not round-trip, names with spaces and commas, nested meta."""
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(1e-4, 1e-3, 200))
    return Trajectory.from_arrays(
        t,
        {"theta_m": rng.standard_normal(200) * 1e-300, "omega, motor": rng.standard_normal(200) / 3,
         "Tm": np.full(200, 1 / 2257), "µ load": rng.standard_normal(200) * 1e300},
        units={"theta_m": "rad", "omega, motor": "rad/s", "Tm": "N·m"},
        roles={"theta_m": "state", "omega, motor": "state", "Tm": "input"},
        meta={"source": "fmu", "dt": None, "noise": {"level": 0.1, "seed": 3}, "list": [1, 2.5, "x"],
              "text": 'quote " and, comma\nnewline'},
    )


# ------------------------------------------------------------------------------------------- construction


def test_construction_validates_shapes_names_and_roles():
    with pytest.raises(DataError, match=r"shape \(3, 1\), expected \(n_samples, n_signals\) = \(3, 2\)"):
        Trajectory(np.arange(3.0), np.zeros((3, 1)), ("a", "b"))
    with pytest.raises(DataError, match="repeated: a"):
        Trajectory(np.arange(3.0), np.zeros((3, 2)), ("a", "a"))
    with pytest.raises(DataError, match="'time'"):
        Trajectory(np.arange(3.0), np.zeros((3, 1)), ("time",))
    with pytest.raises(InvalidSettingError, match="unknown role 'sate'; expected one of state, input"):
        Trajectory(np.arange(3.0), np.zeros((3, 1)), ("a",), roles=("sate",))
    with pytest.raises(DataError, match="units must be 1 strings"):
        Trajectory(np.arange(3.0), np.zeros((3, 1)), ("a",), units=("m", "s"))
    with pytest.raises(DataError, match=r"signal 'b' has shape \(2,\), expected \(3,\)"):
        Trajectory.from_arrays([0.0, 1.0, 2.0], {"a": [1.0, 2.0, 3.0], "b": [1.0, 2.0]})
    with pytest.raises(UnknownVariableError, match="units names 'c'"):
        Trajectory.from_arrays([0.0, 1.0], {"a": [1.0, 2.0]}, units={"c": "m"})
    with pytest.raises(DataError, match="JSON"):
        Trajectory.from_arrays([0.0, 1.0], {"a": [1.0, 2.0]}, meta={"f": object()})


def test_non_finite_values_name_the_column_and_first_bad_time():
    values = np.zeros((5, 2))
    values[3, 1] = np.nan
    values[4, 0] = np.inf
    with pytest.raises(DataError) as info:
        Trajectory(np.arange(5) * 0.25, values, ("a", "b"))
    assert "signal 'b' is nan at t=0.75 s (row 3)" in str(info.value)
    with pytest.raises(DataError, match="time is nan at index 2"):
        Trajectory([0.0, 1.0, np.nan], np.zeros((3, 1)), ("a",))


def test_time_must_strictly_increase():
    with pytest.raises(DataError, match=r"not strictly increasing at index 3 \(t=0.2 s after 0.2 s\)"):
        Trajectory([0.0, 0.1, 0.2, 0.2, 0.3], np.zeros((5, 1)), ("a",))
    with pytest.raises(DataError, match="at index 1"):
        Trajectory([1.0, 0.5], np.zeros((2, 1)), ("a",))


def test_arrays_are_read_only_copies(traj):
    source = np.arange(3.0)
    made = Trajectory.from_arrays(source, {"a": source})
    source[0] = 99.0
    assert made.time[0] == 0.0 and made["a"][0] == 0.0
    for array in (traj.time, traj.values, traj["y"]):
        with pytest.raises(ValueError):
            array[0] = 1.0


# ------------------------------------------------------------------------------------------------- access


def test_access_by_name_and_role(traj):
    np.testing.assert_array_equal(traj["omega_m"], 2 * np.arange(6) * 0.5)
    assert traj[["theta_m", "Tm"]].shape == (6, 2)
    np.testing.assert_array_equal(traj[["y", "Tm"]][:, 0], traj["y"])
    assert len(traj) == 6 and "y" in traj and "z" not in traj
    assert traj.dt == 0.5 and traj.is_uniform()
    assert traj.inputs == ("Tm",) and traj.states == ("theta_m", "omega_m") and traj.outputs == ("y",)
    with pytest.raises(UnknownVariableError, match="no signal named .omega.; available: Tm, theta_m"):
        traj["omega"]


def test_dt_is_the_median_step():
    traj = Trajectory.from_arrays([0.0, 0.1, 0.2, 0.3, 0.5], {"a": np.zeros(5)})
    assert traj.dt == pytest.approx(0.1) and not traj.is_uniform()
    jitter = Trajectory.from_arrays([0.0, 0.1, 0.2 + 1e-9, 0.3], {"a": np.zeros(4)})
    assert jitter.is_uniform(rtol=1e-6) and not jitter.is_uniform(rtol=1e-10)


def test_copies_with_roles_select_slice_meta(traj):
    changed = traj.with_roles(inputs=["y"], outputs="theta_m")
    assert changed.roles == ("input", "output", "state", "input") and traj.roles[3] == "output"
    with pytest.raises(InvalidSettingError, match="two roles"):
        traj.with_roles(states=["y"], inputs=["y"])
    with pytest.raises(UnknownVariableError):
        traj.with_roles(states=["nope"])
    picked = traj.select(["y", "Tm"])
    assert picked.names == ("y", "Tm") and picked.units == ("", "N.m") and picked.roles == ("output", "input")
    part = traj.slice(0.5, 1.5)
    np.testing.assert_array_equal(part.time, [0.5, 1.0, 1.5])
    np.testing.assert_array_equal(part["theta_m"], [0.25, 1.0, 2.25])
    assert len(traj.slice(t_start=2.0)) == 2
    with pytest.raises(DataError, match="no sample lies in"):
        traj.slice(10.0, 11.0)
    assert traj.with_meta({"run": 2}).meta["run"] == 2 and "run" not in traj.meta


def test_to_pandas_and_to_dict(traj):
    frame = traj.to_pandas()
    assert frame.index.name == "time" and list(frame.columns) == list(traj.names)
    np.testing.assert_array_equal(frame["theta_m"].to_numpy(), traj["theta_m"])
    assert frame.attrs["units"]["omega_m"] == "rad/s" and frame.attrs["roles"]["Tm"] == "input"
    assert frame.attrs["meta"] == traj.meta
    data = traj.to_dict()
    json.dumps(data)
    assert Trajectory.from_dict(data) == traj
    assert traj != traj.with_meta({"x": 1})


# -------------------------------------------------------------------------------------------------- noise


def test_noise_follows_the_convention():
    n = 100_000
    t = np.arange(n) * 1e-3
    clean = Trajectory.from_arrays(
        t,
        {"u": np.sign(np.sin(3 * t)), "x": 5.0 * np.sin(t), "v": 0.01 * np.cos(7 * t) + 3.0,
         "c": np.full(n, 2.0), "y": t},
        roles={"u": "input", "x": "state", "v": "state", "c": "state", "y": "output"},
    )
    level = 0.2
    noisy = clean.with_noise(level, seed=11)
    for name in ("x", "v", "y"):
        added = noisy[name] - clean[name]
        assert np.std(added) == pytest.approx(level * np.std(clean[name]), rel=0.05)
        assert abs(np.mean(added)) < 0.02 * level * np.std(clean[name])
    np.testing.assert_array_equal(noisy["u"], clean["u"])  # inputs untouched
    np.testing.assert_array_equal(noisy["c"], clean["c"])  # a constant signal gets no noise
    correlation = np.corrcoef(noisy["x"] - clean["x"], noisy["y"] - clean["y"])[0, 1]
    assert abs(correlation) < 0.02  # independent per signal
    assert noisy.meta["noise"]["level"] == level and noisy.meta["noise"]["seed"] == 11
    assert noisy.meta["noise"]["signals"] == ["x", "v", "c", "y"]
    assert noisy.meta["noise"]["std"]["x"] == pytest.approx(level * np.std(clean["x"]))
    assert noisy == clean.with_noise(level, seed=11)  # reproducible
    assert not np.array_equal(noisy["x"], clean.with_noise(level, seed=12)["x"])


def test_noise_on_named_signals_only_and_bad_settings(traj):
    noisy = traj.with_noise(0.5, seed=0, names=["Tm"])
    assert not np.array_equal(noisy["Tm"], traj["Tm"])  # an input, because it is named
    np.testing.assert_array_equal(noisy["theta_m"], traj["theta_m"])
    assert traj.with_noise(0.0, seed=0).values.tolist() == traj.values.tolist()
    with pytest.raises(InvalidSettingError, match=">= 0"):
        traj.with_noise(-0.1, seed=0)
    with pytest.raises(InvalidSettingError, match="seed"):
        traj.with_noise(0.1, seed=-3)
    with pytest.raises(InvalidSettingError, match="already has noise"):
        noisy.with_noise(0.1, seed=1)
    with pytest.raises(UnknownVariableError):
        traj.with_noise(0.1, seed=1, names=["nope"])


# -------------------------------------------------------------------------------------------------- files


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".pq"])
def test_round_trip_is_exact(tmp_path, suffix):
    original = awkward_trajectory()
    path = original.write(tmp_path / f"run{suffix}")
    back = Trajectory.read(path)
    assert back == original
    assert back.names == original.names and back.units == original.units and back.roles == original.roles
    assert back.meta == original.meta
    assert np.array_equal(back.values, original.values) and np.array_equal(back.time, original.time)


def test_csv_is_plain_and_its_header_is_in_the_sidecar(tmp_path, traj):
    path = traj.to_csv(tmp_path / "run.csv")
    assert path.read_text(encoding="utf-8").splitlines()[0] == "time,Tm,theta_m,omega_m,y"
    frame = pd.read_csv(path)  # what another tool sees, with no options
    assert list(frame.columns) == ["time", "Tm", "theta_m", "omega_m", "y"]
    np.testing.assert_array_equal(frame["omega_m"].to_numpy(), traj["omega_m"])
    np.testing.assert_array_equal(frame["time"].to_numpy(), traj.time)
    side = json.loads((tmp_path / "run.meta.json").read_text())
    assert side["format"] == "cosim-trajectory" and side["columns"] == list(frame.columns)
    assert side["units"]["theta_m"] == "rad" and side["roles"]["Tm"] == "input"
    assert side["sample_time"] == pytest.approx(traj.dt)


def test_a_csv_without_its_sidecar_reads_as_a_plain_table(tmp_path, traj):
    path = traj.to_csv(tmp_path / "run.csv")
    (tmp_path / "run.meta.json").unlink()
    back = Trajectory.read(path)
    assert back.names == traj.names and back.roles == ("output",) * 4 and back.units == ("",) * 4
    np.testing.assert_array_equal(back.values, traj.values)


def test_a_sidecar_of_other_columns_is_ignored_with_a_warning(tmp_path, traj):
    path = traj.to_csv(tmp_path / "run.csv")
    traj.select(["Tm", "y"]).to_csv(tmp_path / "other.csv")
    (tmp_path / "other.meta.json").replace(tmp_path / "run.meta.json")
    with pytest.warns(UserWarning, match="run.meta.json describes columns .* not those of run.csv"):
        back = Trajectory.read(path)
    assert back.roles == ("output",) * 4


def test_a_foreign_sidecar_is_refused(tmp_path, traj):
    path = traj.to_csv(tmp_path / "run.csv")
    (tmp_path / "run.meta.json").write_text('{"author": "someone"}')
    with pytest.raises(DataError, match="run.meta.json beside run.csv is not a cosim-trajectory sidecar"):
        Trajectory.read(path)


def test_read_selects_columns_and_overrides_roles(tmp_path, traj):
    path = traj.write(tmp_path / "run.parquet")
    part = Trajectory.read(path, columns=["y", "theta_m"], roles={"y": "state"})
    assert part.names == ("y", "theta_m") and part.roles == ("state", "state") and part.units == ("", "rad")
    with pytest.raises(DataError, match="lacks column.s. nope; columns present: time, Tm, theta_m"):
        Trajectory.read(path, columns=["nope"])
    with pytest.raises(UnknownVariableError, match="roles names zz"):
        Trajectory.read(path, roles={"zz": "input"})


def test_read_a_foreign_csv(tmp_path):
    path = tmp_path / "bench.csv"
    text = "\ufefft,encoder angle,torque\n0.0,1.5,0\n0.000443,1.25,1\n0.000886,1.0,1\n"  # as Excel saves it
    path.write_text(text, encoding="utf-8")
    traj = Trajectory.read(path, time="t", roles={"torque": "input"})
    assert traj.names == ("encoder angle", "torque") and traj.units == ("", "")
    assert traj.roles == ("output", "input") and traj.meta == {}
    np.testing.assert_array_equal(traj["encoder angle"], [1.5, 1.25, 1.0])
    with pytest.raises(DataError, match="no time column 'time'; columns present: t, encoder angle, torque"):
        Trajectory.read(path)


def test_read_a_foreign_parquet(tmp_path):
    path = tmp_path / "other.parquet"
    pd.DataFrame({"time": [0.0, 0.1, 0.2], "x": [1, 2, 3], "flag": [True, False, True]}).to_parquet(path)
    traj = Trajectory.read(path)
    assert traj.names == ("x", "flag") and traj.roles == ("output", "output")
    np.testing.assert_array_equal(traj["x"], [1.0, 2.0, 3.0])


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("time,a\n0.0,1\n0.1,\n0.2,3\n", "signal 'a' is nan at t=0.1 s (row 1)"),
        ("time,a\n0.0,1\n0.2,2\n0.1,3\n", "not strictly increasing at index 2 (t=0.1 s after 0.2 s)"),
        ("time,a\n0.0,1\n0.1,abc\n", "column 'a' of bad.csv holds 'abc' at data row 1; expected numbers"),
        ("time,a\n", "time must be a non-empty 1-D array"),
    ],
)
def test_bad_files_raise_data_errors(tmp_path, text, fragment):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(DataError) as info:
        Trajectory.read(path)
    assert fragment in str(info.value) and "\n" not in str(info.value)


def test_missing_file_and_unknown_suffix(tmp_path, traj):
    with pytest.raises(FmuNotFoundError) as info:
        Trajectory.read(tmp_path / "nowhere.csv")
    assert str(tmp_path / "nowhere.csv") in str(info.value) and isinstance(info.value, FileNotFoundError)
    with pytest.raises(InvalidSettingError, match=r"use \.csv, \.parquet, \.pq or \.mat"):
        traj.write(tmp_path / "run.txt")
    (tmp_path / "junk.parquet").write_bytes(b"not parquet at all")
    with pytest.raises(DataError, match="cannot read junk.parquet as Parquet"):
        Trajectory.read(tmp_path / "junk.parquet")


def _fail_midway_csv(self, handle, *args, **kwargs):
    handle.write("time,half a row")
    raise OSError("disk full")


def _fail_midway_parquet(table, where, *args, **kwargs):
    with open(where, "wb") as handle:
        handle.write(b"PAR1 half a file")
    raise OSError("disk full")


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_writes_are_atomic(tmp_path, monkeypatch, traj, suffix):
    import pyarrow.parquet as pq

    target = tmp_path / f"run{suffix}"
    monkeypatch.setattr(pd.DataFrame, "to_csv", _fail_midway_csv)
    monkeypatch.setattr(pq, "write_table", _fail_midway_parquet)
    with pytest.raises(OSError, match="disk full"):
        traj.write(target)
    assert list(tmp_path.iterdir()) == []  # no file, no temporary file
    monkeypatch.undo()

    traj.write(target)
    written = sorted(tmp_path.iterdir())  # a CSV has its sidecar run.meta.json
    before = [p.read_bytes() for p in written]
    monkeypatch.setattr(pd.DataFrame, "to_csv", _fail_midway_csv)
    monkeypatch.setattr(pq, "write_table", _fail_midway_parquet)
    with pytest.raises(OSError):
        traj.with_meta({"second": True}).write(target)
    assert [p.read_bytes() for p in written] == before  # the old files survive whole
    assert sorted(tmp_path.iterdir()) == written
    assert Trajectory.read(target).meta == traj.meta


def test_from_pandas_round_trips_to_pandas(traj):
    back = Trajectory.from_pandas(traj.to_pandas())
    assert back == traj and back.units == traj.units and back.roles == traj.roles and back.meta == traj.meta


def test_from_pandas_takes_a_time_column_or_a_time_index(traj):
    frame = pd.DataFrame({"t": [0.0, 0.5, 1.0], "u": [1, 0, 1], "y": [0.0, 0.25, 0.5]})
    got = Trajectory.from_pandas(frame, time="t", roles={"u": "input"}, units={"y": "m"})
    assert got.names == ("u", "y") and got.roles == ("input", "output") and got.units == ("", "m")
    np.testing.assert_array_equal(got.time, [0.0, 0.5, 1.0])
    stamped = frame.drop(columns="t").set_index(pd.Timestamp("2026-01-01") + pd.to_timedelta(
        [0.0, 0.5, 1.0], unit="s"))
    np.testing.assert_allclose(Trajectory.from_pandas(stamped).time, [0.0, 0.5, 1.0])
    with pytest.raises(DataError, match="plain row-number index; pass time="):
        Trajectory.from_pandas(frame.drop(columns="t"))
    with pytest.raises(DataError, match="column.s. name of the DataFrame are not numbers"):
        Trajectory.from_pandas(frame.assign(name="a"), time="t")


def test_plot_returns_a_figure_with_units_and_writes_it_when_asked(tmp_path, traj):
    fig = traj.plot(["Tm", "theta_m"], path=tmp_path / "p.png", title="run")
    assert [ax.get_ylabel() for ax in fig.axes] == ["Tm\n[N m]", "theta_m\n[rad]"]
    assert fig.axes[-1].get_xlabel() == "time [s]"
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
