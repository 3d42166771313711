"""Levenberg-Marquardt and standard errors against known optima and scipy.optimize."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from sysid.errors import IdentificationError
from sysid.optimize import levenberg_marquardt, parameter_std_errors, triangular_factor

#: Rosenbrock's minimum (1, 1) is met to the xtol test's scale (1e-10 relative) and better.
ROSENBROCK_ATOL = 1e-8
#: Two solvers at the same minimum of a well-conditioned fit, both with tolerances <= 1e-12:
#: parameters agree to well below the statistical spread (std errors are ~1e-3 here).
SAME_OPTIMUM_ATOL = 1e-7
#: Our cost may exceed scipy's only by rounding (the issue's bound).
COST_RTOL = 1e-6
#: Standard errors from the SVD versus the textbook inverse on a well-conditioned J.
STD_ERROR_RTOL = 1e-10


def rosenbrock(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x1, x2 = theta
    r = np.array([10.0 * (x2 - x1**2), 1.0 - x1])
    jac = np.array([[-20.0 * x1, 10.0], [-1.0, 0.0]])
    return r, jac


def test_lm_finds_rosenbrock_minimum_from_the_classic_start() -> None:
    res = levenberg_marquardt(rosenbrock, np.array([-1.2, 1.0]))
    assert res.converged, res.message
    np.testing.assert_allclose(res.theta, [1.0, 1.0], rtol=0, atol=ROSENBROCK_ATOL)
    assert res.cost < 1e-20


def _decay_problem(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0.0, 5.0, 400)
    y = 3.0 * np.exp(-0.7 * t) + 0.5 + 0.02 * rng.standard_normal(t.size)
    return t, y


def test_lm_curve_fit_matches_scipy_least_squares(rng: np.random.Generator) -> None:
    t, y = _decay_problem(rng)

    def fun(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g = np.exp(-theta[1] * t)
        r = theta[0] * g + theta[2] - y
        return r, np.column_stack([g, -theta[0] * t * g, np.ones_like(t)])

    ours = levenberg_marquardt(fun, np.array([1.0, 0.1, 0.0]))
    ref = least_squares(
        lambda th: th[0] * np.exp(-th[1] * t) + th[2] - y,
        np.array([1.0, 0.1, 0.0]),
        method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15,
    )
    assert ours.converged, ours.message
    np.testing.assert_allclose(ours.theta, ref.x, rtol=0, atol=SAME_OPTIMUM_ATOL)
    ref_cost = float(np.mean(ref.fun**2))
    assert ours.cost <= ref_cost * (1 + COST_RTOL)


def test_lm_non_convergence_keeps_best_iterate_and_says_why() -> None:
    start = np.array([-1.2, 1.0])
    start_cost = float(np.mean(rosenbrock(start)[0] ** 2))
    res = levenberg_marquardt(rosenbrock, start, max_iterations=2)
    assert not res.converged
    assert "maximum number of iterations (2)" in res.message
    assert res.n_iterations == 2
    assert res.cost < start_cost
    np.testing.assert_array_equal(res.residuals, rosenbrock(res.theta)[0])


def test_lm_rejects_non_finite_trial_points_and_still_converges() -> None:
    # The first Gauss-Newton step from x = 1 lands at x < 0, where log is NaN.
    target = np.log(0.01)

    def fun(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.array([np.log(theta[0]) - target]), np.array([[1.0 / theta[0]]])

    res = levenberg_marquardt(fun, np.array([1.0]))
    assert res.converged, res.message
    np.testing.assert_allclose(res.theta, [0.01], rtol=1e-9, atol=0)


def test_lm_respects_bounds_and_projection_at_every_trial_point() -> None:
    visited: list[np.ndarray] = []

    def fun(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        visited.append(theta.copy())
        return theta - np.array([2.0, -3.0]), np.eye(2)

    res = levenberg_marquardt(
        fun, np.array([0.0, 0.0]), upper=np.array([1.0, np.inf]),
        project=lambda th: np.array([th[0], max(th[1], -1.0)]),
    )
    assert res.converged, res.message
    np.testing.assert_allclose(res.theta, [1.0, -1.0], rtol=0, atol=1e-12)
    points = np.array(visited)
    assert np.all(points[:, 0] <= 1.0) and np.all(points[:, 1] >= -1.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"max_iterations": 0}, "max_iterations must be an int >= 1"),
        ({"max_iterations": 2.5}, "max_iterations must be an int >= 1"),
        ({"xtol": -1.0}, "xtol must be a finite number >= 0"),
        ({"lower": np.array([0.0])}, "lower must have one entry per parameter"),
        ({"lower": np.array([3.0, 0.0]), "upper": np.array([1.0, 1.0])}, "lower must not"),
    ],
    ids=["zero-iterations", "float-iterations", "negative-xtol", "short-bound", "crossed"],
)
def test_lm_rejects_bad_options(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(IdentificationError, match=match):
        levenberg_marquardt(rosenbrock, np.array([0.0, 0.0]), **kwargs)  # type: ignore[arg-type]


def test_lm_rejects_non_finite_start_and_wrong_jacobian_shape() -> None:
    with pytest.raises(IdentificationError, match="starting point .* not finite"):
        levenberg_marquardt(lambda th: (np.array([np.nan]), np.ones((1, 1))), np.ones(1))
    with pytest.raises(IdentificationError, match=r"J of shape \(N, p\)"):
        levenberg_marquardt(lambda th: (np.ones(3), np.ones((3, 2))), np.ones(1))


def test_std_errors_equal_textbook_formula(rng: np.random.Generator) -> None:
    jac = rng.standard_normal((200, 3))
    r = rng.standard_normal(200)
    s2 = r @ r / (200 - 3)
    expected = np.sqrt(np.diag(s2 * np.linalg.inv(jac.T @ jac)))
    np.testing.assert_allclose(
        parameter_std_errors(jac, r), expected, rtol=STD_ERROR_RTOL, atol=0
    )
    # the first p columns of the factor of [J, r] are J's factor
    factor = triangular_factor(jac, None, r)[:3, :3]
    np.testing.assert_allclose(
        parameter_std_errors(jac, r, factor=factor), expected, rtol=STD_ERROR_RTOL, atol=0
    )


def test_std_errors_are_infinite_only_for_unidentifiable_parameters(
    rng: np.random.Generator,
) -> None:
    col = rng.standard_normal(100)
    other = rng.standard_normal(100)
    other -= col * (col @ other) / (col @ col)  # orthogonal to the duplicated pair
    jac = np.column_stack([col, col, other])
    se = parameter_std_errors(jac, rng.standard_normal(100))
    assert np.isinf(se[0]) and np.isinf(se[1])
    assert np.isfinite(se[2])
    assert np.all(np.isinf(parameter_std_errors(np.ones((2, 2)), np.ones(2))))


def test_the_budget_follows_progress_a_crawl_stops_converged_by_the_progress_test() -> None:
    """``r = [1, exp(-theta)]``: each Gauss-Newton step adds 1 to theta (Newton's, with
    the second-order term, 1/2), so V = (1 + exp(-2 theta)) / 2 crawls down to its floor
    by a constant factor per iteration; the progress test (V down by < 1e-6 over 10
    iterations) ends the search as converged before ftol = 1e-12 would."""
    def crawl(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tail = np.exp(-theta[0])
        return np.array([1.0, tail]), np.array([[0.0], [-tail]])

    stopped = levenberg_marquardt(crawl, np.zeros(1))
    assert stopped.converged and "progress test" in stopped.message
    assert stopped.cost == pytest.approx(0.5, rel=1e-6)
    # V - 0.5 = exp(-2 theta) / 2 falls by ~1e-6 relative over ten steps of 1/2 to 1
    # (the Newton and Gauss-Newton steps the two models of the search take) near 10-13
    assert 8.0 < stopped.theta[0] < 14.0
    without = levenberg_marquardt(crawl, np.zeros(1), progress_rtol=0.0)
    assert without.converged and "ftol" in without.message
    assert without.n_iterations > stopped.n_iterations
    with pytest.raises(IdentificationError, match="progress_rtol must be a finite number >= 0"):
        levenberg_marquardt(crawl, np.zeros(1), progress_rtol=-1.0)


#: Where ftol = 1e-12 stops a search on the cost, a parameter may still be off by about
#: sqrt(1e-12 cost / curvature): 1e-7 here, so the two solvers agree to 1e-6.
LARGE_RESIDUAL_ATOL = 1e-6


def test_a_large_residual_fit_takes_fewer_iterations_than_gauss_newton_lm() -> None:
    """``y = exp(-2t) + sin(9t)/2`` fitted by ``c exp(a t)``: the residual is model error,
    so ``S = sum r_k d^2 r_k`` is not small and Gauss-Newton converges only linearly;
    the secant model reaches MINPACK's optimum in fewer Jacobians than MINPACK takes."""
    t = np.linspace(0.0, 1.0, 50)
    y = np.exp(-2.0 * t) + 0.5 * np.sin(9.0 * t)

    def fun(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g = np.exp(theta[0] * t)
        return theta[1] * g - y, np.column_stack([theta[1] * t * g, g])

    ours = levenberg_marquardt(fun, np.array([0.0, 1.0]))
    ref = least_squares(lambda th: fun(th)[0], np.array([0.0, 1.0]), jac=lambda th: fun(th)[1],
                        method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert ours.converged, ours.message
    np.testing.assert_allclose(ours.theta, ref.x, rtol=0, atol=LARGE_RESIDUAL_ATOL)
    assert ours.n_iterations < ref.njev


def test_a_lazy_jacobian_is_made_at_accepted_points_only() -> None:
    made: list[float] = []
    calls: list[float] = []

    def fun(theta: np.ndarray) -> tuple[np.ndarray, object]:
        r, jac = rosenbrock(theta)
        calls.append(float(theta[0]))
        return r, lambda: made.append(float(theta[0])) or jac

    res = levenberg_marquardt(fun, np.array([-1.2, 1.0]))  # type: ignore[arg-type]
    eager = levenberg_marquardt(rosenbrock, np.array([-1.2, 1.0]))
    np.testing.assert_array_equal(res.theta, eager.theta)
    # one Jacobian at the start and one per accepted step, none at the rejected trials
    assert len(made) <= res.n_iterations + 1 < len(calls)


def test_a_trial_whose_jacobian_is_not_finite_is_rejected_and_the_factor_is_the_final_points() -> None:
    # r = x - 2 (so a full step goes to 2), but J is NaN for x > 1.5: every trial beyond it
    # is rejected on its Jacobian (seen through the factor of [J, r]), and the search ends
    # at or below 1.5 with the factor of its own [J, r]
    def fun(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        slope = np.nan if theta[0] > 1.5 else 1.0
        return np.array([theta[0] - 2.0, 0.0]), np.array([[slope], [0.0]])

    res = levenberg_marquardt(fun, np.array([0.0]))
    assert res.theta[0] <= 1.5 and np.all(np.isfinite(res.jacobian))
    np.testing.assert_array_equal(res.factor, triangular_factor(res.jacobian, None, res.residuals))
