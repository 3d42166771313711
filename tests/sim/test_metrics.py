"""Metrics on hand-made trajectories whose IAE, overshoot and settling time are known."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pytest

from sim.errors import ScenarioError
from sim.loop import ClosedLoopResult
from sim.metrics import (
    compute_metrics,
    count_limit_violations,
    count_rate_violations,
    settling_time_s,
    steady_state_error_kw,
)
from sim.scenario import Scenario, SetpointRamp, SetpointStep
from tests.tolerances import IDENTITY_RTOL

TS_S = 2.0
N = 500
K0 = 100            # the step happens at sample 100 (t = 200 s)
FROM_KW, TO_KW = 45.0, 50.0
STEP_KW = TO_KW - FROM_KW
#: Sums of a few hundred terms vs their closed forms: rounding only.
SERIES_RTOL = 1e-10


def _scenario(**changes: object) -> Scenario:
    base: dict[str, object] = dict(
        name="hand", duration_s=N * TS_S, initial_setpoint_kw=FROM_KW,
        setpoints=(SetpointStep(at_s=K0 * TS_S, power_kw=TO_KW),),
    )
    base.update(changes)
    return Scenario(**base)  # type: ignore[arg-type]


def _result(power_kw: np.ndarray, *, scenario: Scenario | None = None,
            triac_pct: np.ndarray | None = None, step_time_s: np.ndarray | None = None,
            diagnostics: tuple[object, ...] | None = None) -> ClosedLoopResult:
    scenario = _scenario() if scenario is None else scenario
    return ClosedLoopResult(
        scenario=scenario, seed=None, time_s=scenario.time_s(),
        setpoint_kw=scenario.setpoint_profile_kw(), power_measured_kw=power_kw,
        power_true_kw=power_kw,
        triac_pct=np.full(N, 45.0) if triac_pct is None else triac_pct,
        step_time_s=np.full(N, 1e-3) if step_time_s is None else step_time_s,
        diagnostics=diagnostics,
    )


def _first_order(lam: float) -> np.ndarray:
    """P = r_new - D lam^j for j = k - K0 >= 0: error D lam^j, no overshoot."""
    power = np.full(N, FROM_KW)
    j = np.arange(N - K0)
    power[K0:] = TO_KW - STEP_KW * lam**j
    return power


def test_first_order_response_iae_ise_settling_have_their_closed_forms() -> None:
    lam = 0.95
    metrics = compute_metrics(_result(_first_order(lam)))
    (change,) = metrics.changes
    m = N - K0
    assert change.iae_kw_s == pytest.approx(STEP_KW * TS_S * (1 - lam**m) / (1 - lam),
                                            rel=SERIES_RTOL)
    assert change.ise_kw2_s == pytest.approx(STEP_KW**2 * TS_S * (1 - lam ** (2 * m)) / (1 - lam**2),
                                             rel=SERIES_RTOL)
    # |e_j| = D lam^j > 0.02 D  <=>  j < ln 0.02 / ln lam = 76.27: last outside j = 76
    j_last = math.ceil(math.log(0.02) / math.log(lam)) - 1
    assert j_last == 76
    assert change.settling_time_s == (j_last + 1) * TS_S
    assert change.overshoot_kw == 0.0 and change.overshoot_pct == 0.0
    assert change.time_s == K0 * TS_S and change.step_kw == STEP_KW
    assert metrics.iae_kw_s == pytest.approx(change.iae_kw_s, rel=IDENTITY_RTOL)  # no other error


def test_overshooting_response_has_its_known_overshoot_and_settling() -> None:
    lam = 0.9
    power = np.full(N, FROM_KW)
    j = np.arange(1, N - K0)
    power[K0 + 1:] = TO_KW + 0.2 * STEP_KW * lam ** (j - 1)      # 20 % overshoot at j = 1
    (change,) = compute_metrics(_result(power)).changes
    assert change.overshoot_kw == pytest.approx(0.2 * STEP_KW, rel=IDENTITY_RTOL)
    assert change.overshoot_pct == pytest.approx(20.0, rel=IDENTITY_RTOL)
    # outside while 0.2 lam^(j-1) > 0.02  <=>  j - 1 < ln 0.1 / ln 0.9 = 21.85: last j = 22
    assert change.settling_time_s == 23 * TS_S
    expected_iae = STEP_KW * TS_S * (1 + 0.2 * (1 - lam ** (N - K0 - 1)) / (1 - lam))
    assert change.iae_kw_s == pytest.approx(expected_iae, rel=SERIES_RTOL)


def test_downward_step_counts_undershoot_below_the_new_setpoint_as_overshoot() -> None:
    scenario = _scenario(initial_setpoint_kw=TO_KW,
                         setpoints=(SetpointStep(at_s=K0 * TS_S, power_kw=FROM_KW),))
    power = np.full(N, TO_KW)
    power[K0 + 1:] = FROM_KW - 0.5                                 # 10 % below, never back
    (change,) = compute_metrics(_result(power, scenario=scenario)).changes
    assert change.overshoot_pct == pytest.approx(10.0, rel=IDENTITY_RTOL)
    assert change.settling_time_s is None                           # ends outside the band
    assert change.steady_state_error_kw == pytest.approx(-0.5, rel=IDENTITY_RTOL)


def test_steady_state_error_is_the_mean_over_the_last_quarter_of_each_segment() -> None:
    power = _first_order(0.5)
    power[:K0] += 0.1                          # initial segment offset by +0.1 kW
    power[N - 100:] -= 0.3                     # last quarter of the step segment (400 samples)
    metrics = compute_metrics(_result(power))
    assert metrics.steady_state_errors_kw[0] == pytest.approx(0.1, rel=IDENTITY_RTOL)
    assert metrics.steady_state_errors_kw[1] == pytest.approx(-0.3, rel=1e-9)
    assert metrics.max_abs_steady_state_error_kw == pytest.approx(0.3, rel=1e-9)
    assert steady_state_error_kw(np.array([1.0, 2.0, np.nan, 4.0]), fraction=0.5) == 4.0


def test_ramp_change_is_measured_against_the_final_setpoint() -> None:
    scenario = _scenario(setpoints=(SetpointRamp(start_s=200.0, end_s=400.0, power_kw=TO_KW),))
    power = scenario.setpoint_profile_kw().copy()     # perfect tracking ...
    power[250:260] = TO_KW + 0.25                     # ... but a 5 % bump after the ramp
    (change,) = compute_metrics(_result(power, scenario=scenario)).changes
    assert change.kind == "ramp"
    assert change.overshoot_pct == pytest.approx(5.0, rel=1e-9)
    assert change.iae_kw_s == pytest.approx(10 * 0.25 * TS_S, rel=1e-9)
    assert change.settling_time_s == (260 - K0) * TS_S


def test_limit_and_rate_violations_are_counted_with_a_solver_tolerance() -> None:
    triac = np.full(N, 50.0)
    triac[10] = 100.0 + 1e-9          # within tolerance: not a violation
    triac[20] = 100.5
    triac[30:33] = -1.0
    metrics = compute_metrics(_result(_first_order(0.5), triac_pct=triac),
                              max_move_pct_per_step=10.0)
    assert metrics.n_limit_violations == 4
    # moves: 10 -> 2 (up, down), 20 -> 2, 30..32 -> 2 (in, out): 6 moves above 10 %
    assert metrics.n_rate_violations == 6
    assert metrics.n_constraint_violations == 10
    assert metrics.max_move_pct == pytest.approx(51.0, rel=IDENTITY_RTOL)
    assert metrics.input_total_variation_pct == pytest.approx(2 * (50 + 1e-9) + 2 * 50.5 + 2 * 51,
                                                              rel=IDENTITY_RTOL)
    assert count_limit_violations(triac, (0.0, 120.0)) == 3
    assert count_rate_violations(triac, 60.0) == 0
    assert compute_metrics(_result(_first_order(0.5), triac_pct=triac)).n_rate_violations == 0


def test_scenario_limits_are_the_default_for_checking() -> None:
    scenario = _scenario(triac_limits_pct=(20.0, 70.0), max_move_pct_per_step=1.0)
    triac = np.full(N, 45.0)
    triac[5] = 75.0
    metrics = compute_metrics(_result(_first_order(0.5), scenario=scenario, triac_pct=triac))
    assert (metrics.n_limit_violations, metrics.n_rate_violations) == (1, 2)
    with pytest.raises(ScenarioError, match=r"min < max"):
        compute_metrics(_result(_first_order(0.5)), triac_limits_pct=(70.0, 20.0))
    with pytest.raises(ScenarioError, match=r"power_signal"):
        compute_metrics(_result(_first_order(0.5)), power_signal="estimated")  # type: ignore[arg-type]


@dataclass(frozen=True)
class _Diag:
    fallback: str


def test_solver_failures_and_step_time_statistics() -> None:
    rng = np.random.default_rng(0)
    step_time = rng.uniform(1e-4, 5e-3, size=N)
    diags = tuple(_Diag("shifted_plan" if k in (3, 99) else "none") for k in range(N))
    metrics = compute_metrics(_result(_first_order(0.5), step_time_s=step_time,
                                      diagnostics=diags))
    assert metrics.n_solver_failures == 2
    assert metrics.step_time_median_ms == pytest.approx(np.median(step_time) * 1e3,
                                                        rel=IDENTITY_RTOL)
    assert metrics.step_time_p95_ms == pytest.approx(np.percentile(step_time, 95) * 1e3,
                                                     rel=IDENTITY_RTOL)
    assert metrics.step_time_max_ms == pytest.approx(step_time.max() * 1e3, rel=IDENTITY_RTOL)
    assert compute_metrics(_result(_first_order(0.5))).n_solver_failures is None


def test_measured_signal_skips_missing_samples_and_to_dict_is_strict_json() -> None:
    power = _first_order(0.5)
    measured = power.copy()
    measured[300:310] = np.nan
    scenario = _scenario()
    result = ClosedLoopResult(
        scenario=scenario, seed=1, time_s=scenario.time_s(),
        setpoint_kw=scenario.setpoint_profile_kw(), power_measured_kw=measured,
        power_true_kw=power, triac_pct=np.full(N, 45.0), step_time_s=np.full(N, 1e-3),
    )
    on_measured = compute_metrics(result, power_signal="measured")
    on_true = compute_metrics(result)
    assert on_measured.changes[0].iae_kw_s == pytest.approx(
        on_true.changes[0].iae_kw_s - float(np.sum(np.abs(power[300:310] - TO_KW))) * TS_S,
        rel=IDENTITY_RTOL)
    text = json.dumps(on_measured.to_dict(), allow_nan=False)
    assert json.loads(text)["changes"][0]["settling_time_s"] == on_measured.changes[0].settling_time_s


def test_settling_time_is_zero_inside_the_band_and_none_when_ending_outside() -> None:
    assert settling_time_s(np.zeros(10), step_kw=5.0, ts_s=TS_S) == 0.0
    assert settling_time_s(np.array([0.0, 0.0, 1.0]), step_kw=5.0, ts_s=TS_S) is None
    assert settling_time_s(np.array([1.0, 0.0, np.nan]), step_kw=5.0, ts_s=TS_S) == TS_S
    assert settling_time_s(np.array([0.0, 1.0, np.nan]), step_kw=5.0, ts_s=TS_S) is None
