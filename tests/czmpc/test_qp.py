"""MPCQP: LQR equivalence, bounds and rate limits, soft limits, warm and cold starts."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from czmpc.errors import DesignError
from czmpc.inversion import InputMap, build_input_map
from czmpc.qp import MPCQP, MoveBounds
from czmpc.realization import InnovationsForm, innovations_form
from czmpc.settings import OSQPOptions
from sysid.model import HammersteinModel, OperatingPoint

#: OSQP run to eps 1e-9 with polishing: the polished unconstrained solution solves the
#: KKT system directly, so it matches the closed form to about 1e-9 relative; 1e-6 kW
#: leaves room for the conditioning of H (entries up to ~1e3).
LQR_ATOL_KW = 1e-6
#: Constraints hold to OSQP's primal tolerance eps_abs + eps_rel * |bound|; we allow 10x.
QP_TOL_FACTOR = 10.0
TIGHT = OSQPOptions(eps_abs=1e-9, eps_rel=1e-9, polishing=True, max_iter=50000)
WEIGHTS = {"output_weight": 1.0, "input_target_weight": 0.01, "move_weight": 0.1}
WIDE = 1e4  # box bounds that never bind [kW-equivalent]


def _qp_tol(options: OSQPOptions, scale: float) -> float:
    return QP_TOL_FACTOR * (options.eps_abs + options.eps_rel * scale)


@pytest.fixture(scope="session")
def linear_block(paper_armax_model: HammersteinModel) -> InnovationsForm:
    return innovations_form(paper_armax_model)


@pytest.fixture(scope="session")
def input_map(paper_armax_model: HammersteinModel) -> InputMap:
    return build_input_map(paper_armax_model, triac_min_pct=0.0, triac_max_pct=100.0,
                           validity_margin_pct=5.0)


def _lqr_gain(ss: InnovationsForm, q_y: float, q_u: float, q_dw: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Infinite-horizon LQR on xi = [dx; w_prev - w_s], built here independently.

    Stage cost q_y (C dx)^2 + q_u u^2 + q_dw (u - prev)^2 with u = w - w_s.
    """
    n = ss.n_states
    A = np.block([[ss.A, np.zeros((n, 1))], [np.zeros((1, n)), np.zeros((1, 1))]])
    B = np.concatenate([ss.B, [1.0]]).reshape(n + 1, 1)
    Q = np.zeros((n + 1, n + 1))
    Q[:n, :n] = q_y * np.outer(ss.C, ss.C)
    Q[n, n] = q_dw
    R = np.array([[q_u + q_dw]])
    S = np.zeros((n + 1, 1))
    S[n, 0] = -q_dw
    P = scipy.linalg.solve_discrete_are(A, B, Q, R, s=S)
    F = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A + S.T)
    return F.ravel(), A - B @ F


@pytest.mark.parametrize("horizon_steps", [50, 5], ids=["N=50", "N=5"])
def test_unconstrained_first_move_equals_the_lqr_law(
    horizon_steps: int, linear_block: InnovationsForm, rng: np.random.Generator
) -> None:
    ss = linear_block
    qp = MPCQP(A=ss.A, B=ss.B, C=ss.C, horizon_steps=horizon_steps, options=TIGHT, **WEIGHTS)
    F, A_cl = _lqr_gain(ss, 1.0, 0.01, 0.1)
    n = ss.n_states
    for _ in range(3):
        dx0 = rng.normal(size=n)
        w_s, w_prev = float(rng.normal()), float(rng.normal())
        xi = np.concatenate([dx0, [w_prev - w_s]])
        sol = qp.solve(h_terms=ss.A @ dx0, w_prev=w_prev, w_target=w_s, y_target=0.0,
                       w_lo=np.full(horizon_steps, -WIDE), w_hi=np.full(horizon_steps, WIDE))
        assert sol.is_accurate
        # The whole plan is the LQR closed-loop rollout (the DARE terminal cost makes
        # the finite horizon exact, for any N).
        expected = []
        for _j in range(horizon_steps):
            expected.append(w_s - F @ xi)
            xi = A_cl @ xi
        np.testing.assert_allclose(sol.w[0], expected[0], rtol=0.0, atol=LQR_ATOL_KW)
        np.testing.assert_allclose(sol.w, expected, rtol=0.0, atol=LQR_ATOL_KW)


def test_box_bounds_hold_to_solver_tolerance(
    linear_block: InnovationsForm, input_map: InputMap
) -> None:
    ss = linear_block
    options = OSQPOptions()
    qp = MPCQP(A=ss.A, B=ss.B, C=ss.C, horizon_steps=30, options=options, **WEIGHTS)
    w_lo, w_hi, _ = MoveBounds(None, 30).compute(input_map, 0.0)
    tol = _qp_tol(options, max(abs(input_map.w_min), abs(input_map.w_max)))
    for w_s in (input_map.w_max, input_map.w_min):  # targets on the bounds
        h = -2.0 * np.sign(w_s) * np.array([30.0, 0.0])  # far on the other side
        sol = qp.solve(h_terms=h, w_prev=0.0, w_target=w_s, y_target=0.0, w_lo=w_lo, w_hi=w_hi)
        assert sol.is_usable
        assert np.all(sol.w >= w_lo - tol) and np.all(sol.w <= w_hi + tol)
        assert np.min(np.abs(sol.w - w_s)) <= tol  # a bound is active


def test_rate_limits_hold_and_translate_to_triac_moves(
    linear_block: InnovationsForm, input_map: InputMap
) -> None:
    ss = linear_block
    options = OSQPOptions()
    delta = 2.0
    qp = MPCQP(A=ss.A, B=ss.B, C=ss.C, horizon_steps=30, has_rate_limit=True,
               options=options, **WEIGHTS)
    ds_prev = -20.0
    w_lo, w_hi, rate = MoveBounds(delta, 30).compute(input_map, ds_prev)
    assert rate is not None
    sol = qp.solve(h_terms=np.zeros(2), w_prev=input_map.f(ds_prev), w_target=input_map.w_max,
                   y_target=0.0, w_lo=w_lo, w_hi=w_hi, rate=rate)
    assert sol.is_usable
    tol = _qp_tol(options, max(abs(input_map.w_min), abs(input_map.w_max)))
    assert np.all(sol.w >= w_lo - tol) and np.all(sol.w <= w_hi + tol)
    assert np.all(np.abs(np.diff(sol.w)) <= rate + tol)
    ds = np.array([input_map.inverse(w) for w in sol.w])
    moves = np.abs(np.diff(np.concatenate([[ds_prev], ds])))
    min_slope = input_map.min_slope(input_map.ds_min_pct, input_map.ds_max_pct)
    assert np.all(moves <= delta + tol / min_slope)
    assert moves[0] >= delta - tol  # the rate limit binds on the first move


@pytest.mark.parametrize("max_iter", [3, 10, 4000])
def test_the_primal_residual_bounds_the_violation_of_box_and_rate_limits(
    max_iter: int, linear_block: InnovationsForm, input_map: InputMap, rng: np.random.Generator
) -> None:
    """MPCQP skips its own bound check when OSQP's |A x - z| (z in [l, u]) is below the
    tolerance: check that premise against the violation computed here, stopped early too."""
    ss = linear_block
    qp = MPCQP(A=ss.A, B=ss.B, C=ss.C, horizon_steps=30, has_rate_limit=True,
               options=OSQPOptions(max_iter=max_iter, check_termination=1), **WEIGHTS)
    bounds = MoveBounds(1.0, 30)
    for _ in range(40):
        ds_prev = float(rng.uniform(-30.0, 20.0))
        w_lo, w_hi, rate = bounds.compute(input_map, ds_prev)
        assert rate is not None
        qp.solve(h_terms=rng.normal(scale=5.0, size=2), w_prev=input_map.f(ds_prev),
                 w_target=float(rng.uniform(input_map.w_min, input_map.w_max)), y_target=0.0,
                 w_lo=w_lo, w_hi=w_hi, rate=rate)
        x = qp._ext.solution.x
        violation = max(float(np.max(w_lo - x)), float(np.max(x - w_hi)),
                        float(np.max(np.abs(np.diff(x)) - rate)), 0.0)
        assert violation <= qp._ext.info.prim_res + 1e-12  # reason: round-off of |A x - z|


def test_the_qps_own_move_bounds_give_the_same_problem_as_copied_ones(
    linear_block: InnovationsForm, input_map: InputMap
) -> None:
    """`MPCQP.move_bounds` writes -rate and rate into l and u itself; solve then takes them."""
    ss = linear_block
    kw = {"A": ss.A, "B": ss.B, "C": ss.C, "horizon_steps": 30, "has_rate_limit": True, **WEIGHTS}
    in_place, copied = MPCQP(**kw), MPCQP(**kw)
    own, separate = in_place.move_bounds(1.5), MoveBounds(1.5, 30)
    for ds_prev in (-20.0, 3.0, 19.0):
        args = {"h_terms": np.array([0.5, -0.2]), "w_prev": input_map.f(ds_prev), "w_target": 2.0,
                "y_target": 0.0}
        w_lo, w_hi, rate = own.compute(input_map, ds_prev)
        a = in_place.solve(**args, w_lo=w_lo, w_hi=w_hi, rate=rate)
        w_lo, w_hi, rate = separate.compute(input_map, ds_prev)
        b = copied.solve(**args, w_lo=w_lo, w_hi=w_hi, rate=rate)
        np.testing.assert_array_equal(in_place._data, copied._data)
        np.testing.assert_array_equal(a.w, b.w)


def test_first_move_bounds_are_exact_and_later_slopes_local(input_map: InputMap) -> None:
    delta, ds_prev = 2.0, -25.0
    w_lo, w_hi, rate = MoveBounds(delta, 30).compute(input_map, ds_prev)
    assert rate is not None
    assert w_lo[0] == input_map.f(ds_prev - delta)
    assert w_hi[0] == input_map.f(ds_prev + delta)
    # Near the bottom of the range f' is high; the global minimum slope (at the top)
    # would give a tighter, needlessly slow limit.
    global_rate = delta * input_map.min_slope(input_map.ds_min_pct, input_map.ds_max_pct)
    assert rate[0] == pytest.approx(delta * input_map.min_slope(ds_prev - 2 * delta,
                                                                ds_prev + 2 * delta))
    assert rate[0] > 1.2 * global_rate


def _cubic_map() -> InputMap:
    """f(ds) = ds + 1e-3 ds^3: f' has its minimum inside the range, at ds = 0."""
    c = (1.0, 0.0, 1e-3)
    return InputMap(coefficients=c, operating_triac_pct=45.0, ds_min_pct=-40.0, ds_max_pct=50.0,
                    w_min=-40.0 - 64.0, w_max=50.0 + 125.0, slope_critical_points_pct=(0.0,))


def _convex_quadratic_map() -> InputMap:
    """f(ds) = ds + 2e-3 ds^2: f' rises with ds, so its minimum is at the lower end."""
    return InputMap(coefficients=(1.0, 2e-3), operating_triac_pct=45.0, ds_min_pct=-40.0,
                    ds_max_pct=50.0, w_min=-40.0 + 3.2, w_max=50.0 + 5.0,
                    slope_critical_points_pct=())


@pytest.mark.parametrize("which", ["linear", "quadratic", "convex quadratic", "cubic"])
def test_move_bounds_match_a_dense_grid_reference(which: str, input_map: InputMap) -> None:
    linear = InputMap(coefficients=(1.2,), operating_triac_pct=45.0, ds_min_pct=-40.0,
                      ds_max_pct=50.0, w_min=-48.0, w_max=60.0, slope_critical_points_pct=())
    im = {"linear": linear, "quadratic": input_map, "convex quadratic": _convex_quadratic_map(),
          "cubic": _cubic_map()}[which]
    delta, n = 1.5, 40
    bounds = MoveBounds(delta, n)
    for ds_prev in (im.ds_min_pct + 1.0, 0.3, im.ds_max_pct - 2.0):  # buffers reused
        w_lo, w_hi, rate = bounds.compute(im, ds_prev)
        assert rate is not None
        for j in range(n):
            lo = max(im.ds_min_pct, ds_prev - (j + 1) * delta)
            hi = min(im.ds_max_pct, ds_prev + (j + 1) * delta)
            assert w_lo[j] == pytest.approx(np.polyval([*im.coefficients[::-1], 0.0], lo),
                                            rel=1e-12, abs=1e-12)
            assert w_hi[j] == pytest.approx(np.polyval([*im.coefficients[::-1], 0.0], hi),
                                            rel=1e-12, abs=1e-12)
            if j >= 1:  # reference: f' on 20001 points of [lo, hi], and at 0 if inside
                grid = np.append(np.linspace(lo, hi, 20001), [0.0] if lo < 0.0 < hi else [])
                d_poly = np.polyder(np.array([*im.coefficients[::-1], 0.0]))
                ref = delta * float(np.min(np.polyval(d_poly, grid)))
                assert rate[j - 1] == pytest.approx(ref, rel=1e-12, abs=1e-12)
    w_lo, w_hi, none = MoveBounds(None, 5).compute(im, 0.0)
    assert none is None and np.all(w_lo == im.w_min) and np.all(w_hi == im.w_max)


def test_move_bounds_follow_a_changed_input_map(input_map: InputMap) -> None:
    # MoveBounds keeps the scalars of the map it last saw; a new map (a limit ramp's
    # restricted one, another f) must be taken up at once.
    restricted = dataclasses.replace(input_map, ds_max_pct=5.0, w_max=input_map.f(5.0))
    bounds = MoveBounds(1.5, 20)
    for im in (input_map, restricted, _convex_quadratic_map(), input_map):
        got = [a.copy() for a in bounds.compute(im, 0.3) if a is not None]
        fresh = [a for a in MoveBounds(1.5, 20).compute(im, 0.3) if a is not None]
        for a, b in zip(got, fresh, strict=True):
            np.testing.assert_array_equal(a, b)


@settings(max_examples=60, deadline=None)
@given(
    ds_prev=st.floats(min_value=-30.0, max_value=30.0),
    delta=st.floats(min_value=0.1, max_value=10.0),
    steps=st.lists(st.floats(min_value=-1.0, max_value=1.0), min_size=20, max_size=20),
)
def test_any_plan_inside_the_w_constraints_moves_the_triac_at_most_delta(
    ds_prev: float, delta: float, steps: list[float], input_map: InputMap
) -> None:
    w_lo, w_hi, rate = MoveBounds(delta, 20).compute(input_map, ds_prev)
    assert rate is not None
    # Build a plan that satisfies every w-constraint: a random walk kept in the boxes
    # (each box contains the previous one, so clipping never lengthens a move).
    w = [w_lo[0] + (steps[0] + 1.0) / 2.0 * (w_hi[0] - w_lo[0])]
    for j in range(1, 20):
        w.append(min(w_hi[j], max(w_lo[j], w[-1] + steps[j] * rate[j - 1])))
    ds = [ds_prev] + [input_map.inverse(v) for v in w]
    assert max(abs(b - a) for a, b in zip(ds, ds[1:], strict=False)) <= delta * (1 + 1e-9)


def test_soft_power_limit_is_met_when_possible_and_slack_reports_violations(
    linear_block: InnovationsForm, input_map: InputMap
) -> None:
    ss = linear_block
    options = OSQPOptions()
    qp = MPCQP(A=ss.A, B=ss.B, C=ss.C, horizon_steps=30, has_soft_max=True,
               options=options, soft_limit_weight=1e3, soft_limit_linear_weight=1e2,
               **WEIGHTS)
    w_lo, w_hi, _ = MoveBounds(None, 30).compute(input_map, 0.0)
    # Target at y_s = 2 kW with the soft maximum at 3 kW: no conflict, slack ~ 0.
    g = ss.static_gain
    free = qp.solve(h_terms=np.zeros(2), w_prev=0.0, w_target=2.0 / g, y_target=2.0, w_lo=w_lo,
                    w_hi=w_hi, soft_max_rel_kw=3.0)
    assert free.is_usable and free.slack_kw == pytest.approx(0.0, abs=_qp_tol(options, 3.0))
    # Soft maximum at 1 kW below the 2 kW target: the plan keeps y near 1 kW.
    capped = qp.solve(h_terms=np.zeros(2), w_prev=0.0, w_target=2.0 / g, y_target=2.0, w_lo=w_lo,
                      w_hi=w_hi, soft_max_rel_kw=1.0)
    assert capped.is_usable and 0.0 < capped.slack_kw < 0.1


def test_an_h_map_solves_the_problem_of_h_formed_first(
    linear_block: InnovationsForm, input_map: InputMap, rng: np.random.Generator
) -> None:
    # h = M t folded into q and the soft rows: the same problem up to the rounding of q.
    ss = linear_block
    kw = {"A": ss.A, "B": ss.B, "C": ss.C, "horizon_steps": 30, "has_soft_max": True,
          "has_soft_min": True, "options": TIGHT, **WEIGHTS}
    h_map = rng.normal(size=(2, 5))
    mapped, plain = MPCQP(**kw, h_map=h_map), MPCQP(**kw)  # type: ignore[arg-type]
    w_lo, w_hi, _ = MoveBounds(None, 30).compute(input_map, 0.0)
    for _ in range(5):
        terms = rng.normal(scale=3.0, size=5)
        args = {"w_prev": 1.0, "w_target": 2.0, "y_target": 2.0 * ss.static_gain,
                "w_lo": w_lo, "w_hi": w_hi, "soft_max_rel_kw": 2.5, "soft_min_rel_kw": -1.0}
        a = mapped.solve(h_terms=terms, **args)  # type: ignore[arg-type]
        b = plain.solve(h_terms=h_map @ terms, **args)  # type: ignore[arg-type]
        np.testing.assert_allclose(mapped._data, plain._data, rtol=1e-13, atol=1e-12)
        assert a.is_usable and b.is_usable
        np.testing.assert_allclose(a.w, b.w, atol=LQR_ATOL_KW)
    with pytest.raises(DesignError, match="h_map must have 2 rows"):
        MPCQP(**kw, h_map=np.ones((3, 5)))  # type: ignore[arg-type]


def test_warm_start_needs_few_iterations_and_failure_forces_a_cold_start(
    linear_block: InnovationsForm, input_map: InputMap
) -> None:
    ss = linear_block
    options = OSQPOptions()

    def make() -> MPCQP:
        return MPCQP(A=ss.A, B=ss.B, C=ss.C, horizon_steps=30, options=options, **WEIGHTS)

    w_lo, w_hi, _ = MoveBounds(None, 30).compute(input_map, 0.0)
    args = {"h_terms": np.array([-3.0, 0.5]), "w_prev": 1.0, "w_target": 4.0, "y_target": 3.6,
            "w_lo": w_lo, "w_hi": w_hi}
    qp = make()
    cold = qp.solve(**args)  # type: ignore[arg-type]
    warm = qp.solve(**args)  # type: ignore[arg-type]
    assert warm.n_iterations <= options.check_termination < cold.n_iterations
    failed = qp.solve(**{**args, "h_terms": np.array([math.nan, 0.0])})  # type: ignore[arg-type]
    assert not failed.is_usable and np.all(np.isnan(failed.w))
    after = qp.solve(**args)  # type: ignore[arg-type]
    # A cold start repeats the fresh solve bit for bit.
    assert after.n_iterations == cold.n_iterations
    assert np.array_equal(after.w, cold.w)


def test_max_iter_one_reports_an_unusable_solution(
    linear_block: InnovationsForm, input_map: InputMap
) -> None:
    ss = linear_block
    qp = MPCQP(A=ss.A, B=ss.B, C=ss.C, horizon_steps=30,
               options=OSQPOptions(max_iter=1), **WEIGHTS)
    w_lo, w_hi, _ = MoveBounds(None, 30).compute(input_map, 0.0)
    sol = qp.solve(h_terms=np.array([-3.0, 0.5]), w_prev=1.0, w_target=4.0, y_target=3.6,
                   w_lo=w_lo, w_hi=w_hi)
    assert sol.status == "maximum iterations reached"
    assert not sol.is_usable and not sol.is_accurate
    assert sol.n_iterations == 1


def test_terminal_cost_without_stabilizing_solution_is_a_design_error() -> None:
    from czmpc.qp import terminal_cost

    A = np.diag([1.1, 0.5])  # unstable mode the input cannot reach
    with pytest.raises(DesignError, match="control DARE must have a stabilizing solution"):
        terminal_cost(A, np.array([0.0, 1.0]), np.array([1.0, 1.0]), output_weight=1.0,
                      input_target_weight=0.01, move_weight=0.1)


def _linear_model(a: list[float], b: list[float], c: list[float]) -> HammersteinModel:
    return HammersteinModel(kind="hammerstein", linear_block="armax", ts_s=2.0,
                            operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
                            a=a, b=b, c=c, input_poly=[1.0], noise_std_kw=0.1,
                            input_range_pct=(20.0, 70.0))


def _lq(a: list[float], b: list[float], c: list[float]) -> tuple[np.ndarray, ...]:
    from czmpc.qp import lq_problem

    form = innovations_form(_linear_model(a, b, c))
    return lq_problem(form.A, form.B, form.C, output_weight=1.0, input_target_weight=0.01,
                      move_weight=0.1)


def test_dare_by_doubling_matches_scipy_where_scipy_solves() -> None:
    from czmpc.qp import dare_by_doubling

    A, B, Q, R, S = _lq([1.0, -0.99], [0.0, 1.0, -0.991], [1.0, -0.9])
    reference = scipy.linalg.solve_discrete_are(A, B, Q, R, s=S)
    P = dare_by_doubling(A, B, Q, R, S)
    assert P is not None
    # both solve the same well-conditioned DARE: agreement to rounding of |P| ~ 1e2
    np.testing.assert_allclose(P, reference, rtol=1e-8, atol=1e-8 * np.abs(reference).max())


def test_terminal_cost_survives_a_dare_that_scipy_cannot_reorder() -> None:
    # identified on a heater with a 3-sample delay (benchmarks.commission_length, seed 0): a
    # double pole at 0.998 over a nearly cancelling double zero, next to the delay
    # states' poles at 0; scipy's QZ reordering fails on it
    from czmpc.qp import terminal_cost

    a = [1.0, -1.9963490489735305, 0.9963597332532107]
    b = [0.0, 0.0, 0.0, 1.0, -1.9965315612772834, 0.9965405535039659]
    c = [1.0, -1.794239969121802, 0.7946518608054333]
    A, B, Q, R, S = _lq(a, b, c)
    with pytest.raises(ValueError, match="Reordering"):
        scipy.linalg.solve_discrete_are(A, B, Q, R, s=S)
    form = innovations_form(_linear_model(a, b, c))
    P = terminal_cost(form.A, form.B, form.C, output_weight=1.0, input_target_weight=0.01,
                      move_weight=0.1)
    # independent checks: the Riccati residual and a stable closed loop
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A + S.T)
    residual = A.T @ P @ A - (A.T @ P @ B + S) @ K + Q - P
    assert np.abs(residual).max() < 1e-8 * np.abs(P).max()
    assert np.abs(np.linalg.eigvals(A - B @ K)).max() < 1.0
