"""The value-case benchmark: its IAE lower bound (an LP) against independent computations.

`benchmarks.iae_bound` is checked against answers found without it: a pure-delay plant
tracks a reference known in advance exactly; a one-sample-delay plant with a rate limit
pays a hand-computed triangle sum on a step; a 10-sample problem solved by SLSQP on a
dense impulse response from `scipy.signal.lfilter`; the LP's optimal inputs replayed on
the model plant give the LP's power and IAE; and no controller beats the bound.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.signal import lfilter, lfiltic

from benchmarks.iae_bound import (
    BoundError,
    MoveCut,
    iae_lower_bound,
    rate_limit_cuts,
    scenario_iae_bound,
    symmetric_move_cuts,
)
from benchmarks.value_case import (
    BOUND_RATIO_GOAL,
    CONTROLLERS,
    PREVIEW_S,
    all_scenarios,
    check_goals,
    compute_bounds,
    main,
    plot_recipes,
    recipe_scenarios,
    run_case,
    section_text,
    tune_pid_table,
    with_preview,
    write_csvs,
)
from czmpc.campaigns.simulation import run_simulation
from czmpc.pid.controller import TableSchedule
from czmpc.settings import MPCSettings
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sim.loop import run_closed_loop
from sim.metrics import compute_metrics
from sim.model_plant import ModelPlant
from sim.scenario import Scenario, load_scenario, scenario_from_dict
from sysid.model import HammersteinModel

#: HiGHS's default primal/dual feasibility tolerance is 1e-7; the LP's optimum is exact
#: to that on problems of unit size (a few samples of kW-sized errors).
LP_ATOL_KW_S = 1e-6
#: SLSQP's default ftol is 1e-6 on the objective; 1e-5 relative leaves it room.
SLSQP_RTOL = 1e-5
#: A near-unpenalised MPC with preview against the bound (measured 1.005 on the short step
#: recipe; the rest is the tangent relaxation's 0.07 % rate slack and the OSQP tolerance).
BOUND_TIGHTNESS = 1.02
#: The replay runs the same difference equation in another order of float operations on
#: ~45 kW levels, plus the inverse of f (stable root formula): 1e-9 kW per sample.
REPLAY_ATOL_KW = 1e-7


# --- the LP against independent answers -------------------------------------------------
def test_pure_delay_tracks_a_known_reference_exactly() -> None:
    # y_k = 1.7 w_{k-2}: knowing r two samples ahead, w_k = r_{k+2} / 1.7 gives no error.
    r = np.concatenate([np.zeros(5), np.full(6, 3.0), np.linspace(3.0, -2.0, 9), np.full(5, 1.0)])
    bound = iae_lower_bound([1.0], [0.0, 0.0, 1.7], r, ts_s=2.0, base_power_kw=0.0,
                            w_bounds_kw=None, w_initial_kw=0.0)
    assert bound.iae_kw_s == pytest.approx(0.0, abs=LP_ATOL_KW_S)
    np.testing.assert_allclose(bound.power_kw, r, atol=1e-7)


@pytest.mark.parametrize(("step_kw", "move_kw"), [(4.0, 1.0), (6.0, 1.0), (3.0, 0.5)])
def test_rate_limited_step_pays_the_triangle_sum(step_kw: float, move_kw: float) -> None:
    # y_k = w_{k-1}, |w_k - w_{k-1}| <= delta: the output climbs D in m = D/delta moves,
    # and each intermediate value i*delta costs min(i delta, D - i delta) wherever the
    # step falls among them (before the step: its height; after: what is missing).
    ts_s, m = 2.0, round(step_kw / move_kw)
    r = np.concatenate([np.zeros(20), np.full(20, step_kw)])
    bound = iae_lower_bound([1.0], [0.0, 1.0], r, ts_s=ts_s, base_power_kw=0.0, w_bounds_kw=None,
                            move_cuts=symmetric_move_cuts(move_kw), w_initial_kw=0.0)
    triangle = ts_s * sum(min(i * move_kw, step_kw - i * move_kw) for i in range(1, m))
    assert bound.iae_kw_s == pytest.approx(triangle, abs=LP_ATOL_KW_S)
    assert np.max(np.abs(np.diff(bound.w_kw))) <= move_kw + 1e-7


def test_small_problem_matches_slsqp_on_a_dense_impulse_response() -> None:
    # A 10-sample problem with every feature: a slow pole, two input taps, a start off
    # zero, bounds, a rate limit, a varying output scale and offset.
    a, b = [1.0, -0.8], [0.0, 0.5, 0.3]
    n, ts_s, p_nom, w0 = 10, 2.0, 10.0, 0.3
    r = np.array([14.0, 14.0, 14.0, 16.0, 17.5, 17.5, 13.0, 13.0, 15.0, 15.0])
    scale = np.array([1.0, 1.0, 0.98, 0.95, 0.95, 1.0, 1.0, 1.02, 1.02, 1.0])
    offset = np.array([0.0, 0.0, 0.0, 0.2, 0.2, 0.2, -0.1, -0.1, 0.0, 0.0])
    lo, hi, move = -1.0, 2.0, 0.6
    bound = iae_lower_bound(a, b, r, ts_s=ts_s, base_power_kw=p_nom, w_bounds_kw=(lo, hi),
                            move_cuts=symmetric_move_cuts(move), w_initial_kw=w0,
                            power_scale=scale, power_offset_kw=offset)

    y0 = sum(b) / sum(a) * w0
    zi = lfiltic(b, a, y=[y0] * 2, x=[w0] * 2)
    free = lfilter(b, a, np.zeros(n), zi=zi)[0]
    impulse = np.array([lfilter(b, a, np.eye(n)[j]) for j in range(n)]).T   # y = free + G w

    def power(w: np.ndarray) -> np.ndarray:
        return scale * (p_nom + free + impulse @ w) + offset

    cons = [{"type": "ineq", "fun": lambda x: x[n:] - (power(x[:n]) - r)},
            {"type": "ineq", "fun": lambda x: x[n:] + (power(x[:n]) - r)},
            {"type": "ineq", "fun": lambda x: move - np.diff(np.concatenate([[w0], x[:n]]))},
            {"type": "ineq", "fun": lambda x: move + np.diff(np.concatenate([[w0], x[:n]]))}]
    x0 = np.concatenate([np.full(n, w0), np.abs(power(np.full(n, w0)) - r) + 1.0])
    res = minimize(lambda x: ts_s * np.sum(x[n:]), x0, method="SLSQP", constraints=cons,
                   bounds=[(lo, hi)] * n + [(0.0, None)] * n,
                   options={"maxiter": 1000, "ftol": 1e-12})
    assert res.success, res.message
    assert bound.iae_kw_s == pytest.approx(res.fun, rel=SLSQP_RTOL)
    np.testing.assert_allclose(bound.power_kw, power(bound.w_kw), atol=1e-7)


def test_malformed_problems_are_refused() -> None:
    with pytest.raises(BoundError, match=r"b\[0\] = 0"):
        iae_lower_bound([1.0], [1.0], [0.0, 1.0], ts_s=2.0, base_power_kw=0.0, w_bounds_kw=None,
                        w_initial_kw=0.0)
    with pytest.raises(BoundError, match="min <= max"):
        iae_lower_bound([1.0], [0.0, 1.0], [0.0, 1.0], ts_s=2.0, base_power_kw=0.0,
                        w_bounds_kw=(1.0, -1.0), w_initial_kw=0.0)
    with pytest.raises(BoundError, match="shape"):
        iae_lower_bound([1.0], [0.0, 1.0], [0.0, 1.0], ts_s=2.0, base_power_kw=0.0,
                        w_bounds_kw=None, w_initial_kw=0.0, power_scale=[1.0])
    with pytest.raises(BoundError, match="side"):
        MoveCut(slope=1.0, intercept_kw=1.0, side="both")  # type: ignore[arg-type]
    with pytest.raises(BoundError, match="optimality"):   # the rate limit cannot leave w0 = 5
        iae_lower_bound([1.0], [0.0, 1.0], [0.0, 1.0], ts_s=2.0, base_power_kw=0.0,
                        w_bounds_kw=(-1.0, 1.0), move_cuts=symmetric_move_cuts(0.1),
                        w_initial_kw=5.0)


# --- the rate-limit relaxations ------------------------------------------------------------
@pytest.mark.parametrize("relaxation", ["tangents", "max_slope"])
def test_rate_cuts_contain_every_rate_limited_move(shipped_model: HammersteinModel,
                                                   relaxation: str, rng: np.random.Generator) -> None:
    # A relaxation: every pair (s_prev, s) the limit allows satisfies every cut (in w).
    allowed, delta = (28.0, 70.0), 1.6
    cuts = rate_limit_cuts(shipped_model, allowed, delta, relaxation=relaxation)  # type: ignore[arg-type]
    s_prev = rng.uniform(*allowed, 5000)
    s = np.clip(s_prev + rng.uniform(-delta, delta, s_prev.size), *allowed)
    s[:2] = [allowed[0] + delta, allowed[1] - delta]           # the full move both ways
    s_prev[:2] = [allowed[0], allowed[1]]
    s_nom = shipped_model.operating_point.triac_pct
    w_prev = shipped_model.input_nonlinearity(s_prev - s_nom)
    w = shipped_model.input_nonlinearity(s - s_nom)
    for cut in cuts:
        bound = cut.slope * w_prev + cut.intercept_kw
        ok = w <= bound + 1e-9 if cut.side == "upper" else w >= bound - 1e-9
        assert ok.all(), cut


def test_tangent_cuts_are_exact_at_their_points(shipped_model: HammersteinModel) -> None:
    # At each tangent point u the upper cut allows exactly f(u + delta) and no more.
    allowed, delta, s_nom = (28.0, 70.0), 1.6, shipped_model.operating_point.triac_pct
    cuts = [c for c in rate_limit_cuts(shipped_model, allowed, delta, n_points=3)
            if c.side == "upper"]
    for cut, s in zip(cuts, (28.0, 49.0, 70.0), strict=True):
        w_prev = float(shipped_model.input_nonlinearity(s - s_nom))
        exact = float(shipped_model.input_nonlinearity(s + delta - s_nom))
        assert cut.slope * w_prev + cut.intercept_kw == pytest.approx(exact, abs=1e-9)


def test_tangents_need_a_quadratic(shipped_model: HammersteinModel) -> None:
    cubic = shipped_model.with_updates(input_poly=[1.4, -0.0076, 1e-6])
    with pytest.raises(BoundError, match="degree 2"):
        rate_limit_cuts(cubic, (28.0, 70.0), 1.6)
    assert len(rate_limit_cuts(cubic, (28.0, 70.0), 1.6, relaxation="max_slope")) == 2


# --- the bound of a scenario ----------------------------------------------------------------
def _short_sag() -> Scenario:
    return scenario_from_dict({
        "name": "short_sag_step", "duration_s": 600.0, "initial_setpoint_kw": 45.0,
        "initial_triac_pct": 45.0,
        "setpoint": [{"kind": "step", "at_s": 100.0, "power_kw": 52.0},
                     {"kind": "ramp", "start_s": 300.0, "end_s": 400.0, "power_kw": 47.0}],
        "disturbance": [{"kind": "voltage_step", "at_s": 200.0, "factor": 0.98,
                         "duration_s": 60.0},
                        {"kind": "power_shift", "at_s": 450.0, "offset_kw": 0.3}]})


class _Replay:
    """Applies a fixed input sequence, whatever it measures."""

    def __init__(self, triac_pct: np.ndarray, ts_s: float) -> None:
        self.triac_pct, self.ts_s = triac_pct, ts_s
        self.reset()

    def reset(self) -> None:
        self._k = 0

    def step(self, power_kw: float, setpoint_kw: float, **_: object) -> float:
        self._k += 1
        return float(self.triac_pct[self._k - 1])


def test_bound_trajectory_replays_on_the_model_plant(shipped_model: HammersteinModel) -> None:
    # The LP's optimal w, inverted to TRIAC inputs and applied to the noise-free model
    # plant through the closed-loop runner, gives the LP's power and IAE: the LP models
    # the plant's timing (delay, exogenous values, start) exactly.
    scenario = _short_sag()
    bound = scenario_iae_bound(shipped_model, scenario)
    d1, d2 = shipped_model.input_poly
    w = bound.w_kw
    triac = shipped_model.operating_point.triac_pct + 2 * w / (d1 + np.sqrt(d1**2 + 4 * d2 * w))
    result = run_closed_loop(ModelPlant(shipped_model, noise=False, initial_triac_pct=45.0),
                             _Replay(triac, shipped_model.ts_s), scenario, rng=0)
    np.testing.assert_allclose(result.power_true_kw, bound.power_kw, atol=REPLAY_ATOL_KW)
    assert compute_metrics(result).iae_kw_s == pytest.approx(bound.iae_kw_s, abs=1e-5)
    assert np.all((triac >= 28.0 - 1e-9) & (triac <= 70.0 + 1e-9))


def test_tangents_tighten_the_max_slope_bound(shipped_model: HammersteinModel) -> None:
    scenario = _short_sag()
    loose = scenario_iae_bound(shipped_model, scenario, relaxation="max_slope").iae_kw_s
    tight = scenario_iae_bound(shipped_model, scenario, relaxation="tangents").iae_kw_s
    assert tight >= loose - LP_ATOL_KW_S
    assert tight > 1.05 * loose   # the 7 kW step climbs at f'(s) < max f' here


def test_no_controller_beats_the_bound(shipped_model: HammersteinModel) -> None:
    scenario = replace(load_scenario("staircase").shortened(0.25), plant_noise=False)
    bound = scenario_iae_bound(shipped_model, scenario)
    mpc = run_simulation(shipped_model, scenario, plant="model", seed=0, noise=False)
    assert mpc.metrics.iae_kw_s >= bound.iae_kw_s
    assert math.isfinite(bound.solve_time_s) and bound.n_variables == 3 * scenario.n_steps


# --- the benchmark --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def pid_schedule(tmp_path_factory: pytest.TempPathFactory) -> TableSchedule:
    return tune_pid_table(shipped_path(HAMMERSTEIN_MODEL_JSON),
                          tmp_path_factory.mktemp("value") / "pid")


def _short_ramp() -> Scenario:
    # The ramp recipe at a third of its length: 45 -> 60 kW over 200 s, hold, back down.
    return next(s for s in recipe_scenarios() if s.name == "ramp_recipe").shortened(1 / 3)


def test_recipes_are_what_the_benchmark_says() -> None:
    ramp, stairs = (next(s for s in recipe_scenarios() if s.name == n)
                    for n in ("ramp_recipe", "recipe_staircase"))
    r = ramp.setpoint_profile_kw()
    k = ramp.time_s()
    assert r[k < 600].max() == 45.0 and r[(k >= 1200) & (k < 2400)].min() == 60.0
    assert r[k >= 3000].max() == 45.0 and np.max(np.abs(np.diff(r))) == pytest.approx(15 / 300)
    assert [c.power_kw for c in stairs.setpoints] == [50.0, 55.0, 60.0, 55.0, 50.0, 45.0]
    shipped = {s.name for s in all_scenarios()}
    assert {"ramp_recipe", "recipe_staircase", "staircase", "voltage_sag"} <= shipped


def test_case_runs_the_four_controllers_with_what_each_is_given(
        shipped_model: HammersteinModel, pid_schedule: TableSchedule) -> None:
    rows = run_case(shipped_model, pid_schedule, _short_ramp(), plant="model", noise=False, seed=7)
    assert [r.controller for r in rows] == list(CONTROLLERS)
    by = {r.controller: r for r in rows}
    # The preview lets the MPC start the ramp before it begins; without it, it lags.
    assert by["mpc_preview"].iae_kw_s < 0.5 * by["mpc_today"].iae_kw_s
    for r in rows:
        assert r.result.scenario.name == "ramp_recipe-short"
        assert r.input_travel_pct == pytest.approx(np.abs(np.diff(r.result.triac_pct)).sum())
    assert by["mpc_preview"].result.scenario.setpoint_preview_s == PREVIEW_S
    assert by["mpc_today"].result.scenario.setpoint_preview_s == 0.0


def test_section_goals_csv_and_figure(shipped_model: HammersteinModel,
                                      pid_schedule: TableSchedule, tmp_path: Path) -> None:
    sag = load_scenario("voltage_sag").shortened(0.3)
    rows = [*run_case(shipped_model, pid_schedule, _short_ramp(), plant="model", noise=False,
                      seed=7),
            *run_case(shipped_model, pid_schedule, sag, plant="model", noise=False, seed=7)]
    bounds = compute_bounds(shipped_model, [_short_ramp(), sag], rows, seed=7)
    goals = check_goals(rows, bounds, shipped=[])
    # Only the bound's goal applies to shortened runs, and only where no disturbance acts.
    assert [g.where for g in goals] == ["ramp_recipe-short, model, noise off"]
    assert goals[0].value == pytest.approx(bounds[0].ratio)
    for bnd in bounds:                                           # no controller beats the bound
        assert bnd.mpc_iae_kw_s >= bnd.bound_iae_kw_s
        assert bnd.sharp_mpc_iae_kw_s >= bnd.bound_iae_kw_s
    runs_csv, bounds_csv = write_csvs(rows, bounds, tmp_path)
    lines = runs_csv.read_text().splitlines()
    assert lines[0].split(",")[:6] == ["scenario", "plant", "noise", "controller", "iae_kw_s",
                                       "iae_ratio"]
    assert len(lines) == 1 + len(rows) and len(bounds_csv.read_text().splitlines()) == 3
    ref = next(r for r in rows if r.controller == "mpc_preview" and r.scenario == "ramp_recipe-short")
    assert float(lines[1 + rows.index(ref)].split(",")[5]) == 1.0
    body = section_text(rows, bounds, goals, command="python -m benchmarks.value_case", machine="m",
                        date="2026-11-29", wall_time_s=1.0, seed=7, short=1 / 3)
    assert "Command: `python -m benchmarks.value_case`" in body and "Date: 2026-11-29" in body
    assert "(disturbances known to the bound)" in body
    figure = plot_recipes(rows, tmp_path / "figure.png", scenarios=("ramp_recipe",), plant="model",
                          noise=False)
    assert figure is not None and figure.stat().st_size > 10_000


def test_bound_is_nearly_reached_by_a_sharp_mpc_with_preview(
        shipped_model: HammersteinModel) -> None:
    # The bound is tight, not just valid: an MPC told the recipe 60 s ahead, with move and
    # input-target weights near zero, comes within 2 % of it (measured 0.5 %) on steps
    # whose rate-limited climbs the preview lets it start early.
    recipe = next(s for s in recipe_scenarios() if s.name == "recipe_staircase")
    scenario = with_preview(recipe.shortened(1 / 3))
    bound = scenario_iae_bound(shipped_model, scenario).iae_kw_s
    sharp = MPCSettings.default_for(shipped_model).with_updates(input_target_weight=1e-6,
                                                                 move_weight=1e-3)
    mpc = run_simulation(shipped_model, scenario, plant="model", seed=0, noise=False,
                         settings=sharp).metrics.iae_kw_s
    assert bound <= mpc <= BOUND_TIGHTNESS * bound


def test_preview_mpc_within_the_bound_goal_on_a_short_step_recipe(
        shipped_model: HammersteinModel) -> None:
    # Steps, not the ramp: a ramp within the rate limit can be tracked exactly (bound
    # 0.08 kW s), so there the ratio measures residues of 0.005 kW, not the use of preview.
    # Seen failing with the input-target weight 0.01 of before issue 40: 1.29 x the bound.
    recipe = next(s for s in recipe_scenarios() if s.name == "recipe_staircase")
    scenario = with_preview(recipe.shortened(1 / 3))
    bound = scenario_iae_bound(shipped_model, scenario)
    mpc = run_simulation(shipped_model, scenario, plant="model", seed=0, noise=False)
    assert mpc.metrics.iae_kw_s >= bound.iae_kw_s
    assert mpc.metrics.iae_kw_s <= BOUND_RATIO_GOAL * bound.iae_kw_s


def test_command_line_refuses_bad_options(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (["--plants", "oven"], ["--short", "2"], ["--scenarios", "nope"]):
        with pytest.raises(SystemExit) as exc:
            main(["--no-record", *argv])
        assert exc.value.code == 2
        assert "expected" in capsys.readouterr().err
