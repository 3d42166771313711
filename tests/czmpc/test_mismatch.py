"""Model-mismatch diagnostic: windowed statistics against numpy, flags on known truths."""

from __future__ import annotations

import copy
import dataclasses
import math
import pickle

import numpy as np
import pytest

from czmpc.mismatch import InnovationMonitor, MismatchStats

SIGMA_KW = 0.0134
WINDOW = 150
#: Running sums against numpy on the same 150 values of O(0.01 kW): rounding only.
STATS_RTOL = 1e-9


def _feed(values: np.ndarray, **kw: object) -> InnovationMonitor:
    monitor = InnovationMonitor(window_samples=WINDOW, sigma_kw=SIGMA_KW, **kw)  # type: ignore[arg-type]
    for v in values:
        monitor.update(float(v), disturbance_kw=0.0)
    return monitor


def test_statistics_equal_numpy_on_the_last_window(rng: np.random.Generator) -> None:
    e = SIGMA_KW * rng.standard_normal(1000) + 0.003
    stats = _feed(e).stats(0.0)
    last = e[-WINDOW:]
    assert stats.n_samples == WINDOW
    np.testing.assert_allclose(stats.mean_kw, last.mean(), rtol=STATS_RTOL, atol=1e-15,
                               err_msg="reason: same sums, different order")
    np.testing.assert_allclose(stats.std_kw, last.std(), rtol=1e-6, atol=0.0,
                               err_msg="reason: E[x^2] - mean^2 loses ~7 digits at mean/std ~ 0.2")
    lag1 = np.mean(last[:-1] * last[1:]) - last.mean() ** 2
    np.testing.assert_allclose(stats.lag1_correlation, lag1 / last.var(), rtol=1e-5, atol=1e-6,
                               err_msg="reason: pair mean over 149 pairs vs the same formula")
    np.testing.assert_allclose(stats.mean_z, last.mean() / (SIGMA_KW / math.sqrt(WINDOW)),
                               rtol=STATS_RTOL, atol=1e-12, err_msg="reason: definition")


def test_white_noise_of_the_model_raises_no_flag() -> None:
    flagged = 0
    for seed in range(20):
        e = SIGMA_KW * np.random.default_rng(seed).standard_normal(400)
        flagged += _feed(e).stats(0.0).flagged
    assert flagged <= 1  # z limit 4: false alarms are rare


def test_biased_innovations_are_flagged() -> None:
    e = SIGMA_KW * np.random.default_rng(5).standard_normal(400) + 0.5 * SIGMA_KW
    stats = _feed(e).stats(0.0)
    assert stats.biased and stats.mean_z > 4.0  # 0.5 sigma * sqrt(150) = 6.1 expected


def test_coloured_or_noisier_innovations_are_flagged_as_drift() -> None:
    rng = np.random.default_rng(6)
    white = rng.standard_normal(600)
    ar = np.empty_like(white)
    ar[0] = white[0]
    for k in range(1, white.size):
        ar[k] = 0.6 * ar[k - 1] + math.sqrt(1 - 0.36) * white[k]  # unit variance, coloured
    stats = _feed(SIGMA_KW * ar).stats(0.0)
    assert stats.drifted and not stats.biased
    assert stats.lag1_correlation == pytest.approx(0.6, abs=0.15)  # reason: 150 samples
    noisy = _feed(3.0 * SIGMA_KW * white).stats(0.0)
    assert noisy.drifted and noisy.variance_ratio == pytest.approx(9.0, rel=0.3)


def test_disturbance_beyond_its_limit_flags_a_bias() -> None:
    monitor = InnovationMonitor(window_samples=WINDOW, sigma_kw=SIGMA_KW,
                                disturbance_limit_kw=2.0)
    assert not monitor.update(0.0, disturbance_kw=1.9).biased
    assert monitor.update(0.0, disturbance_kw=-2.1).biased


def test_no_flag_from_too_few_samples_and_missing_samples_are_skipped() -> None:
    monitor = InnovationMonitor(window_samples=WINDOW, sigma_kw=SIGMA_KW, min_samples=30)
    for _ in range(29):
        stats = monitor.update(10 * SIGMA_KW, disturbance_kw=0.0)
        assert not stats.flagged
    stats = monitor.update(None, disturbance_kw=0.0)
    assert stats.n_samples == 29
    assert monitor.update(10 * SIGMA_KW, disturbance_kw=0.0).biased


def test_a_huge_value_leaves_no_residue_once_out_of_the_window() -> None:
    e = SIGMA_KW * np.random.default_rng(8).standard_normal(3 * WINDOW)
    e[10] = 1e6
    stats = _feed(e).stats(0.0)
    np.testing.assert_allclose(stats.std_kw, e[-WINDOW:].std(), rtol=1e-6, atol=0.0,
                               err_msg="reason: as in the numpy comparison above")


def test_memory_is_bounded_by_the_window() -> None:
    monitor = _feed(np.ones(10 * WINDOW))
    assert monitor.stats(0.0).n_samples == WINDOW


def test_records_read_late_hold_the_window_they_were_made_from(rng: np.random.Generator) -> None:
    # The monitor hands out records whose fields are computed when first read: a record
    # read after the monitor moved on must still describe its own window.
    e = SIGMA_KW * rng.standard_normal(400) + 0.002
    monitor = InnovationMonitor(window_samples=WINDOW, sigma_kw=SIGMA_KW, disturbance_limit_kw=0.5)
    kept = [monitor.update(float(v), disturbance_kw=0.01 * k) for k, v in enumerate(e)]
    for k in (0, 37, 149, 150, 399):
        stats = kept[k]
        last = e[max(0, k + 1 - WINDOW): k + 1]
        assert stats.n_samples == last.size and stats.disturbance_kw == 0.01 * k
        np.testing.assert_allclose(stats.mean_kw, last.mean(), rtol=STATS_RTOL, atol=1e-15,
                                   err_msg="reason: same sums, different order")
    copied = pickle.loads(pickle.dumps(kept[200]))
    assert copied == kept[200] and copy.copy(kept[201]) == kept[201]
    assert dataclasses.replace(kept[202]) == kept[202] and repr(kept[203]).startswith("MismatchStats(")
    assert list(vars(kept[0])) == [f.name for f in dataclasses.fields(MismatchStats)]
    with pytest.raises(AttributeError):
        kept[204].no_such_field  # noqa: B018
    assert InnovationMonitor(window_samples=5, sigma_kw=1.0).stats(0.3).n_samples == 0
