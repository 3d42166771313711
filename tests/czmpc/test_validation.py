"""Measurement validity: limit, rate, stuck and spike checks; re-opening on level changes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from czmpc.validation import (
    MeasurementChecker,
    Verdict,
    check_limits,
    within_gate,
    within_rate,
)

SIGMA_KW = 0.013  # the power sensor's noise std
QUANTUM_KW = 0.001  # it reads whole watts


def _longest_run(values: np.ndarray) -> int:
    longest = run = 1
    for a, b in zip(values[:-1], values[1:], strict=True):
        run = run + 1 if a == b else 1
        longest = max(longest, run)
    return longest


def _checker(**changes: object) -> MeasurementChecker:
    kw: dict[str, object] = dict(
        power_min_kw=0.0, power_max_kw=150.0, max_change_kw=None, stuck_samples=10,
        stuck_min_predicted_change_kw=0.1, gate_k_sigma=8.0, gate_floor_kw=0.0,
        reopen_after=3)
    kw.update(changes)
    return MeasurementChecker(**kw)  # type: ignore[arg-type]


@pytest.mark.parametrize(("power", "verdict"), [
    (math.nan, Verdict.MISSING), (math.inf, Verdict.MISSING), (-math.inf, Verdict.MISSING),
    (-0.001, Verdict.BELOW_LIMIT), (0.0, Verdict.VALID), (150.0, Verdict.VALID),
    (150.001, Verdict.ABOVE_LIMIT), (1e300, Verdict.ABOVE_LIMIT),
])
def test_limits(power: float, verdict: Verdict) -> None:
    assert check_limits(power, power_min_kw=0.0, power_max_kw=150.0) is verdict


def test_no_limits_accepts_any_finite_value() -> None:
    assert check_limits(-1e300, power_min_kw=None, power_max_kw=None) is Verdict.VALID


@pytest.mark.parametrize(("power_min_kw", "power_max_kw"), [(0.0, 150.0), (None, None)])
@pytest.mark.parametrize("power", [math.nan, math.inf, -math.inf, -0.001, 0.0, 45.0, 150.0, 150.001])
def test_the_checker_gives_the_limit_verdict(power: float, power_min_kw: float | None,
                                             power_max_kw: float | None) -> None:
    # the checker's fast path (strictly inside the limits) must agree on the limits and beyond
    checker = _checker(power_min_kw=power_min_kw, power_max_kw=power_max_kw, gate_k_sigma=None)
    verdict = checker.check(power, predicted_kw=45.0, innovation_std_kw=SIGMA_KW).verdict
    assert verdict is check_limits(power, power_min_kw=power_min_kw, power_max_kw=power_max_kw)


def test_rate_and_gate_are_closed_intervals() -> None:
    assert within_rate(46.0, 45.0, max_change_kw=1.0)
    assert not within_rate(46.0 + 1e-9, 45.0, max_change_kw=1.0)
    assert within_rate(99.0, None, max_change_kw=1.0) and within_rate(99.0, 1.0, max_change_kw=None)
    assert within_gate(0.08, innovation_std_kw=0.01, k_sigma=8.0, floor_kw=0.0)
    assert not within_gate(-0.0801, innovation_std_kw=0.01, k_sigma=8.0, floor_kw=0.0)
    assert within_gate(-0.4, innovation_std_kw=0.01, k_sigma=8.0, floor_kw=0.5)


def test_stuck_reading_trips_only_while_the_prediction_moves() -> None:
    checker = _checker()
    verdicts = []
    for k in range(15):
        # the reading is frozen at 45.000 while the prediction ramps 0.02 kW per sample
        verdicts.append(checker.check(45.0, predicted_kw=45.0 + 0.02 * k,
                                      innovation_std_kw=10.0).verdict)
    # after 10 identical readings the prediction has moved 0.18 kW >= 0.1 kW
    assert verdicts[:9] == [Verdict.VALID] * 9
    assert verdicts[9:] == [Verdict.STUCK] * 6
    # a new value ends it
    assert checker.check(45.3, predicted_kw=45.3, innovation_std_kw=10.0).is_valid


def test_quiet_signal_at_constant_input_never_trips(rng: np.random.Generator) -> None:
    # quantized noise around a constant prediction: exact repeats are common
    checker = _checker()
    readings = np.round((45.0 + 0.0003 * rng.standard_normal(2000)) / QUANTUM_KW) * QUANTUM_KW
    assert _longest_run(readings) >= 10  # runs as long as the stuck check's do occur
    for y in readings:
        assert checker.check(float(y), predicted_kw=45.0, innovation_std_kw=SIGMA_KW).is_valid
    # a perfectly constant reading at a constant input is fine too
    for _ in range(100):
        assert checker.check(45.0, predicted_kw=45.0, innovation_std_kw=SIGMA_KW).is_valid


def test_noisy_moving_signal_never_trips_the_stuck_check(rng: np.random.Generator) -> None:
    checker = _checker(gate_k_sigma=None)
    for k in range(3000):
        predicted = 45.0 + 5.0 * math.sin(k / 50.0)
        y = round((predicted + SIGMA_KW * float(rng.standard_normal())) / QUANTUM_KW) * QUANTUM_KW
        assert checker.check(y, predicted_kw=predicted, innovation_std_kw=SIGMA_KW).is_valid


def test_stuck_check_can_be_switched_off() -> None:
    checker = _checker(stuck_samples=0)
    for k in range(30):
        assert checker.check(45.0, predicted_kw=45.0 + k, innovation_std_kw=100.0).is_valid


def test_isolated_spike_is_rejected_and_the_next_sample_accepted() -> None:
    checker = _checker()
    assert checker.check(45.0, predicted_kw=45.0, innovation_std_kw=SIGMA_KW).is_valid
    spike = checker.check(48.0, predicted_kw=45.0, innovation_std_kw=SIGMA_KW)
    assert spike.verdict is Verdict.SPIKE and checker.consecutive_rejections == 1
    back = checker.check(45.01, predicted_kw=45.0, innovation_std_kw=SIGMA_KW)
    assert back.is_valid and not back.reopened and checker.consecutive_rejections == 0


def test_persistent_level_change_is_accepted_after_reopen_after_samples() -> None:
    checker = _checker(reopen_after=3)
    verdicts = [checker.check(47.0, predicted_kw=45.0, innovation_std_kw=SIGMA_KW)
                for _ in range(4)]
    assert [v.verdict for v in verdicts[:3]] == [Verdict.SPIKE] * 3
    assert verdicts[3].is_valid and verdicts[3].reopened
    # the gate stays open while the estimator catches up (innovation shrinking) ...
    for innovation in (1.5, 1.0, 0.5, 0.2):
        assert checker.check(47.0, predicted_kw=47.0 - innovation,
                             innovation_std_kw=SIGMA_KW).is_valid
    # ... and closes once the innovation is back inside: a spike is rejected again
    assert checker.check(47.0, predicted_kw=47.0, innovation_std_kw=SIGMA_KW).is_valid
    assert checker.check(50.0, predicted_kw=47.0, innovation_std_kw=SIGMA_KW).verdict \
        is Verdict.SPIKE


def test_too_fast_change_reopens_on_a_persistent_jump() -> None:
    checker = _checker(max_change_kw=1.0, gate_k_sigma=None, reopen_after=2)
    assert checker.check(45.0, predicted_kw=45.0, innovation_std_kw=1.0).is_valid
    out = [checker.check(50.0, predicted_kw=45.0, innovation_std_kw=1.0) for _ in range(3)]
    assert [o.verdict for o in out] == [Verdict.TOO_FAST, Verdict.TOO_FAST, Verdict.VALID]
    assert out[2].reopened
    assert checker.check(50.5, predicted_kw=50.0, innovation_std_kw=1.0).is_valid


def test_limit_rejections_never_reopen() -> None:
    checker = _checker(reopen_after=1)
    for _ in range(20):
        assert checker.check(-5.0, predicted_kw=45.0, innovation_std_kw=SIGMA_KW).verdict \
            is Verdict.BELOW_LIMIT


def test_gate_off_during_warm_up() -> None:
    checker = _checker()
    assert checker.check(60.0, predicted_kw=45.0, innovation_std_kw=SIGMA_KW, gate=False).is_valid


def test_reset_forgets_history() -> None:
    checker = _checker(reopen_after=5)
    for _ in range(3):
        checker.check(60.0, predicted_kw=45.0, innovation_std_kw=SIGMA_KW)
    assert checker.consecutive_rejections == 3
    checker.reset()
    assert checker.consecutive_rejections == 0
