"""Grey-box PEM engine: residuals against scipy, exact Jacobian, fits against direct fits, errors."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.signal import lfilter, lfiltic

from sysid.errors import IdentificationError, IdentificationWarning
from sysid.greybox import GreyBoxStructure, fit_greybox, greybox_residuals
from tests.tolerances import IDENTITY_RTOL

#: Residuals of the same recursion computed by CasADi and by lfilter: rounding over
#: a few thousand steps of a stable filter.
RECURSION_ATOL = 1e-10
#: Central differences with step 1e-6 on smooth residuals: truncation ~1e-12 relative,
#: cancellation ~1e-10 / 1e-6; the Jacobian columns are O(1..100).
FD_RTOL = 1e-5
FD_ATOL = 1e-6
#: Two least-squares solvers stopping at the same minimum with tolerances ~1e-10
#: agree on the parameters to about sqrt(tol) relative in ill-conditioned directions.
SAME_MINIMUM_RTOL = 1e-5
SAME_MINIMUM_ATOL = 1e-7


def _staircase(rng: np.random.Generator, n: int, hold: int, lo: float, hi: float) -> np.ndarray:
    levels = rng.uniform(lo, hi, size=n // hold + 1)
    return np.repeat(levels, hold)[:n]


def _armax_structure(a1: float, b1: float, b2: float, c1: float) -> GreyBoxStructure:
    """A plain ARMAX(1,2,1) with delay 1 written by hand in observer form."""

    def matrices(p):  # type: ignore[no-untyped-def]
        A = ca.blockcat([[-p["a1"], 1], [0, 0]])
        B = ca.vertcat(p["b1"], p["b2"])
        C = ca.horzcat(1, 0)
        K = ca.vertcat(p["c1"] - p["a1"], 0)
        return A, B, C, None, K

    return GreyBoxStructure(
        parameter_names=("a1", "b1", "b2", "c1"),
        initial_values=(a1, b1, b2, c1),
        matrices=matrices,
        lower=(-0.9999, -np.inf, -np.inf, -0.9999),
        upper=(0.9999, np.inf, np.inf, 0.9999),
        name="armax",
    )


def _two_tank_structure(p1: float, p2: float, g1: float, g2: float) -> GreyBoxStructure:
    """A 2-state physical parameterization: two parallel first-order lags (diagonal A)."""

    def matrices(p):  # type: ignore[no-untyped-def]
        A = ca.diag(ca.vertcat(p["p1"], p["p2"]))
        B = ca.vertcat(p["g1"] * (1 - p["p1"]), p["g2"] * (1 - p["p2"]))
        return A, B, ca.horzcat(1, 1), None, None

    return GreyBoxStructure(
        parameter_names=("p1", "p2", "g1", "g2"),
        initial_values=(p1, p2, g1, g2),
        matrices=matrices,
        lower=(0.0, 0.0, -np.inf, -np.inf),
        upper=(0.999, 0.999, np.inf, np.inf),
        name="two-lags",
    )


def _two_tank_output(u: np.ndarray, p1: float, p2: float, g1: float, g2: float) -> np.ndarray:
    """Reference: sum of two first-order lags g (1-p) q^-1 / (1 - p q^-1), started at rest."""
    out = np.zeros_like(u)
    for p, g in ((p1, g1), (p2, g2)):
        b, a = [0.0, g * (1 - p)], [1.0, -p]
        zi = lfiltic(b, a, [g * u[0]], [u[0]])
        out += lfilter(b, a, u, zi=zi)[0]
    return out


# ----------------------------------------------------------------------- residuals
def test_ballistic_residuals_with_held_past_equal_lfilter(rng: np.random.Generator) -> None:
    u = _staircase(rng, 800, 40, -5, 5)
    y = rng.normal(size=u.size) + 2.0
    a1, b1, b2 = -0.9, 1.2, -0.7
    r = greybox_residuals(_armax_structure(a1, b1, b2, 0.3), y, u)
    b, a = [0.0, b1, b2], [1.0, a1]
    zi = lfiltic(b, a, [y[0]], [u[0], u[0]])  # held past: yhat_{-1} = y0, u_{-j} = u0
    np.testing.assert_allclose(r, y - lfilter(b, a, u, zi=zi)[0], rtol=0, atol=RECURSION_ATOL)


def test_one_step_residuals_with_held_past_equal_lfilter(rng: np.random.Generator) -> None:
    u = _staircase(rng, 800, 40, -5, 5)
    y = rng.normal(size=u.size) + 2.0
    a1, b1, b2, c1 = -0.9, 1.2, -0.7, 0.4
    e = greybox_residuals(_armax_structure(a1, b1, b2, c1), y, u, criterion="one_step")
    # C e = A y - B u with y, u held at their first values and zero past innovations
    v = lfilter([1.0, a1], [1.0], y, zi=[a1 * y[0]])[0] - lfilter(
        [0.0, b1, b2], [1.0], u, zi=lfiltic([0.0, b1, b2], [1.0], [], [u[0], u[0]])
    )[0]
    np.testing.assert_allclose(e, lfilter([1.0], [1.0, c1], v), rtol=0, atol=RECURSION_ATOL)


def test_steady_initial_state_equals_lfilter_started_at_the_models_rest(
    rng: np.random.Generator,
) -> None:
    u = _staircase(rng, 600, 50, -5, 5)
    y = rng.normal(size=u.size)
    a1, b1, b2 = -0.8, 1.0, 0.5
    r = greybox_residuals(_armax_structure(a1, b1, b2, 0.0), y, u, initial_state="steady")
    b, a = [0.0, b1, b2], [1.0, a1]
    rest = u[0] * (b1 + b2) / (1 + a1)
    zi = lfiltic(b, a, [rest], [u[0], u[0]])
    np.testing.assert_allclose(r, y - lfilter(b, a, u, zi=zi)[0], rtol=0, atol=RECURSION_ATOL)


def test_two_state_structure_simulates_like_two_parallel_lags(rng: np.random.Generator) -> None:
    u = _staircase(rng, 1000, 50, 0, 10)
    truth = (0.95, 0.6, 2.0, -0.5)
    y = _two_tank_output(u, *truth)
    r = greybox_residuals(_two_tank_structure(*truth), y, u, initial_state="steady")
    np.testing.assert_allclose(r, np.zeros_like(u), rtol=0, atol=RECURSION_ATOL)


# ----------------------------------------------------------------------- derivatives
@pytest.mark.parametrize("criterion", ["ballistic", "one_step"])
def test_jacobian_is_exact_against_central_differences(
    rng: np.random.Generator, criterion: str
) -> None:
    u = _staircase(rng, 500, 25, -5, 5)
    y = rng.normal(size=u.size)
    theta = np.array([-0.85, 1.1, -0.6, 0.3])
    structure = _armax_structure(*theta)
    result = fit_greybox(structure, y, u, criterion=criterion, max_iterations=1, warn=False)
    # the Jacobian the optimizer holds is at its final point; rebuild it by differences
    final = result.parameters
    jac = result.raw.jacobian  # type: ignore[union-attr]
    h = 1e-6
    fd = np.empty_like(jac)
    values = dict(zip(structure.parameter_names, final, strict=True))
    for j, name in enumerate(structure.parameter_names):
        up = structure.with_initial_values({**values, name: final[j] + h})
        dn = structure.with_initial_values({**values, name: final[j] - h})
        fd[:, j] = (
            greybox_residuals(up, y, u, criterion=criterion)  # type: ignore[arg-type]
            - greybox_residuals(dn, y, u, criterion=criterion)  # type: ignore[arg-type]
        ) / (2 * h)
    np.testing.assert_allclose(jac, fd, rtol=FD_RTOL, atol=FD_ATOL)


# ----------------------------------------------------------------------- fits
def test_armax_fit_matches_a_direct_least_squares_fit(rng: np.random.Generator) -> None:
    n = 3000
    u = _staircase(rng, n, 30, -5, 5)
    a1, b1, b2, c1 = -0.9, 1.0, -0.6, 0.5
    e = 0.1 * rng.standard_normal(n)
    y = lfilter([0.0, b1, b2], [1.0, a1], u) + lfilter([1.0, c1], [1.0, a1], e)
    result = fit_greybox(_armax_structure(-0.5, 0.5, 0.0, 0.0), y, u, criterion="one_step")

    def residuals(theta: np.ndarray) -> np.ndarray:
        ta1, tb1, tb2, tc1 = theta
        v = lfilter([1.0, ta1], [1.0], y, zi=[ta1 * y[0]])[0] - lfilter(
            [0.0, tb1, tb2], [1.0], u, zi=lfiltic([0.0, tb1, tb2], [1.0], [], [u[0], u[0]])
        )[0]
        return lfilter([1.0], [1.0, tc1], v)

    direct = least_squares(residuals, [-0.5, 0.5, 0.0, 0.0], xtol=1e-14, ftol=1e-14, gtol=1e-14)
    assert result.converged
    np.testing.assert_allclose(result.parameters, direct.x, rtol=SAME_MINIMUM_RTOL,
                               atol=SAME_MINIMUM_ATOL)
    np.testing.assert_allclose(result.criterion_value, np.mean(direct.fun**2), rtol=1e-9,
                               atol=0)  # same minimum: equal cost to ~sqrt(eps)^2
    # and the truth lies within 4 standard errors (white innovations: valid errors)
    truth = np.array([a1, b1, b2, c1])
    assert np.all(np.abs(result.parameters - truth) < 4 * result.std_errors)


def test_two_state_fit_recovers_noise_free_truth(rng: np.random.Generator) -> None:
    u = _staircase(rng, 2000, 50, 0, 10)
    truth = np.array([0.95, 0.6, 2.0, -0.5])
    y = _two_tank_output(u, *truth)
    # a start with the poles apart: from symmetric starts the two lags can merge into
    # one (a local minimum of this parameterization, not of the engine)
    result = fit_greybox(_two_tank_structure(0.9, 0.5, 1.5, 0.0), y, u, initial_state="steady")
    assert result.converged
    np.testing.assert_allclose(result.parameters, truth, rtol=1e-7, atol=0)  # noise-free
    assert result.criterion_value < 1e-16


def test_fixed_parameters_stay_fixed_with_zero_standard_error(rng: np.random.Generator) -> None:
    u = _staircase(rng, 1500, 30, -5, 5)
    y = lfilter([0.0, 1.0, -0.6], [1.0, -0.9], u) + 0.05 * rng.standard_normal(u.size)
    structure = _armax_structure(-0.9, 0.5, 0.0, 0.0).with_free(["b1", "b2"])
    result = fit_greybox(structure, y, u)
    assert result.value("a1") == -0.9
    assert result.value("c1") == 0.0
    assert result.std_error("a1") == 0.0
    assert result.std_error("b1") > 0.0
    np.testing.assert_allclose([result.value("b1"), result.value("b2")], [1.0, -0.6],
                               rtol=0, atol=0.02)  # 0.05 kW noise on 1500 samples


def test_bounds_hold_the_estimate_at_the_bound(rng: np.random.Generator) -> None:
    u = _staircase(rng, 1000, 30, -5, 5)
    y = lfilter([0.0, 1.0], [1.0, -0.9], u)
    base = _armax_structure(-0.5, 0.5, 0.0, 0.0).with_free(["a1", "b1"])
    bounded = GreyBoxStructure(
        parameter_names=base.parameter_names, initial_values=base.initial_values,
        matrices=base.matrices, free=base.free, lower=(-0.7, -np.inf, -np.inf, -1.0),
        upper=(0.9, np.inf, np.inf, 1.0),
    )
    result = fit_greybox(bounded, y, u)
    assert result.value("a1") == -0.7


def test_estimated_initial_state_beats_held_past_on_a_record_not_at_rest(
    rng: np.random.Generator,
) -> None:
    u = _staircase(rng, 1500, 50, -5, 5)
    # the record starts in the middle of a transient: 10 kW above where the past implies
    y = lfilter([0.0, 1.0, -0.6], [1.0, -0.95], u, zi=[10.0, 0.0])[0]
    structure = _armax_structure(-0.5, 0.5, 0.0, 0.0).with_free(["a1", "b1", "b2"])
    held = fit_greybox(structure, y, u)
    est = fit_greybox(structure, y, u, initial_state="estimate")
    assert est.criterion_value < 1e-12 < held.criterion_value
    assert est.initial_state.shape == (2,)


def test_non_converging_search_says_so_and_keeps_its_best_iterate(
    rng: np.random.Generator,
) -> None:
    u = _staircase(rng, 1000, 30, -5, 5)
    y = lfilter([0.0, 1.0, -0.6], [1.0, -0.9], u) + 0.05 * rng.standard_normal(u.size)
    structure = _armax_structure(0.0, 0.0, 0.0, 0.0)
    start_cost = float(np.mean(greybox_residuals(structure, y, u) ** 2))
    with pytest.warns(IdentificationWarning, match="did not converge"):
        result = fit_greybox(structure, y, u, max_iterations=1)
    assert not result.converged
    assert result.n_iterations == 1
    assert result.criterion_value < start_cost
    np.testing.assert_allclose(
        result.criterion_value,
        np.mean(greybox_residuals(structure.with_initial_values(result.as_dict()), y, u) ** 2),
        rtol=IDENTITY_RTOL, atol=0,
    )


# ----------------------------------------------------------------------- errors
def test_malformed_options_raise_identification_error(rng: np.random.Generator) -> None:
    u = _staircase(rng, 200, 20, -5, 5)
    y = rng.normal(size=u.size)
    s = _armax_structure(-0.5, 1.0, 0.0, 0.0)
    with pytest.raises(IdentificationError, match="criterion must be"):
        fit_greybox(s, y, u, criterion="simulation")  # type: ignore[arg-type]
    with pytest.raises(IdentificationError, match="initial_state must be"):
        fit_greybox(s, y, u, initial_state="zero")  # type: ignore[arg-type]
    with pytest.raises(IdentificationError, match="max_iterations"):
        fit_greybox(s, y, u, max_iterations=0)
    with pytest.raises(IdentificationError, match="xtol"):
        fit_greybox(s, y, u, xtol=-1.0)


def test_bad_signals_raise_identification_error(rng: np.random.Generator) -> None:
    u = _staircase(rng, 200, 20, -5, 5)
    y = rng.normal(size=u.size)
    s = _armax_structure(-0.5, 1.0, 0.0, 0.0)
    with pytest.raises(IdentificationError, match="u must have shape"):
        fit_greybox(s, y, u[:-1])
    bad = y.copy()
    bad[7] = np.nan
    with pytest.raises(IdentificationError, match="finite"):
        fit_greybox(s, bad, u)
    with pytest.raises(IdentificationError, match="more samples than free parameters"):
        fit_greybox(s, y[:4], u[:4])
    with pytest.raises(IdentificationError, match="input never changes"):
        fit_greybox(s, y, np.full_like(u, 3.0))


def test_malformed_structures_raise_identification_error() -> None:
    def mats(p):  # type: ignore[no-untyped-def]
        return ca.reshape(p["a"], 1, 1), ca.DM.ones(1, 1), ca.DM.ones(1, 1), None, None

    with pytest.raises(IdentificationError, match="unique"):
        GreyBoxStructure(parameter_names=("a", "a"), initial_values=(0, 0), matrices=mats)
    with pytest.raises(IdentificationError, match="one entry per parameter"):
        GreyBoxStructure(parameter_names=("a",), initial_values=(0, 0), matrices=mats)
    with pytest.raises(IdentificationError, match="lower < upper"):
        GreyBoxStructure(parameter_names=("a",), initial_values=(0,), matrices=mats,
                         lower=(1.0,), upper=(0.0,))
    with pytest.raises(IdentificationError, match="must lie in"):
        GreyBoxStructure(parameter_names=("a",), initial_values=(2.0,), matrices=mats,
                         upper=(1.0,))
    with pytest.raises(IdentificationError, match="unknown parameter"):
        GreyBoxStructure(parameter_names=("a",), initial_values=(0,),
                         matrices=mats).with_initial_values({"b": 1.0})

    def wrong_b(p):  # type: ignore[no-untyped-def]
        return ca.reshape(p["a"], 1, 1), ca.DM.ones(2, 1), ca.DM.ones(1, 1), None, None

    s = GreyBoxStructure(parameter_names=("a",), initial_values=(0.5,), matrices=wrong_b)
    u = np.repeat([0.0, 1.0, -1.0], 10)
    with pytest.raises(IdentificationError, match="B of shape"):
        fit_greybox(s, np.zeros(u.size), u)
