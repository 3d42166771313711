"""Closed-loop done-when checks of the offset-free MPC (issue 4), via czmpc.campaigns.simulation.

The controller is built from the shipped identified model data/cz_heater_model.json and
run against the plant built from that model (no mismatch) or against the virtual CZ
heater (model mismatch), through the shipped scenarios.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from czmpc.campaigns.build import controller_settings, heater_steady_state_triac_pct
from czmpc.campaigns.simulation import SimulationOutcome, run_simulation
from czmpc.controller import StepDiagnostics
from czmpc.settings import MPCSettings
from sim.disturbances import PowerShift, VoltageStep
from sim.heater import HeaterParams, steady_state
from sim.metrics import LIMIT_ATOL_PCT
from sim.model_plant import steady_state_triac_pct
from sim.scenario import Scenario, list_scenarios, load_scenario
from sysid.model import HammersteinModel
from sysid.modelfile import load_model

REPO = Path(__file__).resolve().parents[2]
SHIPPED_MODEL = REPO / "data" / "cz_heater_model.json"

#: Issue 4: the steady-state error after a persistent disturbance must fall below this [kW].
OFFSET_FREE_ATOL_KW = 0.01
#: Issue 4: output variance in steady regulation at most this multiple of sigma_e^2.
MIN_VARIANCE_RATIO_GOAL = 1.3
#: Rate limit [%/step] given to the controller in the limit checks (the shipped
#: scenarios have none, and the staircase's steps need about 4 %/step without one).
TEST_RATE_LIMIT_PCT_PER_STEP = 2.0


@pytest.fixture(scope="module")
def model() -> HammersteinModel:
    return load_model(SHIPPED_MODEL)


def _error_kw(outcome: SimulationOutcome, signal: str = "true") -> np.ndarray:
    r = outcome.result
    power = r.power_true_kw if signal == "true" else r.power_measured_kw
    return power - r.setpoint_kw


def _window(outcome: SimulationOutcome, start_s: float, stop_s: float) -> slice:
    ts_s = outcome.result.ts_s
    return slice(math.ceil(start_s / ts_s - 1e-9), math.ceil(stop_s / ts_s - 1e-9))


# --- offset-free ----------------------------------------------------------------------
def test_level_shift_of_015_kw_is_removed_to_below_001_kw_and_stays(
        model: HammersteinModel) -> None:
    scenario = load_scenario("level_shift")
    (shift,) = scenario.disturbances
    assert isinstance(shift, PowerShift) and shift.duration_s is None   # it stays for good
    outcome = run_simulation(model, scenario, plant="model", seed=0, noise=False)
    e = _error_kw(outcome)
    end_s = scenario.duration_s
    # the shift does show (so the check below can fail) ...
    hit = _window(outcome, shift.at_s, shift.at_s + 20.0)
    assert np.max(np.abs(e[hit])) > OFFSET_FREE_ATOL_KW
    # ... and is gone over the whole last half of the time after it
    late = _window(outcome, shift.at_s + 0.5 * (end_s - shift.at_s), end_s)
    assert np.max(np.abs(e[late])) < OFFSET_FREE_ATOL_KW
    assert outcome.metrics.steady_state_errors_kw[-1] == pytest.approx(
        0.0, abs=OFFSET_FREE_ATOL_KW)  # reason: the 0.01 kW goal


def test_voltage_sag_of_3_pct_is_removed_within_and_after_the_sag(
        model: HammersteinModel) -> None:
    scenario = load_scenario("voltage_sag")
    (sag,) = scenario.disturbances
    assert isinstance(sag, VoltageStep) and sag.factor == 0.97 and sag.duration_s is not None
    outcome = run_simulation(model, scenario, plant="model", seed=0, noise=False)
    e = _error_kw(outcome)
    on_s, off_s, end_s = sag.at_s, sag.at_s + sag.duration_s, scenario.duration_s
    # the sag takes about 6 % (2.7 kW) of 45 kW at once: a real disturbance
    assert np.min(e[_window(outcome, on_s, on_s + 10.0)]) < -1.0
    # last quarter of the sag window: held within 0.01 kW despite the sag
    last_of_sag = _window(outcome, off_s - 0.25 * sag.duration_s, off_s)
    assert np.max(np.abs(e[last_of_sag])) < OFFSET_FREE_ATOL_KW
    # the recovery shows, then is removed: last half of the time after the sag
    assert np.max(e[_window(outcome, off_s, off_s + 10.0)]) > 1.0
    after = _window(outcome, off_s + 0.5 * (end_s - off_s), end_s)
    assert np.max(np.abs(e[after])) < OFFSET_FREE_ATOL_KW


def test_staircase_on_the_virtual_heater_ends_every_step_with_zero_mean_offset(
        model: HammersteinModel) -> None:
    """Model mismatch: the controller's model is not the heater, yet no offset remains.

    Without offset-free action the mismatch would show: the input the model says holds
    65 kW gives the heater about 0.07 kW more (checked below), about 25 times the
    tolerance. The tolerance is statistical: over the last quarter of each segment
    (225 samples, at least 75 for the short initial one) the measured error is close to
    white (the heater's 0.0105 kW sensor noise dominates), so its mean has standard
    error ``sd / sqrt(n)``; an unbiased loop stays within 3 of them (about 0.003 kW).
    """
    s_model = steady_state_triac_pct(model, 65.0)
    mismatch_kw = steady_state(s_model, HeaterParams())[0] - 65.0
    assert abs(mismatch_kw) > 0.05

    scenario = load_scenario("staircase")
    outcome = run_simulation(model, scenario, plant="heater", seed=1)
    e = _error_kw(outcome, "measured")
    segments = scenario.segments()
    assert len(segments) == 5
    for seg in segments:
        n = seg.stop_k - seg.start_k
        tail = e[seg.stop_k - n // 4: seg.stop_k]
        bound = 3.0 * float(np.std(tail)) / math.sqrt(tail.size)
        assert abs(float(np.mean(tail))) < bound, (seg.to_kw, float(np.mean(tail)), bound)
    assert outcome.metrics.n_solver_failures == 0


# --- limits ---------------------------------------------------------------------------
@pytest.mark.parametrize("rate_pct", [None, TEST_RATE_LIMIT_PCT_PER_STEP], ids=["free", "rate2"])
@pytest.mark.parametrize("plant", ["model", "heater"])
@pytest.mark.parametrize("name", list_scenarios())
def test_input_stays_in_limits_and_rate_and_is_finite_in_every_shipped_scenario(
        model: HammersteinModel, name: str, plant: str, rate_pct: float | None) -> None:
    scenario = load_scenario(name).shortened(0.25)
    settings = MPCSettings.default_for(model).with_updates(max_move_pct_per_step=rate_pct)
    outcome = run_simulation(model, scenario, plant=plant, seed=5,  # type: ignore[arg-type]
                             settings=settings)
    s = outcome.result.triac_pct
    assert np.all(np.isfinite(s))
    assert np.all((s >= 0.0) & (s <= 100.0))
    s_lo, s_hi = outcome.allowed_triac_range_pct
    assert np.all((s >= s_lo - LIMIT_ATOL_PCT) & (s <= s_hi + LIMIT_ATOL_PCT))
    if rate_pct is not None:
        assert np.max(np.abs(np.diff(s))) <= rate_pct + LIMIT_ATOL_PCT
    m = outcome.metrics
    assert m.n_limit_violations == 0 and m.n_rate_violations == 0
    diags = outcome.result.diagnostics
    assert diags is not None and len(diags) == s.size
    assert all(isinstance(d, StepDiagnostics) and d.fallback == "none" for d in diags)


def test_scenario_limits_tighten_the_controller_and_are_kept(model: HammersteinModel) -> None:
    base = load_scenario("staircase").shortened(0.25)
    scenario = replace(base, triac_limits_pct=(40.0, 60.0), max_move_pct_per_step=0.5,
                       name="tight")
    settings = controller_settings(model, scenario, initial_triac_pct=45.0)
    assert (settings.triac_min_pct, settings.triac_max_pct) == (40.0, 60.0)
    assert settings.max_move_pct_per_step == 0.5
    outcome = run_simulation(model, scenario, plant="heater", seed=2)
    s = outcome.result.triac_pct
    assert s.max() <= 60.0 + LIMIT_ATOL_PCT      # the staircase asks for about 63 %
    assert s.max() > 59.0                        # so the limit binds
    assert np.max(np.abs(np.diff(s))) <= 0.5 + LIMIT_ATOL_PCT
    assert outcome.metrics.n_constraint_violations == 0


# --- start without transient -------------------------------------------------------------
def test_heater_starts_in_steady_state_at_the_initial_setpoint(model: HammersteinModel) -> None:
    s0 = heater_steady_state_triac_pct(50.0)
    # reason: bisection tolerance 1e-9 % times about 1.2 kW/%
    assert steady_state(s0, HeaterParams())[0] == pytest.approx(50.0, abs=1e-8)
    base = load_scenario("missing_samples")
    scenario = replace(base, initial_setpoint_kw=50.0, initial_triac_pct=None, setpoints=(),
                       faults=(), duration_s=200.0, name="hold50")
    outcome = run_simulation(model, scenario, plant="heater", seed=0, noise=False)
    assert outcome.initial_triac_pct == pytest.approx(s0, abs=1e-12)  # reason: same bisection
    e = _error_kw(outcome)
    assert e[0] == pytest.approx(0.0, abs=1e-9)  # reason: the plant starts in steady state at 50 kW
    # The controller's model needs a slightly different input for 50 kW (model mismatch):
    # starting the plant there instead would be off by the static mismatch, about 0.05 kW.
    mismatch_kw = 1.2 * abs(steady_state_triac_pct(model, 50.0) - s0)   # 1.2 kW/% near 50 %
    assert mismatch_kw > 0.04
    # Here only the estimator's first correction shows, about half of it, and decays.
    assert np.max(np.abs(e)) < 0.5 * mismatch_kw + 0.005
    assert np.max(np.abs(e[-20:])) < 0.002


# --- minimum variance ------------------------------------------------------------------
def test_output_variance_in_regulation_is_within_13_times_the_innovation_variance(
        model: HammersteinModel) -> None:
    """With one sample of delay the best any controller can do is ``var(y - r) = sigma_e^2``
    (the innovation cannot be predicted); default tuning must come within 1.3 times it.
    Measured on this model: 1.024 at disturbance_noise 0.3 (1.003 at 0.1; seed 3, 20,000
    samples)."""
    scenario = Scenario(name="regulation-45kW", duration_s=2.0 * 20_000,
                        initial_setpoint_kw=45.0, initial_triac_pct=45.0)
    outcome = run_simulation(model, scenario, plant="model", seed=3,
                             settings=MPCSettings.preset("default", model))
    e = _error_kw(outcome, "measured")[500:]          # after the estimator has settled
    ratio = float(np.var(e)) / model.noise_std_kw**2
    assert ratio < MIN_VARIANCE_RATIO_GOAL
    # and no better than the bound allows (4 standard errors of a variance estimate)
    assert ratio > 1.0 - 4.0 * math.sqrt(2.0 / e.size)


# --- reproducibility -------------------------------------------------------------------
@pytest.mark.parametrize("plant", ["model", "heater"])
def test_same_seed_gives_identical_runs_and_another_seed_does_not(
        model: HammersteinModel, plant: str) -> None:
    scenario = load_scenario("combined").shortened(0.5)   # noise, spikes, outage, drift
    runs = [run_simulation(model, scenario, plant=plant, seed=seed)  # type: ignore[arg-type]
            for seed in (11, 11, 12)]
    fields = ("power_measured_kw", "power_true_kw", "triac_pct", "setpoint_kw")
    for name in fields:
        assert np.array_equal(getattr(runs[0].result, name), getattr(runs[1].result, name),
                              equal_nan=True), name
    estimates = [run.result.disturbance_estimate_kw for run in runs[:2]]
    assert estimates[0] is not None and estimates[1] is not None
    assert np.array_equal(estimates[0], estimates[1])
    assert not np.array_equal(runs[0].result.power_measured_kw,
                              runs[2].result.power_measured_kw, equal_nan=True)
