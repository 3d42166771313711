"""Tests of sysid.design: staircase levels, GBN switching statistics, jump limit, errors."""

from __future__ import annotations

import numpy as np
import pytest

from sysid.design import HOLD_TAUS, ExcitationSpec, SignalDesignError, design_test_signal


def _spec(**kw: object) -> ExcitationSpec:
    base: dict[str, object] = dict(ts_s=10.0, lo_pct=20.0, hi_pct=60.0, tau_s=300.0,
                                   duration_s=200_000.0, max_step_pct=100.0, kind="mixed", degree=3)
    base.update(kw)
    return ExcitationSpec(**base)  # type: ignore[arg-type]


def test_staircase_levels_up_and_down() -> None:
    sig = design_test_signal(_spec(kind="steps", duration_s=60_000.0), np.random.default_rng(0))
    np.testing.assert_allclose(sig.levels_pct, [20.0, 30.0, 40.0, 50.0, 60.0])  # degree + 2 = 5
    holds = sig.hold_times_s()[:-1]  # last stretch includes the padding to the duration
    np.testing.assert_allclose(holds, HOLD_TAUS * 300.0)
    stairs = sig.triac_pct[: sig.steps_samples: sig.spec.hold_samples]
    np.testing.assert_allclose(stairs, [20, 30, 40, 50, 60, 50, 40, 30, 20])


def test_max_step_adds_levels_and_bounds_every_jump() -> None:
    sig = design_test_signal(_spec(max_step_pct=4.0), np.random.default_rng(1))
    assert sig.levels_pct.size == 11
    assert np.abs(np.diff(sig.triac_pct)).max() <= 4.0 + 1e-12
    assert sig.triac_pct.min() >= 20.0 and sig.triac_pct.max() <= 60.0


def test_gbn_mean_switching_time_equals_tau() -> None:
    # Switches are Bernoulli(p = ts/tau) per sample: mean count p*(n-1), std sqrt(n p (1-p)).
    spec = _spec(kind="gbn", duration_s=3_000_000.0)
    sig = design_test_signal(spec, np.random.default_rng(2))
    n_switch = int(np.count_nonzero(np.diff(sig.triac_pct)))
    p = spec.ts_s / spec.tau_s
    n = sig.triac_pct.size - 1
    assert abs(n_switch - p * n) < 4.0 * np.sqrt(n * p * (1 - p))
    # Spectrum corner at 2/tau: theory gives arctan-shaped cumulative power, (2/pi)*atan(w/wc)
    # for the continuous approximation; at w = wc it is 1/2.
    frac = sig.power_fraction_below(2.0 / spec.tau_s)
    assert 0.40 < frac < 0.60


def test_seed_repeats_and_differs() -> None:
    a = design_test_signal(_spec(), np.random.default_rng(5)).triac_pct
    b = design_test_signal(_spec(), np.random.default_rng(5)).triac_pct
    c = design_test_signal(_spec(), np.random.default_rng(6)).triac_pct
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_too_short_names_the_need() -> None:
    with pytest.raises(SignalDesignError, match="too short"):
        design_test_signal(_spec(duration_s=5_000.0), np.random.default_rng(0))


def test_bad_range_rejected() -> None:
    with pytest.raises(SignalDesignError, match="60"):
        _spec(lo_pct=60.0, hi_pct=20.0)
