"""`cosim compare` / `cosim.identify.compare`: a model's prediction of data, scored as fit_pct, nrmse_pct and
r2 (the same names in identify, diagnose and compare); `cosim simulate --input-file` replays recorded inputs;
files other tools read."""

import json

import numpy as np
import pandas as pd
import pytest
import scipy.io
from click.testing import CliRunner

from cosim.cli import main
from cosim.data.trajectory import Trajectory
from cosim.errors import InvalidSettingError, UnknownVariableError
from cosim.identify.compare import compare
from cosim.identify.model import IdentifiedModel

# a damped oscillator x'' = -4 x - 0.4 x' + u, written as a linear model
OSCILLATOR = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("x", "v", "u"),
                             coef=np.array([[0.0, 1.0, 0.0], [-4.0, -0.4, 1.0]]), dt=0.01)


def record(seed: int, noise: float = 0.0, x0=(0.3, -0.2)) -> Trajectory:
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.standard_normal(60), 25)[:, None]
    clean = OSCILLATOR.simulate(list(x0), u[:-1], dt=0.01).to_trajectory()
    return clean.with_noise(noise, seed=seed, names=["x", "v"]) if noise else clean


def test_the_true_model_scores_perfectly_and_its_initial_state_is_found():
    result = compare(OSCILLATOR, record(0))
    assert result.fit_pct == pytest.approx({"x": 100.0, "v": 100.0}, abs=1e-6)
    assert result.nrmse_pct == pytest.approx({"x": 0.0, "v": 0.0}, abs=1e-6)
    assert result.r2 == pytest.approx({"x": 1.0, "v": 1.0}, abs=1e-10)
    assert result.x0 == pytest.approx({"x": 0.3, "v": -0.2}, abs=1e-7)
    one_step = compare(OSCILLATOR, record(0), horizon=1)
    assert one_step.fit_pct["x"] == pytest.approx(100.0, abs=1e-6) and len(one_step.measured) == 1499


def test_the_scores_are_matlabs_fit_its_error_and_r2():
    data = record(1, noise=0.2)
    result = compare(OSCILLATOR, data, x0="measured")
    y, f = data["x"], result.predicted["x"]
    fit = 100 * (1 - np.linalg.norm(y - f) / np.linalg.norm(y - y.mean()))
    assert result.fit_pct["x"] == pytest.approx(fit, rel=1e-12)
    assert result.fit_pct["x"] + result.nrmse_pct["x"] == pytest.approx(100.0)
    assert result.r2["x"] == pytest.approx(1 - np.sum((y - f) ** 2) / np.sum((y - y.mean()) ** 2), rel=1e-12)


def test_an_estimated_initial_state_is_not_thrown_off_by_a_noisy_first_sample():
    data = record(2, noise=0.3)
    estimated, measured = compare(OSCILLATOR, data), compare(OSCILLATOR, data, x0="measured")
    cost = {k: sum(e ** 2 for e in r.nrmse_pct.values()) for k, r in (("e", estimated), ("m", measured))}
    assert cost["e"] < cost["m"]
    truth = np.array([0.3, -0.2])
    first = np.array([data["x"][0], data["v"][0]])
    assert np.linalg.norm(np.array(list(estimated.x0.values())) - truth) < 0.2 * np.linalg.norm(first - truth)


def test_bad_requests_are_refused():
    with pytest.raises(UnknownVariableError, match="the data lack u of the model"):
        compare(OSCILLATOR, record(0).select(["x", "v"]))
    with pytest.raises(InvalidSettingError, match="horizon must be a whole number of samples in 1..1499"):
        compare(OSCILLATOR, record(0), horizon=1500)
    with pytest.raises(InvalidSettingError, match="x0='first'; choose one of estimate, measured, model"):
        compare(OSCILLATOR, record(0), x0="first")


def test_the_figure_has_an_error_panel_under_each_state_and_the_html_a_row_each(tmp_path):
    result = compare(OSCILLATOR, record(3, noise=0.1))
    fig = result.plot(tmp_path / "c.png")
    assert [ax.get_ylabel() for ax in fig.axes] == ["x", "error", "v", "error"]
    assert (tmp_path / "c.png").stat().st_size > 1000
    assert result._repr_html_().count("<tr>") == 3


@pytest.fixture(scope="module")
def identified(fmu, tmp_path_factory):
    folder = tmp_path_factory.mktemp("compare")
    runner = CliRunner()
    data = folder / "data.csv"
    assert runner.invoke(main, ["simulate", str(fmu), "--input", "Tm=square:amp=500,freq=2", "--duration", "2",
                                "--dt", "1/2257", "--noise", "0.02", "-o", str(data)]).exit_code == 0
    result = runner.invoke(main, ["identify", str(data), "--state", "theta_m,omega_m,theta_L,omega_L", "--input",
                                  "Tm", "-o", str(folder / "model.json"), "--json"])
    assert result.exit_code == 0, result.output
    return folder, json.loads(result.stdout)


def test_compare_on_the_training_data_gives_identifys_fit(identified):
    folder, printed = identified
    result = CliRunner().invoke(main, ["compare", str(folder / "model.json"), str(folder / "data.csv"), "--json",
                                       "--plot", str(folder / "compare.png")])
    assert result.exit_code == 0, result.output
    scores = json.loads(result.stdout)
    for key in ("fit_pct", "nrmse_pct", "r2"):
        assert scores[key] == pytest.approx(printed["fit"][key], rel=1e-12, abs=1e-12)
    library = compare(IdentifiedModel.load(folder / "model.json"), Trajectory.read(folder / "data.csv"))
    assert library.fit_pct == pytest.approx(scores["fit_pct"], rel=1e-12)
    assert min(scores["fit_pct"].values()) > 90.0 and (folder / "compare.png").is_file()


def test_compare_bad_input_is_one_line_exit_2(identified, tmp_path):
    folder, _ = identified
    result = CliRunner().invoke(main, ["compare", str(folder / "model.json"), str(folder / "data.csv"),
                                       "--state", "theta_m,omega_m,theta_L,nope"])
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and "nope" in result.stderr
    result = CliRunner().invoke(main, ["compare", str(folder / "model.json"), str(tmp_path / "none.csv")])
    assert result.exit_code == 2 and "none.csv" in result.stderr


def test_simulate_replays_its_own_recorded_inputs_exactly(fmu, tmp_path):
    runner = CliRunner()
    first = ["simulate", str(fmu), "--input", "Tm=multisine:amp=1000,fmin=1,fmax=40", "--input",
             "TL=step:value=300,at=0.2", "--duration", "1128/2257", "--dt", "1/2257", "--set", "Fc=50",
             "-o", str(tmp_path / "a.csv")]
    assert runner.invoke(main, first).exit_code == 0
    again = runner.invoke(main, ["simulate", str(fmu), "--input-file", str(tmp_path / "a.csv"), "--set", "Fc=50",
                                 "-o", str(tmp_path / "b.csv"), "--json"])
    assert again.exit_code == 0, again.output
    assert json.loads(again.stdout)["input_file"]["hold"] == "zoh"
    a, b = pd.read_csv(tmp_path / "a.csv"), pd.read_csv(tmp_path / "b.csv")  # plain CSV: no options
    assert list(a.columns) == ["time", "Tm", "TL", "theta_m", "omega_m", "theta_L", "omega_L"] == list(b.columns)
    np.testing.assert_allclose(b.to_numpy(), a.to_numpy(), rtol=0, atol=1e-12)
    assert Trajectory.read(tmp_path / "a.csv").roles[:2] == ("input", "input")


def test_simulate_input_file_interpolates_when_asked_and_refuses_what_it_cannot_do(fmu, tmp_path):
    t = np.arange(11) * 0.01
    Trajectory.from_arrays(t, {"Tm": np.linspace(0.0, 100.0, 11), "other": t}).write(tmp_path / "u.csv")
    runner = CliRunner()
    out = runner.invoke(main, ["simulate", str(fmu), "--input-file", str(tmp_path / "u.csv"), "--hold", "linear",
                               "--dt", "0.005", "-o", str(tmp_path / "r.csv")])
    assert out.exit_code == 0, out.output
    assert "interpolated linearly; drove Tm; left TL to the FMU (start 0)" in out.stdout
    np.testing.assert_allclose(pd.read_csv(tmp_path / "r.csv")["Tm"], np.linspace(0.0, 100.0, 21), atol=1e-9)
    for args, message in [(["--duration", "1"], "reaches outside the recorded inputs"),
                          (["--input", "Tm=1"], "input Tm is given by --input and by --input-file")]:
        bad = runner.invoke(main, ["simulate", str(fmu), "--input-file", str(tmp_path / "u.csv"), *args,
                                   "-o", str(tmp_path / "x.csv")])
        assert bad.exit_code == 2 and message in bad.stderr and not (tmp_path / "x.csv").exists()
    Trajectory.from_arrays(t, {"torque": t}).write(tmp_path / "w.csv")
    bad = runner.invoke(main, ["simulate", str(fmu), "--input-file", str(tmp_path / "w.csv")])
    assert bad.exit_code == 2 and "has no column named as an input of" in bad.stderr


def test_every_mat_file_cosim_writes_reads_in_scipy(identified):
    folder, _ = identified
    result = CliRunner().invoke(main, ["export", str(folder / "model.json"), "-o", str(folder / "ss.mat")])
    assert result.exit_code == 0, result.output
    mat = scipy.io.loadmat(folder / "ss.mat")
    assert mat["A"].shape == (4, 4) and mat["B"].shape[0] == 4


def test_a_mat_matrix_reads_wherever_a_csv_does(tmp_path):
    """One .mat array of channels (time, x, v, u), addressed by column in identify, compare and data info."""
    data = record(4, noise=0.01)
    scipy.io.savemat(tmp_path / "rig.mat", {"data": np.column_stack([data.time, data["x"], data["v"], data["u"]])})
    columns = ["--time", "data[:,0]", "--state", "x=data[:,1],v=data[:,2]", "--input", "u=data[:,3]"]
    runner = CliRunner()
    made = runner.invoke(main, ["identify", str(tmp_path / "rig.mat"), *columns, "-o", str(tmp_path / "m.json"),
                                "--json"])
    assert made.exit_code == 0, made.output
    scored = runner.invoke(main, ["compare", str(tmp_path / "m.json"), str(tmp_path / "rig.mat"), *columns,
                                  "--json"])
    assert scored.exit_code == 0, scored.output
    assert json.loads(scored.stdout)["fit_pct"] == pytest.approx(json.loads(made.stdout)["fit"]["fit_pct"])
    assert min(json.loads(scored.stdout)["fit_pct"].values()) > 95.0
    info = runner.invoke(main, ["data", "info", str(tmp_path / "rig.mat"), "--time", "data[:,0]", "--columns",
                                "x=data[:,1],u=data[:,3]", "--json"])
    assert info.exit_code == 0, info.output
    assert [s["name"] for s in json.loads(info.stdout)["signals"]] == ["x", "u"]


@pytest.mark.parametrize("index", [0, 2, 3])  # one mass; two masses; two masses measured by positions only
def test_identify_then_compare_on_records_of_an_independent_simulator(tmp_path, index):
    """benchmarks/independent_plants.py (scipy solve_ivp, its own equations): `cosim identify` with its defaults,
    then `cosim compare` on the training record (identify's own figures, through the same reader, --derive
    included) and on the held-out twin, where the estimated initial state beats the twin's noisy first sample."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import independent_plants as ip

    record = ip.make_record(index, max_samples=1000)
    record.write(tmp_path)
    cli = record.cli
    columns = ["--state", ",".join(cli["states"]), "--input", cli["input"]]
    columns += ["--derive", ",".join(cli["derive"])] if cli["derive"] else []
    runner = CliRunner()
    made = runner.invoke(main, ["identify", str(tmp_path / "train.csv"), *columns, "--allow-unstable",
                                "-o", str(tmp_path / "m.json"), "--json"])
    assert made.exit_code == 0, made.output
    scores = {}
    for name, x0 in (("train", "estimate"), ("heldout", "estimate"), ("heldout", "measured")):
        out = runner.invoke(main, ["compare", str(tmp_path / "m.json"), str(tmp_path / f"{name}.csv"), *columns,
                                   "--x0", x0, "--json"])
        assert out.exit_code == 0, out.output
        scores[name, x0] = json.loads(out.stdout)
    fit = json.loads(made.stdout)["fit"]
    if fit:  # a model whose free run diverges on its own data has no fit to compare
        assert scores["train", "estimate"]["fit_pct"] == pytest.approx(fit["fit_pct"], rel=1e-9, abs=1e-9)
    cost = {x0: sum(v ** 2 for v in scores["heldout", x0]["nrmse_pct"].values() if v is not None)
            for x0 in ("estimate", "measured")}
    assert cost["estimate"] <= cost["measured"] * (1 + 1e-12)
