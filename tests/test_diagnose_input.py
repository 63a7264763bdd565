"""Bad input to the diagnosis, through the library (load_data then diagnose) and through `cosim diagnose`.

Each case is a file as a user would have it: too short, an input that never changes, a NaN, a ``.mat`` without
the named variables, time that is not uniform. Each must give a one-line error naming what is wrong and what to
do, a non-zero exit and no traceback.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io
from click.testing import CliRunner
from diagnose_fixtures import MODEL, assert_one_line_error, record, write_csv

from cosim.cli import main
from cosim.data.datafile import load_data
from cosim.diagnose.diagnosis import diagnose
from cosim.errors import DataError, UnknownVariableError


@pytest.fixture()
def files(tmp_path):
    good = record(1000)
    nan = {**good, "x": good["x"].copy()}
    nan["x"][300] = np.nan
    gap = {**good, "t": good["t"].copy()}
    gap["t"][500:] += 0.0004
    scipy.io.savemat(tmp_path / "renamed.mat", {"t": good["t"][:, None], "pos": good["x"][:, None],
                                                "vel": good["v"][:, None], "u": good["u"][:, None]})
    scipy.io.savemat(tmp_path / "notime.mat", {"time_s": good["t"][:, None], **{k: good[k][:, None]
                                                                                 for k in ("x", "v", "u")}})
    return {"short": write_csv(tmp_path / "short.csv", record(100)),
            "tiny": write_csv(tmp_path / "tiny.csv", record(5)),
            "constant": write_csv(tmp_path / "constant.csv", record(1000, constant=True)),
            "nan": write_csv(tmp_path / "nan.csv", nan),
            "gap": write_csv(tmp_path / "gap.csv", gap),
            "renamed": tmp_path / "renamed.mat",
            "notime": tmp_path / "notime.mat",
            "model": MODEL.save(tmp_path / "model.json")}


def cli(*args: str):
    return CliRunner().invoke(main, ["diagnose", *map(str, args)], catch_exceptions=False)


@pytest.mark.parametrize(("case", "with_model", "fragments"), [
    ("short", True, ["short.csv has 100 samples; diagnosis needs at least 200; use a longer record"]),
    # without a model the identification would come first and complain about its library: the length is
    # checked before it
    ("short", False, ["short.csv has 100 samples; diagnosis needs at least 200"]),
    ("tiny", False, ["tiny.csv has 5 samples; diagnosis needs at least 200"]),
    ("constant", False, ["input 'u' is constant", "excite the system"]),
    ("nan", False, ["'x' is nan at t=0.3 s (row 300)", "drop or fill the bad samples"]),
    ("gap", True, ["time 't' of gap.csv is not uniform: the step before row 500", "--resample"]),
    ("renamed", False, ["renamed.mat has no variable 'x'", "it has: t, pos, vel, u"]),
    ("notime", False, ["notime.mat has no time variable 't' or 'time'; it has: time_s", "--time"]),
])
def test_cli_bad_input_is_one_line_that_says_what_to_do(files, case, with_model, fragments):
    model = ["--model", files["model"]] if with_model else []
    assert_one_line_error(cli(files[case], "--state", "x,v", "--input", "u", "--json", *model), *fragments)


def test_cli_mat_without_the_expression_variable(files):
    result = cli(files["renamed"], "--state", "pos,vel", "--input", "force=35.15*vir")
    assert_one_line_error(result, "renamed.mat has no variable 'vir' (column 'force=35.15*vir')", "it has: t, pos")


def test_cli_the_remedies_the_errors_name_work(files):
    """--resample and --time, which the errors point to, make the same files diagnosable."""
    import json

    result = cli(files["gap"], "--state", "x,v", "--input", "u", "--model", files["model"], "--resample",
                 "--effects", "offset", "--json")
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["before"]["r2"] > 0.99
    result = cli(files["notime"], "--state", "x,v", "--input", "u", "--model", files["model"], "--time", "time_s",
                 "--effects", "offset", "--json")
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["effects"] == []


@pytest.mark.parametrize(("case", "error", "fragment"), [
    ("short", DataError, "diagnosis needs at least 200 samples per record, the data have 100"),
    ("constant", DataError, "input 'u' is constant"),
    ("nan", DataError, r"'x' is nan at t=0.3 s \(row 300\)"),
    ("gap", DataError, "not uniform.*pass resample=True"),
    ("renamed", UnknownVariableError, "renamed.mat has no variable 'x'.*it has: t, pos, vel, u"),
])
def test_api_load_data_then_diagnose_refuses_bad_input(files, case, error, fragment):
    with pytest.raises(error, match=fragment):
        data = load_data(files[case], columns=["x", "v", "u"], roles={"x": "state", "v": "state", "u": "input"})
        diagnose(MODEL, data)


def test_an_effect_refitted_out_of_range_is_dropped():
    """A delay whose taps the later refits left with a centroid of minus hundreds of samples (seen on the
    record of benchmarks/bench_diagnosis.py: -115) is no finding: _drop_implausible removes it, refits, and
    reports it as rejected with ``plausible`` False; a plausible one stays."""
    from cosim.diagnose._trials import _FitOptions
    from cosim.diagnose.candidates import EffectCandidate
    from cosim.diagnose.diagnosis import _drop_implausible
    from cosim.diagnose.effects import delayed_name
    from cosim.identify.model import IdentifiedModel

    data = record(3000)
    columns = {k: v for k, v in data.items() if k != "t"}
    taps = (delayed_name("u", 3), delayed_name("u", 4))
    for k, name in zip((3, 4), taps, strict=True):
        columns[name] = np.concatenate([np.full(k, data["u"][0]), data["u"][:len(data["u"]) - k]])
    fit = _FitOptions(estimate_x0=True, noise=None)
    delay = EffectCandidate("delay", "u", ("v",), 3.0, taps, -100.0, 1e-9, {"size": 0.01}, True)

    def model(weights):
        return IdentifiedModel(states=("x", "v"), inputs=("u", *taps), terms=("v", "x", "u", *taps),
                               coef=np.array([[1.0, 0.0, 0.0, 0.0, 0.0], [-3.0, -20.0, *weights]]), dt=1e-3,
                               meta={"x0": [[0.0, 0.0]], "refinement": {"cost": 1.0}})

    # the input's gain 1.0 split as 10 - 8.5 - 0.5: centroid (3 * -8.5 + 4 * -0.5) / 1.0 = -27.5 samples
    current, kept, owners, _, gone = _drop_implausible(model((10.0, -8.5, -0.5)), [delay], [], [], columns,
                                                       1e-3, fit)
    assert kept == [] and [c.name for c in gone] == ["delay"] and gone[0].explained["plausible"] is False
    assert gone[0].parameters["delay_samples"] == pytest.approx(-27.5)
    assert not any(t in current.terms for t in taps)
    assert current.coef[1, current.terms.index("u")] == pytest.approx(1.0, rel=1e-3)  # the refit without it
    # 0.2 + 0.6 + 0.2 of the gain at 0, 3 and 4 samples: centroid 2.6, plausible, kept untouched
    plausible = model((0.2, 0.6, 0.2))
    current, kept, _, _, gone = _drop_implausible(plausible, [delay], [], [], columns, 1e-3, fit)
    assert kept == [delay] and gone == [] and current is plausible
