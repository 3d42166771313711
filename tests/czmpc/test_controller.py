"""OffsetFreeMPC: limits and rate under any data, offset-free, deadbeat, LQR, fallbacks."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from czmpc.controller import OffsetFreeMPC
from czmpc.diagnostics import StepDiagnostics
from czmpc.errors import DesignError
from czmpc.mismatch import MismatchStats
from czmpc.qp import QPSolution
from czmpc.realization import innovations_form
from czmpc.settings import MPCSettings, OSQPOptions, ReliabilitySettings
from czmpc.target import Target, compute_target, steady_state_map
from sim.protocols import Controller
from sysid.model import HammersteinModel

#: Rate limit check: the controller clips ds to [ds_prev - delta, ds_prev + delta] in
#: floating point, so a move can exceed delta only by the rounding of that sum.
RATE_ATOL_PCT = 1e-9
#: OSQP at eps 1e-9 with polishing against the closed-form LQR law (see test_qp.py).
LQR_ATOL_KW = 1e-6
#: Offset-free requirement of the issue [kW].
OFFSET_TOL_KW = 0.01
#: Same filter recursion in two algebraic arrangements, 60 steps of O(1) numbers.
FILTER_ATOL = 1e-10


class ExactPlant:
    """The model's own difference equation A dP = B f(ds) + C e, plus an output shift."""

    def __init__(self, model: HammersteinModel, *, noise_std_kw: float = 0.0,
                 rng: np.random.Generator | int | None = None) -> None:
        self.model = model
        n = max(model.a.size, model.b.size, model.c.size)
        self.y = [0.0] * n  # y_{k-1}, y_{k-2}, ...
        self.w = [0.0] * n
        self.e = [0.0] * n
        self.noise_std_kw = noise_std_kw
        self.rng = np.random.default_rng(rng)
        self.current = 0.0  # y_k (deviation) of the current sample

    def output_kw(self) -> float:
        return self.model.operating_point.power_kw + self.current

    def advance(self, triac_pct: float) -> None:
        m = self.model
        w = float(m.input_nonlinearity(triac_pct - m.operating_point.triac_pct))
        self.y = [self.current, *self.y[:-1]]
        self.w = [w, *self.w[:-1]]
        e = self.noise_std_kw * float(self.rng.standard_normal()) if self.noise_std_kw else 0.0
        y = e
        y -= sum(m.a[i] * self.y[i - 1] for i in range(1, m.a.size))
        y += sum(m.b[i] * self.w[i - 1] for i in range(1, m.b.size))
        y += sum(m.c[i] * self.e[i - 1] for i in range(1, m.c.size))
        self.e = [e, *self.e[:-1]]
        self.current = y


def run_loop(mpc: OffsetFreeMPC, plant: ExactPlant, n_steps: int,
             setpoint_kw: Callable[[int], float],
             shift_kw: Callable[[int], float] = lambda k: 0.0,
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (measured power, setpoint, input) per sample; the shift adds to the output."""
    power, ref, triac = np.empty(n_steps), np.empty(n_steps), np.empty(n_steps)
    for k in range(n_steps):
        power[k] = plant.output_kw() + shift_kw(k)
        ref[k] = setpoint_kw(k)
        triac[k] = mpc.step(power[k], ref[k])
        plant.advance(triac[k])
    return power, ref, triac


@pytest.fixture(scope="session")
def paper_models(paper_oe_model: HammersteinModel, paper_armax_model: HammersteinModel
                 ) -> dict[str, HammersteinModel]:
    return {"oe": paper_oe_model, "armax": paper_armax_model}


def test_controller_satisfies_the_sim_protocol(paper_armax_model: HammersteinModel) -> None:
    mpc = OffsetFreeMPC(paper_armax_model)
    assert isinstance(mpc, Controller)
    assert mpc.ts_s == paper_armax_model.ts_s
    assert mpc.last_step is None and mpc.n_fallbacks == 0


@functools.cache
def _cached_controller(model: HammersteinModel, settings: MPCSettings) -> OffsetFreeMPC:
    return OffsetFreeMPC(model, settings)


_ANY_FLOAT = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=20.0, max_value=80.0),
    st.sampled_from([math.nan, math.inf, -math.inf, 0.0, 1e308]),
)


@pytest.mark.parametrize(
    "changes",
    [{}, {"max_move_pct_per_step": 1.5},
     {"max_move_pct_per_step": 3.0, "triac_min_pct": 25.0, "triac_max_pct": 60.0,
      "soft_power_max_kw": 50.0, "disturbance_model": "input"}],
    ids=["free", "rate", "rate+limits+soft+input"],
)
@settings(max_examples=40, deadline=None)
@given(data=st.lists(st.tuples(_ANY_FLOAT, _ANY_FLOAT), min_size=1, max_size=40))
def test_inputs_stay_finite_in_limits_and_rate_under_any_data(
    changes: dict[str, object], data: list[tuple[float, float]],
    paper_armax_model: HammersteinModel,
) -> None:
    settings_ = MPCSettings.default_for(paper_armax_model).with_updates(**changes)
    mpc = _cached_controller(paper_armax_model, settings_)
    mpc.reset()
    lo, hi = mpc.allowed_triac_range_pct
    assert settings_.triac_min_pct <= lo < hi <= settings_.triac_max_pct
    delta = settings_.max_move_pct_per_step
    previous = paper_armax_model.operating_point.triac_pct
    for power_kw, setpoint_kw in data:
        s = mpc.step(power_kw, setpoint_kw)
        assert math.isfinite(s)
        assert lo <= s <= hi
        if delta is not None:
            assert abs(s - previous) <= delta + RATE_ATOL_PCT
        previous = s


@pytest.mark.parametrize("disturbance_model", ["input", "output"])
@pytest.mark.parametrize("which", ["oe", "armax"])
def test_persistent_output_shift_leaves_no_offset(
    which: str, disturbance_model: str, paper_models: dict[str, HammersteinModel]
) -> None:
    model = paper_models[which]
    mpc = OffsetFreeMPC(model, MPCSettings.default_for(model).with_updates(
        disturbance_model=disturbance_model))
    power, ref, _ = run_loop(mpc, ExactPlant(model), 600, lambda k: 46.0,
                             shift_kw=lambda k: 0.15 if k >= 100 else 0.0)
    error = np.abs(power - ref)
    assert error[100] > 0.1  # the shift is felt ...
    late = np.flatnonzero(error >= OFFSET_TOL_KW)
    assert late[-1] < 300  # ... settles below 0.01 kW within 200 samples and stays there
    last = mpc.last_step
    assert last is not None
    # The estimate explains the shift as a steady power change of 0.15 kW.
    assert last.disturbance_power_kw == pytest.approx(0.15, abs=OFFSET_TOL_KW)


@pytest.mark.parametrize("disturbance_model", ["input", "output"])
def test_aggressive_small_step_is_within_ten_percent_of_deadbeat_iae(
    disturbance_model: str, paper_oe_model: HammersteinModel
) -> None:
    model = paper_oe_model
    settings_ = MPCSettings.preset("aggressive", model).with_updates(
        disturbance_model=disturbance_model)
    mpc = OffsetFreeMPC(model, settings_)
    k0, step_kw = 10, 0.5
    power, ref, _ = run_loop(mpc, ExactPlant(model), 400,
                             lambda k: 45.0 + (step_kw if k >= k0 else 0.0))
    # IAE by the rectangle rule: each sample's |error| held for one sampling period.
    iae_kw_s = model.ts_s * float(np.sum(np.abs(ref[k0:] - power[k0:])))
    # One sample of delay: the error at k0 is the whole step whatever the input, so
    # |step| * Ts is the least IAE possible (deadbeat).
    deadbeat_kw_s = step_kw * model.ts_s
    assert deadbeat_kw_s * (1 - 1e-12) <= iae_kw_s <= 1.1 * deadbeat_kw_s


def test_first_move_equals_the_lqr_law_of_the_augmented_problem(
    paper_armax_model: HammersteinModel, rng: np.random.Generator
) -> None:
    model = paper_armax_model
    settings_ = MPCSettings.default_for(model).with_updates(
        horizon_steps=50, osqp=OSQPOptions(eps_abs=1e-9, eps_rel=1e-9, polishing=True,
                                           max_iter=50000))
    mpc = OffsetFreeMPC(model, settings_)
    for _ in range(20):  # excite the estimator with small, noisy measurements
        s_prev = mpc.step(45.0 + 0.3 * float(rng.standard_normal()), 45.5)
    # A missing sample makes the innovation 0, so the QP starts from A (x - x_s):
    # exactly the LQR setting, u = w_s - F [x - x_s; w_prev - w_s].
    mpc.step(math.nan, 45.5)
    last = mpc.last_step
    assert last is not None and not last.measurement_used
    ss = innovations_form(model)
    n = ss.n_states
    A = np.block([[ss.A, np.zeros((n, 1))], [np.zeros((1, n)), np.zeros((1, 1))]])
    B = np.concatenate([ss.B, [1.0]]).reshape(n + 1, 1)
    q_y, q_u, q_dw = settings_.output_weight, settings_.input_target_weight, settings_.move_weight
    Q = np.zeros((n + 1, n + 1))
    Q[:n, :n] = q_y * np.outer(ss.C, ss.C)
    Q[n, n] = q_dw
    R = np.array([[q_u + q_dw]])
    S = np.zeros((n + 1, 1))
    S[n, 0] = -q_dw
    P = scipy.linalg.solve_discrete_are(A, B, Q, R, s=S)
    F = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A + S.T).ravel()
    x_s = np.linalg.solve(np.eye(n) - ss.A, ss.B) * last.target_w  # output disturbance
    w_prev = float(model.input_nonlinearity(s_prev - 45.0))
    xi0 = np.concatenate([last.state_estimate[:n] - x_s, [w_prev - last.target_w]])
    expected = last.target_w - F @ xi0
    np.testing.assert_allclose(last.planned_w[0], expected, rtol=0.0, atol=LQR_ATOL_KW)


def test_missing_measurement_and_setpoint_are_handled_and_recorded(
    paper_armax_model: HammersteinModel,
) -> None:
    mpc = OffsetFreeMPC(paper_armax_model)
    mpc.step(45.0, 46.0)
    for bad in (math.nan, math.inf, -math.inf):
        s = mpc.step(bad, math.nan)
        last = mpc.last_step
        assert last is not None and math.isfinite(s)
        assert not last.measurement_used and last.innovation_kw == 0.0
        assert last.setpoint_held and last.setpoint_used_kw == 46.0
        assert math.isnan(last.setpoint_kw)


@pytest.mark.parametrize("mode", ["on", "predict", "off"])
def test_step_records_name_every_field_in_order(
    paper_armax_model: HammersteinModel, mode: str,
) -> None:
    # The step builds its records with record_from_fields (no __init__): every field, in order.
    mpc = OffsetFreeMPC(paper_armax_model)
    if mode != "on":
        mpc.request_mode(mode)
    mpc.step(45.0, 46.0)
    last = mpc.last_step
    assert last is not None
    assert list(vars(last)) == [f.name for f in dataclasses.fields(StepDiagnostics)]
    assert dataclasses.replace(last) is not last
    horizon = mpc.settings.horizon_steps
    solution = mpc.qp.solve(
        h_terms=np.zeros(mpc.qp.h_input.size), w_prev=0.0, w_target=0.0, y_target=0.0,
        w_lo=np.full(horizon, -1.0), w_hi=np.full(horizon, 1.0),
        rate=np.full(horizon - 1, 1.0) if mpc.qp.has_rate_limit else None)
    target = compute_target(steady_state_map(innovations_form(paper_armax_model), "input"),
                            setpoint=1.0, disturbance=0.0, w_min=-10.0, w_max=10.0)
    records = [(solution, QPSolution), (target, Target)]
    if mode != "off":
        assert last.mismatch is not None and last.mismatch.n_samples >= 0  # computed when read
        records.append((last.mismatch, MismatchStats))
    for record, cls in records:
        assert list(vars(record)) == [f.name for f in dataclasses.fields(cls)]


def test_reset_restarts_bit_for_bit(paper_armax_model: HammersteinModel) -> None:
    mpc = OffsetFreeMPC(paper_armax_model)
    inputs = np.random.default_rng(3).normal(45.0, 0.5, size=30)
    first = [mpc.step(p, 46.0) for p in inputs]
    mpc.reset()
    assert mpc.last_step is None and mpc.n_fallbacks == 0
    second = [mpc.step(p, 46.0) for p in inputs]
    other = OffsetFreeMPC(paper_armax_model)
    third = [other.step(p, 46.0) for p in inputs]
    assert first == second == third


def test_max_iter_one_falls_back_to_the_target_and_counts(
    paper_oe_model: HammersteinModel,
) -> None:
    model = paper_oe_model
    settings_ = MPCSettings.default_for(model).with_updates(
        max_move_pct_per_step=2.0, osqp=OSQPOptions(max_iter=1))
    mpc = OffsetFreeMPC(model, settings_)
    power, ref, triac = run_loop(mpc, ExactPlant(model), 800, lambda k: 47.0)
    last = mpc.last_step
    assert last is not None
    assert last.fallback == "target" and last.solver_status == "maximum iterations reached"
    assert mpc.n_fallbacks == 800
    assert np.all(np.abs(np.diff(np.concatenate([[45.0], triac]))) <= 2.0 + RATE_ATOL_PCT)
    # Holding the offset-free target still removes the error, only slowly (open loop).
    assert abs(power[-1] - ref[-1]) < OFFSET_TOL_KW


def test_failed_solves_use_the_shifted_plan_then_the_target(
    paper_oe_model: HammersteinModel, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = paper_oe_model
    settings_ = MPCSettings.default_for(model).with_updates(horizon_steps=3)
    mpc = OffsetFreeMPC(model, settings_)
    plant = ExactPlant(model)
    s = mpc.step(plant.output_kw(), 46.0)
    plant.advance(s)
    first = mpc.last_step
    assert first is not None and first.fallback == "none"
    plan = np.array(first.planned_w)
    real_solve = mpc.qp.solve

    def failing_solve(**kwargs: object) -> QPSolution:
        real = real_solve(**kwargs)  # type: ignore[arg-type]
        return QPSolution(status="simulated failure", is_usable=False, is_accurate=False,
                          w=np.full(3, math.nan), slack_kw=0.0, objective=math.nan,
                          n_iterations=real.n_iterations, solve_time_s=0.0)

    monkeypatch.setattr(mpc.qp, "solve", failing_solve)
    kinds = []
    for age in (1, 2, 3):
        s = mpc.step(plant.output_kw(), 46.0)
        plant.advance(s)
        last = mpc.last_step
        assert last is not None
        kinds.append(last.fallback)
        if last.fallback == "shifted_plan":
            w_applied = float(model.input_nonlinearity(s - 45.0))
            assert w_applied == pytest.approx(plan[age], abs=1e-9)  # f(f^-1(w)) = w
        else:
            assert s == pytest.approx(last.target_triac_pct, abs=1e-9)
    assert kinds == ["shifted_plan", "shifted_plan", "target"]
    assert mpc.n_fallbacks == 3
    monkeypatch.undo()
    mpc.step(plant.output_kw(), 46.0)
    assert mpc.last_step is not None and mpc.last_step.fallback == "none"


def test_soft_power_maximum_holds_the_power_below_an_excessive_setpoint(
    paper_oe_model: HammersteinModel,
) -> None:
    model = paper_oe_model
    settings_ = MPCSettings.default_for(model).with_updates(soft_power_max_kw=47.0)
    mpc = OffsetFreeMPC(model, settings_)
    power, _, _ = run_loop(mpc, ExactPlant(model), 300, lambda k: 48.0)
    # The slack's linear weight is an exact penalty: the limit holds wherever the hard
    # constraints allow it, up to the solver tolerance (OSQP eps 1e-5 on |y| ~ 2 kW).
    assert power.max() < 47.0 + 1e-3
    assert power[-1] == pytest.approx(47.0, abs=1e-3)
    last = mpc.last_step
    assert last is not None and last.setpoint_reachable  # 48 kW is reachable, not allowed
    assert 0.0 <= last.soft_limit_slack_kw < 1e-3


def test_initial_triac_input_starts_bumpless(paper_oe_model: HammersteinModel) -> None:
    model = paper_oe_model
    settings_ = MPCSettings.default_for(model).with_updates(initial_triac_pct=30.0)
    mpc = OffsetFreeMPC(model, settings_)
    steady_kw = float(model.steady_state_power_kw(30.0))
    s = mpc.step(steady_kw, steady_kw)
    # The plan is exact to OSQP's eps 1e-5 relative on |w| ~ 20 kW, i.e. 2e-4 kW of w or
    # about 1.5e-4 % of TRIAC input at f' ~ 1.5 kW/%.
    assert s == pytest.approx(30.0, abs=1e-3)


def test_initial_input_outside_the_allowed_range_is_a_design_error(
    paper_oe_model: HammersteinModel,
) -> None:
    settings_ = MPCSettings.default_for(paper_oe_model).with_updates(initial_triac_pct=10.0)
    with pytest.raises(DesignError, match=r"initial_triac_pct must lie in the allowed range"):
        OffsetFreeMPC(paper_oe_model, settings_)


def test_input_disturbance_on_a_model_with_b_zero_at_one_is_refused(
    paper_oe_model: HammersteinModel,
) -> None:
    model = paper_oe_model.with_updates(b=[0.0, 1.0, -1.0])
    settings_ = MPCSettings.default_for(model).with_updates(disturbance_model="input")
    with pytest.raises(DesignError, match="must be detectable"):
        OffsetFreeMPC(model, settings_)


def test_allowed_range_beyond_the_vertex_of_f_is_refused_at_construction(
    paper_oe_model: HammersteinModel,
) -> None:
    steep = paper_oe_model.with_updates(input_poly=[1.35, -0.03])  # vertex at s = 67.5 %
    with pytest.raises(DesignError, match="monotone branch"):
        OffsetFreeMPC(steep)
    # Lowering the TRIAC maximum below the vertex makes the design sound again.
    settings_ = MPCSettings.default_for(steep).with_updates(triac_max_pct=65.0)
    assert OffsetFreeMPC(steep, settings_).allowed_triac_range_pct == (15.0, 65.0)


def test_estimator_matches_a_reference_predictor_fed_the_applied_input(
    paper_armax_model: HammersteinModel, rng: np.random.Generator
) -> None:
    model = paper_armax_model
    # Measurements 37 noise-model sigmas apart: the spike gate is off so that every
    # finite sample reaches the estimator (the gate has its own tests).
    settings_ = MPCSettings.default_for(model).with_updates(
        max_move_pct_per_step=0.5,
        reliability=ReliabilitySettings(spike_gate_k_sigma=None, level_change_k_sigma=None))
    mpc = OffsetFreeMPC(model, settings_)
    aug, kf = mpc.augmented_model, mpc.estimator
    z_pred = np.zeros(aug.n_states)  # starts at the operating point's steady state
    for k in range(60):
        power = math.nan if k % 7 == 3 else 45.0 + 0.5 * float(rng.standard_normal())
        s = mpc.step(power, 47.0)  # the rate limit makes the applied w differ from plans
        last = mpc.last_step
        assert last is not None
        measured = math.isfinite(power)
        eps = (power - 45.0) - aug.C @ z_pred if measured else 0.0
        np.testing.assert_allclose(last.state_estimate, z_pred + kf.M * eps,
                                   rtol=0.0, atol=FILTER_ATOL)
        w = float(model.input_nonlinearity(s - 45.0))
        # Textbook one-step predictor: z+ = A z + B w + L eps (L = A M + G).
        z_pred = aug.A @ z_pred + aug.B * w + kf.L * eps
