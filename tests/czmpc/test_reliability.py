"""Reliability settings, applied input, setpoint shaping, limit ramps, checked QP results,
and a stateful property test of `OffsetFreeMPC.step` under any data and operation."""

from __future__ import annotations

import functools
import math
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.signal
from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, rule, run_state_machine_as_test

from czmpc.controller import OffsetFreeMPC
from czmpc.errors import SettingsError
from czmpc.kalman import innovation_variance_after_gap, noise_covariances
from czmpc.modes import Mode, Status
from czmpc.settings import MPCSettings, ReliabilitySettings
from sim.model_plant import ModelPlant
from sysid.model import HammersteinModel

#: The controller clips to [s_prev - delta, s_prev + delta] in floating point.
RATE_ATOL_PCT = 1e-9
#: Same recursion in two algebraic arrangements over a few dozen O(1..100) numbers.
RECURSION_ATOL = 1e-10


# --- settings ---------------------------------------------------------------------------
@pytest.mark.parametrize(("changes", "message"), [
    ({"power_min_kw": 10.0, "power_max_kw": 5.0}, "power_min_kw < power_max_kw"),
    ({"warmup_samples": -1}, "warmup_samples must be an int >= 0"),
    ({"max_predicted_samples": -3}, "max_predicted_samples"),
    ({"max_bad_solves": 0}, "max_bad_solves must be an int >= 1"),
    ({"stuck_samples": 1}, "stuck_samples must be 0 (off) or >= 2"),
    ({"spike_gate_k_sigma": -1.0}, "spike_gate_k_sigma"),
    ({"setpoint_ramp_kw_per_s": 0.0}, "setpoint_ramp_kw_per_s"),
    ({"setpoint_filter_time_s": math.nan}, "setpoint_filter_time_s must be a finite number"),
    ({"limit_ramp_pct_per_s": -0.5}, "limit_ramp_pct_per_s"),
    ({"initial_mode": "auto"}, "initial_mode must be 'off', 'predict' or 'on'"),
    ({"shed_triac_pct": 120.0}, "shed_triac_pct must lie in 0..100"),
    ({"mismatch_window_samples": 1}, "mismatch_window_samples"),
    ({"transition_log_size": 0}, "transition_log_size"),
    ({"reopen_after_samples": True}, "reopen_after_samples must be an int"),
])
def test_invalid_reliability_settings_are_refused(changes: dict[str, object],
                                                  message: str) -> None:
    with pytest.raises(SettingsError, match=f"ReliabilitySettings.*{_escape(message)}"):
        ReliabilitySettings(**changes)  # type: ignore[arg-type]


def _escape(text: str) -> str:
    import re

    return re.escape(text)


def test_shed_input_outside_the_triac_limits_is_refused() -> None:
    with pytest.raises(SettingsError, match="shed_triac_pct must lie within"):
        MPCSettings(triac_max_pct=60.0, reliability=ReliabilitySettings(shed_triac_pct=70.0))


def test_reliability_must_be_reliability_settings() -> None:
    with pytest.raises(SettingsError, match="reliability must be a ReliabilitySettings"):
        MPCSettings(reliability={"max_bad_solves": 3})  # type: ignore[arg-type]


def test_a_sampling_time_that_does_not_match_the_model_is_refused(
        paper_armax_model: HammersteinModel) -> None:
    with pytest.raises(SettingsError, match="expected the model's sampling time 2 s; got 1 s"):
        OffsetFreeMPC(paper_armax_model, MPCSettings(ts_s=1.0))
    assert OffsetFreeMPC(paper_armax_model, MPCSettings(ts_s=2.0)).ts_s == 2.0


def test_defaults_change_nothing_on_clean_data(paper_armax_model: HammersteinModel) -> None:
    """With the spike gate off by default, clean and noisy data all reach the estimator."""
    mpc = OffsetFreeMPC(paper_armax_model)
    rng = np.random.default_rng(2)
    for p in 45.0 + 0.5 * rng.standard_normal(200):
        mpc.step(float(p), 47.0)
        last = mpc.last_step
        assert last is not None and last.measurement_used and last.mode is Mode.ON
    assert mpc.n_rejected_measurements == 0


# --- estimator internals ------------------------------------------------------------------
def test_innovation_variance_after_a_gap_matches_the_closed_form(
        paper_armax_model: HammersteinModel) -> None:
    mpc = OffsetFreeMPC(paper_armax_model)
    aug, kf = mpc.augmented_model, mpc.estimator
    rho = mpc.settings.disturbance_noise
    got = innovation_variance_after_gap(aug, kf, rho, 40)
    Q, R, _ = noise_covariances(aug, rho)
    A, C = aug.A, aug.C
    for m in (0, 1, 7, 40):
        # P_m = A^m P A^mT + sum_{j<m} A^j Q A^jT
        Am = np.linalg.matrix_power(A, m)
        P = Am @ kf.P @ Am.T + sum(
            (np.linalg.matrix_power(A, j) @ Q @ np.linalg.matrix_power(A, j).T
             for j in range(m)), np.zeros_like(Q))
        np.testing.assert_allclose(got[m], C @ P @ C + R, rtol=1e-9, atol=0.0,
                                   err_msg="reason: recursion vs explicit sum, m <= 40")
    assert got[0] == pytest.approx(kf.innovation_variance, rel=1e-12)  # reason: definition
    assert np.all(np.diff(got) > 0.0)  # the gate widens while samples are missed


def test_estimator_uses_the_applied_input(paper_armax_model: HammersteinModel) -> None:
    """Reference one-step predictor fed the applied input, not the command."""
    model = paper_armax_model
    # The plant does not follow (45 kW throughout): the textbook filter, without taking
    # the innovations that grow on as a level change.
    s_ = MPCSettings.default_for(model).with_updates(
        max_move_pct_per_step=1.0, reliability=ReliabilitySettings(level_change_k_sigma=None))
    mpc = OffsetFreeMPC(model, s_)
    aug, kf = mpc.augmented_model, mpc.estimator
    rng = np.random.default_rng(4)
    z_pred = np.zeros(aug.n_states)
    applied_prev: float | None = None
    w_prev = 0.0
    for k in range(50):
        power = 45.0 + 0.02 * float(rng.standard_normal())
        if applied_prev is not None:
            # the command of last sample was overridden: correct the prediction
            w_app = float(model.input_nonlinearity(applied_prev - 45.0))
            z_pred = z_pred + aug.B * (w_app - w_prev)
        s = (mpc.step(power, 47.0, applied_triac_pct=applied_prev) if applied_prev is not None
             else mpc.step(power, 47.0))
        last = mpc.last_step
        assert last is not None
        eps = (power - 45.0) - aug.C @ z_pred
        np.testing.assert_allclose(last.state_estimate, z_pred + kf.M * eps, rtol=0.0,
                                   atol=RECURSION_ATOL, err_msg="reason: same filter")
        if applied_prev is not None:
            assert abs(s - applied_prev) <= 1.0 + RATE_ATOL_PCT  # rate from the applied input
        w_prev = float(model.input_nonlinearity(s - 45.0))
        z_pred = aug.A @ z_pred + aug.B * w_prev + kf.L * eps
        applied_prev = 44.0 if k % 3 == 1 else None  # every third sample, overridden


def test_positional_api_still_works(paper_armax_model: HammersteinModel) -> None:
    a, b = OffsetFreeMPC(paper_armax_model), OffsetFreeMPC(paper_armax_model)
    assert a.step(45.0, 46.0) == b.step(power_kw=45.0, setpoint_kw=46.0,
                                         applied_triac_pct=None)


# --- setpoint shaping ---------------------------------------------------------------------
def test_setpoint_ramp_then_filter_match_references(paper_armax_model: HammersteinModel) -> None:
    rel = ReliabilitySettings(setpoint_ramp_kw_per_s=0.25, setpoint_filter_time_s=10.0)
    mpc = OffsetFreeMPC(paper_armax_model, MPCSettings.default_for(paper_armax_model)
                        .with_updates(reliability=rel))
    raw = np.array([45.0] * 3 + [50.0] * 30 + [44.0] * 30)
    used = []
    for r in raw:
        mpc.step(45.0, float(r))
        assert mpc.last_step is not None
        used.append(mpc.last_step.setpoint_used_kw)
    # reference: a 0.5 kW/sample rate limiter, then y_k = y_{k-1} + a (u_k - y_{k-1})
    ramped = np.empty_like(raw)
    prev = 45.0
    for i, r in enumerate(raw):
        prev = prev + float(np.clip(r - prev, -0.5, 0.5))
        ramped[i] = prev
    a = 1.0 - math.exp(-2.0 / 10.0)
    # y_k = y_{k-1} + a (u_k - y_{k-1}) is lfilter([a], [1, a - 1]) in deviation form
    reference = scipy.signal.lfilter([a], [1.0, a - 1.0], ramped - 45.0) + 45.0
    np.testing.assert_allclose(used, reference, rtol=0.0, atol=RECURSION_ATOL,
                               err_msg="reason: same recursion, 63 samples of O(10) numbers")
    assert used[3] < 45.5 and used[-1] < used[40]  # ramped and filtered, both ways


# --- limits ---------------------------------------------------------------------------------
def test_tightened_limit_starts_at_the_input_and_ramps(paper_armax_model: HammersteinModel
                                                       ) -> None:
    rel = ReliabilitySettings(limit_ramp_pct_per_s=0.5)
    mpc = OffsetFreeMPC(paper_armax_model, MPCSettings.default_for(paper_armax_model)
                        .with_updates(reliability=rel))
    for _ in range(5):
        s = mpc.step(45.0, 45.0)
    mpc.set_triac_limits(0.0, 40.0)
    assert mpc.triac_limits_pct[1] == pytest.approx(s, abs=1e-12)  # reason: starts at s
    highs = []
    for _ in range(10):
        s = mpc.step(45.0, 45.0)
        highs.append(mpc.triac_limits_pct[1])
        assert s <= highs[-1] + 1e-12
    assert np.allclose(-np.diff(highs[:4]), 1.0, atol=1e-12)  # reason: 0.5 %/s * 2 s
    assert highs[-1] == 40.0
    mpc.set_triac_limits(0.0, 100.0)  # widening applies at once
    assert mpc.triac_limits_pct == mpc.allowed_triac_range_pct


@pytest.mark.parametrize(("lo", "hi", "message"), [
    (50.0, 40.0, "expected finite min < max"), (math.nan, 40.0, "expected finite min < max"),
    (90.0, 95.0, "overlapping the allowed range"),
])
def test_bad_run_time_limits_are_refused(lo: float, hi: float, message: str,
                                         paper_armax_model: HammersteinModel) -> None:
    mpc = OffsetFreeMPC(paper_armax_model)
    with pytest.raises(SettingsError, match=message):
        mpc.set_triac_limits(lo, hi)


# --- checked QP results ---------------------------------------------------------------------
@pytest.mark.parametrize(("x_value", "status_val"), [(1e30, 1), (math.nan, 1), (60.0, 2)],
                         ids=["huge", "nan", "inaccurate-outside"])
def test_a_solution_outside_its_bounds_is_not_used(
        x_value: float, status_val: int, paper_armax_model: HammersteinModel,
        monkeypatch: pytest.MonkeyPatch) -> None:
    s_ = MPCSettings.default_for(paper_armax_model).with_updates(max_move_pct_per_step=2.0)
    mpc = OffsetFreeMPC(paper_armax_model, s_)
    mpc.step(45.0, 47.0)
    n = mpc.settings.horizon_steps

    class FakeSolver:  # OSQP's solver object, reporting a point outside the bounds
        info = SimpleNamespace(status="solved" if status_val == 1 else "solved inaccurate",
                               status_val=status_val, obj_val=0.0, iter=3, solve_time=1e-5,
                               prim_res=abs(x_value))
        solution = SimpleNamespace(x=np.full(n, x_value))

        def update_data_vec(self, *args: object) -> None: ...
        def warm_start(self, *args: object) -> None: ...
        def solve(self) -> None: ...

    fake = FakeSolver()  # MPCQP keeps the solver object's info and solution objects too
    for name, value in (("_ext", fake), ("_info", fake.info), ("_solution", fake.solution)):
        monkeypatch.setattr(mpc.qp, name, value)
    s_prev = mpc.last_step.triac_pct  # type: ignore[union-attr]
    s = mpc.step(45.0, 47.0)
    last = mpc.last_step
    assert last is not None and last.fallback == "shifted_plan" and last.status is Status.HELD
    assert math.isfinite(s) and abs(s - s_prev) <= 2.0 + RATE_ATOL_PCT
    assert mpc.n_fallbacks == 1 and last.bad_solves_in_row == 1


def test_solver_shed_clears_at_the_first_good_solve(paper_oe_model: HammersteinModel,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    rel = ReliabilitySettings(max_bad_solves=3)
    mpc = OffsetFreeMPC(paper_oe_model, MPCSettings.default_for(paper_oe_model)
                        .with_updates(reliability=rel))
    mpc.step(45.0, 46.0)
    real = mpc.qp.solve

    def failing(**kwargs: object):  # type: ignore[no-untyped-def]
        sol = real(**kwargs)  # type: ignore[arg-type]
        return type(sol)(status="simulated failure", is_usable=False, is_accurate=False,
                         w=sol.w * math.nan, slack_kw=0.0, objective=math.nan,
                         n_iterations=0, solve_time_s=0.0)

    monkeypatch.setattr(mpc.qp, "solve", failing)
    statuses = []
    for _ in range(4):
        mpc.step(45.0, 46.0)
        statuses.append(mpc.last_step.status)  # type: ignore[union-attr]
    assert statuses == [Status.HELD, Status.HELD, Status.SHED, Status.SHED]
    monkeypatch.undo()
    mpc.step(45.0, 46.0)
    assert mpc.last_step is not None and mpc.last_step.status is not Status.SHED
    assert mpc.last_step.fallback == "none"


# --- stateful property test of step() ---------------------------------------------------------
_ANY_POWER = st.one_of(
    st.none(),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=30.0, max_value=60.0),
    st.sampled_from([math.nan, math.inf, -math.inf, -5.0, 0.0, 1e308, -1e308, 45.0]),
)
#: Setpoint the machine's teardown must track after any sequence [kW], and how closely
#: its mean over the last 100 samples must sit (noisy model plant, sigma_e 0.0134 kW:
#: the mean's noise is ~0.01 kW; a poisoned estimator would be off by kW) [kW].
_FINAL_SETPOINT_KW = 46.0
_FINAL_TRACK_TOL_KW = 0.1


@functools.cache
def _mpc(model: HammersteinModel, delta: float | None) -> OffsetFreeMPC:
    rel = ReliabilitySettings(spike_gate_k_sigma=8.0, spike_gate_floor_kw=0.5,
                              power_max_kw=150.0, max_predicted_samples=4, warmup_samples=2,
                              stuck_samples=3, max_change_kw_per_sample=20.0,
                              setpoint_ramp_kw_per_s=1.0)
    s_ = MPCSettings.default_for(model).with_updates(max_move_pct_per_step=delta,
                                                     reliability=rel)
    return OffsetFreeMPC(model, s_)


class StepMachine(RuleBasedStateMachine):
    """Any measurements, setpoints, applied inputs, mode and limit changes."""

    model: HammersteinModel
    delta: float | None

    def __init__(self) -> None:
        super().__init__()
        self.mpc = _mpc(self.model, self.delta)
        self.mpc.reset()
        self.applied = 45.0  # the input really applied over the last sample

    @rule(power=_ANY_POWER, setpoint=_ANY_POWER,
          override=st.one_of(st.none(), st.floats(0.0, 100.0),
                             st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308])))
    def step(self, power: float | None, setpoint: float | None, override: float | None) -> None:
        mpc = self.mpc
        if override is not None and math.isfinite(override):
            self.applied = min(100.0, max(0.0, override))
        s = mpc.step(power, setpoint, applied_triac_pct=override)
        last = mpc.last_step
        assert last is not None and math.isfinite(s)
        if last.mode is Mode.ON:
            lo, hi = last.triac_limits_pct
            assert lo <= s <= hi
            if self.delta is not None and lo <= self.applied <= hi:
                assert abs(s - self.applied) <= self.delta + RATE_ATOL_PCT
            self.applied = s
        else:
            assert s == pytest.approx(self.applied, abs=1e-12)  # reason: handed back
        assert np.isfinite(last.state_estimate).all()
        assert math.isfinite(last.setpoint_used_kw)
        valid = setpoint is not None and math.isfinite(setpoint) and 0.0 <= setpoint <= 150.0
        assert last.setpoint_held is not valid
        if not valid:
            assert last.setpoint_verdict != "valid"

    def teardown(self) -> None:
        # After any sequence, a valid setpoint is tracked: full limits, PREDICT, then ON.
        mpc = self.mpc
        mpc.set_triac_limits(*mpc.allowed_triac_range_pct)
        plant = ModelPlant(self.model, noise=True, initial_triac_pct=self.applied)
        power = plant.reset(np.random.default_rng(0))
        mpc.request_mode(Mode.PREDICT)
        s = self.applied
        true_kw = []
        for _ in range(500):
            if mpc.mode is not Mode.ON:
                mpc.request_mode(Mode.ON)   # accepted once the estimator is warm
            s = mpc.step(power, _FINAL_SETPOINT_KW, applied_triac_pct=s)
            power = plant.step(s)
            true_kw.append(plant.true_power_kw)
        assert mpc.mode is Mode.ON
        assert abs(np.mean(true_kw[-100:]) - _FINAL_SETPOINT_KW) < _FINAL_TRACK_TOL_KW

    @rule(mode=st.sampled_from(list(Mode)))
    def request(self, mode: Mode) -> None:
        self.mpc.request_mode(mode)

    @rule(lo=st.floats(0.0, 60.0), width=st.floats(1.0, 60.0))
    def limits(self, lo: float, width: float) -> None:
        a_lo, a_hi = self.mpc.allowed_triac_range_pct
        if min(lo + width, 100.0) > a_lo and lo < a_hi:
            self.mpc.set_triac_limits(lo, min(lo + width, 100.0))


@pytest.mark.parametrize("delta", [None, 1.5], ids=["free", "rate"])
def test_step_is_safe_under_any_data_and_operation(
        delta: float | None, paper_armax_model: HammersteinModel) -> None:
    StepMachine.model = paper_armax_model
    StepMachine.delta = delta
    run_state_machine_as_test(
        StepMachine, settings=settings(max_examples=60, stateful_step_count=40, deadline=None))
