"""sysid.polynomials: the slowest time constant of a q^-1 polynomial."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sysid.polynomials import slowest_time_constant_samples


def test_slowest_time_constant_is_minus_one_over_log_of_the_largest_root() -> None:
    # (1 - 0.99 q^-1)(1 - 0.5 q^-1): roots 0.99 and 0.5
    assert slowest_time_constant_samples(np.convolve([1.0, -0.99], [1.0, -0.5])) == \
        pytest.approx(-1.0 / math.log(0.99), rel=1e-12)
    assert slowest_time_constant_samples(np.array([1.0, -1.0])) == math.inf
    assert slowest_time_constant_samples(np.array([1.0])) == 0.0
    assert slowest_time_constant_samples(np.array([1.0, 0.0, 0.0])) == 0.0
