"""A long record searched at a lower rate: cosim.data.decimation, and diagnose(decimate="auto") on it.

The plant is simulated here with scipy's solve_ivp and its own equations (not cosim's model code): a mass
``m v' = u(t - tau) - b v - Fc tanh(v / vs)`` driven by a multisine, sampled at 1 kHz for 15 s, far faster
than its motion (below 6 Hz): the diagnosis searches at a third of the rate, then refits at the record's own.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cosim.data.decimation import decimate, noise_gain, signal_bandwidth
from cosim.data.trajectory import Trajectory
from cosim.diagnose.diagnosis import diagnose
from cosim.errors import DataError, InvalidSettingError
from cosim.identify.model import IdentifiedModel

M, B = 1.0, 2.0
DT, T = 1e-3, 15.0


def _plant(*, fc: float = 0.0, delay: int = 0, noise: float = 0.005, seed: int = 0) -> Trajectory:
    """The mass's record: a smooth input acting `delay` samples late (recorded on time, sampled)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, T + DT / 2, DT)
    freqs, phases = rng.uniform(0.2, 3.0, 5), rng.uniform(0, 2 * np.pi, 5)

    def force(tt):
        return sum(2.0 * np.sin(2 * np.pi * f * tt + p) for f, p in zip(freqs, phases, strict=True))

    def rhs(tt, s):
        return [s[1], (force(tt - delay * DT) - B * s[1] - fc * np.tanh(s[1] / 0.02)) / M]

    x, v = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0], t_eval=t, rtol=1e-9, atol=1e-11).y
    x = x + rng.normal(scale=noise * np.ptp(x), size=x.size)
    v = v + rng.normal(scale=noise * np.ptp(v), size=v.size)
    return Trajectory.from_arrays(t, {"x": x, "v": v, "u": force(t)}, roles={"x": "state", "v": "state",
                                                                           "u": "input"})


LINEAR = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "x", "u", "1"),
                         coef=np.array([[1.0, 0.0, 0.0, 0.0], [-B / M, 0.0, 1.0 / M, 0.0]]))


def test_decimate_keeps_the_band_averages_the_held_input_and_scales_the_noise():
    rng = np.random.default_rng(3)
    t = np.arange(12000) * DT
    clean = np.sin(2 * np.pi * 2.0 * t) + 0.3 * np.sin(2 * np.pi * 17.0 * t)
    u = np.repeat(rng.standard_normal(3000), 4)  # held for four samples: each new interval's mean is exact
    traj = Trajectory.from_arrays(t, {"x": clean + 0.1 * rng.standard_normal(t.size), "u": u, "c": clean},
                                  roles={"x": "state", "u": "input", "c": "state"})
    slow = decimate(traj, 4)
    assert len(slow) == 3000 and slow.dt == pytest.approx(4 * DT) and slow.names == traj.names
    assert slow.roles == traj.roles and slow.meta["decimated"]["factor"] == 4
    np.testing.assert_allclose(slow["u"], u[::4], rtol=0, atol=1e-12)
    assert np.max(np.abs(slow["c"][10:-10] - clean[::4][10:-10])) < 2e-3   # 17 Hz, well inside 125 Hz: kept
    residual = slow["x"] - clean[::4]
    assert np.var(residual) / 0.01 == pytest.approx(noise_gain(4), rel=0.08)
    assert noise_gain(4) == pytest.approx(0.25, rel=0.05) and noise_gain(1) == 1.0
    assert decimate(traj, 1) is traj


def test_signal_bandwidth_is_the_highest_frequency_above_the_noise():
    rng = np.random.default_rng(5)
    t = np.arange(20000) * DT
    x = np.sin(2 * np.pi * 1.0 * t) + 0.003 * np.sin(2 * np.pi * 40.0 * t)
    assert 39.0 < signal_bandwidth(x + 1e-4 * rng.standard_normal(t.size), DT) < 45.0
    assert signal_bandwidth(x + 0.2 * rng.standard_normal(t.size), DT) < 10.0   # the 40 Hz line under the noise
    assert signal_bandwidth(rng.standard_normal(t.size), DT) < 100.0


@pytest.mark.parametrize(("call", "error", "fragment"), [
    (lambda tr: decimate(tr, 0), InvalidSettingError, "positive integer, got 0"),
    (lambda tr: decimate(tr, 2.5), InvalidSettingError, "positive integer, got 2.5"),
    (lambda tr: decimate(tr, 3, held=["w"]), InvalidSettingError, "held names 'w'"),
    (lambda tr: decimate(tr.slice(0.0, 0.004), 3), DataError, "too short to decimate by 3"),
    (lambda tr: diagnose(LINEAR, tr, decimate=100), InvalidSettingError, "leaves 151 samples.*needs 200"),
    (lambda tr: diagnose(LINEAR, tr, decimate="fast"), InvalidSettingError, 'must be "auto" or a positive'),
])
def test_bad_decimation_settings_are_one_line_errors(call, error, fragment):
    with pytest.raises(error, match=fragment):
        call(_plant())


@pytest.mark.slow
def test_a_long_record_is_searched_decimated_and_its_friction_fitted_at_its_own_rate(tmp_path):
    data = _plant(fc=0.3)
    report = diagnose(LINEAR, data, effects="coulomb_friction,viscous_asymmetry,offset", max_effects=1)
    assert report.analysis["decimation"] == 3 and report.analysis["record_dt"] == pytest.approx(DT)
    assert [e.name for e in report.effects] == ["coulomb_friction"], report.message
    assert report.effects[0].parameters["Fc"] == pytest.approx(0.3, rel=0.1)
    assert report.data is not None and len(report.data) == len(data)   # the figures are the record's own
    assert report.after["nrmse_pct"] < 0.6 * report.before["nrmse_pct"]
    assert "decimated by 3 (333.3 Hz)" in report.write_report(tmp_path / "diagnosis.html").read_text()


def test_a_fixed_value_the_decimated_record_cannot_show_keeps_the_records_rate():
    """1500 periods per radian: inside the 1 kHz record's band, beyond the band of a third of its rate."""
    data = _plant(fc=0.3)
    report = diagnose(LINEAR, data, effects="cogging:periods=1500", max_effects=1)
    assert report.analysis["decimation"] == 1
    assert diagnose(LINEAR, data, effects="cogging:periods=40", max_effects=1).analysis["decimation"] == 3


@pytest.mark.slow
def test_a_delay_found_decimated_is_placed_again_at_the_records_rate():
    """7 samples late at 1 kHz: 2.33 samples of the search's 3 ms step, placed again as taps 7 and 8."""
    report = diagnose(LINEAR, _plant(delay=7), effects="delay", max_effects=1)
    assert report.analysis["decimation"] == 3
    assert [e.name for e in report.effects] == ["delay"], report.message
    assert report.effects[0].parameters["delay_samples"] == pytest.approx(7.0, abs=0.7)
    assert set(report.effects[0].terms) <= {"u_delayed_6", "u_delayed_7", "u_delayed_8"}


def test_cli_decimate_option(tmp_path):
    import json

    from click.testing import CliRunner

    from cosim.cli import main

    path = _plant(fc=0.3).to_csv(tmp_path / "long.csv")
    model = LINEAR.save(tmp_path / "model.json")
    common = ["diagnose", str(path), "--state", "x,v", "--input", "u", "--model", str(model), "--effects", "offset"]
    runner = CliRunner()
    for option, factor in ((["--decimate", "1"], 1), ([], 3), (["--decimate", "5"], 5)):
        result = runner.invoke(main, [*common, *option, "--json"])
        assert result.exit_code == 0, result.output
        assert json.loads(result.stdout)["analysis"]["decimation"] == factor
    assert "searched at 333.3 Hz (the records decimated by 3)" in runner.invoke(main, common).stdout
    for command in (common, ["identify", str(path), "--state", "x,v", "--input", "u"]):
        result = runner.invoke(main, [*command, "--decimate", "fast"])
        assert result.exit_code != 0 and "--decimate must be auto or a positive integer, got 'fast'" in result.output
        assert "Traceback" not in result.output and len(result.output.strip().splitlines()) == 1
    identified = runner.invoke(main, ["identify", str(path), "--state", "x,v", "--input", "u", "--decimate", "2",
                                      "-o", str(tmp_path / "identified.json")])
    assert identified.exit_code == 0, identified.output
    meta = IdentifiedModel.load(tmp_path / "identified.json").meta
    assert meta["refinement"]["decimation"] == 2


@pytest.mark.slow
def test_identification_refines_decimated_then_at_the_records_rate():
    from cosim import SINDYc

    data = _plant(noise=0.02)
    est = SINDYc(refine="output_error").fit(data, states=["x", "v"], inputs=["u"])
    refinement = est.model_.meta["refinement"]
    assert refinement["decimation"] == 3 and refinement["analysis_dt"] == pytest.approx(3 * DT)
    coef = dict(zip(est.terms_, est.coef_[1], strict=True))
    assert coef["v"] == pytest.approx(-B / M, rel=0.02) and coef["u"] == pytest.approx(1.0 / M, rel=0.02)
    plain = SINDYc(refine="output_error", decimate=1).fit(data, states=["x", "v"], inputs=["u"])
    assert "decimation" not in plain.model_.meta["refinement"]
    assert refinement["cost"] <= 1.01 * plain.model_.meta["refinement"]["cost"]   # as good on the record itself
    with pytest.raises(InvalidSettingError, match='decimate must be "auto" or a positive integer, got 0'):
        SINDYc(decimate=0)
    with pytest.raises(InvalidSettingError, match="decimate=100 leaves 151 samples of a 15001-sample record"):
        SINDYc(refine="output_error", decimate=100).fit(data, states=["x", "v"], inputs=["u"])
