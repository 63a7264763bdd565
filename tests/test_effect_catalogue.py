"""The effect catalogue: nuisance grids from the physics of the record, effect selections with fixed values,
standard errors of every effect's parameter, and the cubic spring on one position (a Duffing oscillator).

The records are built here: synthetic signals with known ranges for the grid rules, and a Duffing oscillator
``m x'' + c x' + k x + k3 x^3 = u`` integrated with scipy's ``solve_ivp`` (input held over each sample) for the
end-to-end case.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cosim.data.trajectory import Trajectory
from cosim.diagnose import _record_band as rb
from cosim.diagnose._ranking import check_effect_selection
from cosim.diagnose.candidates import _uncertainty
from cosim.diagnose.effects import EFFECTS, Attachment, RecordBand, Roles, effect_names, effect_selection
from cosim.errors import InvalidSettingError, UnknownVariableError
from cosim.identify.model import IdentifiedModel

DT = 1e-3


def slew(extent: float, speed: float, n: int = 4000) -> np.ndarray:
    """A position ramping through `extent` at `speed` (units per s), sampled at DT."""
    return np.minimum(np.arange(n) * DT * speed, extent)


def attachment(name: str) -> Attachment:
    return Attachment(name, (name,), ("v",))


# ---------------------------------------------------------------------------------------------- grids and bounds
def test_cogging_grid_is_bounded_by_the_nyquist_band_and_two_periods_of_travel():
    p = slew(3.0, 2.0)  # 3 rad at 2 rad/s, 1 kHz: Nyquist 500 Hz
    band = RecordBand.of({"p": p}, DT)
    lo, hi = EFFECTS["cogging"].nuisance_span(attachment("p"), {"p": p}, band)
    assert lo == math.ceil(2 * 2 * math.pi / 3.0)  # two periods over the 3 rad of travel: n >= 4.19
    assert hi == math.floor(0.8 * 500 * 2 * math.pi / 2.0)  # n * 2 rad/s / (2 pi) below 400 Hz
    grid = EFFECTS["cogging"].grid(attachment("p"), {"p": p}, band)
    assert grid[0] == lo and np.all(np.diff(grid) == 1.0)  # the travel resolves every whole period
    assert len(grid) == rb.PERIODIC_POINTS
    # the same motion sampled ten times faster: the band's top moves with the sampling
    fast = np.minimum(np.arange(40000) * DT / 10 * 2.0, 3.0)
    span = EFFECTS["cogging"].nuisance_span(attachment("p"), {"p": fast}, RecordBand.of({"p": fast}, DT / 10))
    assert span == (lo, pytest.approx(10 * hi, abs=10))


def test_cogging_grid_on_a_short_travel_starts_high_and_steps_at_its_resolution():
    p = 0.02 * np.sin(2 * np.pi * np.arange(4000) * DT)  # +-0.02 rad: two periods need n >= 315
    grid = EFFECTS["cogging"].grid(attachment("p"), {"p": p}, RecordBand.of({"p": p}, DT))
    assert grid[0] == math.ceil(4 * math.pi / np.ptp(p))
    assert np.diff(grid)[0] == int(math.pi / np.ptp(p))


def test_cogging_is_not_tried_where_the_record_cannot_show_it():
    # +-0.25 rad at 30 Hz (up to 47 rad/s) sampled at 100 Hz: two periods need n >= 26, Nyquist allows n <= 6
    p = 0.25 * np.sin(2 * np.pi * 30.0 * np.arange(400) * 0.01 + 0.3)
    band = RecordBand.of({"p": p}, 0.01)
    assert EFFECTS["cogging"].grid(attachment("p"), {"p": p}, band) == []


def test_cogging_range_is_the_measured_one_when_the_free_run_moves_less():
    # a poor base model's free run turns through 0.5 rad where the plant turned through 3 (noise 0.01 each
    # side): two periods over 3 - 4 x 0.01 rad, not over 0.5
    free = slew(0.5, 2.0)
    measured = slew(3.0, 2.0) + 0.01 * np.random.default_rng(0).standard_normal(4000)
    band = RecordBand.of({"p": free}, DT, {"p": 0.01}, measured={"p": measured})
    assert band.measured_ranges["p"] == pytest.approx(np.ptp(measured) - 0.04)
    lo, _ = EFFECTS["cogging"].nuisance_span(attachment("p"), {"p": free}, band)
    assert lo == math.ceil(4 * math.pi / (np.ptp(measured) - 0.04)) < math.ceil(4 * math.pi / 0.5)


def test_cogging_resonance_limit_holds_at_the_median_speed():
    # half the record creeping at 0.1 rad/s, a tenth sweeping at 10 rad/s: a ripple of n periods per rad is at
    # n * 0.1 / (2 pi) Hz for half the record, whatever it is at the top speed
    speed = np.r_[np.full(2400, 0.1), np.full(1200, 1.0), np.full(400, 10.0)]
    p = np.cumsum(speed) * DT
    band = RecordBand(dt=DT, samples=p.size, visible={"p": 2.0})
    _, hi = rb.periodic_span(p, band, "p")
    median = float(np.median(rb.speed_of(p, band)))
    assert hi == math.floor(2.0 * 2 * math.pi / median)
    assert hi > math.floor(2.0 * 2 * math.pi / rb.typical_speed(rb.speed_of(p, band)))  # the old, top-speed cap


def test_gravity_needs_the_angle_to_turn():
    band = RecordBand.of({}, DT)
    assert EFFECTS["gravity"].grid(attachment("p"), {"p": slew(0.3, 1.0)}, band) == []
    assert EFFECTS["gravity"].grid(attachment("p"), {"p": slew(2.0, 1.0)}, band) == [None]


def test_stribeck_grid_lies_between_the_noise_and_a_third_of_the_speed():
    t = np.arange(6000) * DT
    v = 0.3 * np.sin(2 * np.pi * 1.0 * t)
    band = RecordBand.of({"v": v}, DT, {"v": 0.005})
    grid = EFFECTS["stribeck"].grid(attachment("v"), {"v": v}, band)
    assert grid and min(grid) >= 2 * 0.005 - 1e-12 and max(grid) <= 0.1 + 1e-12
    # a record that hardly ever moves slowly cannot show a small Stribeck velocity
    always_fast = np.sign(np.sin(2 * np.pi * 0.5 * t)) * (1.0 + 0.2 * np.sin(2 * np.pi * 3 * t))
    grid = EFFECTS["stribeck"].grid(attachment("v"), {"v": always_fast}, RecordBand.of({"v": always_fast}, DT))
    assert all(np.mean(np.abs(always_fast) < 2 * vs) >= rb.MIN_SHARE for vs in grid)
    assert not grid or min(grid) > 0.3


def test_coulomb_smoothing_grid_follows_the_speed_range():
    v = 0.3 * np.sin(2 * np.pi * np.arange(6000) * DT)
    for scale in (1.0, 100.0):
        grid = EFFECTS["coulomb_friction"].grid(attachment("v"), {"v": scale * v},
                                                RecordBand.of({"v": scale * v}, DT))
        assert 1e-4 * 0.3 * scale <= min(grid) and max(grid) <= 0.1 * 0.3 * scale + 1e-12
        assert len(grid) >= 3 and np.all(np.diff(np.log(grid)) > 0)


def test_the_step_from_one_record_into_the_next_is_no_reversal():
    """Two records, each moving one way from rest, concatenated: the join is no reversal, and the friction's
    switch is not held as smooth as the motion's speed there."""
    t = np.arange(2000) * DT
    one_way = 0.3 * (1.0 - np.exp(-t / 0.2)) * (1.2 + np.sin(2 * np.pi * 0.7 * t))  # never below zero
    v = np.concatenate([one_way, -one_way[::-1] - 0.01])
    assert rb.reversal_step(v) == pytest.approx(abs(v[1999] - v[2000]))  # the join, read as a reversal
    assert np.isnan(rb.reversal_step(v, [0, 2000]))
    joined = rb.smoothing_span(v, RecordBand.of({"v": v}, DT), "v")
    apart = rb.smoothing_span(v, RecordBand.of({"v": v}, DT, segments=[0, 2000]), "v")
    assert joined[0] >= 0.01 and apart[0] == pytest.approx(1e-4 * np.abs(v).max())
    turning = 0.3 * np.sin(2 * np.pi * t)  # a genuine reversal inside a record still counts
    both = np.concatenate([turning, turning])
    assert rb.reversal_step(both, [0, 2000]) == pytest.approx(rb.reversal_step(turning), rel=0.2)


@pytest.mark.parametrize(("samples", "longest"), [(300, 6), (4000, 75), (10**6, 185)])
def test_delay_grid_is_bounded_by_the_record(samples, longest):
    u = np.sin(np.arange(samples) * DT * 7.0)
    grid = EFFECTS["delay"].grid(Attachment("u", ("u",), ("v",)), {"u": u}, RecordBand.of({"u": u}, DT))
    assert grid[:6] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert max(grid) == longest and max(grid) <= max(rb.DELAY_SHARE * samples, 1)


def test_cubic_stiffness_attaches_to_each_position_and_each_coupled_pair():
    model = IdentifiedModel(states=("a", "va", "b", "vb"), inputs=("u",), terms=("va", "a", "b", "vb", "u"),
                            coef=np.array([[1.0, 0, 0, 0, 0], [-1.0, -100.0, 100.0, 0, 2.0],
                                           [0, 0, 0, 1.0, 0], [0, 50.0, -50.0, -1.0, 0]]))
    roles = Roles.of(model)
    places = {a.label: EFFECTS["cubic_stiffness"].terms(a, None) for a in EFFECTS["cubic_stiffness"].attachments(roles)}
    assert places == {"a": ("a**3",), "b": ("b**3",), "a-b": ("(a-b)**3",)}


# ---------------------------------------------------------------------------------------------- selections
def test_selection_text():
    assert effect_selection("all").names == tuple(EFFECTS)
    sel = effect_selection("coulomb_friction, cogging")
    assert sel.names == ("coulomb_friction", "cogging") and not sel.fixed
    sel = effect_selection("cogging:periods=120")
    assert sel.names == ("cogging",) and sel.fixed == {"cogging": 120.0}
    assert effect_selection("all,cogging:periods=12").fixed == {"cogging": 12.0}
    assert effect_selection(["offset", "delay:delay=3"]).specs == ("offset", "delay:delay=3")
    assert effect_names("coulomb_friction,cogging:periods=120") == ["coulomb_friction", "cogging:periods=120"]
    assert effect_selection(effect_names("all,cogging:periods=12")) == effect_selection("all,cogging:periods=12")


@pytest.mark.parametrize(("text", "error", "fragment"), [
    ("frction", UnknownVariableError, "no effect named 'frction'"),
    ("cogging:period=12", InvalidSettingError, "write cogging:periods=VALUE"),
    ("cogging:periods=-3", InvalidSettingError, "must be positive"),
    ("cogging:periods=12.5", InvalidSettingError, "whole periods"),
    ("cogging:periods=abc", InvalidSettingError, "must be a number"),
    ("offset:level=1", InvalidSettingError, "has no nuisance parameter"),
])
def test_bad_selection_is_one_line(text, error, fragment):
    with pytest.raises(error, match=fragment) as info:
        effect_selection(text)
    assert "\n" not in str(info.value)


def test_a_fixed_period_outside_the_records_band_is_refused_up_front():
    model = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "u"), coef=np.array([[1.0, 0], [-1, 1]]))
    n = 4000
    x = slew(3.0, 2.0, n)
    columns = {"x": x, "v": np.gradient(x, DT), "u": np.sin(np.arange(n) * DT)}
    fine = {"x": 1e-9, "v": 1e-9}  # precise sensors: the Nyquist band is the limit
    assert check_effect_selection("cogging:periods=120", model, columns, DT, fine).fixed == {"cogging": 120.0}
    with pytest.raises(InvalidSettingError, match=r"cogging:periods=5000 is outside what these data can show "
                                                  r"\(on x periods 5 to 1256") as info:
        check_effect_selection("coulomb_friction,cogging:periods=5000", model, columns, DT, fine)
    assert "\n" not in str(info.value) and "1000 Hz sampling" in str(info.value)
    with pytest.raises(InvalidSettingError, match="outside"):
        check_effect_selection("cogging:periods=2", model, columns, DT, fine)  # under two periods over 3 rad
    # a spring of 100 (x'' = u - v - 100 x, a resonance at 10 rad/s = 1.59 Hz): a ripple at most ten times
    # faster, 15.9 Hz at 2 rad/s, is n <= 15.9 * 2 pi / 2 = 50
    spring = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "x", "u"),
                             coef=np.array([[1.0, 0, 0], [-1, -100, 1]]))
    with pytest.raises(InvalidSettingError, match=r"on x periods 5 to 49 "):
        check_effect_selection("cogging:periods=120", spring, columns, DT, fine)


def test_a_fixed_period_is_judged_on_the_motion_not_on_the_positions_noise():
    """At 1 % noise on a position sampled at 1 kHz, central differences of the measured position gave 15 times
    the motion's speed, and refused periods the record shows; the band is now that of the smoothed motion."""
    model = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "u"), coef=np.array([[1.0, 0], [-1, 1]]))
    n = 4000
    x = slew(3.0, 2.0, n)
    noisy = x + 0.01 * np.ptp(x) * np.random.default_rng(2).standard_normal(n)
    columns = {"x": noisy, "v": np.gradient(x, DT), "u": np.sin(np.arange(n) * DT)}
    assert check_effect_selection("cogging:periods=1000", model, columns, DT).fixed == {"cogging": 1000.0}
    with pytest.raises(InvalidSettingError, match=r"on x periods 5 to 1[12]\d\d "):  # clean: 5 to 1256
        check_effect_selection("cogging:periods=5000", model, columns, DT)


# ---------------------------------------------------------------------------------------------- standard errors
#: Each effect's main physical parameter, by the name its parameters give it (rows: "va", "vb").
MAIN = {"coulomb_friction": "Fc", "viscous_asymmetry": "viscous_asymmetry", "stribeck": "Fs",
        "backlash": "half_width", "deadzone": "gain_ratio", "saturation": "gain_ratio", "cogging": "amplitude_va",
        "gravity": "amplitude_va", "offset": "offset_va", "delay": "delay_samples", "cubic_stiffness": "k3",
        "sqrt_outflow": "a", "hard_stop": "stiffness"}


def test_every_effect_names_its_main_parameter():
    assert set(MAIN) == set(EFFECTS)


@pytest.mark.parametrize("name", sorted(MAIN))
def test_every_effects_main_parameter_has_a_standard_error(name):
    """Delta-method standard errors from the coefficients' covariance, against the first-order answer."""
    model = IdentifiedModel(states=("a", "va", "b", "vb"), inputs=("u",), terms=("va", "a", "b", "vb", "u"),
                            coef=np.array([[1.0, 0, 0, 0, 0], [-1.0, -100.0, 100.0, 0, 2.0],
                                           [0, 0, 0, 1.0, 0], [0, 50.0, -50.0, -1.0, 0]]))
    roles = Roles.of(model)
    effect = EFFECTS[name]
    place = next((a for a in effect.attachments(roles) if "va" in a.rows or a.rows), Attachment("va", ("va",), ()))
    place = Attachment(place.label, place.signals, ("va",))
    q = len(effect.terms(place, 3.0 if effect.nuisance else None))
    if name == "delay":
        q = 2
    coef = {"va": np.linspace(-3.0, -2.0, q) if name != "backlash" else np.array([80.0])}
    rel = 0.01
    cov = np.diag((rel * coef["va"]) ** 2)
    value = 3.0 if effect.nuisance else None
    params = effect.parameters(coef, value, roles, place)
    se = _uncertainty(effect, coef, cov, value, roles, place)
    key = MAIN[name]
    assert math.isfinite(params[key]) and se.get(key, 0.0) > 0.0, (params, se)
    if name in ("coulomb_friction", "viscous_asymmetry", "stribeck", "offset", "cubic_stiffness"):
        # a force: the coefficient over the row's gain (2), so its relative error is the coefficient's
        assert abs(params[key]) == pytest.approx(abs(coef["va"][0]) / 2.0)
        assert se[key] == pytest.approx(rel * abs(params[key]), rel=1e-3)


# ---------------------------------------------------------------------------------------------- Duffing
M, C, K, K3 = 2.0, 4.0, 200.0, 2000.0


def duffing(seed: int = 0, n: int = 4000, dt: float = 2e-3, noise: float = 0.01) -> Trajectory:
    """m x'' + c x' + k x + k3 x^3 = u, a 0.2-4 Hz multisine held over each sample, noise on x and v."""
    rng = np.random.default_rng(seed)
    t = np.arange(n + 1) * dt
    freqs, phases = np.linspace(0.2, 4.0, 12), rng.uniform(0, 2 * np.pi, 12)
    u = 12.0 * sum(np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, phases, strict=True)) / np.sqrt(6)

    def rhs(time, s):
        k = min(int(time / dt + 1e-9), n)
        return [s[1], (u[k] - C * s[1] - K * s[0] - K3 * s[0] ** 3) / M]

    sol = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0], t_eval=t, rtol=1e-8, atol=1e-10)
    x, v = sol.y
    x = x + noise * x.std() * rng.standard_normal(x.size)
    v = v + noise * v.std() * rng.standard_normal(v.size)
    return Trajectory.from_arrays(t, {"x": x, "v": v, "u": u}, roles={"x": "state", "v": "state", "u": "input"})


@pytest.mark.slow
def test_duffing_oscillator_gets_a_cubic_spring_on_its_position():
    from cosim.diagnose.diagnosis import diagnose

    data = duffing()
    linear = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "x", "u"),
                             coef=np.array([[1.0, 0.0, 0.0], [-C / M, -K / M, 1.0 / M]]))
    report = diagnose(linear, data, max_effects=1)
    assert report.effects, report.message
    found = report.effects[0]
    assert (found.name, found.attached_to, found.rows) == ("cubic_stiffness", "x", ("v",)), report.message
    assert found.terms == ("x**3",)
    assert found.parameters["k3"] == pytest.approx(K3, rel=0.10)
    assert 0.0 < found.uncertainty["k3"] < 0.05 * K3
    assert report.after["nrmse_pct"] * 10 < report.before["nrmse_pct"]


@pytest.mark.slow
def test_duffing_positions_only_default_cli_path_names_the_cubic_spring(tmp_path):
    """Issue 13: positions only (the velocity derived with the data-chosen window), the default path
    (`cosim diagnose DATA` identifies first; no per-case option): `cubic_stiffness` on x, k3 within 10 %."""
    import json

    from click.testing import CliRunner

    from cosim.cli import main

    data = duffing()
    path = tmp_path / "duffing.csv"
    np.savetxt(path, np.column_stack([data.time, data["x"], data["u"]]), delimiter=",", header="time,x,u",
               comments="")
    result = CliRunner().invoke(main, ["diagnose", str(path), "--state", "x,x_dot", "--derive", "x", "--input", "u",
                                       "--json"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert payload["effects"], payload["message"]
    found = payload["effects"][0]
    assert (found["name"], found["attached_to"]) == ("cubic_stiffness", "x"), payload["message"]
    assert found["parameters"]["k3"] == pytest.approx(K3, rel=0.10)
    # the headline error is the measured position's (what the search fitted), not a mean with its derivative
    for figures in (payload["before"], payload["after"]):
        assert figures["states"] == ["x"]
        assert figures["nrmse_pct"] == pytest.approx(figures["per_state"]["x"]["nrmse_pct"])
    assert "of the measured states (x)" in payload["message"]
    assert payload["after"]["nrmse_pct"] < payload["before"]["nrmse_pct"]


# ---------------------------------------------------------------------------------------------- saturation on steps
def stepped_mass(level: float, seed: int = 0, n: int = 4000, dt: float = 2e-3, noise: float = 0.005) -> Trajectory:
    """m x'' + c x' + k x = clip(u, level): steps among seven command levels, of which only the largest
    magnitude passes `level`, integrated with solve_ivp (command held over each sample)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n + 1) * dt
    levels = np.array([-9.0, -5.0, -2.5, 0.0, 2.5, 5.0, 7.0])
    u = np.repeat(rng.choice(levels, size=n // 200 + 1), 200)[:n + 1]
    u[:200] = -9.0  # the clipped level surely appears

    def rhs(time, s):
        k = min(int(time / dt + 1e-9), n)
        return [s[1], (np.clip(u[k], -level, level) - C * s[1] - K * s[0]) / M]

    sol = solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0], t_eval=t, max_step=dt, rtol=1e-8, atol=1e-10)
    x, v = sol.y
    x = x + noise * np.ptp(x) * rng.standard_normal(x.size)
    v = v + noise * np.ptp(v) * rng.standard_normal(v.size)
    return Trajectory.from_arrays(t, {"x": x, "v": v, "u": u}, roles={"x": "state", "v": "state", "u": "input"})


@pytest.mark.slow
def test_a_saturation_seen_on_one_step_level_is_placed_by_the_inputs_own_gain():
    """A saturation the plant sees through its input's gain (``b clip(u)``): with a free gain on the clipped
    part, the level between the two largest commands (7 and 9) trades against that gain; tied to the input's,
    the one clipped step pins it."""
    from cosim.diagnose.diagnosis import diagnose

    linear = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "x", "u"),
                             coef=np.array([[1.0, 0.0, 0.0], [-C / M, -K / M, 1.0 / M]]))
    report = diagnose(linear, stepped_mass(8.0), max_effects=1)
    assert report.effects, report.message
    found = report.effects[0]
    assert (found.name, found.attached_to) == ("saturation", "u"), report.message
    assert found.parameters["level"] == pytest.approx(8.0, rel=0.02)
    assert found.parameters["gain_ratio"] == pytest.approx(1.0, abs=1e-9)
    assert report.after["nrmse_pct"] * 3 < report.before["nrmse_pct"]
