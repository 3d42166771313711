"""czmpc.peers.pi and czmpc.peers.open_loop: PI (anti-windup, gain schedule, lambda rule), open loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from czmpc.errors import SettingsError
from czmpc.peers.open_loop import OpenLoopInversion
from czmpc.peers.pi import (
    MAX_INSTANT_LOOP_GAIN,
    GainSchedule,
    PIController,
)
from czmpc.pid.errors import PIDTuningError
from sim.loop import run_closed_loop
from sim.metrics import compute_metrics
from sim.model_plant import ModelPlant
from sim.protocols import Controller
from sim.scenario import Scenario, SetpointStep
from sysid.model import HammersteinModel


def _gain(pi: PIController, s_pct: float) -> float:
    """``Kc`` [%/kW] in force when ``s_pct`` was the last input."""
    return pi.schedule.tuning_at(s_pct).kc_pct_per_kw


def _slope(model: HammersteinModel, s_pct: float) -> float:
    """f'(s - s_nom) from numpy's polynomial derivative (independent of czmpc)."""
    coef = np.concatenate([[0.0], np.asarray(model.input_poly)])  # ascending, constant 0
    return float(np.polynomial.polynomial.polyval(
        s_pct - model.operating_point.triac_pct, np.polynomial.polynomial.polyder(coef)))


def test_pi_and_open_loop_satisfy_the_controller_protocol(
    paper_armax_model: HammersteinModel,
) -> None:
    assert isinstance(PIController.tuned_for(paper_armax_model), Controller)
    assert isinstance(PIController.tuned_for(paper_armax_model, gain_scheduled=True), Controller)
    assert isinstance(OpenLoopInversion(paper_armax_model), Controller)


def test_lambda_rule_gives_gain_and_integral_time_of_the_stated_formula(
    paper_armax_model: HammersteinModel,
) -> None:
    pi = PIController.tuned_for(paper_armax_model, closed_loop_time_constant_s=90.0,
                                initial_triac_pct=55.0)
    beta = MAX_INSTANT_LOOP_GAIN
    np.testing.assert_allclose(pi.gain_pct_per_kw, beta / _slope(paper_armax_model, 55.0),
                               rtol=1e-12, atol=0.0)  # same formula, polynomial evaluated twice
    np.testing.assert_allclose(pi.integral_time_s, 90.0 * beta / (1 + beta), rtol=1e-15, atol=0.0)


@pytest.mark.parametrize("lambda_s", [60.0, 200.0, 600.0])
def test_lambda_rule_puts_the_dominant_pole_of_a_gain_delay_loop_at_exp_minus_ts_over_lambda(
    paper_armax_model: HammersteinModel, lambda_s: float,
) -> None:
    pi = PIController.tuned_for(paper_armax_model, closed_loop_time_constant_s=lambda_s)
    g = _slope(paper_armax_model, 45.0)
    kc, ts, ti = pi.gain_pct_per_kw, pi.ts_s, pi.integral_time_s
    # y+ = g u; u_k = u_{k-1} + Kc (e_k - e_{k-1}) + Kc ts/Ti e_{k-1} with e = -y (the
    # velocity form of the back-calculation PI); state [y_k, u_{k-1}, y_{k-1}]
    a = kc * (1 - ts / ti)
    A = np.array([[-g * kc, g, g * a], [-kc, 1.0, a], [1.0, 0.0, 0.0]])
    dominant = max(abs(np.linalg.eigvals(A)))
    # the rule linearizes near z = 1: 0.14 % off at lambda = 60 s, less for slower loops
    np.testing.assert_allclose(dominant, math.exp(-ts / lambda_s), rtol=2e-3, atol=0.0)


def test_scheduled_gain_keeps_the_instantaneous_loop_gain_constant(
    paper_armax_model: HammersteinModel,
) -> None:
    pi = PIController.tuned_for(paper_armax_model, gain_scheduled=True, initial_triac_pct=45.0)
    assert pi.gain_schedule is not None
    lo, hi = pi.gain_schedule.valid_triac_pct
    for s in np.linspace(lo, hi, 9):
        np.testing.assert_allclose(_gain(pi, float(s)) * _slope(paper_armax_model, float(s)),
                                   MAX_INSTANT_LOOP_GAIN, rtol=1e-12, atol=0.0)  # exact identity
    # outside the valid range f' is taken at the range's end
    assert _gain(pi, hi + 20.0) == _gain(pi, hi)
    assert _gain(pi, lo - 20.0) == _gain(pi, lo)


def test_fixed_gain_pi_ignores_the_input() -> None:
    pi = PIController(gain_pct_per_kw=0.4, integral_time_s=10.0, ts_s=2.0, initial_triac_pct=45.0)
    assert _gain(pi, 10.0) == _gain(pi, 90.0) == 0.4


def test_gain_schedule_refuses_a_range_where_f_falls() -> None:
    with pytest.raises(SettingsError, match=r"f'\(ds\) > 0"):
        GainSchedule(coefficients=(1.0, -0.02), operating_triac_pct=45.0,
                     reference_triac_pct=45.0, valid_triac_pct=(0.0, 100.0))


def test_pi_velocity_form_with_back_calculation() -> None:
    pi = PIController(gain_pct_per_kw=0.5, integral_time_s=4.0, ts_s=2.0, initial_triac_pct=40.0)
    # reference recursion u_k = u_{k-1} + Kc (e_k - e_{k-1}) + Kc ts/Ti e_{k-1} (unsaturated)
    errors = [2.0, 1.0, -0.5, 0.25, 0.0]
    u_ref, e_prev, out = 40.0, 0.0, []
    for e in errors:
        u_ref = u_ref + 0.5 * (e - e_prev) + 0.5 * 2.0 / 4.0 * e_prev
        e_prev = e
        out.append(pi.step(power_kw=50.0 - e, setpoint_kw=50.0))
        np.testing.assert_allclose(out[-1], u_ref, rtol=0.0, atol=1e-12)  # same arithmetic


def test_pi_does_not_wind_up_at_the_limit() -> None:
    pi = PIController(gain_pct_per_kw=1.0, integral_time_s=2.0, ts_s=2.0, initial_triac_pct=60.0,
                      triac_limits_pct=(0.0, 70.0))
    for _ in range(200):  # a setpoint far out of reach saturates the input for a long time
        assert pi.step(power_kw=60.0, setpoint_kw=100.0) == 70.0
    # the error changes sign: the input leaves the limit at once (no integrator to unwind)
    u = pi.step(power_kw=60.0, setpoint_kw=59.0)
    assert u == pytest.approx(70.0 + 1.0 * (-1.0), abs=1e-12)  # I = 70 exactly, v = I + Kc e
    assert pi.last_step is not None and not pi.last_step.saturated


def test_pi_respects_the_rate_limit_and_holds_on_missing_samples() -> None:
    pi = PIController(gain_pct_per_kw=2.0, integral_time_s=2.0, ts_s=2.0, initial_triac_pct=45.0,
                      max_move_pct_per_step=0.5)
    assert pi.step(power_kw=45.0, setpoint_kw=60.0) == 45.5
    held = pi.step(power_kw=math.nan, setpoint_kw=60.0)
    assert held == 45.5
    assert pi.last_step is not None and not pi.last_step.measurement_used
    assert pi.step(power_kw=45.0, setpoint_kw=math.inf) == 45.5


@pytest.mark.parametrize("gain_scheduled", [False, True])
def test_pi_tracks_a_step_without_offset_on_the_model_plant(
    paper_armax_model: HammersteinModel, gain_scheduled: bool,
) -> None:
    scenario = Scenario(name="t", duration_s=6000.0, initial_setpoint_kw=45.0,
                        initial_triac_pct=45.0, plant_noise=False,
                        setpoints=(SetpointStep(at_s=20.0, power_kw=55.0),))
    pi = PIController.tuned_for(paper_armax_model, gain_scheduled=gain_scheduled)
    result = run_closed_loop(ModelPlant.for_scenario(paper_armax_model, scenario), pi, scenario,
                             rng=0)
    metrics = compute_metrics(result)
    assert abs(metrics.max_abs_steady_state_error_kw) < 1e-6  # integral action, noise-free
    assert metrics.changes[0].overshoot_pct < 2.0


def test_pi_rejects_bad_parameters() -> None:
    with pytest.raises(PIDTuningError, match=r"kc_pct_per_kw: expected a finite value.*got 0.0"):
        PIController(gain_pct_per_kw=0.0, integral_time_s=1.0, ts_s=2.0, initial_triac_pct=45.0)
    with pytest.raises(PIDTuningError, match="triac_limits_pct"):
        PIController(gain_pct_per_kw=1.0, integral_time_s=1.0, ts_s=2.0, initial_triac_pct=45.0,
                     triac_limits_pct=(50.0, 40.0))
    with pytest.raises(PIDTuningError, match="initial_triac_pct"):
        PIController(gain_pct_per_kw=1.0, integral_time_s=1.0, ts_s=2.0, initial_triac_pct=95.0,
                     triac_limits_pct=(0.0, 70.0))


def test_open_loop_input_holds_the_setpoint_in_the_models_steady_state(
    paper_armax_model: HammersteinModel,
) -> None:
    ol = OpenLoopInversion(paper_armax_model)
    s = ol.step(power_kw=math.nan, setpoint_kw=52.0)
    m = paper_armax_model
    gain = float(np.sum(m.b) / np.sum(m.a))  # B(1)/A(1)
    ds = s - m.operating_point.triac_pct
    w = float(np.polynomial.polynomial.polyval(ds, np.concatenate([[0.0], m.input_poly])))
    np.testing.assert_allclose(m.operating_point.power_kw + gain * w, 52.0, rtol=0.0,
                               atol=1e-9)  # root formula vs polyval, round-off only
    # no feedback: the measurement does not matter
    assert ol.step(power_kw=10.0, setpoint_kw=52.0) == s


def test_open_loop_on_the_noise_free_exact_model_settles_on_the_setpoint(
    paper_oe_model: HammersteinModel,
) -> None:
    scenario = Scenario(name="t", duration_s=4000.0, initial_setpoint_kw=45.0,
                        initial_triac_pct=45.0, plant_noise=False,
                        setpoints=(SetpointStep(at_s=20.0, power_kw=50.0),))
    result = run_closed_loop(ModelPlant.for_scenario(paper_oe_model, scenario),
                             OpenLoopInversion(paper_oe_model), scenario, rng=0)
    # the slow pole 0.99 decays as 0.99^k: after 1990 samples below 1e-8 of the step
    np.testing.assert_allclose(result.power_true_kw[-1], 50.0, rtol=0.0, atol=1e-6)


def test_open_loop_clips_to_the_allowed_range_and_flags_unreachable_setpoints(
    paper_armax_model: HammersteinModel,
) -> None:
    ol = OpenLoopInversion(paper_armax_model, validity_margin_pct=0.0)
    assert ol.allowed_triac_range_pct == (20.0, 70.0)
    assert ol.step(power_kw=45.0, setpoint_kw=500.0) == 70.0
    assert ol.last_step is not None and not ol.last_step.setpoint_reachable
    ol_rate = OpenLoopInversion(paper_armax_model, max_move_pct_per_step=1.0)
    assert ol_rate.step(power_kw=45.0, setpoint_kw=60.0) == 46.0
    with pytest.raises(SettingsError, match="max_move_pct_per_step"):
        OpenLoopInversion(paper_armax_model, max_move_pct_per_step=0.0)
