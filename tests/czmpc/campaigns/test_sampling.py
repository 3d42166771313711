"""Plants sampled from the model's parameter covariance, against independent references."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.stats import norm

from czmpc.campaigns.campaign import CampaignError, execute_run, spec_from_dict
from czmpc.campaigns.sampling import (
    MAX_DRAWS,
    SamplingError,
    draw_parameters,
    parameter_distribution,
    rejection_reason,
    sample_plant,
)
from czmpc.shipped import shipped_path
from sysid.model import HammersteinModel, Provenance
from sysid.modelfile import load_model, save_model
from sysid.uncertainty import model_parameters, model_with_parameters
from tests.tolerances import IDENTITY_RTOL, SAMPLING_SIGMAS

#: Covariance of (b2, d1, d2, a1, k1) that `czmpc identify` computes for the shipped
#: experiment (its parameters equal the shipped model's to 1e-11); a1 and b2 correlate
#: at 0.9998.
IDENTIFIED_COVARIANCE = (
    (9.915436969340119e-08, 7.251413008622223e-09, 1.4087451659567007e-09,
     1.1272202020517138e-07, 6.787352432478627e-08),
    (7.251413008622223e-09, 1.1422809383933879e-06, -2.2135398646657712e-08,
     1.3649862880043698e-08, -1.374819987837074e-08),
    (1.4087451659567007e-09, -2.2135398646657712e-08, 1.7197010270777665e-09,
     1.575621497220355e-09, 4.056188356806925e-09),
    (1.1272202020517138e-07, 1.3649862880043698e-08, 1.575621497220355e-09,
     1.2819231747223775e-07, 7.723777685562542e-08),
    (6.787352432478627e-08, -1.374819987837074e-08, 4.056188356806925e-09,
     7.723777685562542e-08, 5.4195312556055756e-05),
)


@pytest.fixture(scope="module")
def shipped() -> HammersteinModel:
    """The shipped model without its covariance (as model files written before 0.2.0)."""
    return load_model(shipped_path("cz_heater_model.json")).with_updates(covariance=None)


def test_the_shipped_model_carries_the_identified_covariance() -> None:
    model = load_model(shipped_path("cz_heater_model.json"))
    assert model.covariance is not None
    np.testing.assert_allclose(np.asarray(model.covariance), np.asarray(IDENTIFIED_COVARIANCE),
                               rtol=1e-6)
    assert parameter_distribution(model).source == "covariance"


@pytest.fixture(scope="module")
def with_cov(shipped: HammersteinModel) -> HammersteinModel:
    return shipped.with_updates(covariance=IDENTIFIED_COVARIANCE)


def test_parameters_read_back_the_fit(shipped: HammersteinModel) -> None:
    names = shipped.provenance.parameter_names
    assert names == ("b2", "d1", "d2", "a1", "k1")
    theta = model_parameters(shipped, names)
    np.testing.assert_allclose(theta, shipped.provenance.extra["parameters"], rtol=0, atol=1e-12)
    rebuilt = model_with_parameters(shipped, names, theta)
    for field in ("a", "b", "c", "input_poly"):
        np.testing.assert_allclose(getattr(rebuilt, field), getattr(shipped, field),
                                   rtol=IDENTITY_RTOL, atol=1e-15)


def test_k_moves_c_with_a(shipped: HammersteinModel) -> None:
    names = ("a1", "k1")
    changed = model_with_parameters(shipped, names, np.array([-0.95, 0.25]))
    assert changed.a[1] == -0.95
    assert changed.c[1] == pytest.approx(-0.95 + 0.25, rel=IDENTITY_RTOL)
    assert changed.b[2] == shipped.b[2]


def test_draws_have_the_mean_and_covariance_asked(with_cov: HammersteinModel) -> None:
    """Sample moments of 20,000 draws against theta and Sigma, within SAMPLING_SIGMAS
    standard errors of the estimators (mean: sqrt(S_ii/N); covariance entry:
    sqrt((S_ij^2 + S_ii S_jj)/N), the Gaussian variance of a sample covariance)."""
    dist = parameter_distribution(with_cov)
    assert dist.source == "covariance" and dist.warning == ""
    n = 20_000
    x = draw_parameters(np.random.default_rng(3), dist.theta, dist.covariance, n)
    sigma = np.asarray(IDENTIFIED_COVARIANCE)
    var = np.diag(sigma)
    mean_se = np.sqrt(var / n)
    assert np.all(np.abs(x.mean(axis=0) - dist.theta) < SAMPLING_SIGMAS * mean_se)
    cov_se = np.sqrt((sigma**2 + np.outer(var, var)) / n)
    assert np.all(np.abs(np.cov(x, rowvar=False) - sigma) < SAMPLING_SIGMAS * cov_se)
    # the correlation that matters: a1 and b2 move together, so the static gain is tight
    corr = np.corrcoef(x[:, 0], x[:, 3])[0, 1]
    assert corr == pytest.approx(sigma[0, 3] / np.sqrt(var[0] * var[3]), abs=0.001)


def test_a_singular_covariance_is_sampled_on_its_subspace() -> None:
    theta = np.array([1.0, 2.0])
    cov = np.array([[1.0, 2.0], [2.0, 4.0]])  # rank 1: x2 - 2 x1 = 0 exactly
    x = draw_parameters(np.random.default_rng(0), theta, cov, 2000)
    np.testing.assert_allclose(x[:, 1] - theta[1], 2.0 * (x[:, 0] - theta[0]), atol=1e-12)
    assert np.std(x[:, 0]) == pytest.approx(1.0, rel=0.1)


def test_without_covariance_the_standard_errors_are_used_with_a_warning(
        shipped: HammersteinModel, tmp_path: Path) -> None:
    dist = parameter_distribution(shipped)
    assert dist.source == "std_errors"
    assert "no parameter covariance" in dist.warning
    np.testing.assert_allclose(np.sqrt(np.diag(dist.covariance)),
                               shipped.provenance.extra["std_errors"], rtol=IDENTITY_RTOL)
    assert np.count_nonzero(dist.covariance - np.diag(np.diag(dist.covariance))) == 0
    save_model(shipped, tmp_path / "no_covariance.json")
    spec = spec_from_dict({"model": "no_covariance.json", "scenarios": ["staircase"],
                           "controllers": [{"preset": "pi"}],
                           "plants": [{"kind": "sampled", "n": 3}]}, base_dir=tmp_path)
    assert len(spec.expand()) == 3
    assert any("standard errors" in w for w in spec.warnings)


def test_a_model_without_parameter_names_is_refused(shipped: HammersteinModel,
                                                    tmp_path: object) -> None:
    bare = shipped.with_updates(provenance=Provenance())
    with pytest.raises(SamplingError, match="names no estimated parameters"):
        parameter_distribution(bare)
    from pathlib import Path
    path = Path(str(tmp_path)) / "bare.json"
    save_model(bare, path)
    with pytest.raises(CampaignError, match="names no estimated parameters"):
        spec_from_dict({"model": str(path), "scenarios": ["staircase"],
                        "controllers": [{"preset": "pi"}], "plants": [{"kind": "sampled", "n": 1}]})


def test_rejection_rule_unstable_and_wrong_gain_sign(shipped: HammersteinModel) -> None:
    names = shipped.provenance.parameter_names
    assert names is not None
    theta = model_parameters(shipped, names)
    unstable = theta.copy()
    unstable[3] = -1.001  # a1: pole outside the unit circle
    assert rejection_reason(shipped, names, unstable)[0].startswith("not a valid model")
    flipped = theta.copy()
    flipped[1] = -flipped[1]  # d1 < 0: power falls as the input rises
    assert rejection_reason(shipped, names, flipped)[0].startswith("static gain of the wrong sign")
    reason, drawn = rejection_reason(shipped, names, theta)
    assert reason == "" and drawn is not None


def test_rejected_fraction_matches_the_gaussian_probability(shipped: HammersteinModel) -> None:
    """Only d1 uncertain, sd 1.0: f'(ds) = d1 + 2 d2 ds is smallest at the top of the
    identified range, so a draw is rejected iff d1 <= -2 d2 ds_max; the rejected
    fraction must match Phi((-2 d2 ds_max - d1) / sd) (scipy) within SAMPLING_SIGMAS
    binomial standard errors."""
    names = shipped.provenance.parameter_names
    assert names is not None
    cov = np.zeros((5, 5))
    cov[1, 1] = 1.0
    model = shipped.with_updates(covariance=tuple(map(tuple, cov)))
    d1, d2 = shipped.input_poly
    ds_max = shipped.input_range_pct[1] - shipped.operating_point.triac_pct
    p_reject = float(norm.cdf((-2.0 * d2 * ds_max - d1) / 1.0))
    n, rejected = 600, 0
    for k in range(n):
        plant = sample_plant(model, 5, k)
        rejected += plant.n_rejected
        assert plant.source == "covariance"
        assert float(np.min(plant.model.input_nonlinearity_slope(np.linspace(0.0, ds_max, 11)))) > 0
    # draws until acceptance are geometric: rejected / (rejected + n) estimates p
    total = rejected + n
    frac = rejected / total
    assert abs(frac - p_reject) < SAMPLING_SIGMAS * np.sqrt(p_reject * (1 - p_reject) / total)


def test_all_draws_rejected_is_an_error_row(shipped: HammersteinModel, tmp_path: object) -> None:
    from pathlib import Path
    names = shipped.provenance.parameter_names
    assert names is not None
    # f'(ds) = 0.2 + 2 d2 ds changes sign inside the identified range: every draw of a
    # zero covariance is this model, and it is rejected
    bad = shipped.with_updates(input_poly=np.array([0.2, shipped.input_poly[1]]),
                               covariance=tuple(map(tuple, np.zeros((5, 5)))))
    with pytest.raises(SamplingError, match=f"all {MAX_DRAWS} draws rejected"):
        sample_plant(bad, 0, 0)
    path = Path(str(tmp_path)) / "bad.json"
    save_model(bad, path)
    run = spec_from_dict({"model": str(path), "scenarios": ["staircase"], "time_scale": 0.02,
                          "controllers": [{"preset": "pi"}],
                          "plants": [{"kind": "sampled", "n": 1}]}).expand()[0]
    row = execute_run(run)
    assert row["status"] == "error" and "draws rejected" in row["error"]


def test_plant_k_is_the_same_for_every_controller_and_scenario(with_cov: HammersteinModel) -> None:
    a, b = sample_plant(with_cov, 9, 4), sample_plant(with_cov, 9, 4)
    np.testing.assert_array_equal(a.parameters, b.parameters)
    assert not np.array_equal(a.parameters, sample_plant(with_cov, 9, 5).parameters)
    assert not np.array_equal(a.parameters, sample_plant(with_cov, 10, 4).parameters)
    spec = spec_from_dict({"scenarios": ["staircase", "voltage_sag"], "time_scale": 0.02,
                           "controllers": [{"preset": "pi"}, {"preset": "pi-scheduled"}],
                           "plants": [{"kind": "sampled", "n": 1, "first": 4}]})
    rows = [execute_run(r) for r in spec.expand()]
    assert {r["plant"] for r in rows} == {"sampled 4"}
    assert all(r["sample_index"] == 4 and r["status"] == "ok" for r in rows)
    gains = {r["plant_static_gain_kw_per_pct"] for r in rows}
    assert len(gains) == 1
    nominal_gain = 1.0
    shipped_model = load_model(shipped_path("cz_heater_model.json"))
    nominal_gain = shipped_model.linear_static_gain * float(shipped_model.input_poly[0])
    assert gains.pop() != pytest.approx(nominal_gain, rel=1e-9)
