"""Kinematics detection (cosim.identify.kinematics) and SINDYc's kinematics="auto", against an independent
two-mass simulator (scipy solve_ivp, equations written here)."""

from __future__ import annotations

import functools
import warnings

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.signal import lfilter

from cosim.data.trajectory import Trajectory
from cosim.errors import DataError, IdentificationWarning, InvalidSettingError
from cosim.identify.kinematics import KinematicPair, _name_pairs, detect_kinematics
from cosim.identify.sindyc import SINDYc


def two_mass(fs: float, *, f_res: float, noise: float, seed: int = 0, duration: float = 4.0) -> np.ndarray:
    """theta1, omega1, theta2, omega2 of two inertias, a damped spring between them, driven by a square wave
    and a sine; white noise of `noise` x each signal's range."""
    x = _noise_free(fs, f_res, seed, duration)
    return x + noise * np.ptp(x, axis=0) * np.random.default_rng(seed + 1).standard_normal(x.shape)


@functools.lru_cache(maxsize=8)  # the grid's three noise levels share one run (most of this file's time)
def _noise_free(fs: float, f_res: float, seed: int, duration: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    j1, j2 = 0.02, 0.06
    jr = j1 * j2 / (j1 + j2)
    k = (2 * np.pi * f_res) ** 2 * jr
    c, b1, b2 = 0.04 * np.sqrt(k * jr), 0.01, 0.03
    f1, f2 = rng.uniform(0.3, 3.0, 2)

    def torque(t):
        return np.sign(np.sin(2 * np.pi * f1 * t + 0.3)) + 0.5 * np.sin(2 * np.pi * f2 * t)

    def rhs(t, s):
        th1, w1, th2, w2 = s
        twist = k * (th1 - th2) + c * (w1 - w2)
        return [w1, (torque(t) - twist - b1 * w1) / j1, w2, (twist - b2 * w2) / j2]

    t = np.arange(int(round(duration * fs)) + 1) / fs
    x = solve_ivp(rhs, (0, t[-1]), [0.0, 0.0, 0.1, 0.0], t_eval=t, rtol=1e-9, atol=1e-11, max_step=1 / fs).y.T
    x.flags.writeable = False  # shared by the cases that use it
    return x


NAMES = ["theta_m", "omega_m", "theta_L", "omega_L"]
GRID = [(fs, f_res, noise) for fs in (200, 1000, 5000) for f_res in (1.0, 10.0) for noise in (0.0, 0.01, 0.05)]


@pytest.mark.parametrize("fs,f_res,noise", GRID)
def test_name_pairs_are_confirmed_and_data_pairs_found(fs, f_res, noise):
    x = two_mass(fs, f_res=f_res, noise=noise)
    with warnings.catch_warnings():
        warnings.simplefilter("error", IdentificationWarning)  # a true name pair is never contradicted
        pairs = detect_kinematics(NAMES, x, 1 / fs)
    assert [(p.position, p.velocity, p.found) for p in pairs] == [("theta_m", "omega_m", "name"),
                                                                  ("theta_L", "omega_L", "name")]
    assert all(abs(p.gain - 1) < 0.03 for p in pairs)
    # the same signals under names that say nothing, shuffled: found from the data alone (when the gain is
    # known to 1 %: up to 1 % noise on these 4 s records; at 5 % the data may stay silent, never wrong)
    shuffled = detect_kinematics(["s1", "s2", "s3", "s4"], x[:, [2, 0, 3, 1]], 1 / fs)
    found = sorted((p.position, p.velocity) for p in shuffled)
    if noise <= 0.01:
        assert found == [("s1", "s3"), ("s2", "s4")] and {p.found for p in shuffled} == {"data"}
    else:
        assert set(found) <= {("s1", "s3"), ("s2", "s4")}


@pytest.mark.parametrize("fs,f_res,noise", GRID)
def test_no_pair_where_none_exists(fs, f_res, noise):
    x = two_mass(fs, f_res=f_res, noise=noise, seed=5)
    dt = 1 / fs
    rpm = x[:, 1] * 60 / (2 * np.pi)
    alpha = np.exp(-dt / 0.05)  # a first-order low-pass, 50 ms
    filtered = lfilter([1 - alpha], [1, -alpha], x[:, 1])
    assert detect_kinematics(["w1", "w2"], x[:, [1, 3]], dt) == ()              # two coupled velocities
    assert detect_kinematics(["a", "b"], np.c_[x[:, 0], rpm], dt) == ()         # a velocity in rpm
    assert detect_kinematics(["p", "q"], np.c_[filtered, x[:, 1]], dt) == ()    # a filtered signal, its input
    assert detect_kinematics(["p", "q"], np.c_[x[:, 1], filtered], dt) == ()
    with pytest.warns(IdentificationWarning, match="omega_m is not the derivative of theta_m"):
        assert detect_kinematics(["theta_m", "omega_m"], np.c_[x[:, 0], rpm], dt) == ()


@pytest.mark.parametrize("names,expected", [
    (["x", "x_dot"], [("x", "x_dot")]), (["x", "xdot"], [("x", "xdot")]), (["x", "dx"], [("x", "dx")]),
    (["x", "x_d"], [("x", "x_d")]), (["q", "qd"], [("q", "qd")]), (["qm", "qm_dot"], [("qm", "qm_dot")]),
    (["theta_m", "omega_m"], [("theta_m", "omega_m")]), (["pos", "vel"], [("pos", "vel")]),
    (["x1", "v1", "x2", "v2"], [("x1", "v1"), ("x2", "v2")]), (["phi", "w"], [("phi", "w")]),
    (["position_2", "velocity_2"], [("position_2", "velocity_2")]), (["Theta_L", "Omega_L"], [("Theta_L", "Omega_L")]),
    (["xylo", "vylo"], []), (["theta_m", "omega_L"], []), (["u", "y"], []),
])
def test_name_patterns(names, expected):
    assert _name_pairs(names) == expected


def test_bad_arguments():
    x = np.zeros((50, 2))
    with pytest.raises(DataError, match="one column per name"):
        detect_kinematics(["a", "b", "c"], x, 0.01)
    with pytest.raises(InvalidSettingError, match="dt must be a positive"):
        detect_kinematics(["a", "b"], x, 0.0)
    with pytest.raises(InvalidSettingError, match="repeated names"):
        detect_kinematics(["a", "a"], x, 0.01)
    with pytest.raises(DataError, match="NaN or inf"):
        detect_kinematics(["a", "b"], np.full((50, 2), np.nan), 0.01)


# ------------------------------------------------------------------------------------------ SINDYc
def _record(names: list[str], noise: float = 0.0, fs: float = 1000.0) -> Trajectory:
    x = two_mass(fs, f_res=5.0, noise=noise, duration=3.0, seed=2)
    t = np.arange(len(x)) / fs
    rng = np.random.default_rng(2)
    f1, f2 = rng.uniform(0.3, 3.0, 2)
    u = np.sign(np.sin(2 * np.pi * f1 * t + 0.3)) + 0.5 * np.sin(2 * np.pi * f2 * t)
    # the simulator's torque is continuous-time; SINDYc reads it as held, which is close at 1 kHz
    return Trajectory.from_arrays(t, {**dict(zip(names, x.T, strict=True)), "u": u},
                                  roles={**dict.fromkeys(names, "state"), "u": "input"})


@pytest.mark.parametrize("names,found", [(NAMES, "name"), (["a", "b", "c", "d"], "data")])
def test_sindyc_pins_detected_rows_exactly(names, found):
    est = SINDYc(allow_unstable=True).fit(_record(names, noise=0.005))
    assert [(p.position, p.velocity, p.found) for p in est.kinematics_] == [
        (names[0], names[1], found), (names[2], names[3], found)]
    coef = dict(zip(est.terms_, est.coef_[0], strict=True))
    assert coef[names[1]] == 1.0 and sum(v != 0 for v in coef.values()) == 1
    assert est.model_.meta["kinematics"] == {names[0]: names[1], names[2]: names[3]}
    assert [p["found"] for p in est.model_.meta["kinematics_found"]] == [found, found]


def test_sindyc_kinematics_off_and_given():
    record = _record(NAMES, noise=0.0)
    free = SINDYc(kinematics=None, allow_unstable=True).fit(record)
    assert free.kinematics_ == () and free.model_.meta["kinematics"] == {}
    assert free.get_params()["kinematics"] == "none"
    given = SINDYc(kinematics={"theta_m": "omega_m"}, allow_unstable=True).fit(record)
    assert given.kinematics_ == (KinematicPair("theta_m", "omega_m", "given"),)
    assert SINDYc(kinematics="none").get_params()["kinematics"] == "none"
    with pytest.raises(InvalidSettingError, match="kinematics must be 'auto', 'none'"):
        SINDYc(kinematics="sometimes")


def test_records_of_unequal_lengths():
    """Separate experiments rarely have the same length: the pairs are found over records of 2001, 1500 and
    801 samples alike (a list of such arrays once failed inside numpy before any test ran)."""
    x = two_mass(500, f_res=1.0, noise=0.01)
    records = [x[:2001], x[:1500], x[200:1001]]
    pairs = detect_kinematics(["s1", "s2", "s3", "s4"], [r[:, [2, 0, 3, 1]] for r in records], 1 / 500)
    assert sorted((p.position, p.velocity) for p in pairs) == [("s1", "s3"), ("s2", "s4")]
    # rows of samples given as lists are still one record
    assert len(detect_kinematics(NAMES, x.tolist(), 1 / 500)) == 2
