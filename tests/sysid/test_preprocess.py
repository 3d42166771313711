"""Preprocessing (paper sec. 5): operating point, deviations, outlier candidates and repairs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from sysid.data import Dataset
from sysid.errors import DataFileError, IdentificationError
from sysid.model import OperatingPoint
from sysid.preprocess import (
    correct_level_shift,
    estimate_level_shift,
    find_operating_point,
    find_outlier_candidates,
    interpolate_spike,
    to_deviation,
)
from tests.tolerances import IDENTITY_RTOL

TS_S = 2.0
OP = OperatingPoint(triac_pct=45.0, power_kw=45.0)
NOISE_STD_KW = 0.01
SPIKE_SAMPLE, SPIKE_KW = 1550, -1.0
SHIFT_SAMPLE, SHIFT_KW = 2450, 0.15  # the paper's 0.15 kW shift (sec. 5.2)
#: Input steps of the synthetic record: (sample, triac_pct).
STAIRCASE = ((0, 45.0), (400, 50.0), (700, 55.0), (1000, 40.0), (1300, 60.0), (1800, 45.0),
             (2100, 35.0), (2700, 50.0))
#: A 5-sample median of N(0, 0.01^2) noise on each side: a few noise std.
LEVEL_ATOL_KW = 0.03


def _staircase(n: int, steps: tuple[tuple[int, float], ...]) -> np.ndarray:
    s = np.empty(n)
    for k, value in steps:
        s[k:] = value
    return s


def _heater_record(
    *, n: int = 3000, steps: tuple[tuple[int, float], ...] = STAIRCASE, seed: int = 1,
    spike: bool = False, shift: bool = False,
) -> Dataset:
    """A sagging Hammerstein heater (paper eq. 27 shape) with white measurement noise."""
    rng = np.random.default_rng(seed)
    s = _staircase(n, steps)
    ds = s - OP.triac_pct
    power = OP.power_kw + lfilter([0.0, 1.0, -0.991], [1.0, -0.99], 1.35 * ds - 0.0065 * ds**2)
    power = power + NOISE_STD_KW * rng.standard_normal(n)
    if spike:
        power[SPIKE_SAMPLE] += SPIKE_KW
    if shift:
        power[SHIFT_SAMPLE:] += SHIFT_KW
    return Dataset(time_s=TS_S * np.arange(n), triac_pct=s, power_kw=power, ts_s=TS_S)


@pytest.fixture(scope="module")
def clean() -> Dataset:
    return _heater_record()


@pytest.fixture(scope="module")
def dirty() -> Dataset:
    return _heater_record(spike=True, shift=True)


# --------------------------------------------------------------------------- operating point


def test_given_operating_point_is_returned_with_its_method(clean: Dataset) -> None:
    choice = find_operating_point(clean, method="given", given=OP)
    assert choice.operating_point == OP
    assert choice.method == "given"
    assert choice.window is None


def test_means_operating_point_is_the_sample_means(clean: Dataset) -> None:
    choice = find_operating_point(clean, method="means")
    assert choice.method == "means"
    assert choice.operating_point.triac_pct == pytest.approx(np.mean(clean.triac_pct),
                                                             rel=IDENTITY_RTOL)
    assert choice.operating_point.power_kw == pytest.approx(np.mean(clean.power_kw),
                                                            rel=IDENTITY_RTOL)


def _line_drift(y: np.ndarray) -> float:
    """Change across ``y`` of its least-squares straight line (numpy.polyfit)."""
    return float(abs(np.polyfit(np.arange(y.size), y, 1)[0]) * (y.size - 1))


def test_steady_window_is_the_settled_end_of_the_long_constant_stretch() -> None:
    # 45 % held for samples 900..1799 after a step from 60 %: the sag settles with a
    # time constant of 100 samples, so the steady part is the stretch's later half.
    steps = ((0, 50.0), (150, 55.0), (300, 40.0), (450, 60.0), (900, 45.0), (1800, 50.0),
             (1950, 35.0))
    data = _heater_record(n=2100, steps=steps, seed=5)
    choice = find_operating_point(data, method="steady")
    window = choice.window
    assert choice.method == "steady" and window is not None
    assert window.stop_sample == 1800
    assert 1000 < window.start_sample < 1500
    assert window.input_spread == 0.0
    assert window.start_time_s == TS_S * window.start_sample
    assert window.end_time_s == TS_S * (window.stop_sample - 1)
    # the documented rule, checked sample by sample: from the start on, every
    # 20-sample mean lies within the band around the stretch's final level (the mean
    # of its last 225 samples); the 20-sample mean just before the start does not
    y, width, limit = data.power_kw, 20, window.settle_limit_kw
    final = y[1800 - 225 : 1800].mean()
    assert window.final_level_kw == pytest.approx(final, rel=IDENTITY_RTOL)
    start = window.start_sample
    for k in range(start, 1800 - width + 1):
        assert abs(y[k : k + width].mean() - final) <= limit
    assert abs(y[start - 1 : start - 1 + width].mean() - final) > limit
    assert _line_drift(y[start:1800]) <= limit
    assert window.output_drift_kw == pytest.approx(_line_drift(y[start:1800]), rel=1e-9,
                                                   abs=1e-12)  # reason: two line fits
    # the true steady state at ds = 0 is P = 45 kW
    assert choice.operating_point.triac_pct == 45.0
    assert abs(choice.operating_point.power_kw - 45.0) < limit
    assert window.output_spread_kw < 10 * NOISE_STD_KW


def test_steady_band_widens_with_output_atol_for_slow_disturbances() -> None:
    # a slow wander of +-0.1 kW (period 400 samples) on a steady output: the white
    # noise scale cannot see it, so only a band set by output_atol_kw accepts it
    n = 1200
    k = np.arange(n)
    power = 45.0 + 0.1 * np.sin(2 * np.pi * k / 400.0)
    power = power + NOISE_STD_KW * np.random.default_rng(8).standard_normal(n)
    data = Dataset(time_s=TS_S * k, triac_pct=np.full(n, 45.0), power_kw=power, ts_s=TS_S)
    with pytest.raises(IdentificationError, match="got none"):
        find_operating_point(data, method="steady")
    window = find_operating_point(data, method="steady", output_atol_kw=0.15).window
    assert window is not None and (window.start_sample, window.stop_sample) == (0, n)
    assert window.settle_limit_kw == 0.15


def test_steady_prefers_a_settled_window_to_a_longer_drifting_one() -> None:
    rng = np.random.default_rng(2)
    n_ramp, n_flat = 100, 60
    power = np.concatenate([np.linspace(40.0, 44.0, n_ramp), np.full(n_flat, 44.0)])
    power = power + 0.01 * rng.standard_normal(power.size)
    triac = np.concatenate([np.full(n_ramp, 30.0), np.full(n_flat, 35.0)])
    data = Dataset(time_s=np.arange(power.size, dtype=float), triac_pct=triac,
                   power_kw=power, ts_s=1.0)
    window = find_operating_point(data, method="steady").window
    assert window is not None
    assert (window.start_sample, window.stop_sample) == (n_ramp, n_ramp + n_flat)


def _held_levels(levels_and_lengths: tuple[tuple[float, int], ...]) -> Dataset:
    """Input levels held for the given samples; output settles at once (P = s) + noise."""
    triac = np.concatenate([np.full(n, level) for level, n in levels_and_lengths])
    power = triac + 0.01 * np.random.default_rng(3).standard_normal(triac.size)
    return Dataset(time_s=np.arange(triac.size, dtype=float), triac_pct=triac,
                   power_kw=power, ts_s=1.0)


def test_steady_takes_the_window_nearest_the_middle_of_the_input_range() -> None:
    # a record that starts at rest at the bottom of its range (the usual test): the
    # longest window is the first; the middle of 30 .. 70 % is 50 %
    data = _held_levels(((30.0, 400), (40.0, 150), (50.0, 250), (60.0, 300), (70.0, 100)))
    choice = find_operating_point(data, method="steady")
    assert choice.window is not None
    assert choice.operating_point.triac_pct == 50.0          # 250 >= 400 / 2 samples
    assert (choice.window.start_sample, choice.window.stop_sample) == (550, 800)
    # a central window shorter than half the longest is too poorly averaged to compete:
    # 60 % (300 samples) is then the nearest to the middle that qualifies
    data = _held_levels(((30.0, 400), (40.0, 150), (50.0, 150), (60.0, 300), (70.0, 100)))
    assert find_operating_point(data, method="steady").operating_point.triac_pct == 60.0


def test_steady_input_tolerance_joins_a_dithered_input() -> None:
    n = 200
    triac = 45.0 + 0.01 * (-1.0) ** np.arange(n)
    power = np.full(n, 45.0) + 0.001 * np.sin(np.arange(n))
    data = Dataset(time_s=np.arange(n, dtype=float), triac_pct=triac, power_kw=power, ts_s=1.0)
    with pytest.raises(IdentificationError, match="got none"):
        find_operating_point(data, method="steady")
    window = find_operating_point(data, method="steady", input_tol=0.05).window
    assert window is not None and window.n_samples == n
    assert window.input_spread == pytest.approx(0.02, rel=1e-9)  # reason: 45.01 - 44.99 in floats


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"method": "median"}, r"method must be 'given', 'means' or 'steady'; got 'median'"),
        ({"method": "given"}, r"method='given' needs given=OperatingPoint"),
        ({"method": "means", "given": OP}, r"given is only used with method='given'"),
        ({"method": "steady", "input_tol": -1.0}, r"input_tol must be a finite number >= 0"),
        ({"method": "steady", "drift_sigmas": float("nan")}, r"drift_sigmas must be"),
        ({"method": "steady", "output_atol_kw": float("inf")}, r"output_atol_kw must be"),
        ({"method": "steady", "min_window_samples": 3}, r"min_window_samples must be an int >= 4"),
        ({"method": "steady", "min_window_samples": 5000}, r"at least 5000 samples.*got none"),
    ],
    ids=["unknown-method", "given-missing", "given-extra", "input-tol", "drift-sigmas",
         "output-atol", "min-window", "no-window"],
)
def test_find_operating_point_rejects_bad_options(clean: Dataset, kwargs: dict[str, object],
                                                  match: str) -> None:
    with pytest.raises(IdentificationError, match=match):
        find_operating_point(clean, **kwargs)  # type: ignore[arg-type]


def test_to_deviation_subtracts_the_operating_point(clean: Dataset) -> None:
    op = OperatingPoint(triac_pct=40.0, power_kw=42.5)
    ds, dp = to_deviation(clean, op)
    np.testing.assert_array_equal(ds, clean.triac_pct - 40.0)
    np.testing.assert_array_equal(dp, clean.power_kw - 42.5)
    assert not ds.flags.writeable and not dp.flags.writeable


# --------------------------------------------------------------------------- outliers


def test_clean_record_has_step_residuals_but_no_candidates(clean: Dataset) -> None:
    report = find_outlier_candidates(clean, operating_point=OP)
    assert report.candidates == ()
    assert report.input_step_samples == tuple(k for k, _ in STAIRCASE[1:])
    # the Hammerstein curvature leaves large ARX residuals right after big steps; they
    # are model imperfection (paper sec. 5.2), excluded with the step they follow
    assert len(report.step_residuals) >= 3
    for item in report.step_residuals:
        assert item.input_step_sample in report.input_step_samples
        assert 0 <= item.sample - report.nk - item.input_step_sample <= 5
        assert abs(item.peak_residual_kw) > report.threshold_kw
    assert report.clipped_samples == ()


def test_planted_spike_and_level_shift_are_found_and_classified(dirty: Dataset) -> None:
    report = find_outlier_candidates(dirty, operating_point=OP)
    assert [(c.sample, c.kind) for c in report.candidates] == [
        (SPIKE_SAMPLE, "spike"), (SHIFT_SAMPLE, "level_shift")]
    spike, shift = report.candidates
    assert spike.time_s == TS_S * SPIKE_SAMPLE
    assert spike.output_jump_kw == pytest.approx(SPIKE_KW, abs=LEVEL_ATOL_KW)
    assert abs(spike.persisting_change_kw) < LEVEL_ATOL_KW
    assert spike.opposite_residual_follows  # the ARX predicted the next sample from the spike
    assert spike.residual_kw == pytest.approx(SPIKE_KW, abs=0.1)  # reason: ARX residual ~ spike
    assert shift.output_jump_kw == pytest.approx(SHIFT_KW, abs=LEVEL_ATOL_KW)
    assert shift.persisting_change_kw == pytest.approx(SHIFT_KW, abs=LEVEL_ATOL_KW)
    assert shift.residual_kw > report.threshold_kw
    assert not shift.opposite_residual_follows  # same-sign residuals only (paper Fig. 5)
    # the scale is robust: the outliers barely move it from the clean record's
    clean_scale = find_outlier_candidates(_heater_record(), operating_point=OP).scale_kw
    assert report.scale_kw == pytest.approx(clean_scale, rel=0.05)  # reason: MAD ignores 4 samples
    assert report.threshold_kw == pytest.approx(5.0 * report.scale_kw, rel=IDENTITY_RTOL)


def test_report_residuals_equal_an_independent_least_squares_arx(dirty: Dataset) -> None:
    report = find_outlier_candidates(dirty, operating_point=OP, na=2, nb=2, nk=1)
    ds, dp = to_deviation(dirty, OP)
    phi = np.column_stack([-dp[1:-1], -dp[:-2], ds[1:-1], ds[:-2]])
    theta = np.linalg.lstsq(phi, dp[2:], rcond=None)[0]
    assert report.first_sample == 2
    assert np.all(np.isnan(report.residuals_kw[:2]))
    # reason: two least-squares solvers on the same well-conditioned regression
    np.testing.assert_allclose(report.residuals_kw[2:], dp[2:] - phi @ theta, rtol=0, atol=1e-9)


def test_step_guard_zero_keeps_only_onsets_exactly_at_the_delayed_step(dirty: Dataset) -> None:
    wide = find_outlier_candidates(dirty, operating_point=OP, step_guard_samples=5)
    narrow = find_outlier_candidates(dirty, operating_point=OP, step_guard_samples=0)
    assert all(item.sample == item.input_step_sample + 1 for item in narrow.step_residuals)
    assert len(narrow.step_residuals) + len(narrow.candidates) >= len(wide.step_residuals) + 2


def test_outlier_threshold_changes_what_is_flagged(dirty: Dataset) -> None:
    strict = find_outlier_candidates(dirty, operating_point=OP, threshold=30.0)
    assert [c.kind for c in strict.candidates] == ["spike"]  # 1 kW is ~70 sigma, 0.15 kW ~10


def test_smooth_input_has_no_steps_unless_the_tolerance_says_so() -> None:
    n = 600
    k = np.arange(n)
    triac = 45.0 + 5.0 * np.sin(2 * np.pi * k / 97.0) + 3.0 * np.sin(2 * np.pi * k / 31.0)
    ds = triac - 45.0
    power = 45.0 + lfilter([0.0, 0.5, 0.3], [1.0, -0.7], ds)
    power = power + 0.01 * np.random.default_rng(4).standard_normal(n)
    data = Dataset(time_s=TS_S * k, triac_pct=triac, power_kw=power, ts_s=TS_S)
    auto = find_outlier_candidates(data, operating_point=OP, na=2, nb=2)
    assert auto.input_step_samples == ()
    assert auto.input_step_tol > 0.0
    every = find_outlier_candidates(data, operating_point=OP, na=2, nb=2, input_step_tol=0.0)
    assert len(every.input_step_samples) == n - 1


def test_clipped_output_runs_are_reported() -> None:
    data = _heater_record()
    power = np.minimum(data.power_kw, 52.0)  # the 55 % stair (samples 700..999) clips
    clipped = data.with_signals(power_kw=power)
    report = find_outlier_candidates(clipped, operating_point=OP)
    expected = tuple(int(k) for k in np.flatnonzero(power == 52.0))
    assert len(expected) > 100
    assert report.clipped_samples == expected
    short = find_outlier_candidates(clipped, operating_point=OP,
                                    clip_min_run_samples=len(expected) + 1)
    assert short.clipped_samples == ()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"na": -1}, r"na must be an int >= 0; got -1"),
        ({"nb": 0}, r"nb must be an int >= 1; got 0"),
        ({"nk": 1.5}, r"nk must be an int >= 0; got 1.5"),
        ({"threshold": 0.0}, r"threshold must be a finite number > 0; got 0.0"),
        ({"step_guard_samples": -2}, r"step_guard_samples must be an int >= 0; got -2"),
        ({"input_step_tol": float("nan")}, r"input_step_tol must be a finite number >= 0"),
        ({"clip_min_run_samples": 1}, r"clip_min_run_samples must be an int >= 2; got 1"),
    ],
    ids=["na", "nb", "nk", "threshold", "guard", "step-tol", "clip-run"],
)
def test_find_outlier_candidates_rejects_bad_options(clean: Dataset, kwargs: dict[str, object],
                                                     match: str) -> None:
    with pytest.raises(IdentificationError, match=match):
        find_outlier_candidates(clean, operating_point=OP, **kwargs)  # type: ignore[arg-type]


def test_exactly_fitted_data_has_no_residual_scale() -> None:
    n = 200
    triac = _staircase(n, ((0, 45.0), (50, 50.0), (100, 40.0), (150, 47.0)))
    power = 45.0 + lfilter([0.0, 0.8], [1.0, -0.5], triac - 45.0)
    data = Dataset(time_s=TS_S * np.arange(n), triac_pct=triac, power_kw=power, ts_s=TS_S)
    with pytest.raises(IdentificationError, match=r"positive robust scale \(MAD\); got .*exactly"):
        find_outlier_candidates(data, operating_point=OP, na=1, nb=1)


def test_too_short_record_for_the_arx_orders_is_refused() -> None:
    data = _heater_record(n=25, steps=((0, 45.0), (10, 50.0)))
    with pytest.raises(IdentificationError, match="need at least"):
        find_outlier_candidates(data, operating_point=OP)


# --------------------------------------------------------------------------- repairs


def test_interpolate_spike_repairs_and_records_the_change(dirty: Dataset) -> None:
    fixed = interpolate_spike(dirty, sample=SPIKE_SAMPLE)
    y = dirty.power_kw
    expected = 0.5 * (y[SPIKE_SAMPLE - 1] + y[SPIKE_SAMPLE + 1])
    assert fixed.power_kw[SPIKE_SAMPLE] == expected
    changed = np.flatnonzero(fixed.power_kw != y)
    assert changed.tolist() == [SPIKE_SAMPLE]
    assert fixed.preprocessing[-1] == {
        "what": "interpolate_spike", "signal": "power_kw", "sample": SPIKE_SAMPLE,
        "time_s": TS_S * SPIKE_SAMPLE, "old_value": float(y[SPIKE_SAMPLE]),
        "new_value": expected,
    }
    assert dirty.preprocessing == ()  # the input data set is untouched
    by_time = interpolate_spike(dirty, time_s=TS_S * SPIKE_SAMPLE + 0.4)
    np.testing.assert_array_equal(by_time.power_kw, fixed.power_kw)


def test_estimate_level_shift_measures_the_planted_shift(dirty: Dataset) -> None:
    estimate = estimate_level_shift(dirty, TS_S * SHIFT_SAMPLE)
    assert estimate.from_sample == SHIFT_SAMPLE
    assert estimate.input_constant
    assert estimate.before_samples == (SHIFT_SAMPLE - 30, SHIFT_SAMPLE)
    assert estimate.after_samples == (SHIFT_SAMPLE + 3, SHIFT_SAMPLE + 33)
    # noise 0.01 kW over 2 x 30 samples with a common line: std error ~0.005 kW
    assert 0.002 < estimate.std_error_kw < 0.01
    assert abs(estimate.shift_kw - SHIFT_KW) < 4 * estimate.std_error_kw
    across_step = estimate_level_shift(dirty, TS_S * 1810, window_samples=20)
    assert not across_step.input_constant  # samples 1790.. include the step at 1800


def test_estimate_level_shift_equals_the_line_plus_step_regression(dirty: Dataset) -> None:
    estimate = estimate_level_shift(dirty, TS_S * SHIFT_SAMPLE, window_samples=10,
                                    transition_samples=0)
    k = np.arange(SHIFT_SAMPLE - 10, SHIFT_SAMPLE + 10)
    phi = np.column_stack([np.ones(k.size), k - SHIFT_SAMPLE, k >= SHIFT_SAMPLE])
    delta = np.linalg.lstsq(phi, dirty.power_kw[k], rcond=None)[0][2]
    assert estimate.shift_kw == pytest.approx(delta, rel=1e-9)  # reason: same lstsq problem


def test_repairs_remove_both_candidates_and_chain_in_provenance(dirty: Dataset) -> None:
    report = find_outlier_candidates(dirty, operating_point=OP)
    spike, shift = report.candidates
    estimate = estimate_level_shift(dirty, shift.time_s)
    repaired = correct_level_shift(interpolate_spike(dirty, sample=spike.sample),
                                   from_time_s=shift.time_s, shift_kw=estimate.shift_kw)
    assert [step["what"] for step in repaired.preprocessing] == [
        "interpolate_spike", "correct_level_shift"]
    record = repaired.preprocessing[1]
    assert record["from_sample"] == SHIFT_SAMPLE
    assert record["shift_kw"] == estimate.shift_kw
    assert record["n_samples_changed"] == dirty.n_samples - SHIFT_SAMPLE
    after = find_outlier_candidates(repaired, operating_point=OP)
    assert after.candidates == ()
    # reason: only the repaired samples changed, by exactly the recorded amounts
    np.testing.assert_allclose(repaired.power_kw[SHIFT_SAMPLE:],
                               dirty.power_kw[SHIFT_SAMPLE:] - estimate.shift_kw,
                               rtol=0, atol=1e-12)
    np.testing.assert_array_equal(repaired.power_kw[:SPIKE_SAMPLE],
                                  dirty.power_kw[:SPIKE_SAMPLE])


def test_correct_level_shift_at_the_papers_time() -> None:
    data = _heater_record(n=12000, steps=((0, 45.0), (100, 50.0)))
    fixed = correct_level_shift(data, from_time_s=20714.0, shift_kw=0.15)
    k0 = 10357  # t = 2 s * 10357 = 20714 s
    np.testing.assert_array_equal(fixed.power_kw[:k0], data.power_kw[:k0])
    # reason: one float subtraction per sample
    np.testing.assert_allclose(fixed.power_kw[k0:], data.power_kw[k0:] - 0.15, rtol=0,
                               atol=1e-12)
    assert fixed.preprocessing[-1]["from_time_s"] == 20714.0
    # a time between samples affects the samples from the next one on
    between = correct_level_shift(data, from_time_s=20713.0, shift_kw=0.15)
    assert between.preprocessing[-1]["from_sample"] == k0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({}, r"give exactly one of sample and time_s"),
        ({"sample": 3, "time_s": 6.0}, r"give exactly one of sample and time_s"),
        ({"sample": 0}, r"1 <= sample <= 2998; got 0"),
        ({"sample": 2999}, r"1 <= sample <= 2998; got 2999"),
        ({"sample": -5}, r"got -5"),
        ({"sample": 2.0}, r"sample must be an int; got 2.0"),
        ({"time_s": 7000.0}, r"within the record \[0, 5998\] s; got 7000 s"),
        ({"time_s": float("nan")}, r"time_s must be a finite number; got nan"),
        ({"time_s": 0.0}, r"got 0$"),
    ],
    ids=["neither", "both", "first", "last", "negative", "float", "outside", "nan", "edge-time"],
)
def test_interpolate_spike_rejects_bad_locations(clean: Dataset, kwargs: dict[str, object],
                                                 match: str) -> None:
    with pytest.raises(DataFileError, match=match):
        interpolate_spike(clean, **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("from_time_s", "shift_kw", "match"),
    [
        (0.0, 0.15, r"inside the record \(0, 5998\] s; got 0.0 s"),
        (6000.0, 0.15, r"got 6000.0 s"),
        (float("inf"), 0.15, r"got inf s"),
        (100.0, float("nan"), r"shift_kw must be a finite number; got nan"),
    ],
    ids=["start", "after-end", "inf", "nan-shift"],
)
def test_correct_level_shift_rejects_bad_arguments(clean: Dataset, from_time_s: float,
                                                   shift_kw: float, match: str) -> None:
    with pytest.raises(DataFileError, match=match):
        correct_level_shift(clean, from_time_s=from_time_s, shift_kw=shift_kw)


def test_estimate_level_shift_rejects_bad_windows(clean: Dataset) -> None:
    with pytest.raises(IdentificationError, match=r"window_samples must be an int >= 2; got 1"):
        estimate_level_shift(clean, 100.0, window_samples=1)
    with pytest.raises(IdentificationError, match=r"transition_samples must be an int >= 0"):
        estimate_level_shift(clean, 100.0, transition_samples=-1)
    with pytest.raises(IdentificationError, match=r"at least 2 samples before 2 s.*got 1 and"):
        estimate_level_shift(clean, 2.0)
    with pytest.raises(IdentificationError, match=r"2 after the 3-sample transition; got 30 and 1"):
        estimate_level_shift(clean, TS_S * 2996)
    with pytest.raises(DataFileError, match=r"within the record"):
        estimate_level_shift(clean, -50.0)
