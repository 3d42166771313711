"""The shared array helpers against scipy's normal quantile and numpy's standard deviation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from sysid._arrays import MAD_TO_STD, clipped_samples, robust_std


def test_the_mad_factor_is_one_over_the_normal_quartile() -> None:
    assert MAD_TO_STD == pytest.approx(1.0 / stats.norm.ppf(0.75), rel=1e-15)


def test_robust_std_is_the_standard_deviation_of_gaussian_data_and_ignores_outliers() -> None:
    rng = np.random.default_rng(11)
    x = 40.0 + 3.0 * rng.standard_normal(200_000)
    # the MAD's standard error is about 1.67 sigma / sqrt(n) = 0.4 % here; 1 % is 2.7 of them
    assert robust_std(x) == pytest.approx(np.std(x), rel=0.01)
    x[::100] = 1e6                                        # 1 % gross outliers
    assert robust_std(x) == pytest.approx(3.0, rel=0.03)  # the median moves by 1 % of a sigma
    assert np.std(x) > 1e4


def test_clipped_samples_are_runs_at_either_extreme_only() -> None:
    y = np.array([1.0, 2.0, 5.0, 5.0, 5.0, 3.0, 0.0, 0.0, 2.0, 2.0, 2.0])
    assert clipped_samples(y, 3) == (2, 3, 4)          # the run of 2.0 is not at an extreme
    assert clipped_samples(y, 2) == (2, 3, 4, 6, 7)
    assert clipped_samples(y, 4) == ()


def test_a_run_at_an_extreme_from_the_first_sample_is_the_start_not_clipping() -> None:
    # a heating test starts cold, at its minimum; a held or quantised sensor repeats it
    y = np.array([0.0, 0.0, 0.0, 1.0, 3.0, 3.0, 3.0, 2.0])
    assert clipped_samples(y, 3) == (4, 5, 6)
    assert clipped_samples(y[::-1], 3) == (1, 2, 3, 5, 6, 7)   # at the end it may be a limit
