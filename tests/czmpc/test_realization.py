"""Innovations-form realization and disturbance augmentation against lfilter and PBH."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from czmpc.errors import DesignError
from czmpc.realization import augment, check_detectable, innovations_form
from sysid.model import HammersteinModel

#: State-space recursion vs lfilter: the same linear recursion summed in another
#: order; 300 samples of a pole at 0.99 accumulate a few hundred ulps of |y| <= 1e3.
LFILTER_ATOL_KW = 1e-9


@pytest.fixture(scope="session")
def high_order_model(paper_armax_model: HammersteinModel) -> HammersteinModel:
    # na = 3, delay nk = 2, nb = 4 (B = q^-2 + 0.3 q^-3 - 0.5 q^-4), nc = 2.
    return paper_armax_model.with_updates(
        a=[1.0, -1.2, 0.5, -0.1], b=[0.0, 0.0, 1.0, 0.3, -0.5], c=[1.0, -0.4, 0.1],
    )


def _simulate(A: np.ndarray, B: np.ndarray, C: np.ndarray, K: np.ndarray,
              w: np.ndarray, e: np.ndarray) -> np.ndarray:
    x = np.zeros(B.size)
    y = np.empty(w.size)
    for k in range(w.size):
        y[k] = C @ x + e[k]
        x = A @ x + B * w[k] + K * e[k]
    return y


@pytest.mark.parametrize("which", ["oe", "armax", "high_order"])
def test_innovations_form_reproduces_the_polynomial_model(
    which: str, request: pytest.FixtureRequest, rng: np.random.Generator
) -> None:
    fixture = {"oe": "paper_oe_model", "armax": "paper_armax_model",
               "high_order": "high_order_model"}[which]
    model: HammersteinModel = request.getfixturevalue(fixture)
    ss = innovations_form(model)
    w = rng.standard_normal(300)
    e = rng.standard_normal(300)
    reference = lfilter(model.b, model.a, w) + lfilter(model.c, model.a, e)
    np.testing.assert_allclose(_simulate(ss.A, ss.B, ss.C, ss.K, w, e), reference,
                               rtol=0.0, atol=LFILTER_ATOL_KW)


def test_delay_becomes_states(high_order_model: HammersteinModel) -> None:
    ss = innovations_form(high_order_model)
    assert ss.n_states == 4  # max(na, nb, nc) with nb counting B's two leading zeros
    assert ss.B[0] == 0.0  # the extra sample of delay


def test_oe_model_has_zero_innovation_gain(paper_oe_model: HammersteinModel) -> None:
    # OE is stored with C = A, so K = c - a = 0: the noise is white on the output.
    assert not np.any(innovations_form(paper_oe_model).K)


def test_static_gain_is_b_over_a_at_one(paper_armax_model: HammersteinModel) -> None:
    ss = innovations_form(paper_armax_model)
    assert ss.static_gain == pytest.approx(paper_armax_model.linear_static_gain, rel=1e-12)


def test_model_without_delay_is_a_design_error(paper_oe_model: HammersteinModel) -> None:
    direct = paper_oe_model.with_updates(b=[1.0, -0.991])
    with pytest.raises(DesignError, match=r"at least one sample of input delay.*b = \[1\.0"):
        innovations_form(direct)


@pytest.mark.parametrize("disturbance_model", ["input", "output"])
def test_augmented_disturbance_has_unit_steady_effect_where_placed(
    disturbance_model: str, paper_armax_model: HammersteinModel
) -> None:
    aug = augment(innovations_form(paper_armax_model), disturbance_model)  # type: ignore[arg-type]
    n = aug.n_states
    # Steady state of z+ = A z with d = 1 held: x solves (I - A_xx) x = A_xd.
    x = np.linalg.solve(np.eye(n - 1) - aug.A[:-1, :-1], aug.A[:-1, -1])
    y = aug.C[:-1] @ x + aug.C[-1]
    assert y == pytest.approx(aug.disturbance_power_gain, rel=1e-12)
    assert aug.A[-1, -1] == 1.0 and aug.K[-1] == 0.0 and aug.B[-1] == 0.0


def test_input_disturbance_with_a_zero_of_b_at_one_is_not_detectable(
    paper_oe_model: HammersteinModel,
) -> None:
    differentiator = paper_oe_model.with_updates(b=[0.0, 1.0, -1.0])  # B(1) = 0
    base = innovations_form(differentiator)
    with pytest.raises(DesignError, match=r"must be detectable.*z = 1.*B\(1\) = 0"):
        augment(base, "input")
    augment(base, "output")  # an output disturbance is still seen


def test_check_detectable_accepts_stable_unobservable_modes() -> None:
    A = np.diag([0.5, 1.0])
    check_detectable(A, np.array([0.0, 1.0]), what="test")  # only z = 0.5 hidden
    with pytest.raises(DesignError, match="test: the augmented pair"):
        check_detectable(A, np.array([1.0, 0.0]), what="test")
