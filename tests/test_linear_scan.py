"""The linear recursion of the output-error refinement (`cosim.identify.output_error._scan`) against the step-by-step
loop it replaces: every record length around the block size, a stack of columns, a diverging model."""

import numpy as np
import pytest

from cosim.identify.output_error import _scan, simulate_linear_batch


def _stepwise(ad: np.ndarray, s: np.ndarray) -> np.ndarray:
    y = np.array(s, dtype=float, copy=True)
    for k in range(1, len(y)):
        y[k] = y[k - 1] @ ad.T + s[k]
    return y


@pytest.mark.parametrize("steps", [0, 1, 2, 3, 8, 9, 10, 17, 1000, 4099])
@pytest.mark.parametrize("tail", [(4,), (3, 2)])
def test_scan_matches_the_stepwise_recursion(steps: int, tail: tuple[int, ...]) -> None:
    rng = np.random.default_rng(steps)
    n = tail[-1]
    ad = np.eye(n) + 0.01 * rng.standard_normal((n, n))
    s = rng.standard_normal((steps + 1, *tail))
    expected = _stepwise(ad, s)
    got = _scan(ad, s)
    assert got.shape == expected.shape
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())


def test_a_diverging_model_gives_non_finite_values_without_warnings() -> None:
    ad = np.array([[1e3, 0.0], [0.0, 0.5]])
    with np.errstate(all="raise"):  # the scan silences its own overflow
        x = simulate_linear_batch(ad, np.eye(2), np.zeros(2), np.ones(2), np.ones((400, 2)))
    assert np.all(np.isfinite(x[:50]))  # 1e3^50 still fits a double
    assert not np.all(np.isfinite(x[:, 0]))
