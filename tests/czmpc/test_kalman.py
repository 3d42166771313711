"""Steady-state Kalman estimator: DARE gains, and updates against a reference filter."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from czmpc.errors import DesignError
from czmpc.kalman import (
    design_estimator,
    measurement_update,
    noise_covariances,
    steady_state_kalman,
    time_update,
)
from czmpc.realization import augment, innovations_form
from sysid.model import HammersteinModel

#: Two DARE solutions (scipy's Schur method vs our call of it, or vs 5000 Riccati
#: iterations with contraction <= 0.99 per step) agree to round-off of O(1) entries.
DARE_ATOL = 1e-9
#: Filter recursions with the same gains in two algebraic arrangements.
FILTER_ATOL_KW = 1e-10


def _high_order(model: HammersteinModel) -> HammersteinModel:
    return model.with_updates(a=[1.0, -1.2, 0.5, -0.1], b=[0.0, 0.0, 1.0, 0.3, -0.5],
                              c=[1.0, -0.4, 0.1])


@pytest.mark.parametrize("which", ["oe", "armax", "high_order"])
def test_without_augmentation_the_kalman_gain_equals_k(
    which: str, paper_oe_model: HammersteinModel, paper_armax_model: HammersteinModel
) -> None:
    model = {"oe": paper_oe_model, "armax": paper_armax_model,
             "high_order": _high_order(paper_armax_model)}[which]
    ss = innovations_form(model)
    s2 = model.noise_std_kw**2
    Q, S, R = s2 * np.outer(ss.K, ss.K), s2 * ss.K, s2
    # Independent reference: scipy's DARE with the cross term, gain written out here.
    n = ss.n_states
    P = scipy.linalg.solve_discrete_are(ss.A.T, ss.C.reshape(n, 1), Q, np.array([[R]]),
                                        s=S.reshape(n, 1))
    L_ref = (ss.A @ P @ ss.C + S) / (ss.C @ P @ ss.C + R)
    np.testing.assert_allclose(L_ref, ss.K, rtol=0.0, atol=DARE_ATOL)
    kf = steady_state_kalman(ss.A, ss.C, Q, R, S)
    np.testing.assert_allclose(kf.L, ss.K, rtol=0.0, atol=DARE_ATOL)
    np.testing.assert_allclose(kf.P, 0.0, rtol=0.0, atol=DARE_ATOL * s2)


@pytest.mark.parametrize("disturbance_model", ["input", "output"])
def test_augmented_gains_are_the_limit_of_the_riccati_recursion(
    disturbance_model: str, paper_armax_model: HammersteinModel
) -> None:
    aug = augment(innovations_form(paper_armax_model), disturbance_model)  # type: ignore[arg-type]
    Q, R, S = noise_covariances(aug, 0.1)
    kf = design_estimator(aug, 0.1)
    A, C = aug.A, aug.C
    P = np.eye(aug.n_states)
    for _ in range(5000):  # time-varying filter Riccati recursion with correlated noise
        re = C @ P @ C + R
        gain = (A @ P @ C + S) / re
        P = A @ P @ A.T + Q - np.outer(gain, gain) * re
    np.testing.assert_allclose(kf.P, P, rtol=0.0, atol=DARE_ATOL)
    re = C @ P @ C + R
    np.testing.assert_allclose(kf.L, (A @ P @ C + S) / re, rtol=0.0, atol=DARE_ATOL)
    np.testing.assert_allclose(kf.L, A @ kf.M + kf.G, rtol=0.0, atol=DARE_ATOL)
    assert kf.M[-1] > 0.0  # the disturbance is corrected by every innovation


def test_measurement_and_time_updates_equal_the_one_step_predictor(
    paper_armax_model: HammersteinModel, rng: np.random.Generator
) -> None:
    aug = augment(innovations_form(paper_armax_model), "output")
    kf = design_estimator(aug, 0.1)
    A, B, C = aug.A, aug.B, aug.C
    z = np.zeros(aug.n_states)
    z_ref = np.zeros(aug.n_states)
    for _ in range(200):
        y, w = float(rng.normal()), float(rng.normal())
        z_filt, eps = measurement_update(z, y, C, kf.M)
        z = time_update(z_filt, w, eps, A, B, kf.G)
        z_ref = A @ z_ref + B * w + kf.L * (y - C @ z_ref)  # textbook predictor form
        np.testing.assert_allclose(z, z_ref, rtol=0.0, atol=FILTER_ATOL_KW)


def test_dare_without_stabilizing_solution_is_a_design_error() -> None:
    A = np.diag([1.1, 0.5])  # unstable mode invisible in C: no stabilizing solution
    with pytest.raises(DesignError, match="filter DARE must have a stabilizing solution"):
        steady_state_kalman(A, np.array([0.0, 1.0]), np.eye(2), 1.0, np.zeros(2))
