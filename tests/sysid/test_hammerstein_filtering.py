"""Filter kernels of the Hammerstein fits: residuals against the CasADi grey-box, exact Jacobians."""

from __future__ import annotations

import numpy as np
import pytest

from sysid.greybox import greybox_residuals
from sysid.hammerstein import fit_hammerstein_oe, hammerstein_armax_structure, hammerstein_oe_structure
from sysid.hammerstein.filtering import (
    HammersteinOrders,
    estimate_transients,
    mean_square_criterion,
    segment_residuals,
)

#: Same recursion by CasADi (state space) and lfilter (direct form): rounding only.
RECURSION_ATOL = 1e-12
#: Central differences with step 1e-6 on residuals of order 1: truncation ~1e-12,
#: rounding ~1e-10.
JACOBIAN_ATOL = 1e-7


def _record(rng: np.random.Generator, n: int = 300) -> tuple[np.ndarray, np.ndarray]:
    ds = np.repeat(rng.uniform(-5.0, 5.0, n // 10), 10)
    return rng.standard_normal(n) + 3.0, ds


@pytest.mark.parametrize("block", ["oe", "armax"])
def test_held_residuals_equal_the_greybox_simulator(block: str, rng: np.random.Generator) -> None:
    y, ds = _record(rng)
    orders = HammersteinOrders(block=block, degree=2, nb=3, na=2, nc=1, nk=2)  # type: ignore[arg-type]
    start = dict(zip(orders.parameter_names(), rng.uniform(-0.3, 0.3, orders.n_model), strict=True))
    if block == "oe":
        structure = hammerstein_oe_structure(degree=2, nb=3, nf=2, nk=2, initial_values=start)
    else:
        structure = hammerstein_armax_structure(degree=2, na=2, nb=3, nc=1, nk=2,
                                                initial_values=start)
    theta = np.array(structure.initial_values)
    reference = greybox_residuals(structure, y, ds,
                                  criterion="ballistic" if block == "oe" else "one_step")
    r, _ = segment_residuals(orders, theta, [(y, ds)], "held")
    np.testing.assert_allclose(r, reference, rtol=0, atol=RECURSION_ATOL)


@pytest.mark.parametrize("block", ["oe", "armax"])
@pytest.mark.parametrize("policy", ["held", "zero", "estimate"])
@pytest.mark.parametrize("n_segments", [1, 2, 3])
def test_jacobian_equals_central_differences_over_one_two_and_three_segments(
    block: str, policy: str, n_segments: int, rng: np.random.Generator,
) -> None:
    y, ds = _record(rng)
    orders = HammersteinOrders(block=block, degree=2, nb=3, na=2, nc=1, nk=2)  # type: ignore[arg-type]
    theta = rng.uniform(-0.3, 0.3, orders.n_model)
    if policy == "estimate":
        theta = np.concatenate([theta, rng.standard_normal(n_segments * orders.n_state)])
    # Three: a segment of 3 samples, shorter than the longest input lag (nk + nb - 1 = 4),
    # as a plant link that loses samples under load leaves between gaps; its Jacobian
    # raised a broadcast error (the commissioning gallery example, 2026-11-29).
    segments = ([(y, ds)] if n_segments == 1
                else [(y[:150], ds[:150]), (y[150:], ds[150:])] if n_segments == 2
                else [(y[:150], ds[:150]), (y[150:153], ds[150:153]), (y[153:], ds[153:])])
    r, jac = segment_residuals(orders, theta, segments, policy)  # type: ignore[arg-type]
    assert jac is not None and jac.shape == (y.size, theta.size)
    numeric = np.empty_like(jac)
    for i in range(theta.size):
        up, down = theta.copy(), theta.copy()
        up[i] += 1e-6
        down[i] -= 1e-6
        numeric[:, i] = (
            segment_residuals(orders, up, segments, policy, jacobian=False)[0]  # type: ignore[arg-type]
            - segment_residuals(orders, down, segments, policy, jacobian=False)[0]  # type: ignore[arg-type]
        ) / 2e-6
    np.testing.assert_allclose(jac, numeric, rtol=0, atol=JACOBIAN_ATOL)


def test_estimated_initial_state_recovers_a_record_that_does_not_start_at_rest(
    rng: np.random.Generator,
) -> None:
    # truth: y = (1 - 0.5 q^-1) q^-1 / (1 - 0.95 q^-1) f(ds), started far from rest
    from scipy.signal import lfilter, lfiltic
    ds = np.repeat(rng.uniform(-8.0, 8.0, 60), 40)
    w = 1.1 * ds - 0.02 * ds**2
    b, f = [0.0, 1.0, -0.5], [1.0, -0.95]
    y = lfilter(b, f, w, zi=lfiltic(b, f, [30.0], [0.0, 0.0]))[0]
    held = fit_hammerstein_oe(y, ds, initial_state="held", initial={"d1": 1.0, "f1": -0.9})
    est = fit_hammerstein_oe(y, ds, initial_state="estimate", initial={"d1": 1.0, "f1": -0.9})
    truth = {"b2": -0.5, "d1": 1.1, "d2": -0.02, "f1": -0.95}
    for name, value in truth.items():
        np.testing.assert_allclose(est.values()[name], value, rtol=1e-6)
    assert held.cost > 1e3 * max(est.cost, 1e-20)
    orders = HammersteinOrders(block="oe", degree=2, nb=2, na=1, nc=0, nk=1)
    theta = np.array([truth[n] for n in orders.parameter_names()])
    assert mean_square_criterion(orders, theta, [(y, ds)], "estimate") < 1e-18
    assert estimate_transients(orders, theta, [(y, ds)]).shape == (orders.n_state,)
