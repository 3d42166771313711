"""sysid.identifiability: each check against an independent reference or a known truth."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
from scipy import stats
from scipy.signal import lfilter

from sysid.data import Dataset
from sysid.errors import IdentificationError
from sysid.hammerstein import fit_hammerstein_oe, hammerstein_model
from sysid.identifiability import (
    GAIN_Z_MIN,
    INFORMATION_P_VALUE,
    SAMPLES_PER_PARAMETER,
    IdentifiabilityAssessment,
    UnidentifiableDataError,
    assess_data,
    assess_model,
    input_information_test,
    input_std_ratio,
    persistent_excitation_order,
    pole_nearest_one,
    static_gain,
    structure_before_fit,
)
from sysid.model import HammersteinModel, OperatingPoint, Provenance
from tests.tolerances import DELTA_METHOD_STD_RTOL, F_TEST_SIZE_ATOL, IDENTITY_RTOL

OP = OperatingPoint(triac_pct=45.0, power_kw=45.0)


def _log(s: np.ndarray, y: np.ndarray) -> Dataset:
    return Dataset(time_s=2.0 * np.arange(s.size), triac_pct=s, power_kw=45.0 + y, ts_s=2.0)


def _steps(n: int, rng: np.random.Generator, hold: int = 40) -> np.ndarray:
    return 45.0 + np.repeat(rng.uniform(-10.0, 10.0, n // hold + 1), hold)[:n]


def _model(a: list[float], b: list[float], poly: list[float], cov: np.ndarray | None,
           names: tuple[str, ...], block: str = "oe") -> HammersteinModel:
    return HammersteinModel(
        kind="hammerstein", linear_block=block, ts_s=2.0, operating_point=OP,  # type: ignore[arg-type]
        a=a, b=b, c=a, input_poly=poly, noise_std_kw=0.1, input_range_pct=(35.0, 55.0),
        covariance=None if cov is None else tuple(tuple(r) for r in cov),
        provenance=Provenance(extra={"parameter_names": list(names)}))


# --------------------------------------------------------------------------- excitation
def test_persistent_excitation_order_of_known_signals() -> None:
    rng = np.random.default_rng(1)
    k = np.arange(2000)
    assert persistent_excitation_order([np.full(500, 45.0)], 4) == 0
    # a sinusoid (whole periods, so centring removes no constant) obeys a 2nd-order
    # recurrence: PE of order exactly 2 (Ljung, ch. 13)
    assert persistent_excitation_order([np.sin(2 * np.pi * 50 * k / k.size)], 5) == 2
    assert persistent_excitation_order([rng.standard_normal(2000)], 6) == 6
    # two segments, each constant at its own level: order 1 inside segments, no edge effect
    assert persistent_excitation_order([np.full(100, 1.0), np.full(100, 3.0)], 3) == 1
    with pytest.raises(IdentificationError, match="max_order"):
        persistent_excitation_order([k.astype(float)], 0)


def test_input_std_ratio_is_zero_for_a_constant_input_and_ignores_nan() -> None:
    assert input_std_ratio(np.full(10, 45.0)) == 0.0
    s = np.array([40.0, 50.0, np.nan, 40.0, 50.0])
    assert math.isclose(input_std_ratio(s), 5.0 / 50.0, rel_tol=IDENTITY_RTOL)


@pytest.mark.parametrize(
    ("case", "refused"),
    [("constant", ["input_excitation", "input_levels", "persistent_excitation"]),
     ("dither", ["input_excitation"]), ("twenty_samples", ["samples_per_parameter"])],
)
def test_assess_data_refuses_logs_without_information(case: str, refused: list[str]) -> None:
    rng = np.random.default_rng(2)
    n = 20 if case == "twenty_samples" else 400
    if case == "constant":
        s = np.full(n, 45.0)
    elif case == "dither":                       # 0.01 % of scale: noise, not excitation
        s = 45.0 + 0.0045 * rng.standard_normal(n)
    else:
        s = _steps(n, rng, hold=5)
    data = _log(s, rng.standard_normal(n))
    degree, nb, n_par, what = structure_before_fit("paper")
    judged = assess_data(data, degree=degree, nb=nb, n_parameters=n_par, what=what)
    assert [c.name for c in judged.refusals] == refused
    assert not judged.is_identifiable
    for check in refused:
        failed = judged.check(check)
        assert failed.measured < failed.threshold
    if case == "twenty_samples":
        assert (failed.measured, failed.threshold) == (20.0, SAMPLES_PER_PARAMETER * 5.0)


def test_two_levels_warn_for_the_polynomial_but_support_a_linear_model() -> None:
    """A square wave between two levels identifies a linear model (the pipeline falls back
    to one) but not a quadratic f: a warning, not a refusal."""
    rng = np.random.default_rng(2)
    s = np.where(np.arange(400) % 80 < 40, 40.0, 50.0)
    data = _log(s, rng.standard_normal(400))
    degree, nb, n_par, what = structure_before_fit("paper")
    judged = assess_data(data, degree=degree, nb=nb, n_parameters=n_par, what=what)
    assert not judged.refusals
    assert judged.is_identifiable
    levels = judged.check("input_levels")
    assert not levels.passed and levels.severity == "warning"
    assert (levels.measured, levels.threshold) == (2.0, 3.0)
    assert "model written is of lower order" in levels.message


def test_as_many_levels_as_the_degree_fit_f_exactly_and_the_warning_says_so() -> None:
    """A square wave between 40 and 50 % about an operating point of 45 %: two levels away
    from it, so a quadratic f is fitted (not dropped to a lower order, as the warning used
    to say), drawn exactly through them."""
    rng = np.random.default_rng(2)
    s = np.where(np.arange(400) % 80 < 40, 40.0, 50.0)
    ds = s - OP.triac_pct
    y = lfilter([0.0, 0.2], [1.0, -0.8], 0.5 * ds + 0.01 * ds**2)
    y = y + 0.01 * rng.standard_normal(y.size)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_hammerstein_oe(y, ds, degree=2, nb=1, nf=1, nk=1)
    model = hammerstein_model(fit, _log(s, y), operating_point=OP)
    assert model.input_degree == 2
    levels = assess_model(model, _log(s, y)).check("input_levels")
    assert not levels.passed and levels.severity == "warning"
    assert "a degree-2 f is at best drawn exactly through these levels" in levels.message


def test_structure_before_fit_counts_the_parameters_of_each_orders_option() -> None:
    assert structure_before_fit("paper")[:3] == (2, 2, 5)          # b2, d1, d2, a1, k1
    assert structure_before_fit("auto")[:3] == (1, 1, 3)           # d1, a1, k1
    assert structure_before_fit((4, 3, 2))[:3] == (2, 4, 3 + 2 + 3 + 3)
    assert structure_before_fit((2, 1, 1, 2))[:3] == (2, 2, 1 + 2 + 1 + 2)
    with pytest.raises(IdentificationError, match="orders"):
        structure_before_fit("best")


def test_unidentifiable_error_lists_every_refusal() -> None:
    data = _log(np.full(20, 45.0), np.zeros(20))
    judged = assess_data(data, degree=2, nb=2, n_parameters=5)
    err = UnidentifiableDataError(judged)
    assert isinstance(err, IdentificationError)
    assert {c.name for c in judged.refusals} == {
        "input_excitation", "input_levels", "persistent_excitation", "samples_per_parameter"}
    for c in judged.refusals:
        assert c.message in str(err)


# --------------------------------------------------------------------------- F-test
def test_f_test_matches_scipy_on_a_hand_built_regression() -> None:
    rng = np.random.default_rng(3)
    n = 300
    s = _steps(n, rng)
    y = 0.05 * (s - 45.0) + rng.standard_normal(n)
    f_stat, p_value = input_information_test(_log(s, y), degree=1, na=1, nb=1, nk=1,
                                             operating_triac_pct=45.0)
    # reference: the same nested regressions by hand, scipy's F distribution
    yy = 45.0 + y
    target, lag_y, lag_u = yy[1:], yy[:-1], (s - 45.0)[:-1]
    restricted = np.column_stack([np.ones(n - 1), lag_y])
    full = np.column_stack([restricted, lag_u])
    rss = [float(np.sum((target - m @ np.linalg.lstsq(m, target, rcond=None)[0]) ** 2))
           for m in (restricted, full)]
    f_ref = (rss[0] - rss[1]) / (rss[1] / (n - 1 - 3))
    np.testing.assert_allclose(f_stat, f_ref, rtol=1e-9)
    np.testing.assert_allclose(p_value, stats.f.sf(f_ref, 1, n - 4), rtol=1e-9)


@pytest.mark.slow
def test_f_test_has_its_nominal_size_on_output_unrelated_to_the_input() -> None:
    rng = np.random.default_rng(4)
    p_values = []
    for _ in range(400):
        s = _steps(300, rng)
        y = lfilter([1.0], [1.0, -0.8], rng.standard_normal(300))   # AR(1): one output lag
        p_values.append(input_information_test(_log(s, y), degree=2, na=1, nb=2, nk=1)[1])
    share = float(np.mean(np.array(p_values) < 0.1))
    assert abs(share - 0.1) <= F_TEST_SIZE_ATOL, share


# --------------------------------------------------------------------------- delta method
def test_static_gain_gradient_matches_finite_differences_of_the_steady_state_map() -> None:
    names = ("b2", "d1", "d2", "f1")
    theta = np.array([-0.8, 1.3, -0.01, -0.9])
    cov = np.diag([1e-4, 4e-4, 1e-7, 1e-5]) + 1e-6 * (np.ones((4, 4)) - np.eye(4))

    def gain_of(t: np.ndarray) -> float:
        m = _model([1.0, t[3]], [0.0, 1.0, t[0]], [t[1], t[2]], None, names)
        p = m.steady_state_power_kw(np.array(m.input_range_pct))
        return float((p[1] - p[0]) / (m.input_range_pct[1] - m.input_range_pct[0]))

    model = _model([1.0, theta[3]], [0.0, 1.0, theta[0]], list(theta[1:3]), cov, names)
    gain, std = static_gain(model)
    assert math.isclose(gain, gain_of(theta), rel_tol=1e-12)
    grad = np.array([(gain_of(theta + h) - gain_of(theta - h)) / (2 * h[i])
                     for i, h in enumerate(1e-6 * np.eye(4) * np.maximum(abs(theta), 1e-3))])
    np.testing.assert_allclose(std, math.sqrt(grad @ cov @ grad), rtol=1e-6)


def test_pole_std_matches_finite_differences_of_numpy_roots() -> None:
    names = ("b2", "d1", "f1", "f2")
    theta = np.array([0.5, 1.0, -1.5, 0.56])                    # poles 0.7 and 0.8
    cov = np.diag([1e-4, 1e-4, 2e-5, 1e-5])
    model = _model([1.0, *theta[2:]], [0.0, 1.0, theta[0]], [theta[1]], cov, names)
    pole, std = pole_nearest_one(model)
    assert math.isclose(pole.real, 0.8, rel_tol=1e-9)

    def distance(f: np.ndarray) -> float:
        return float(np.min(np.abs(1.0 - np.roots([1.0, *f]))))

    grad = np.zeros(4)
    for i in (2, 3):
        h = np.zeros(2)
        h[i - 2] = 1e-7
        grad[i] = (distance(theta[2:] + h) - distance(theta[2:] - h)) / 2e-7
    np.testing.assert_allclose(std, math.sqrt(grad @ cov @ grad), rtol=1e-5)


@pytest.mark.slow
def test_delta_method_std_matches_monte_carlo_over_noise_realizations() -> None:
    """Known-truth Hammerstein-OE, 100 noise realizations, one PEM fit each."""
    rng = np.random.default_rng(5)
    n = 400
    s = _steps(n, rng)
    ds = s - 45.0
    noiseless = lfilter([0.0, 1.0, -0.8], [1.0, -0.9], 1.3 * ds - 0.01 * ds**2)
    truth = {"b2": -0.8, "d1": 1.3, "d2": -0.01, "f1": -0.9}
    gains, gain_stds, distances, distance_stds = [], [], [], []
    for _ in range(100):
        y = noiseless + 0.3 * rng.standard_normal(n)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit = fit_hammerstein_oe(y, ds, initial=truth, initial_state="zero")
        model = hammerstein_model(fit, _log(s, y), operating_point=OP)
        g, g_std = static_gain(model)
        p, p_std = pole_nearest_one(model)
        gains.append(g)
        gain_stds.append(g_std)
        distances.append(abs(1.0 - p))
        distance_stds.append(p_std)
    # truth: K = (1 - 0.8) / (1 - 0.9) = 2 times the secant slope of f over the range
    lo, hi = min(ds), max(ds)
    true_gain = 2.0 * (1.3 - 0.01 * (lo + hi))
    assert abs(np.mean(gains) - true_gain) < 3 * np.std(gains) / math.sqrt(100) + 1e-3
    np.testing.assert_allclose(np.median(gain_stds), np.std(gains, ddof=1),
                               rtol=DELTA_METHOD_STD_RTOL)
    np.testing.assert_allclose(np.median(distance_stds), np.std(distances, ddof=1),
                               rtol=DELTA_METHOD_STD_RTOL)


# --------------------------------------------------------------------------- the model checks
def _fitted(y: np.ndarray, s: np.ndarray) -> HammersteinModel:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_hammerstein_oe(y, s - 45.0, degree=1, nb=1, nf=1, nk=1)
    return hammerstein_model(fit, _log(s, y), operating_point=OP)


def test_output_unrelated_to_the_input_is_refused_by_the_f_test() -> None:
    rng = np.random.default_rng(6)
    s = _steps(600, rng)
    y = lfilter([1.0], [1.0, -0.8], 0.2 * rng.standard_normal(600))
    judged = assess_model(_fitted(y, s), _log(s, y))
    assert [c.name for c in judged.refusals] == ["input_information"]
    check = judged.check("input_information")
    assert check.measured > INFORMATION_P_VALUE
    # The OE fit's covariance assumes white output errors; with this coloured noise it
    # is too small and the gain looks significant (z = 6.1): why the refusal rests on the
    # F-test, whose regression has the output's own past, and not on the model's z.
    assert judged.check("gain_significance").measured > GAIN_Z_MIN


def test_negative_gain_is_a_warning_not_a_refusal() -> None:
    rng = np.random.default_rng(7)
    s = _steps(600, rng)
    y = lfilter([0.0, -0.5], [1.0, -0.8], s - 45.0) + 0.05 * rng.standard_normal(600)
    judged = assess_model(_fitted(y, s), _log(s, y))
    assert judged.is_identifiable
    assert [c.name for c in judged.warnings] == ["gain_sign"]
    np.testing.assert_allclose(judged.check("gain_sign").measured, -2.5, rtol=0.02)
    assert judged.check("gain_significance").passed
    assert "refuses a model whose static gain" in judged.check("gain_sign").message
    # the checks go into model.json's provenance: plain bools (a numpy bool made
    # save_model fail on a test run's log whose Hammerstein gain came out negative)
    assert all(type(c.passed) is bool for c in judged.checks)
    assert '"passed": false' in json.dumps(judged.as_dicts())


def test_integrator_and_long_delay_are_warnings() -> None:
    names = ("d1", "f1")
    cov = np.diag([1e-4, 1e-6])
    near_one = _model([1.0, -(1.0 - 1e-7)], [0.0] * 200 + [1.0], [1.0], cov, names)
    data = _log(_steps(800, np.random.default_rng(8)), np.zeros(800))
    judged = assess_model(near_one, data)
    warned = {c.name for c in judged.warnings}
    assert {"pole_at_one", "slow_pole", "long_delay", "gain_significance"} <= warned
    assert judged.check("pole_at_one").measured < 1.0


def test_missing_covariance_is_a_warning_that_says_so() -> None:
    model = _model([1.0, -0.9], [0.0, 1.0], [1.0], None, ("d1", "f1"))
    rng = np.random.default_rng(9)
    s = _steps(400, rng)
    y = lfilter([0.0, 1.0], [1.0, -0.9], s - 45.0) + 0.05 * rng.standard_normal(400)
    check = assess_model(model, _log(s, y)).check("gain_significance")
    assert not check.passed and check.severity == "warning"
    assert "cannot be judged" in check.message


def test_assessment_keeps_the_latest_check_of_each_name_and_renders_markdown() -> None:
    bad = assess_data(_log(np.full(40, 45.0), np.zeros(40)), degree=1, nb=1, n_parameters=1)
    rng = np.random.default_rng(10)
    good = assess_data(_log(_steps(400, rng), np.zeros(400)), degree=1, nb=1, n_parameters=1)
    combined: IdentifiabilityAssessment = bad + good
    assert combined.is_identifiable and not bad.is_identifiable
    text = bad.markdown()
    assert text.startswith("## Identifiability") and "**refused**" in text
    assert [d["check"] for d in bad.as_dicts()] == [c.name for c in bad.checks]
    with pytest.raises(KeyError, match="no check named"):
        bad.check("gain_sign")
