"""Steady-state Kalman estimator: DARE gains, and the Estimator against a reference filter."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from czmpc.errors import DesignError
from czmpc.kalman import (
    MAX_INNOVATION_KW,
    Estimator,
    design_estimator,
    noise_covariances,
    steady_state_kalman,
)
from czmpc.realization import AugmentedModel, augment, innovations_form
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


def _reference_gains(aug: AugmentedModel, rho: float) -> tuple[np.ndarray, np.ndarray]:
    """``(M, L)`` written out from scipy's DARE with the cross term (independent of kalman.py)."""
    n = aug.n_states
    K = aug.K
    Q = np.outer(K, K)
    Q[n - 1, n - 1] += rho
    P = scipy.linalg.solve_discrete_are(aug.A.T, aug.C.reshape(n, 1), Q, np.array([[1.0]]),
                                        s=K.reshape(n, 1))
    re = aug.C @ P @ aug.C + 1.0
    return P @ aug.C / re, (aug.A @ P @ aug.C + K) / re


@pytest.mark.parametrize("disturbance_model", ["input", "output"])
def test_estimator_equals_a_hand_written_kalman_recursion_with_missing_samples(
    disturbance_model: str, paper_armax_model: HammersteinModel, rng: np.random.Generator
) -> None:
    aug = augment(innovations_form(paper_armax_model), disturbance_model)  # type: ignore[arg-type]
    M, L = _reference_gains(aug, 0.1)
    est = Estimator(aug, 0.1, noise_std_kw=1.0)
    A, B, C = aug.A, aug.B, aug.C
    z_ref = np.zeros(aug.n_states)  # z_{k|k-1}
    for k in range(200):
        y, w = float(rng.normal()), float(rng.normal())
        missing = k % 9 == 4
        assert est.predicted_output == pytest.approx(C @ z_ref, abs=FILTER_ATOL_KW)
        if missing:
            est.skip()
            eps = 0.0
        else:
            assert est.update(y)
            eps = y - C @ z_ref
        np.testing.assert_allclose(est.z, z_ref + M * eps, rtol=0.0, atol=FILTER_ATOL_KW)
        assert est.eps == pytest.approx(eps, abs=FILTER_ATOL_KW)
        assert est.gap == (1 if missing else 0)
        est.predict(w)
        z_ref = A @ z_ref + B * w + L * eps  # textbook one-step predictor
        np.testing.assert_allclose(est.z, z_ref, rtol=0.0, atol=FILTER_ATOL_KW)


def test_every_state_handed_out_stays_read_only_and_unchanged(
    paper_armax_model: HammersteinModel, rng: np.random.Generator
) -> None:
    # The estimator makes z read-only when it first hands it out (not when it makes it).
    aug = augment(innovations_form(paper_armax_model), "input")
    est = Estimator(aug, 0.1, noise_std_kw=1.0, history_samples=5)
    kept = []
    for k in range(12):
        if k % 4 == 3:
            est.skip()
        else:
            est.update(float(rng.normal()))
        z = est.z
        assert not z.flags.writeable
        kept.append((z, z.copy()))
        est.predict(float(rng.normal()))
        if k == 6:
            est.correct_input(0.0, 0.5)
    assert est.roll_back(2) == 2
    assert not est.z.flags.writeable
    for z, value in kept:
        np.testing.assert_array_equal(z, value)


def test_roll_back_predicts_as_if_the_undone_samples_were_skipped(
    paper_armax_model: HammersteinModel, rng: np.random.Generator
) -> None:
    aug = augment(innovations_form(paper_armax_model), "input")
    est = Estimator(aug, 0.1, noise_std_kw=1.0, history_samples=20)
    ref = Estimator(aug, 0.1, noise_std_kw=1.0, history_samples=20)
    ys, ws = rng.normal(size=15), rng.normal(size=15)
    for k in range(15):
        est.update(float(ys[k]))
        if k < 10:  # the reference never sees the last 5 readings
            ref.update(float(ys[k]))
        else:
            ref.skip()
        est.predict(float(ws[k]))
        ref.predict(float(ws[k]))
    assert est.roll_back(5) == 5
    np.testing.assert_allclose(est.z, ref.z, rtol=0.0, atol=FILTER_ATOL_KW)
    assert est.gap == 5 and est.predicted_output == pytest.approx(float(aug.C @ ref.z), abs=1e-12)
    assert est.roll_back(100) == 15 - 1  # as far as the trace reaches: before its first update


def test_correct_input_moves_the_prediction_by_b_times_the_difference(
    paper_oe_model: HammersteinModel
) -> None:
    aug = augment(innovations_form(paper_oe_model), "input")
    est = Estimator(aug, 0.1, noise_std_kw=1.0)
    est.update(0.3)
    est.predict(1.0)
    z_assumed = est.z.copy()
    est.correct_input(1.0, 2.5)
    np.testing.assert_allclose(est.z, z_assumed + aug.B * 1.5, rtol=0.0, atol=FILTER_ATOL_KW)
    assert est.predicted_output == pytest.approx(float(aug.C @ est.z), abs=1e-12)


def test_absurd_innovation_is_skipped_and_innovation_std_grows_with_the_gap(
    paper_armax_model: HammersteinModel
) -> None:
    aug = augment(innovations_form(paper_armax_model), "output")
    sigma = 0.02
    est = Estimator(aug, 0.1, noise_std_kw=sigma, max_gap=3)
    kf = est.gains
    z0 = est.z.copy()
    assert not est.update(2 * MAX_INNOVATION_KW) and not est.update(float("nan"))
    np.testing.assert_array_equal(est.z, z0)
    assert est.gap == 2 and est.eps == 0.0
    # Reference: P_m = A P_{m-1} A^T + Q from the stationary P; std = sigma sqrt(C P_m C + R).
    Q, R, _ = noise_covariances(aug, 0.1)
    P = kf.P @ np.eye(aug.n_states)
    for _ in range(2):
        P = aug.A @ P @ aug.A.T + Q
    assert est.innovation_std_kw == pytest.approx(sigma * np.sqrt(aug.C @ P @ aug.C + R), rel=1e-12)
    assert est.sigma_kw == pytest.approx(sigma * np.sqrt(kf.innovation_variance), rel=1e-12)
    for _ in range(5):
        est.skip()
    P = aug.A @ P @ aug.A.T + Q  # gap 3 is the last tabulated
    assert est.innovation_std_kw == pytest.approx(sigma * np.sqrt(aug.C @ P @ aug.C + R), rel=1e-12)


def test_dare_without_stabilizing_solution_is_a_design_error() -> None:
    A = np.diag([1.1, 0.5])  # unstable mode invisible in C: no stabilizing solution
    with pytest.raises(DesignError, match="filter DARE must have a stabilizing solution"):
        steady_state_kalman(A, np.array([0.0, 1.0]), np.eye(2), 1.0, np.zeros(2))
