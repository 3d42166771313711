"""Tests of sysid.design: staircase levels, GBN switching statistics, jump limit, errors."""

from __future__ import annotations

import numpy as np
import pytest

from sysid.design import (
    HOLD_TAUS,
    MIN_GBN_TAUS,
    ExcitationSpec,
    SignalDesignError,
    design_test_signal,
    shortest_duration_s,
)


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


def test_multilevel_visits_every_level_equally_and_ramps_large_jumps() -> None:
    spec = _spec(kind="multilevel", degree=2, duration_s=400_000.0)
    sig = design_test_signal(spec, np.random.default_rng(3))
    np.testing.assert_allclose(sig.levels_pct, np.linspace(20.0, 60.0, 4))
    # no step limit: every switch jumps to another level; the shuffled rounds visit each
    # level once per round, so the visit counts differ by at most one
    starts = np.concatenate(([0], np.flatnonzero(np.diff(sig.triac_pct)) + 1))
    assert np.all(np.diff(sig.triac_pct[starts]) != 0.0)
    visits = [int(np.count_nonzero(np.isclose(sig.triac_pct[starts], v))) for v in sig.levels_pct]
    assert max(visits) - min(visits) <= 1 and sum(visits) == starts.size, visits
    # the switch rate is the GBN's: about one per tau
    assert abs(starts.size - 400_000.0 / 300.0) < 4.0 * np.sqrt(400_000.0 / 300.0)
    limited = design_test_signal(_spec(kind="multilevel", degree=2, duration_s=400_000.0,
                                       max_step_pct=15.0), np.random.default_rng(3))
    assert np.abs(np.diff(limited.triac_pct)).max() <= 15.0 + 1e-12
    assert set(sig.levels_pct) <= set(np.unique(limited.triac_pct))


def test_multilevel_holds_every_level_in_each_half_for_about_one_tau() -> None:
    """The order search estimates on one half of a test and validates on the other: each
    half holds every level equally often, and no hold is far from the mean (geometric
    holds gave one level 142 s in one half and 1,254 s in the other)."""
    from sysid.design import MULTILEVEL_HOLD_SPREAD

    spec = ExcitationSpec(ts_s=2.0, lo_pct=35.0, hi_pct=60.0, tau_s=600.0, duration_s=7200.0,
                          max_step_pct=5.0, kind="multilevel", degree=3)
    assert spec.multilevel_rounds_per_half == 1     # 3600 s / 5 levels: 720 s per visit
    assert spec.multilevel_mean_hold_s == 720.0
    for seed in range(20):
        sig = design_test_signal(spec, np.random.default_rng(seed))
        u = sig.triac_pct
        half = u.size // 2
        for part in (u[:half], u[half:]):
            starts = np.concatenate(([0], np.flatnonzero(np.diff(part)) + 1))
            at_level = [v for v in part[starts] if np.isclose(sig.levels_pct, v).any()]
            assert sorted(np.round(at_level, 6)) == sorted(np.round(sig.levels_pct, 6)), seed
        holds = sig.hold_times_s(at_levels=True)
        # 360 .. 1080 s evenly; a ramp of up to 25 % / 5 % = 5 samples (10 s) eats into the
        # level it leads to
        assert holds.min() >= (1 - MULTILEVEL_HOLD_SPREAD) * 720.0 - 10.0 - 2.0, seed
        assert holds.max() <= (1 + MULTILEVEL_HOLD_SPREAD) * 720.0 + 2.0, seed
        assert abs(np.median(holds) - 720.0) <= 0.25 * 720.0, seed


def test_multilevel_fits_a_slow_plant_into_two_hours_where_mixed_cannot() -> None:
    from sysid.design import MIN_MULTILEVEL_ROUNDS, shortest_duration_s

    slow = dict(ts_s=2.0, lo_pct=35.0, hi_pct=60.0, tau_s=600.0, duration_s=7200.0,
                max_step_pct=5.0, degree=2)
    ml = ExcitationSpec(kind="multilevel", **slow)  # type: ignore[arg-type]
    assert shortest_duration_s(ml) == MIN_MULTILEVEL_ROUNDS * 4 * 600.0 == 4800.0
    sig = design_test_signal(ml, np.random.default_rng(0))
    assert sig.time_s[-1] == 7200.0 and np.unique(np.round(sig.triac_pct, 9)).size > 4
    mixed = ExcitationSpec(kind="mixed", **slow)  # type: ignore[arg-type]
    # 6 levels (25 % in steps of 5 %) held 4 tau, up and down, plus 20 tau of GBN
    assert shortest_duration_s(mixed) == (11 * 1200 - 1) * 2.0 + 20 * 600.0
    with pytest.raises(SignalDesignError, match="too short for a mixed test"):
        design_test_signal(mixed, np.random.default_rng(0))
    with pytest.raises(SignalDesignError, match="at least 4800 s"):
        design_test_signal(ExcitationSpec(kind="multilevel", **{**slow, "duration_s": 4000.0}),
                           np.random.default_rng(0))


def test_a_gbn_shorter_than_its_shortest_duration_is_refused() -> None:
    # shortest_duration_s says a GBN needs MIN_GBN_TAUS tau (20 x 300 s = 6000 s here); a
    # 1,000 s GBN holds about three switches, too few to identify anything from
    spec = _spec(kind="gbn", duration_s=1_000.0)
    assert shortest_duration_s(spec) == MIN_GBN_TAUS * 300.0
    with pytest.raises(SignalDesignError, match=r"too short for a gbn test: 20 tau of 300 s "
                                                r"need at least 6000 s"):
        design_test_signal(spec, np.random.default_rng(0))
    ok = design_test_signal(_spec(kind="gbn", duration_s=6_000.0), np.random.default_rng(0))
    assert ok.triac_pct.size == 601
