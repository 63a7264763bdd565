"""Output error on the measured states only (``refine_output_error(measured=...)``): a velocity derived from a
measured position by a smoothing differentiator lags and flattens the plant's, and fitting it bends the model."""

from __future__ import annotations

import numpy as np
import pytest

from cosim.errors import InvalidSettingError
from cosim.identify.model import IdentifiedModel
from cosim.identify.output_error import refine_output_error

DT, N = 0.002, 2000
#: A lightly damped mode at 6 Hz: x'' = -W2 x - C x' + G u.
W2, C, G = (2 * np.pi * 6.0) ** 2, 3.0, 400.0


def _record() -> tuple[np.ndarray, np.ndarray]:
    """Four seconds of the mode under a multisine, its position with 0.5 % noise, and its velocity as a
    centred moving average of the position's differences over 61 samples (a smoothing differentiator's
    velocity: the 6 Hz mode is flattened to about a third)."""
    rng = np.random.default_rng(3)
    t = DT * np.arange(N)
    u = sum(np.sin(2 * np.pi * f * t + p) for f, p in zip((0.7, 2.3, 5.1, 7.9), rng.uniform(0, 6, 4), strict=True))
    true = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("x", "v", "u"),
                           coef=np.array([[0.0, 1.0, 0.0], [-W2, -C, G]]), dt=DT)
    x = true.simulate([0.0, 0.0], u[:, None], dt=DT).states[:, 0]
    x = x + 0.005 * np.ptp(x) * rng.standard_normal(x.size)
    v = np.convolve(np.gradient(x, DT), np.ones(61) / 61, mode="same")
    return np.column_stack([x, v]), u[:, None]


def _fit(measured):
    data, u = _record()
    start = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("x", "v", "u"),
                            coef=np.array([[0.0, 1.0, 0.0], [-0.8 * W2, -2.0 * C, 0.8 * G]]), dt=DT)
    support = np.array([[False, False, False], [True, True, True]])
    return refine_output_error(start, [(data, u)], dt=DT, support=support, measured=measured)


def test_the_measured_position_alone_gives_the_plants_mode():
    """Fitted on the position only, the stiffness is within 1 % of the plant's; fitted on the smoothed velocity
    too, it is pulled off by more than that (the test could fail both ways)."""
    alone = _fit((True, False))
    both = _fit(None)
    assert abs(alone.coef[1, 0] / -W2 - 1.0) < 0.01
    assert abs(both.coef[1, 0] / -W2 - 1.0) > 0.01
    assert alone.status == "ok"


def test_measured_flags_are_checked():
    with pytest.raises(InvalidSettingError, match="measured must give 2 flags"):
        _fit((False, False))
    with pytest.raises(InvalidSettingError, match="measured must give 2 flags"):
        _fit((True,))
