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
