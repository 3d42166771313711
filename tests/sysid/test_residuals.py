"""Residual analysis: correlations against numpy.correlate and whiteness verdicts."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from sysid.errors import IdentificationError
from sysid.residuals import Z_99, autocorrelation, cross_correlation
from tests.tolerances import IDENTITY_RTOL

#: Sums of up to ~2000 products in a different order than numpy.correlate.
SUM_ORDER_ATOL = 1e-12


def _numpy_autocorrelation(e: np.ndarray, max_lag: int) -> np.ndarray:
    x = e - e.mean()
    full = np.correlate(x, x, mode="full")  # full[n-1+tau] = sum_k x_{k+tau} x_k
    n = x.size
    return full[n - 1 : n + max_lag] / full[n - 1]


def _numpy_cross_correlation(e: np.ndarray, u: np.ndarray, max_lag: int) -> np.ndarray:
    x, z = e - e.mean(), u - u.mean()
    full = np.correlate(x, z, mode="full")  # full[n-1+tau] = sum_k x_{k+tau} z_k
    n = x.size
    return full[n - 1 - max_lag : n + max_lag] / math.sqrt((x @ x) * (z @ z))


def test_autocorrelation_matches_numpy_correlate(rng: np.random.Generator) -> None:
    e = lfilter([1.0], [1.0, -0.6], rng.standard_normal(500))
    result = autocorrelation(e, max_lag=25)
    np.testing.assert_array_equal(result.lags, np.arange(26))
    # reason: same sums in another order
    np.testing.assert_allclose(result.values, _numpy_autocorrelation(e, 25), rtol=IDENTITY_RTOL,
                               atol=SUM_ORDER_ATOL)
    assert result.values[0] == pytest.approx(1.0, rel=IDENTITY_RTOL)


def test_autocorrelation_matches_direct_formula_at_one_lag() -> None:
    e = np.array([1.0, -2.0, 3.0, 0.5, -1.5, 2.0])
    x = e - e.mean()
    expected = sum(x[k] * x[k - 2] for k in range(2, 6)) / sum(x * x)
    result = autocorrelation(e, max_lag=3)
    assert result.values[2] == pytest.approx(expected, rel=IDENTITY_RTOL)


def test_cross_correlation_matches_numpy_correlate_and_sign_convention(
    rng: np.random.Generator,
) -> None:
    u = rng.standard_normal(400)
    e = np.concatenate([[0.0, 0.0, 0.0], u[:-3]]) + 0.1 * rng.standard_normal(400)  # e_k ~ u_{k-3}
    result = cross_correlation(e, u, max_lag=10)
    np.testing.assert_array_equal(result.lags, np.arange(-10, 11))
    # reason: same sums in another order
    np.testing.assert_allclose(result.values, _numpy_cross_correlation(e, u, 10),
                               rtol=IDENTITY_RTOL, atol=SUM_ORDER_ATOL)
    assert int(result.lags[np.argmax(result.values)]) == 3
    assert not result.is_independent
    assert 3 in result.lags_outside


def test_white_noise_passes_and_coloured_noise_fails_whiteness(rng: np.random.Generator) -> None:
    white = rng.standard_normal(2000)
    coloured = lfilter([1.0], [1.0, -0.8], rng.standard_normal(2000))
    white_result = autocorrelation(white)
    assert white_result.bound == pytest.approx(Z_99 / math.sqrt(2000), rel=IDENTITY_RTOL)
    assert white_result.n_tested == 25
    assert white_result.fraction_outside <= 2 / 25  # 99 % bound: ~0.25 lags expected outside
    coloured_result = autocorrelation(coloured)
    assert not coloured_result.is_white
    assert coloured_result.fraction_outside > 0.5
    assert 1 in coloured_result.lags_outside


def test_seeded_white_noise_is_white_and_independent() -> None:
    rng = np.random.default_rng(3)
    e, u = rng.standard_normal(1000), rng.standard_normal(1000)
    auto = autocorrelation(e, max_lag=10)
    cross = cross_correlation(e, u, max_lag=10)
    assert auto.within_bound == (auto.n_outside == 0)
    assert cross.within_bound == (cross.n_outside == 0)
    assert cross.n_tested == 21
    # a verdict of the right kind only: an autocorrelation never claims independence
    assert not auto.is_independent
    assert not cross.is_white


def test_arx_residuals_are_white_on_arx_data_and_not_on_an_oe_misfit(
    rng: np.random.Generator,
) -> None:
    u = np.repeat(rng.uniform(-1.0, 1.0, 100), 10)
    noise = 0.05 * rng.standard_normal(u.size)
    y = lfilter([0.0, 0.5], [1.0, -0.9], u) + lfilter([1.0], [1.0, -0.9], noise)
    # exact ARX(1,1,1) one-step residuals with the true parameters are the white noise
    e_true = y[1:] - 0.9 * y[:-1] - 0.5 * u[:-1]
    assert autocorrelation(e_true).fraction_outside <= 2 / 25
    # ignoring the dynamics (static gain only) leaves strongly coloured residuals
    e_static = y - 5.0 * u
    assert not autocorrelation(e_static).is_white


@pytest.mark.parametrize(
    ("e", "match"),
    [
        (np.ones((3, 4)), r"e must be a 1-D array; got shape \(3, 4\)"),
        (np.array([1.0, np.nan, 2.0, 3.0]), r"finite numbers; got nan at sample 1"),
        (np.full(10, 2.5), r"e must vary"),
    ],
    ids=["2d", "nan", "constant"],
)
def test_autocorrelation_rejects_bad_residuals(e: np.ndarray, match: str) -> None:
    with pytest.raises(IdentificationError, match=match):
        autocorrelation(e, max_lag=2)


@pytest.mark.parametrize("max_lag", [0, 10, 2.5, True], ids=["zero", "too-long", "float", "bool"])
def test_correlations_reject_bad_max_lag(max_lag: object) -> None:
    e = np.arange(10.0) ** 2
    with pytest.raises(IdentificationError, match="max_lag"):
        autocorrelation(e, max_lag=max_lag)  # type: ignore[arg-type]
    with pytest.raises(IdentificationError, match="max_lag"):
        cross_correlation(e, np.sin(np.arange(10.0)), max_lag=max_lag)  # type: ignore[arg-type]


def test_cross_correlation_rejects_unequal_lengths_and_constant_input() -> None:
    e = np.sin(np.arange(20.0))
    with pytest.raises(IdentificationError, match="equal lengths; got 20 and 19"):
        cross_correlation(e, np.arange(19.0), max_lag=3)
    with pytest.raises(IdentificationError, match="u must vary"):
        cross_correlation(e, np.full(20, 4.0), max_lag=3)
    with pytest.raises(IdentificationError, match=r"u must hold finite numbers; got inf"):
        cross_correlation(e, np.concatenate([np.arange(19.0), [np.inf]]), max_lag=3)
