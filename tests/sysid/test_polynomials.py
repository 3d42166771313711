"""sysid.polynomials: the slowest time constant and the stability test of a q^-1 polynomial."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from sysid.polynomials import impulse_response, is_stable, slowest_time_constant_samples


def test_slowest_time_constant_is_minus_one_over_log_of_the_largest_root() -> None:
    # (1 - 0.99 q^-1)(1 - 0.5 q^-1): roots 0.99 and 0.5
    assert slowest_time_constant_samples(np.convolve([1.0, -0.99], [1.0, -0.5])) == \
        pytest.approx(-1.0 / math.log(0.99), rel=1e-12)
    assert slowest_time_constant_samples(np.array([1.0, -1.0])) == math.inf
    assert slowest_time_constant_samples(np.array([1.0])) == 0.0
    assert slowest_time_constant_samples(np.array([1.0, 0.0, 0.0])) == 0.0


def test_the_step_down_stability_test_agrees_with_the_roots() -> None:
    rng = np.random.default_rng(7)
    for _ in range(2000):
        f = np.r_[1.0, rng.uniform(-3.0, 3.0, int(rng.integers(1, 4)))]
        assert is_stable(f) == (np.max(np.abs(np.roots(f))) < 1.0), f
    assert is_stable(np.array([1.0])) and not is_stable(np.array([1.0, -1.0]))


def test_the_stability_test_normalises_a_leading_coefficient_and_trailing_zeros() -> None:
    # 2 - 1.8 q^-1 has its root at 0.9; with a trailing zero a root at 0 joins it
    assert is_stable(np.array([2.0, -1.8, 0.0]))
    assert not is_stable(np.array([0.5, -0.6]))    # root 1.2
    assert not is_stable(np.array([0.0, 1.0]))     # no leading coefficient: no polynomial


def test_the_impulse_response_is_lfilters_bit_for_bit() -> None:
    # first order by cumprod: the same products as lfilter's recursion, so no tolerance
    rng = np.random.default_rng(3)
    pulse = np.zeros(3000)
    pulse[0] = 1.0
    for den in [np.r_[1.0, a] for a in rng.uniform(-0.9999, 0.9999, 300)] + [
            np.array([1.0, -1.5, 0.7]), np.array([1.0, 0.0]), np.array([1.0])]:
        np.testing.assert_array_equal(impulse_response(den, 3000), lfilter([1.0], den, pulse))
    assert impulse_response(np.array([1.0, -0.5]), 0).size == 0
