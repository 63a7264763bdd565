"""Excitation signals: known values, periods, spectra, and the command-line spec form."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from cosim.data.signals import (
    SIGNAL_KINDS,
    Chirp,
    Multisine,
    Prbs,
    Signal,
    SineWave,
    SquareWave,
    chirp,
    constant,
    multisine,
    parse_signal,
    prbs,
    signal_kinds_help,
    sine,
    square,
    step,
)
from cosim.errors import CosimDeprecationWarning, InvalidSettingError, SignalSpecError

# ----------------------------------------------------------------------------------------------------- square


def test_square_values_at_known_times():
    u = square(0.1, 2.0, offset=1.0, duty=0.25)  # period 0.5 s, high on [0, 0.125)
    t = np.array([0.0, 0.1, 0.125, 0.3, 0.4999, 0.5, 0.62, 0.625])
    np.testing.assert_allclose(u(t), [1.1, 1.1, 0.9, 0.9, 0.9, 1.1, 1.1, 0.9])
    assert u(0.0) == pytest.approx(1.1) and isinstance(u(0.0), float)


def test_square_period_and_duty_on_a_sampled_grid():
    """Sampled at k*dt with edges on the grid: 5 high then 5 low samples per period, no rounding slip."""
    u = square(2.0, 10.0)
    values = u(np.arange(100_000) * 0.01)
    pattern = np.tile([2.0] * 5 + [-2.0] * 5, 10_000)
    np.testing.assert_array_equal(values, pattern)


@pytest.mark.parametrize("duty", [0.1, 0.5, 0.8])
def test_square_duty_fraction(duty):
    u = square(1.0, 3.0, duty=duty)
    t = np.arange(300_000) / 300_000 * 10.0  # 30 whole periods, 10000 samples each
    assert np.mean(u(t) > 0) == pytest.approx(duty, abs=1e-4)
    np.testing.assert_array_equal(u(t), u(t + 1.0 / 3.0 * 7))


def test_square_phase_follows_the_sine():
    u = square(1.0, 1.0, phase=np.pi)  # half a cycle ahead: starts low
    assert u(0.0) == -1.0 and u(0.6) == 1.0
    t = np.linspace(0.01, 4.99, 999)
    np.testing.assert_array_equal(square(1.0, 1.0, phase=0.3)(t), np.sign(sine(1.0, 1.0, phase=0.3)(t)))


@pytest.mark.parametrize("kwargs", [{"duty": 0.0}, {"duty": 1.0}, {"phase": math.nan}])
def test_square_rejects_bad_settings(kwargs):
    with pytest.raises(InvalidSettingError):
        square(1.0, 1.0, **kwargs)
    with pytest.raises(InvalidSettingError, match="frequency"):
        square(1.0, 0.0)


# ------------------------------------------------------------------------------------------------------- sine


def test_sine_known_values():
    u = sine(2.0, 5.0, offset=1.0, phase=np.pi / 2)  # a cosine: 3 at t=0, -1 half a period later
    assert u(0.0) == pytest.approx(3.0)
    assert u(0.1) == pytest.approx(-1.0)
    assert u(0.05) == pytest.approx(1.0, abs=1e-12)
    t = np.random.default_rng(0).uniform(0.0, 10.0, 1000)
    np.testing.assert_allclose(u(t), 1.0 + 2.0 * np.cos(2 * np.pi * 5.0 * t), atol=1e-12)


def test_sine_keeps_its_phase_on_long_records():
    u = sine(1.0, 5.0)
    assert u(1e6 + 0.05) == pytest.approx(1.0, abs=1e-9)  # 5e6 + 1/4 cycles


def test_sine_shape_follows_the_input():
    u = sine(1.0, 1.0)
    assert u(np.zeros((3, 4))).shape == (3, 4)
    assert isinstance(u(0.25), float)


# ------------------------------------------------------------------------------------------------------- prbs


def test_prbs_levels_period_and_balance():
    order, clock, amp = 7, 0.01, 0.3
    u = prbs(amp, clock=clock, order=order, seed=3, offset=1.0)
    n_bits = 2**order - 1
    centres = (np.arange(2 * n_bits) + 0.5) * clock
    bits = (u(centres) - 1.0) / amp
    np.testing.assert_allclose(np.abs(bits), 1.0)  # offset ± amp only
    bits = np.rint(bits).astype(int)
    np.testing.assert_array_equal(bits[:n_bits], bits[n_bits:])  # repeats after 2^order - 1 bits
    first = bits[:n_bits]
    assert all(not np.array_equal(first, np.roll(first, s)) for s in range(1, n_bits))  # and not sooner
    assert np.sum(first == 1) == np.sum(first == -1) + 1  # maximum-length: balanced
    assert u.period == pytest.approx(n_bits * clock)


def test_prbs_holds_each_bit_for_one_clock():
    u = prbs(1.0, clock=0.01, order=6)
    samples = u(np.arange(63 * 10) * 0.001).reshape(63, 10)  # 10 samples per bit, first on the edge
    assert np.all(samples == samples[:, :1])
    np.testing.assert_array_equal(samples[:, 0], u.bits)


def test_prbs_seed_shifts_the_sequence():
    a, b = prbs(1.0, clock=1.0, order=8, seed=0), prbs(1.0, clock=1.0, order=8, seed=5)
    assert np.array_equal(a.bits, prbs(1.0, clock=1.0, order=8, seed=0).bits)
    assert not np.array_equal(a.bits, b.bits)
    assert any(np.array_equal(a.bits, np.roll(b.bits, s)) for s in range(255))


@pytest.mark.parametrize("kwargs", [{"order": 1}, {"order": 25}, {"order": 9.0}, {"seed": -1}, {"clock": 0}])
def test_prbs_rejects_bad_settings(kwargs):
    with pytest.raises(InvalidSettingError):
        prbs(1.0, **{"clock": 0.1, **kwargs})


# ------------------------------------------------------------------------------------------------------ chirp


def _zero_crossings(sig: Signal, t_end: float, n: int = 2_000_001) -> np.ndarray:
    t = np.linspace(0.0, t_end, n)
    x = sig(t)
    i = np.flatnonzero(np.sign(x[1:-1]) != np.sign(x[2:])) + 1
    return t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])


def test_linear_chirp_frequency_at_start_and_end():
    """Half a period lies between two zero crossings; for a linear law its frequency is the midpoint's."""
    u = chirp(0.1, 1.0, 20.0, 4.0)
    crossings = _zero_crossings(u, 4.0 - 1e-9)
    mid, measured = 0.5 * (crossings[1:] + crossings[:-1]), 0.5 / np.diff(crossings)
    expected = 1.0 + 19.0 * mid / 4.0
    assert mid[0] < 0.6 and measured[0] == pytest.approx(expected[0], rel=1e-4)  # start: about 1.3 Hz
    assert expected[-1] > 19.5 and measured[-1] == pytest.approx(expected[-1], rel=1e-4)  # end: about 20 Hz
    np.testing.assert_allclose(measured, expected, rtol=1e-4)
    assert np.abs(u(np.linspace(0, 4, 100_001))).max() == pytest.approx(0.1, rel=1e-3)


def test_logarithmic_chirp_frequency_law():
    """Between two zero crossings the mean of f(t) = f0*(f1/f0)**(t/T) is half a cycle per interval."""
    f0, f1, duration = 0.5, 50.0, 2.0
    u = chirp(1.0, f0, f1, duration, method="logarithmic")
    c = _zero_crossings(u, duration - 1e-9)
    k = math.log(f1 / f0) / duration
    mean_frequency = f0 / k * (np.exp(k * c[1:]) - np.exp(k * c[:-1])) / np.diff(c)
    np.testing.assert_allclose(0.5 / np.diff(c), mean_frequency, rtol=1e-4)
    assert c[0] < 1.0 and 0.5 / (c[-1] - c[-2]) > 45.0  # covers start and end of the sweep
    assert u.frequency_at(0.0) == pytest.approx(f0) and u.frequency_at(duration) == pytest.approx(f1)


def test_chirp_starts_at_zero_and_rests_at_offset_outside_the_sweep():
    u = chirp(0.2, 1.0, 5.0, 3.0, offset=0.5)
    assert u(0.0) == pytest.approx(0.5, abs=1e-12)
    np.testing.assert_array_equal(u(np.array([-1.0, 3.0, 10.0])), [0.5, 0.5, 0.5])
    with pytest.raises(InvalidSettingError):
        chirp(1.0, 0.0, 5.0, 1.0, method="logarithmic")
    with pytest.raises(InvalidSettingError, match="method"):
        chirp(1.0, 1.0, 5.0, 1.0, method="cubic")


# -------------------------------------------------------------------------------------------------- multisine


def _one_period(u: Multisine, size: int = 1 << 14) -> np.ndarray:
    return u(np.arange(size) / size * u.period)


@pytest.mark.parametrize("band", [(1.0, 10.0), (0.1, 20.0), (2.0, 3.0)])
def test_multisine_crest_factor_and_peak(band):
    u = multisine(0.1, band=band)
    x = _one_period(u, 1 << 16)
    crest = np.abs(x).max() / np.sqrt(np.mean(x**2))
    assert crest < 1.7
    assert crest == pytest.approx(u.crest_factor, rel=1e-2)
    assert np.abs(x).max() <= 0.1 * (1 + 1e-9)
    assert np.abs(x).max() >= 0.1 * 0.995


def test_multisine_spectrum_has_energy_only_at_its_lines():
    u = multisine(0.1, band=(0.1, 20.0), n=30)
    assert len(u.frequencies) == 30 and u.period == pytest.approx(10.0)
    assert min(u.frequencies) == pytest.approx(0.1) and max(u.frequencies) == pytest.approx(20.0)
    size = 1 << 13
    spectrum = np.abs(np.fft.rfft(_one_period(u, size))) / (size / 2)
    lines = np.rint(np.array(u.frequencies) * u.period).astype(int)
    np.testing.assert_allclose(spectrum[lines], u.line_amplitude, rtol=1e-9)  # equal amplitudes
    others = np.delete(spectrum, lines)
    assert others.max() < 1e-12 * spectrum.max()
    assert np.abs(_one_period(u)).max() <= 0.1 * (1 + 1e-9)


def test_multisine_explicit_frequencies_and_period():
    u = multisine(1.0, [1.0, 2.5, 4.0], crest="schroeder", offset=2.0)
    assert u.period == pytest.approx(2.0)  # shortest common period
    t = np.linspace(0.0, 2.0, 1001)
    np.testing.assert_allclose(u(t), u(t + 3 * u.period), atol=1e-9)
    assert np.mean(_one_period(u)) == pytest.approx(2.0, abs=1e-12)
    with pytest.raises(InvalidSettingError, match="whole multiples"):
        multisine(1.0, [1.0, 1.5], period=1.0)


def test_multisine_random_phases_follow_the_seed():
    a = multisine(1.0, band=(1.0, 8.0), crest="random", seed=4)
    assert a == multisine(1.0, band=(1.0, 8.0), crest="random", seed=4)
    assert a.phases != multisine(1.0, band=(1.0, 8.0), crest="random", seed=5).phases


def test_multisine_rejects_bad_settings():
    with pytest.raises(InvalidSettingError, match="exactly one"):
        multisine(1.0)
    with pytest.raises(InvalidSettingError, match="holds only"):
        multisine(1.0, band=(1.0, 5.0), n=10)
    with pytest.raises(InvalidSettingError, match="crest"):
        multisine(1.0, band=(1.0, 5.0), crest="best")


# -------------------------------------------------------------------------------------- step, const, algebra


def test_step_constant_and_arithmetic():
    np.testing.assert_array_equal(step(0.5, at=1.0, offset=1.0)(np.array([0.0, 0.999, 1.0, 5.0])),
                                  [1.0, 1.0, 1.5, 1.5])
    assert step(1.0, at=0.29)(29 * 0.01) == 1.0  # 29*0.01 = 0.28999999999999998: counts as at the step
    assert constant(3.0)(7.0) == 3.0
    u = 1.0 + 2.0 * sine(1.0, 1.0) - step(0.5, at=0.5)
    np.testing.assert_allclose(u(np.array([0.25, 0.75])), [3.0, -1.5])
    assert (u / 2.0)(0.25) == pytest.approx(1.5)
    assert (np.float64(3.0) * constant(2.0))(0.0) == 6.0
    with pytest.raises(TypeError):
        sine(1.0, 1.0) * sine(1.0, 1.0)
    description = u.to_dict()
    assert description["kind"] == "sum"
    assert [term["kind"] for term in description["terms"]] == ["const", "scaled", "scaled"]


# -------------------------------------------------------------------------------------------- parse_signal


@pytest.mark.parametrize(
    ("spec", "expected"),
    [
        ("square:frac=0.1,freq=2", square(1.0, 2.0)),
        ("square:amp=3,freq=2", square(3.0, 2.0)),  # amp: in the input's unit
        ("square:frac=0.1,freq=2,duty=0.3,offset=-1,phase=1",
         square(1.0, 2.0, duty=0.3, offset=-1.0, phase=1.0)),
        ("sine:frac=0.05,freq=5", sine(0.5, 5.0)),
        ("prbs:frac=0.1,clock=0.01,order=9,seed=1", prbs(1.0, clock=0.01, order=9, seed=1)),
        ("chirp:frac=0.1,f0=0.1,f1=20,duration=4", chirp(1.0, 0.1, 20.0, 4.0)),
        ("chirp:value=2,f0=1,f1=20,duration=4,method=log", chirp(2.0, 1.0, 20.0, 4.0, method="logarithmic")),
        ("multisine:frac=0.1,fmin=0.1,fmax=20,n=30", multisine(1.0, band=(0.1, 20.0), n=30)),
        ("multisine:value=1,freqs=1;2.5;4,crest=schroeder",
         multisine(1.0, [1.0, 2.5, 4.0], crest="schroeder")),
        ("step:frac=0.1,at=0.5", step(1.0, at=0.5)),
        ("step:amp=20,at=0.5", step(20.0, at=0.5)),
        ("const:value=3.0", constant(3.0)),
        ("const:frac=0.5", constant(5.0)),
        ("3.5", constant(3.5)),
        ("-1/4", constant(-0.25)),
        (" SINE : frac = 0.5 , freq = 1/2257 ", sine(5.0, 1 / 2257)),
    ],
)
def test_parse_signal_each_kind(spec, expected, recwarn):
    assert parse_signal(spec, maximum=10.0) == expected
    assert not [w for w in recwarn if issubclass(w.category, CosimDeprecationWarning)]


def test_parse_signal_amplitude_sources():
    assert parse_signal("square:frac=0.5,max=4,freq=1", maximum=10.0).amplitude == 2.0  # max= wins
    assert parse_signal("square:frac=0.5,max=4,freq=1").amplitude == 2.0
    assert parse_signal("square:value=0.7,freq=1", maximum=10.0).amplitude == 0.7  # absolute
    assert parse_signal("square:amp=0.7,freq=1").amplitude == 0.7  # absolute; no maximum needed
    assert parse_signal("step:amp=-250", maximum=5000.0).amplitude == -250.0
    assert parse_signal("step:frac=-0.1", maximum=10.0).amplitude == -1.0
    assert parse_signal("sine:frac=1/2257,freq=1", maximum=2257.0).amplitude == pytest.approx(1.0)


def test_an_old_fraction_amp_still_reads_as_before_with_a_deprecation_warning():
    """Before 0.2, amp= was a fraction of the maximum: amp=0.1 on a 5000 N m input still means 500 N m, and says
    what to write instead; where the two readings agree (a maximum of 1) or cannot be meant (no maximum, |amp| > 1)
    nothing is said."""
    with pytest.warns(CosimDeprecationWarning, match=r"write frac=0.1 for this, or value=0.1"):
        assert parse_signal("square:amp=0.1,freq=2", maximum=5000.0).amplitude == 500.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", CosimDeprecationWarning)
        assert parse_signal("square:amp=0.1,freq=2").amplitude == 0.1
        assert parse_signal("square:amp=0.5,freq=2", maximum=1.0).amplitude == 0.5
        assert parse_signal("square:amp=1.5,freq=2", maximum=5000.0).amplitude == 1.5


@pytest.mark.parametrize("name", list(SIGNAL_KINDS))
def test_every_registered_kind_parses_its_example(name):
    kind = SIGNAL_KINDS[name]
    with warnings.catch_warnings():
        warnings.simplefilter("error", CosimDeprecationWarning)  # the examples teach today's spelling
        sig = parse_signal(kind.example, maximum=5000.0)
    assert isinstance(sig, Signal) and sig.kind == name
    assert set(kind.required) <= set(kind.keys) and {"amp", "frac", "value", "max"} <= set(kind.keys)
    assert np.all(np.isfinite(sig(np.linspace(0.0, 5.0, 101))))
    assert f"{name}:" in signal_kinds_help()


@pytest.mark.parametrize(
    ("spec", "maximum", "fragment"),
    [
        ("squar:amp=1,freq=2", 1.0, "unknown kind 'squar'; expected one of: square, sine, prbs"),
        ("square:amp=1,frq=2", 1.0, "unknown key 'frq' for square; valid keys: amp, frac, value, max, freq"),
        ("square:frac=0.1,freq=2", None, "declares no maximum; add max=VALUE"),
        ("square:amp=1,freq=2x", 1.0, "freq='2x' is not a number"),
        ("square:amp=1,freq=1/0", 1.0, "freq='1/0' is not a number"),
        ("square:amp=nan,freq=1", 1.0, "amp='nan' is not a number"),
        ("1/x", None, "is not a number"),
        ("square:amp=1", 1.0, "missing required key(s) freq"),
        ("chirp:amp=1,f0=1", 1.0, "missing required key(s) f1, duration"),
        ("square:freq=2", 1.0, "missing amplitude: add amp="),
        ("square:amp=1,value=1,freq=2", 1.0, "not amp= and value="),
        ("square:amp=1,frac=0.2,freq=2", 1.0, "not amp= and frac="),
        ("square:amp=1,amp=2,freq=2", 1.0, "given twice"),
        ("square:frac=1.5,freq=2", 1.0, "outside -1..1"),
        ("square:amp,freq=2", 1.0, "is not key=value"),
        ("prbs:amp=1,clock=0.01,order=9.5", 1.0, "order='9.5' must be a whole number"),
        ("prbs:amp=1,clock=0.01,order=40", 1.0, "order must be between 2 and 24"),
        ("square:amp=1,freq=-2", 1.0, "frequency must be > 0"),
        ("multisine:amp=1,fmin=1", 1.0, "needs both fmin= and fmax="),
        ("multisine:amp=1,n=3", 1.0, "missing required keys fmin and fmax"),
        ("square:frac=0.1,freq=2", 0.0, "positive finite maximum"),
        ("", None, "empty signal spec"),
    ],
)
def test_parse_signal_errors(spec, maximum, fragment):
    with pytest.raises(SignalSpecError) as info:
        parse_signal(spec, maximum=maximum)
    message = str(info.value)
    assert fragment in message
    assert "\n" not in message
    assert isinstance(info.value, ValueError)


def test_parsed_signals_are_the_documented_classes():
    assert isinstance(parse_signal("square:value=1,freq=1"), SquareWave)
    assert isinstance(parse_signal("sine:value=1,freq=1"), SineWave)
    assert isinstance(parse_signal("prbs:value=1,clock=1"), Prbs)
    assert isinstance(parse_signal("chirp:value=1,f0=1,f1=2,duration=1"), Chirp)
