"""load_data: CSV, Parquet and MATLAB files, column expressions, derivatives, resampling, and every error."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import scipy.io

from cosim.data.datafile import DERIVATIVE_METHODS, MIN_SAMPLES, check_excitation, differentiate, load_data
from cosim.data.trajectory import Trajectory
from cosim.errors import DataError, FmuNotFoundError, InvalidSettingError, UnknownVariableError

DT = 1e-3
N = 400


def signals(n: int = N) -> dict[str, np.ndarray]:
    t = np.arange(n) * DT
    return {"t": t, "qm": 0.1 * np.sin(2 * np.pi * 2 * t), "vir": np.sign(np.sin(2 * np.pi * 5 * t)) + 0.1 * t,
            "pulses_N": (5 * (np.sin(2 * np.pi * 3 * t) > 0)).astype(np.uint8)}


def write_mat(path, data: dict, **scalars) -> None:
    scipy.io.savemat(path, {**{k: np.asarray(v)[:, None] for k, v in data.items()}, **scalars})


@pytest.fixture
def mat(tmp_path):
    path = tmp_path / "bench.mat"
    write_mat(path, signals(), gtau=35.15, kp=160.18)
    return path


@pytest.fixture
def csv(tmp_path):
    path = tmp_path / "bench.csv"
    pd.DataFrame(signals()).to_csv(path, index=False)
    return path


# ------------------------------------------------------------------------------------------- formats


def test_mat_columns_expressions_scalars_and_roles(mat):
    s = signals()
    traj = load_data(mat, columns=["qm", "force=gtau*vir+pulses_N", "neg=-(vir - 2)/4"],
                     roles={"qm": "state", "force": "input"}, units={"qm": "m", "force": "N"})
    assert traj.names == ("qm", "force", "neg")
    assert traj.roles == ("state", "input", "output")
    assert traj.units == ("m", "N", "")
    np.testing.assert_allclose(traj["force"], 35.15 * s["vir"] + s["pulses_N"].astype(float), rtol=1e-15)
    np.testing.assert_allclose(traj["neg"], -(s["vir"] - 2) / 4, rtol=1e-15)
    np.testing.assert_array_equal(traj.time, s["t"])
    assert traj.dt == pytest.approx(DT)
    meta = traj.meta["data_file"]
    assert meta["format"] == "mat" and meta["time"] == "t"
    assert meta["columns"] == {"qm": "qm", "force": "gtau*vir+pulses_N", "neg": "-(vir - 2)/4"}
    assert meta["scalars"] == {"gtau": 35.15}
    assert meta["derivatives"] is None and meta["resampled"] is None


def test_mat_uint8_is_converted_before_arithmetic(mat):
    # 5 * 100 overflows uint8; the loader works in float64
    traj = load_data(mat, columns=["p=100*pulses_N"])
    assert traj["p"].max() == 500.0


def test_mat_mapping_form_row_vectors_and_default_columns(tmp_path):
    s = signals()
    path = tmp_path / "rows.mat"
    scipy.io.savemat(path, {"t": s["t"][None, :], "qm": s["qm"][None, :], "vir": s["vir"], "gain": 2.0})
    traj = load_data(path, columns={"force": "gain*vir", "qm": "qm"})
    assert traj.names == ("force", "qm")
    np.testing.assert_allclose(traj["force"], 2 * s["vir"])
    # default: every vector of one value per time, scalars left out
    assert load_data(path).names == ("qm", "vir")


def test_csv_plain_file_and_expression(csv):
    s = signals()
    traj = load_data(csv, columns=["qm", "force=35.15*vir"], roles={"force": "input"})
    np.testing.assert_allclose(traj["force"], 35.15 * s["vir"])
    assert traj.meta["data_file"]["format"] == "csv"
    assert load_data(csv).names == ("qm", "vir", "pulses_N")


def test_csv_written_by_cosim_keeps_units_roles_and_meta(tmp_path):
    t = np.arange(50) * 0.01
    written = Trajectory.from_arrays(t, {"u": np.sin(7 * t), "x": t**2}, units={"x": "rad"},
                                     roles={"u": "input", "x": "state"}, meta={"fmu": "servo.fmu"})
    path = written.write(tmp_path / "run.csv")
    traj = load_data(path, columns=["x", "u2=2*u"], derive=["x"], derive_method="finite_difference")
    assert traj.names == ("x", "x_dot", "u2")
    assert traj.units == ("rad", "rad/s", "")
    assert traj.roles == ("state", "output", "output")
    assert traj.meta["fmu"] == "servo.fmu" and traj.meta["data_file"]["time"] == "time"
    np.testing.assert_allclose(traj["x_dot"], 2 * t, atol=1e-12)


def test_csv_header_names_that_are_not_identifiers_and_renames(tmp_path):
    t = np.arange(30) * 0.01
    written = Trajectory.from_arrays(t, {"motor speed": np.cos(t), "x": t}, units={"x": "rad", "motor speed": "1/s"})
    path = written.write(tmp_path / "odd.csv")
    assert load_data(path).names == ("motor speed", "x")
    traj = load_data(path, columns=["motor speed", "angle=x"])
    assert traj.names == ("motor speed", "angle") and traj.units == ("1/s", "rad")
    with pytest.raises(InvalidSettingError, match="'motor speed' is not an expression"):
        load_data(path, columns=["w=motor speed"])


def test_parquet(tmp_path):
    s = signals()
    path = tmp_path / "bench.parquet"
    pd.DataFrame({"time": s["t"], "qm": s["qm"], "vir": s["vir"]}).to_parquet(path)
    traj = load_data(path, columns=["qm", "force=vir*35.15"], roles={"force": "input"})
    np.testing.assert_allclose(traj["force"], 35.15 * s["vir"])
    assert traj.meta["data_file"]["format"] == "parquet" and traj.meta["data_file"]["time"] == "time"


def test_time_jitter_is_regularised_to_a_uniform_grid(tmp_path):
    s = signals()
    t = s["t"] + np.random.default_rng(0).uniform(-1e-7, 1e-7, N)  # 1e-4 of a step: uniform
    path = tmp_path / "jitter.mat"
    write_mat(path, {"t": t, "qm": s["qm"]})
    traj = load_data(path)
    np.testing.assert_allclose(traj.time, t[0] + (t[-1] - t[0]) / (N - 1) * np.arange(N), rtol=0, atol=1e-15)
    assert 0 < traj.meta["data_file"]["time_jitter"] < 2e-7
    assert traj.is_uniform()


# ------------------------------------------------------------------------------------------- matrix variables


def channels(n: int = N) -> np.ndarray:
    """Time then three channels, one per column, as a rig saves them (n x 4)."""
    s = signals(n)
    return np.column_stack([s["t"], s["qm"], s["vir"], s["pulses_N"].astype(float)])


def test_mat_matrix_columns_equal_the_source_columns(tmp_path):
    data = channels()
    path = tmp_path / "rig.mat"
    scipy.io.savemat(path, {"t": data[:, 0], "data": data})
    traj = load_data(path, columns=["pos=data[:,1]", "volts=data[:, 2]", "pulses=data[ : , 3 ]"])
    assert traj.names == ("pos", "volts", "pulses")
    for k, name in enumerate(traj.names, start=1):
        np.testing.assert_array_equal(traj[name], data[:, k])  # exactly the stored column, 0-based
    assert traj.meta["data_file"]["columns"] == {"pos": "data[:,1]", "volts": "data[:, 2]",
                                                 "pulses": "data[ : , 3 ]"}
    mapping = load_data(path, columns={"pos": "data[:,1]"})
    np.testing.assert_array_equal(mapping["pos"], data[:, 1])


def test_mat_matrix_stored_with_channels_as_rows(tmp_path):
    rows = channels().T  # 4 x N
    path = tmp_path / "rows.mat"
    scipy.io.savemat(path, {"t": rows[0], "data": rows})
    traj = load_data(path, columns=["pos=data[1,:]", "volts=data[2, :]"])
    np.testing.assert_array_equal(traj["pos"], rows[1])
    np.testing.assert_array_equal(traj["volts"], rows[2])
    # the other way round, the message says which way the channels run
    with pytest.raises(DataError, match=r"^data\[:,1\]: data is 4 x 400: its rows are the channels .* "
                                        r"write data\[1,:\] \(indices are 0-based"):
        load_data(path, columns=["pos=data[:,1]"])


def test_mat_expression_with_indexed_variables(tmp_path):
    data = channels()
    path = tmp_path / "rig.mat"
    scipy.io.savemat(path, {"t": data[:, 0], "data": data, "gain": 2.0})
    traj = load_data(path, columns=["force=35.15*data[:,2]", "mix=gain*(data[:,1] - data[:, 3])/4"],
                     roles={"force": "input"})
    np.testing.assert_allclose(traj["force"], 35.15 * data[:, 2], rtol=1e-15)
    np.testing.assert_allclose(traj["mix"], 2.0 * (data[:, 1] - data[:, 3]) / 4, rtol=1e-15)
    assert traj.meta["data_file"]["scalars"] == {"gain": 2.0}
    # a vector takes index 0, whichever way it is stored (savemat writes a 1-D array as a 1 x N row)
    scipy.io.savemat(path, {"t": data[:, 0], "v": data[:, 1], "w": data[:, 2][:, None]})
    vectors = load_data(path, columns=["a=v[:,0]", "b=v[0,:]", "c=w[:,0]"])
    for name, source in (("a", 1), ("b", 1), ("c", 2)):
        np.testing.assert_array_equal(vectors[name], data[:, source])


def test_mat_time_from_an_indexed_column(tmp_path):
    data = channels()
    path = tmp_path / "rig.mat"
    scipy.io.savemat(path, {"data": data, "rows": data.T})
    traj = load_data(path, time="data[:, 0]", columns=["pos=data[:,1]"], derive=["pos"])
    np.testing.assert_array_equal(traj.time, data[:, 0])
    np.testing.assert_array_equal(traj["pos"], data[:, 1])
    assert traj.names == ("pos", "pos_dot") and traj.dt == pytest.approx(DT)
    assert traj.meta["data_file"]["time"] == "data[:,0]"
    by_row = load_data(path, time="rows[0,:]", columns=["volts=rows[2,:]"])
    np.testing.assert_array_equal(by_row.time, data[:, 0])
    np.testing.assert_array_equal(by_row["volts"], data[:, 2])
    with pytest.raises(UnknownVariableError, match=r"rig.mat has no variable 'dat' \(time 'dat\[:,0\]'\)"):
        load_data(path, time="dat[:,0]", columns=["pos=data[:,1]"])
    with pytest.raises(DataError, match=r"has no vector of 400 samples besides 'data\[:,0\]'.*"
                                        r"columns=\['x=data\[:,1\]'\]"):
        load_data(path, time="data[:,0]")


@pytest.mark.parametrize(("time", "column", "message"), [
    ("data[:,0]", "pos=data[:,7]", "data[:,7]: data is 400 x 4, column index must be 0..3"),
    ("data[:,0]", "pos=data[:,-1]", "data[:,-1]: data is 400 x 4, column index must be 0..3"),
    ("data[:,0]", "pos=rows[9,:]", "rows[9,:]: rows is 4 x 400, row index must be 0..3"),
    ("data[:,4]", "pos=data[:,1]", "data[:,4]: data is 400 x 4, column index must be 0..3"),
    ("data[:,0]", "pos=2*v[:,1]", "v[:,1]: v is 1 x 400, a vector: column index must be 0"),
])
def test_mat_index_out_of_range_is_one_line(tmp_path, time, column, message):
    data = channels()
    path = tmp_path / "rig.mat"
    scipy.io.savemat(path, {"data": data, "rows": data.T, "v": data[:, 1]})
    with pytest.raises(DataError) as caught:
        load_data(path, time=time, columns=[column])
    text = str(caught.value)
    assert text == f"{message} (indices are 0-based, as in NumPy; file rig.mat)"
    assert "\n" not in text


@pytest.mark.parametrize(("column", "message"), [
    ("pos=data[0]", r"'data\[0\]' is not allowed; index a .mat matrix as data\[:,k\] \(its column k\) or "
                    r"data\[k,:\] \(its row k\), k a whole number; indices are 0-based"),
    ("pos=data[:,1:3]", r"'data\[:, 1:3\]' is not allowed"),
    ("pos=data[:,1.0]", r"'data\[:, 1.0\]' is not allowed"),
    ("pos=data[:,:]", r"'data\[:, :\]' is not allowed"),
    ("pos=(2*data)[:,1]", r"'\(2 \* data\)\[:, 1\]' is not allowed"),
])
def test_mat_malformed_index_is_refused(mat, column, message):
    with pytest.raises(InvalidSettingError, match=message):
        load_data(mat, columns=[column])


def test_indexing_a_csv_or_parquet_column_is_refused(csv, tmp_path):
    with pytest.raises(DataError, match=r"^column 'p=2\*qm\[:,0\]': qm\[:,0\] indexes 'qm' as a matrix, but "
                                        r"bench.csv is a CSV file, whose columns are vectors \(only a .mat variable "
                                        r"can be a matrix; indices are 0-based, as in NumPy\); use the column by "
                                        r"name, qm$"):
        load_data(csv, columns=["p=2*qm[:,0]"])
    with pytest.raises(DataError, match=r"^time 't\[:,0\]': t\[:,0\] indexes 't' as a matrix, but bench.csv"):
        load_data(csv, time="t[:,0]", columns=["qm"])
    pq = tmp_path / "b.parquet"
    pd.DataFrame({"time": [0.0, 1.0, 2.0], "y": [1.0, 2.0, 3.0]}).to_parquet(pq)
    with pytest.raises(DataError, match="b.parquet is a Parquet file, whose columns are vectors"):
        load_data(pq, columns=["z=y[:,0]"])


def test_a_whole_matrix_or_an_unnamed_index_says_how_to_index(tmp_path):
    data = channels()
    path = tmp_path / "rig.mat"
    scipy.io.savemat(path, {"t": data[:, 0], "data": data})
    with pytest.raises(DataError, match=r"has shape \(400, 4\); expected a vector .*; index a .mat matrix as "
                                        r"data\[:,k\]"):
        load_data(path, columns=["pos=data"])
    with pytest.raises(UnknownVariableError, match=r"no variable 'data\[:,1\]'.*; to read one column of the "
                                                   r"matrix data, name it: x=data\[:,1\] \(indices are 0-based\)"):
        load_data(path, columns=["data[:,1]"])


# ------------------------------------------------------------------------------------------- derivatives


@pytest.mark.parametrize("method", list(DERIVATIVE_METHODS))
def test_every_method_differentiates_a_sine(method):
    """Known answer: 1 Hz sine at 1 kHz, velocity and acceleration, away from the ends."""
    t = np.arange(2000) * DT
    x = np.sin(2 * np.pi * t)
    v, a = differentiate(x, DT, order=2, method=method)
    inner = slice(100, -100)
    w = 2 * np.pi
    np.testing.assert_allclose(v[inner], w * np.cos(w * t[inner]), atol=1e-4 * w)
    np.testing.assert_allclose(a[inner], -w**2 * np.sin(w * t[inner]), atol=1e-3 * w**2)


def test_savitzky_golay_is_exact_on_a_cubic_including_the_ends():
    t = np.arange(60) * 0.01
    v, a = differentiate(2 * t**3 - t, 0.01, order=2, method="savitzky_golay")
    np.testing.assert_allclose(v, 6 * t**2 - 1, atol=1e-9)
    np.testing.assert_allclose(a, 12 * t, atol=1e-8)


def test_smoothing_methods_reject_noise_that_plain_differences_amplify():
    t = np.arange(5000) * DT
    x = np.sin(2 * np.pi * t) + np.random.default_rng(1).normal(0, 1e-4, t.size)
    true = 2 * np.pi * np.cos(2 * np.pi * t)
    err = {m: np.sqrt(np.mean((differentiate(x, DT, method=m)[0] - true)[100:-100] ** 2)) for m in DERIVATIVE_METHODS}
    assert err["savitzky_golay"] < err["finite_difference"] / 5
    assert err["butterworth"] < err["finite_difference"] / 5


def test_load_data_derives_velocity_and_acceleration(mat):
    s = signals()
    traj = load_data(mat, columns=["qm", "force=gtau*vir"], derive="qm", derive_order=2, units={"qm": "m"},
                     roles={"qm": "state", "qm_dot": "state", "force": "input"})
    assert traj.names == ("qm", "qm_dot", "qm_ddot", "force")
    assert traj.units == ("m", "m/s", "m/s^2", "")
    assert traj.states == ("qm", "qm_dot") and traj.inputs == ("force",)
    w = 2 * np.pi * 2
    inner = slice(20, -20)
    np.testing.assert_allclose(traj["qm_dot"][inner], 0.1 * w * np.cos(w * s["t"][inner]), atol=1e-6)
    np.testing.assert_allclose(traj["qm_ddot"][inner], -0.1 * w**2 * np.sin(w * s["t"][inner]),
                               atol=2e-3 * 0.1 * w**2)  # the 21-sample cubic's bias at 2 Hz, 1 kHz
    # clean data: the window chosen from the data is the shortest (a cubic has no noise to average)
    assert traj.meta["data_file"]["derivatives"] == {"of": ["qm"], "order": 2, "method": "savitzky_golay",
                                                     "options": {"window": "auto", "polyorder": 3},
                                                     "windows": {"qm_dot": 5, "qm_ddot": 5}, "window_from": "data"}
    fixed = load_data(mat, columns=["qm"], derive="qm", derive_window=21)
    assert fixed.meta["data_file"]["derivatives"]["windows"] == {"qm_dot": 21}
    assert fixed.meta["data_file"]["derivatives"]["window_from"] == "given"
    bw = load_data(mat, columns=["qm"], derive=["qm"], derive_method="butterworth", derive_options={"cutoff": 50.0})
    middle = slice(60, -60)  # beyond the zero-phase filter's edge transients
    np.testing.assert_allclose(bw["qm_dot"][middle], 0.1 * w * np.cos(w * s["t"][middle]), atol=1e-4)


def test_differentiate_settings_are_checked():
    x = np.sin(np.arange(100) * 0.1)
    with pytest.raises(InvalidSettingError, match="unknown derive_method 'spline'; expected one of savitzky_golay"):
        differentiate(x, 0.1, method="spline")
    with pytest.raises(InvalidSettingError, match="no option 'win'; its options: window, polyorder"):
        differentiate(x, 0.1, options={"win": 5})
    with pytest.raises(InvalidSettingError, match="derive_order must be 1"):
        differentiate(x, 0.1, order=3)
    with pytest.raises(InvalidSettingError, match="window must be odd"):
        differentiate(x, 0.1, options={"window": 20})
    with pytest.raises(InvalidSettingError, match=r"derive_order \(2\) <= polyorder \(1\)"):
        differentiate(x, 0.1, order=2, options={"polyorder": 1})
    with pytest.raises(InvalidSettingError, match="cutoff must lie between 0 and the Nyquist frequency 5 Hz"):
        differentiate(x, 0.1, method="butterworth", options={"cutoff": 7.0})
    with pytest.raises(InvalidSettingError, match="dt must be a positive"):
        differentiate(x, 0.0)
    with pytest.raises(DataError, match="has 10 samples; savitzky_golay needs at least 21"):
        differentiate(x[:10], 0.1, options={"window": 21})
    with pytest.raises(DataError, match="has 4 samples; savitzky_golay needs at least 5"):
        differentiate(x[:4], 0.1)
    with pytest.raises(DataError, match="nan at sample 3"):
        differentiate(np.where(np.arange(100) == 3, np.nan, x), 0.1)


# ------------------------------------------------------------------------------------------- errors


def test_missing_file_folder_and_unknown_suffix(tmp_path):
    with pytest.raises(FmuNotFoundError, match=r"data file .*nope\.mat does not exist"):
        load_data(tmp_path / "nope.mat")
    (tmp_path / "dir.csv").mkdir()
    with pytest.raises(FmuNotFoundError, match="is a folder, not a file"):
        load_data(tmp_path / "dir.csv")
    (tmp_path / "data.xlsx").write_text("x")
    with pytest.raises(InvalidSettingError, match=r"'data.xlsx' from its suffix; use .csv, .parquet, .pq or .mat"):
        load_data(tmp_path / "data.xlsx")


def test_too_short_says_the_minimum(tmp_path):
    s = signals(2)
    write_mat(tmp_path / "short.mat", {"t": s["t"], "qm": s["qm"]})
    with pytest.raises(DataError, match=f"short.mat has 2 samples; at least {MIN_SAMPLES} are needed"):
        load_data(tmp_path / "short.mat")
    s = signals(15)
    write_mat(tmp_path / "short.mat", {"t": s["t"], "qm": s["qm"]})
    with pytest.raises(DataError, match=r"has 15 samples; at least 21 are needed \(savitzky_golay with"):
        load_data(tmp_path / "short.mat", derive=["qm"], derive_window=21)
    assert len(load_data(tmp_path / "short.mat", derive=["qm"])) == 15  # the window chosen fits the record
    assert len(load_data(tmp_path / "short.mat", derive=["qm"], derive_options={"window": 11})) == 15


def test_nan_says_column_time_and_row(tmp_path, csv, mat):
    s = signals()
    s["vir"] = s["vir"].copy()
    s["vir"][123] = np.nan
    write_mat(tmp_path / "nan.mat", s, gtau=35.15)
    with pytest.raises(DataError, match=r"column 'force' of nan.mat is nan at t=0.123 s \(row 123\)"):
        load_data(tmp_path / "nan.mat", columns=["force=gtau*vir"])
    load_data(tmp_path / "nan.mat", columns=["qm"])  # a NaN in a column not asked for does not matter
    frame = pd.read_csv(csv)
    frame.loc[7, "qm"] = np.nan
    frame.to_csv(csv, index=False)
    with pytest.raises(DataError, match=r"'qm' is nan at t=0.007 s \(row 7\)"):
        load_data(csv, columns=["qm"])
    with pytest.raises(DataError, match=r"column 'r' of bench.mat is inf at t=0 s \(row 0\)"):
        load_data(mat, columns=["r=1/t"])


def test_time_not_increasing_says_where(tmp_path, csv):
    s = signals()
    s["t"] = s["t"].copy()
    s["t"][50] = s["t"][49]
    write_mat(tmp_path / "rep.mat", s)
    with pytest.raises(DataError, match=r"time 't' of rep.mat is not strictly increasing at row 50 "
                                        r"\(t=0.049 s after 0.049 s\); sort the rows"):
        load_data(tmp_path / "rep.mat", columns=["qm"], resample=True)
    s["t"][50] = np.nan
    write_mat(tmp_path / "rep.mat", s)
    with pytest.raises(DataError, match="time 't' of rep.mat is nan at row 50"):
        load_data(tmp_path / "rep.mat", columns=["qm"])
    frame = pd.read_csv(csv)
    frame.loc[10, "t"] = 0.0
    frame.to_csv(csv, index=False)
    with pytest.raises(DataError, match="not strictly increasing at index 10"):
        load_data(csv, columns=["qm"])


def test_non_uniform_time_is_refused_or_resampled(tmp_path):
    s = signals()
    t = s["t"].copy()
    t[200:] += 0.0005  # one step of 1.5 ms
    x = 3.0 * t + 1.0
    write_mat(tmp_path / "gap.mat", {"t": t, "x": x, "u": np.sin(40 * t)})
    with pytest.raises(DataError, match=r"time 't' of gap.mat is not uniform: the step before row 200 \(t=0.2005 s\) "
                                        r"is 0.0015 s against a median step of 0.001 s .*pass resample=True"):
        load_data(tmp_path / "gap.mat")
    traj = load_data(tmp_path / "gap.mat", resample=True, derive=["x"], roles={"u": "input"})
    assert traj.is_uniform() and traj.dt == pytest.approx(DT)
    assert len(traj) == int(np.floor((t[-1] - t[0]) / DT)) + 1
    np.testing.assert_allclose(traj["x"], 3.0 * traj.time + 1.0, rtol=1e-12)  # linear interpolation is exact
    np.testing.assert_allclose(traj["x_dot"], 3.0, rtol=1e-9)
    assert traj.meta["data_file"]["resampled"] == {"from_samples": N, "samples": len(traj),
                                                   "dt": pytest.approx(DT), "method": "linear interpolation"}


def test_missing_variables_list_what_the_file_has(mat, csv, tmp_path):
    with pytest.raises(UnknownVariableError, match=r"bench.mat has no variable 'pulses' \(column 'force=gtau\*vir"
                                                   r"\+pulses'\); it has: t, qm, vir, pulses_N, gtau, kp"):
        load_data(mat, columns=["force=gtau*vir+pulses"])
    with pytest.raises(UnknownVariableError, match="bench.csv has no variable 'qg'.*it has: t, qm, vir, pulses_N"):
        load_data(csv, columns=["qg"])
    with pytest.raises(UnknownVariableError, match=r"no time variable 'time'; it has: t, qm.*pass time="):
        load_data(mat, time="time")
    scipy.io.savemat(tmp_path / "notime.mat", {"x": np.zeros((5, 1))})
    with pytest.raises(UnknownVariableError, match=r"no time variable 't' or 'time'; it has: x"):
        load_data(tmp_path / "notime.mat")
    pq = tmp_path / "b.parquet"
    pd.DataFrame({"time": [0.0, 1.0, 2.0], "y": [1.0, 2.0, 3.0]}).to_parquet(pq)
    with pytest.raises(UnknownVariableError, match="b.parquet has no variable 'z'.*it has: time, y"):
        load_data(pq, columns=["w=2*z"])


def test_variables_that_are_not_vectors_of_the_right_length(tmp_path):
    s = signals()
    scipy.io.savemat(tmp_path / "bad.mat", {"t": s["t"][:, None], "short": np.zeros((10, 1)),
                                            "matrix": np.zeros((N, 2)), "name": "qm", "tt": np.zeros((3, 3))})
    with pytest.raises(DataError, match=f"variable 'short' of bad.mat has 10 samples, expected {N} like 't'"):
        load_data(tmp_path / "bad.mat", columns=["short"])
    with pytest.raises(DataError, match=rf"variable 'matrix' of bad.mat has shape \({N}, 2\); expected a vector of "
                                        f"{N} samples like 't' or a scalar"):
        load_data(tmp_path / "bad.mat", columns=["m=2*matrix"])
    with pytest.raises(DataError, match="variable 'name' of bad.mat is a <U2 array, not numbers"):
        load_data(tmp_path / "bad.mat", columns=["name"])
    with pytest.raises(DataError, match=r"variable 'tt' of bad.mat has shape \(3, 3\); expected a vector"):
        load_data(tmp_path / "bad.mat", time="tt", columns=["short"])


def test_matlab_v73_and_unreadable_files(tmp_path):
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(116, b" ") + b"\0" * 8 + b"\x00\x02IM"
    (tmp_path / "big.mat").write_bytes(header + b"\x89HDF\r\n\x1a\n" + b"\0" * 512)
    with pytest.raises(DataError, match=r"big.mat is a MATLAB v7.3 \(HDF5\) file, which cosim does not read; "
                                        r"re-save it in MATLAB with save\('big.mat', ..., '-v7'\)"):
        load_data(tmp_path / "big.mat")
    (tmp_path / "junk.mat").write_bytes(b"not a mat file at all")
    with pytest.raises(DataError, match="cannot read junk.mat as a MATLAB file"):
        load_data(tmp_path / "junk.mat")
    (tmp_path / "junk.parquet").write_bytes(b"nope")
    with pytest.raises(DataError, match="cannot read junk.parquet as Parquet"):
        load_data(tmp_path / "junk.parquet")
    (tmp_path / "empty.csv").write_text("# only a comment\n")
    with pytest.raises(DataError, match="empty.csv has no header row"):
        load_data(tmp_path / "empty.csv")


def test_constant_input_has_nothing_to_identify_from(mat):
    with pytest.raises(DataError, match="input 'force' is constant: nothing to identify from"):
        load_data(mat, columns=["qm", "force=gtau*1"], roles={"force": "input"})
    traj = load_data(mat, columns=["qm", "force=gtau+0*qm"])  # an output may be constant
    with pytest.raises(DataError, match="input 'force' is constant"):
        check_excitation(traj, "force")
    assert check_excitation(traj, ["qm"]) is traj
    with pytest.raises(UnknownVariableError, match="no signal named 'u'"):
        check_excitation(traj, ["u"])


@pytest.mark.parametrize(("columns", "message"), [
    (["force=gtau*"], r"column 'force=gtau\*': 'gtau\*' is not an expression; write numbers and the file's"),
    (["force=sin(vir)"], r"'sin\(vir\)' is not allowed"),
    (["force=vir**2"], r"'vir \*\* 2' is not allowed"),
    (["force=vir.real()"], r"'vir.real\(\)' is not allowed"),
    (["force=__import__('os')"], "is not allowed"),
    (["2x=vir"], "'2x' is not a usable name"),
    (["time=vir"], "'time' is not a usable name"),
    (["qm", "qm=2*qm"], "column name 'qm' is given twice"),
    ([], "columns is empty"),
    ([3], "columns must be names or 'name=expression' strings"),
])
def test_malformed_columns(mat, columns, message):
    with pytest.raises(InvalidSettingError, match=message):
        load_data(mat, columns=columns)


def test_roles_units_and_derive_names_are_checked(mat):
    with pytest.raises(UnknownVariableError, match="roles names 'qm_dot', not among the signals qm, force"):
        load_data(mat, columns=["qm", "force=gtau*vir"], roles={"qm_dot": "state"})
    with pytest.raises(UnknownVariableError, match="units names 'x'"):
        load_data(mat, columns=["qm"], units={"x": "m"})
    with pytest.raises(UnknownVariableError, match="derive names 'vir', not among the columns qm; add it"):
        load_data(mat, columns=["qm"], derive=["vir"])
    with pytest.raises(InvalidSettingError, match="derive would add 'qm_dot', which is already a column"):
        load_data(mat, columns=["qm", "qm_dot=vir"], derive=["qm"])
    with pytest.raises(InvalidSettingError, match="unknown role 'sate'"):
        load_data(mat, columns=["qm"], roles={"qm": "sate"})
    with pytest.raises(InvalidSettingError, match="unknown derive_method"):
        load_data(mat, columns=["qm"], derive=["qm"], derive_method="magic")


def test_unknown_keyword_is_refused(mat):
    with pytest.raises(TypeError):
        load_data(mat, column=["qm"])  # type: ignore[call-arg]
