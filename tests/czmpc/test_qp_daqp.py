"""DAQPMPCQP: DAQP's plans against OSQP's on the same closed-loop QPs, hot and cold starts,
the fallbacks, the closed loop with either solver."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from czmpc import qp_daqp
from czmpc.campaigns.simulation import run_simulation
from czmpc.controller import OffsetFreeMPC
from czmpc.modes import Status
from czmpc.qp import MPCQP
from czmpc.qp_daqp import DAQP_PRIMAL_TOL_KW, DAQPMPCQP, general_rows
from czmpc.realization import innovations_form
from czmpc.settings import MPCSettings, OSQPOptions
from sim.model_plant import ModelPlant
from sim.protocols import NOMINAL
from sim.scenario import load_scenario
from sysid.model import HammersteinModel

pytest.importorskip("daqp")

#: OSQP run to eps 1e-10 with polishing: the reference DAQP's plans are held to.
TIGHT = OSQPOptions(eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=200_000)
#: DAQP's plan against tight OSQP's on the same q, l, u [kW-equivalent]. Where OSQP
#: polishes, both solve the same active set's KKT system (measured 3e-14 kW); where it
#: finds no active set to polish, its iterate is within about eps * cond(H) of the
#: optimum (measured 2.3e-9 kW on the staircase, N = 39).
PLAN_ATOL_KW = 1e-8
#: Relative agreement of the objectives. DAQP's comes from its least-distance form,
#: 0.5 |u|^2 - 0.5 |v|^2, which loses digits to cancellation when the optimum is small
#: against the unconstrained one (measured 1.7e-10 with soft limits, 4e-15 without).
OBJECTIVE_RTOL = 1e-8
#: Staircase samples replayed: the first two setpoint steps (at 300 and 1200).
REPLAY_SAMPLES = 1400
#: A row within this of its bound counts as active [kW-equivalent].
ACTIVE_ATOL_KW = 1e-9


def _copy(value: object) -> object:
    return np.array(value) if isinstance(value, np.ndarray) else value


def _recorded_solves(model: HammersteinModel, settings: MPCSettings, *, samples: int,
                     preview_steps: int) -> list[dict[str, Any]]:
    """Every ``solve`` call (its arguments, copied) of the OSQP controller on the staircase.

    The noisy model plant (seed 0); each step told ``preview_steps`` setpoints ahead.
    """
    scenario = load_scenario("staircase")
    mpc = OffsetFreeMPC(model, settings.with_updates(initial_triac_pct=scenario.initial_triac_pct))
    calls: list[dict[str, Any]] = []
    real = mpc.qp.solve

    def recording(**kwargs: Any) -> Any:
        calls.append({k: _copy(v) for k, v in kwargs.items()})
        return real(**kwargs)

    mpc.qp.solve = recording  # type: ignore[method-assign]
    setpoints = np.asarray(scenario.setpoint_profile_kw(), dtype=float)[:samples]
    plant = ModelPlant.for_scenario(model, scenario)
    power = plant.reset(np.random.default_rng(0))
    for k, setpoint in enumerate(setpoints):
        triac = mpc.step(power, float(setpoint),
                         setpoint_preview_kw=setpoints[k + 1 : k + 1 + preview_steps])
        power = plant.step(triac, NOMINAL)
    return calls


def _fresh_qp(model: HammersteinModel, settings: MPCSettings) -> MPCQP:
    return OffsetFreeMPC(model, settings).qp


CASES: dict[str, Callable[[MPCSettings], MPCSettings]] = {
    "default": lambda s: s,
    "soft-limits": lambda s: s.with_updates(soft_power_min_kw=44.0, soft_power_max_kw=50.5),
    "slow-rate": lambda s: s.with_updates(max_move_pct_per_step=0.3),
    "no-rate-limit": lambda s: s.with_updates(max_move_pct_per_step=None),
}
#: Least number of the replayed QPs with an active box or rate row, per case (measured 60,
#: 30, 70 and 0 of 1,400): the comparison covers constrained optima, not only unconstrained
#: ones (with soft limits, 229 have a positive slack besides).
MIN_ACTIVE = {"default": 50, "soft-limits": 25, "slow-rate": 60, "no-rate-limit": 0}


@pytest.mark.parametrize("case", list(CASES))
def test_daqp_plans_equal_tight_osqp_plans_on_the_same_closed_loop_qps(
        case: str, shipped_model: HammersteinModel) -> None:
    settings = CASES[case](MPCSettings.default_for(shipped_model))
    calls = _recorded_solves(shipped_model, settings, samples=REPLAY_SAMPLES, preview_steps=30)
    tight = _fresh_qp(shipped_model, settings.with_updates(osqp=TIGHT))
    daqp = _fresh_qp(shipped_model, settings.with_updates(solver="daqp"))
    assert isinstance(daqp, DAQPMPCQP) and not isinstance(tight, DAQPMPCQP)
    worst_w = worst_violation = 0.0
    n_active = n_slack = 0
    for kwargs in calls:
        ref, sol = tight.solve(**kwargs), daqp.solve(**kwargs)
        assert ref.is_usable and ref.is_accurate, ref.status
        assert sol.is_usable and sol.is_accurate and sol.status == "solved"
        assert not sol.w.flags.writeable
        worst_w = max(worst_w, float(np.max(np.abs(sol.w - ref.w))))
        assert sol.objective == pytest.approx(ref.objective, rel=OBJECTIVE_RTOL, abs=1e-12)
        assert sol.slack_kw == pytest.approx(ref.slack_kw, abs=PLAN_ATOL_KW)
        n_slack += sol.slack_kw > PLAN_ATOL_KW
        gaps = [sol.w - kwargs["w_lo"], kwargs["w_hi"] - sol.w]
        if kwargs["rate"] is not None:
            gaps.append(kwargs["rate"] - np.abs(np.diff(sol.w)))
        worst_violation = max(worst_violation, -float(np.min(np.concatenate(gaps))))
        n_active += float(np.min(np.abs(np.concatenate(gaps)))) <= ACTIVE_ATOL_KW
    assert worst_w <= PLAN_ATOL_KW
    assert worst_violation <= DAQP_PRIMAL_TOL_KW   # measured 1e-14: active rows hold exactly
    assert n_active >= MIN_ACTIVE[case]
    assert (n_slack > 0) == (case == "soft-limits")   # the soft limits bind in that case


def test_the_general_rows_are_the_moves_the_soft_outputs_and_the_slack(
        shipped_model: HammersteinModel, rng: np.random.Generator) -> None:
    # Reference: the moves by np.diff, the outputs' w part by the state recursion
    # x_{j+1} = A x_j + B w_j from x_0 = 0 (C dx_{j+1} = C x_{j+1} without h and w_s).
    block = innovations_form(shipped_model)
    A, B, C = block.A, block.B, block.C
    N = 12
    rows = general_rows(A, B, C, horizon_steps=N, has_rate_limit=True, has_soft_min=True,
                        has_soft_max=True)
    w, v = rng.normal(size=N), 0.37
    x = np.zeros(B.size)
    outputs = np.empty(N)
    for j in range(N):
        x = A @ x + B * w[j]
        outputs[j] = C @ x
    expected = np.concatenate([np.diff(w), outputs - v, outputs + v, [v]])
    np.testing.assert_allclose(rows @ np.append(w, v), expected, rtol=1e-12, atol=1e-12)
    assert general_rows(A, B, C, horizon_steps=N, has_rate_limit=False, has_soft_min=False,
                        has_soft_max=False).shape == (0, N)


def _constrained_problem(model: HammersteinModel) -> tuple[MPCQP, dict[str, Any]]:
    """A DAQP QP and one of its closed-loop problems with rows active (the rate limit)."""
    settings = MPCSettings.default_for(model).with_updates(max_move_pct_per_step=0.3)
    calls = _recorded_solves(model, settings, samples=310, preview_steps=0)
    return _fresh_qp(model, settings.with_updates(solver="daqp")), calls[-1]


def test_a_hot_start_takes_one_iteration_and_a_cold_start_the_same_plan(
        shipped_model: HammersteinModel) -> None:
    qp, kwargs = _constrained_problem(shipped_model)
    cold = qp.solve(**kwargs)            # the first solve starts from an empty working set
    hot = qp.solve(**kwargs)             # the same data: its working set is optimal at once
    qp.request_cold_start()
    again = qp.solve(**kwargs)
    assert cold.is_usable and hot.is_usable and again.is_usable
    assert cold.n_iterations >= 5        # measured 8: one per row it activates, and the last
    assert hot.n_iterations == 1
    assert again.n_iterations == cold.n_iterations
    np.testing.assert_allclose(hot.w, cold.w, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(again.w, cold.w)


# --- failures and the fallbacks -------------------------------------------------------------
def test_non_finite_or_infeasible_problems_are_not_usable_and_force_a_cold_start(
        shipped_model: HammersteinModel) -> None:
    qp, kwargs = _constrained_problem(shipped_model)
    reference = _fresh_qp(shipped_model, MPCSettings.default_for(shipped_model)
                          .with_updates(max_move_pct_per_step=0.3, solver="daqp"))
    good = reference.solve(**kwargs)
    nan = qp.solve(**{**kwargs, "w_target": math.nan})
    assert (nan.status, nan.is_usable, nan.n_iterations) == ("non-finite problem data", False, 0)
    assert np.isnan(nan.w).all()
    # Bounds crossed in one row: DAQP's update refuses them before solving.
    crossed = qp.solve(**{**kwargs, "w_lo": kwargs["w_hi"] + 1.0})
    assert crossed.status == "primal infeasible (daqp exit -1)" and not crossed.is_usable
    assert crossed.n_iterations == 0 and math.isnan(crossed.objective)
    # Every row consistent, the rows together not: w_0 in [10, 11], later w in [0, 1],
    # moves of at most 1. DAQP's dual detects it.
    N = kwargs["w_lo"].size
    w_lo, w_hi = np.zeros(N), np.ones(N)
    w_lo[0], w_hi[0] = 10.0, 11.0
    apart = qp.solve(**{**kwargs, "w_lo": w_lo, "w_hi": w_hi, "rate": np.ones(N - 1)})
    assert apart.status == "primal infeasible (daqp exit -1)" and not apart.is_usable
    assert apart.n_iterations >= 1 and np.isnan(apart.w).all()   # measured 4
    assert math.isnan(apart.objective)
    # The next solve starts from scratch and finds what a fresh problem finds.
    after = qp.solve(**kwargs)
    assert after.is_usable and after.n_iterations == good.n_iterations
    np.testing.assert_array_equal(after.w, good.w)


def test_the_iteration_cap_makes_a_solve_unusable(
        shipped_model: HammersteinModel, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(qp_daqp, "DAQP_ITER_LIMIT", 3)
    qp, kwargs = _constrained_problem(shipped_model)   # needs 8 iterations from cold
    sol = qp.solve(**kwargs)
    assert sol.status == "maximum iterations reached (daqp exit -4)" and not sol.is_usable


def test_the_controller_falls_back_when_daqp_fails(
        shipped_model: HammersteinModel, monkeypatch: pytest.MonkeyPatch) -> None:
    delta = 1.6
    settings = MPCSettings.default_for(shipped_model).with_updates(
        solver="daqp", max_move_pct_per_step=delta, initial_triac_pct=45.0)
    mpc = OffsetFreeMPC(shipped_model, settings)
    for _ in range(5):
        mpc.step(45.0, 47.0)
    assert mpc.last_step is not None and mpc.last_step.fallback == "none"
    real = mpc.qp.solve
    broken: list[str] = []

    def infeasible(**kwargs: Any) -> Any:   # the real DAQP solve of crossed bounds
        sol = real(**{**kwargs, "w_lo": np.asarray(kwargs["w_hi"]) + 1.0})
        broken.append(sol.status)
        return sol

    monkeypatch.setattr(mpc.qp, "solve", infeasible)
    s_prev = mpc.last_step.triac_pct
    lo, hi = mpc.allowed_triac_range_pct
    for _ in range(2):
        s = mpc.step(45.5, 47.0)
        last = mpc.last_step
        assert last is not None and last.fallback == "shifted_plan" and last.status is Status.HELD
        assert math.isfinite(s) and abs(s - s_prev) <= delta + 1e-9 and lo <= s <= hi
        assert last.solver_status == "primal infeasible (daqp exit -1)"
        s_prev = s
    assert broken == ["primal infeasible (daqp exit -1)"] * 2 and mpc.n_fallbacks == 2
    monkeypatch.undo()
    mpc.step(45.5, 47.0)
    assert mpc.last_step is not None and mpc.last_step.fallback == "none"
    assert mpc.last_step.solver_status == "solved"


# --- the closed loop --------------------------------------------------------------------------
#: IAE [kW s] of the noise-free staircase (3,900 samples of 2 s) with DAQP against OSQP at
#: eps 1e-10: their plans agree to PLAN_ATOL_KW, so the power to about that, and the IAE to
#: 7,800 s times it (measured 5e-7 on the model plant, 8e-8 on the heater).
IAE_EXACT_ATOL_KW_S = 7800.0 * PLAN_ATOL_KW
#: DAQP against OSQP at its default eps 1e-5: the golden suite's rule for a solver's share
#: of a metric, 10 x |metric(default solver) - metric(tight solver)| (measured 1.0 x).
SOLVER_SHARE_FACTOR = 10.0


@pytest.mark.parametrize("plant", ["model", "heater"])
def test_the_staircase_iae_with_daqp_is_the_exact_qps_and_within_osqps_tolerance(
        plant: str, shipped_model: HammersteinModel) -> None:
    default = MPCSettings.default_for(shipped_model)
    iae = {}
    for name, settings in (("osqp", default), ("tight", default.with_updates(osqp=TIGHT)),
                           ("daqp", default.with_updates(solver="daqp"))):
        outcome = run_simulation(shipped_model, load_scenario("staircase"), plant=plant,  # type: ignore[arg-type]
                                 seed=0, settings=settings, noise=False)
        assert outcome.metrics.n_solver_failures == 0
        iae[name] = outcome.metrics.iae_kw_s
    assert abs(iae["daqp"] - iae["tight"]) <= IAE_EXACT_ATOL_KW_S
    share = abs(iae["osqp"] - iae["tight"])
    assert 0.0 < share and abs(iae["daqp"] - iae["osqp"]) <= SOLVER_SHARE_FACTOR * share
    assert iae["daqp"] == pytest.approx(iae["osqp"], rel=1e-4)   # measured 3.9e-5, 9.0e-5
