"""check-model (czmpc.commissioning.check): the verdicts the issue asks for, the checks, the check file."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from czmpc.commissioning.check import check_model, write_check
from czmpc.runtime.session import check_path, read_check
from czmpc.shipped import shipped_path
from sim.heater import VirtualHeater
from sysid.atomic import file_sha256
from sysid.data import Dataset, read_csv
from sysid.model import HammersteinModel
from sysid.modelfile import load_model
from sysid.pipeline import run_paper_pipeline
from sysid.uncertainty import ParameterError, model_with_parameters
from tests.tolerances import IDENTITY_RTOL

SHIPPED_PATH = shipped_path("cz_heater_model.json")
SHIPPED = load_model(SHIPPED_PATH)
EXPERIMENT = read_csv(shipped_path("cz_heater_experiment.csv"))


def _status(check: object, name: str) -> str:
    return next(i.status for i in check.items if i.name == name)  # type: ignore[attr-defined]


@pytest.mark.slow
def test_the_shipped_model_on_the_shipped_experiment_is_ready() -> None:
    check = check_model(SHIPPED, EXPERIMENT, mc_runs=3)
    assert check.verdict == "ready", check.format_text()
    assert check.reasons == ()
    assert check.exit_code == 0
    assert check.monte_carlo is not None and check.monte_carlo.n_good == 3


def test_a_model_with_the_wrong_delay_is_not_ready() -> None:
    wrong = SHIPPED.with_updates(b=np.concatenate([[0.0], SHIPPED.b]))
    check = check_model(wrong, EXPERIMENT, mc_runs=0)
    assert check.verdict == "not ready"
    assert _status(check, "input-residual correlation") == "fail"
    assert check.reasons[0].startswith("input-residual correlation: ")
    assert "at lag 1" in check.reasons[0]
    assert check.exit_code == 1


def test_a_model_fitted_to_uninformative_data_is_not_ready() -> None:
    """The heater dithered by +-0.3 % around 45 %: no information about the input range."""
    rng = np.random.default_rng(4)
    n = 2000
    triac = 45.0 + 0.3 * np.sign(rng.standard_normal(n // 30 + 1)).repeat(30)[:n]
    heater = VirtualHeater(rng=4)
    power = [heater.reset(4)]
    for k in range(n - 1):
        power.append(heater.step(float(triac[k])))
    data = Dataset(time_s=np.arange(n) * 2.0, triac_pct=triac, power_kw=np.array(power),
                   ts_s=2.0, source="dither only")
    model = run_paper_pipeline(data).models[-1].model
    check = check_model(model, EXPERIMENT, mc_runs=2)
    assert check.verdict == "not ready"
    assert _status(check, "input range") == "fail"
    assert any(r.startswith("input range: ") and "0.6 % wide" in r for r in check.reasons)


def test_no_data_and_no_covariance_are_conditions() -> None:
    bare = SHIPPED.with_updates(provenance=replace(SHIPPED.provenance, extra={}))
    check = check_model(bare, None)
    assert check.verdict == "ready with conditions"
    assert {i.name for i in check.items if i.status != "pass"} == {
        "validation fit", "parameter uncertainty", "closed-loop Monte Carlo"}


def test_a_negative_gain_model_fails_the_static_gain() -> None:
    negative = SHIPPED.with_updates(input_poly=-SHIPPED.input_poly)
    check = check_model(negative, None, mc_runs=0)
    assert _status(check, "static gain") == "fail"
    assert check.verdict == "not ready"


def test_recorded_parameters_rebuild_the_model() -> None:
    """provenance.parameters (b2, d1, d2, a1, k1) map back to the file's polynomials."""
    names = SHIPPED.provenance.parameter_names
    assert names is not None
    theta = np.asarray(SHIPPED.provenance.extra["parameters"], dtype=float)
    rebuilt = model_with_parameters(SHIPPED, names, theta)
    assert isinstance(rebuilt, HammersteinModel)
    for got, want in ((rebuilt.a, SHIPPED.a), (rebuilt.b, SHIPPED.b), (rebuilt.c, SHIPPED.c),
                      (rebuilt.input_poly, SHIPPED.input_poly)):
        np.testing.assert_allclose(got, want, rtol=IDENTITY_RTOL, atol=1e-15)
    with pytest.raises(ParameterError, match="parameter 'z1' does not exist"):
        model_with_parameters(SHIPPED, ("z1",), np.array([1.0]))


def test_the_check_file_carries_the_verdict_until_the_model_changes(tmp_path: Path) -> None:
    model_path = tmp_path / "model.json"
    model_path.write_bytes(SHIPPED_PATH.read_bytes())
    assert read_check(model_path)[0] is None
    assert "never checked" in read_check(model_path)[1]
    check = check_model(SHIPPED, None, mc_runs=0, model_sha256=file_sha256(model_path))
    written = write_check(check, model_path)
    assert written == tmp_path / "model.check.json" == check_path(model_path)
    doc = json.loads(written.read_text(encoding="utf-8"))
    assert doc["verdict"] == "ready with conditions"
    assert doc["reasons"] == list(check.reasons)
    verdict, note = read_check(model_path)
    assert verdict == "ready with conditions"
    assert "validation fit" in note
    model_path.write_text(model_path.read_text(encoding="utf-8") + "\n", encoding="utf-8")
    verdict, note = read_check(model_path)
    assert verdict is None and "changed since" in note


def test_validation_data_of_another_sampling_time_are_refused() -> None:
    from sysid.errors import SamplingTimeError

    other = Dataset(time_s=np.arange(100) * 1.0, triac_pct=np.full(100, 45.0),
                    power_kw=np.full(100, 45.0), ts_s=1.0, source="fast.csv")
    with pytest.raises(SamplingTimeError, match="fast.csv"):
        check_model(SHIPPED, other, mc_runs=0)



def test_a_model_without_input_delay_is_not_ready_and_does_not_crash() -> None:
    """A model fitted with delay 0 (B starting non-zero): neither the MPC nor the model
    plant of the Monte Carlo can run on it; the check says so instead of raising."""
    no_delay = SHIPPED.with_updates(b=np.asarray(SHIPPED.b)[1:])
    check = check_model(no_delay, None, mc_runs=2)
    assert _status(check, "closed-loop Monte Carlo") == "fail"
    assert check.verdict == "not ready"
    assert any("cannot run on the model's own plant" in r for r in check.reasons)


def test_a_correct_model_gets_a_correlation_condition_one_time_in_a_hundred() -> None:
    """Residuals independent of the input: the largest of 26 correlations stays inside the
    family bound 99 % of the time (Sidak), where the per-lag 99 % bound would flag 23 %.

    4,000 trials: the binomial standard deviation of a 1 % rate is 0.16 %, of 23 % is
    0.67 %; the accepted bands are about 4 of them wide on each side.
    """
    from czmpc.commissioning.check import MAX_LAG, family_bound
    from sysid.residuals import cross_correlation

    rng = np.random.default_rng(11)
    n, trials = 300, 4000
    bound = family_bound(MAX_LAG + 1, n)
    assert bound * np.sqrt(n) == pytest.approx(3.55, abs=0.01)
    over_family = over_lag = 0
    for _ in range(trials):
        cc = cross_correlation(rng.standard_normal(n), rng.standard_normal(n), max_lag=MAX_LAG)
        worst = float(np.max(np.abs(cc.values[cc.lags >= 0])))
        over_family += worst > bound
        over_lag += worst > cc.bound
    assert 0.004 <= over_family / trials <= 0.018
    # 1 - 0.99^26 = 0.23 for independent N(0, 1/N) values; the variance at lag tau is
    # (N - tau)/N^2, a little less, so the rate is a little lower (measured 19.9 %)
    assert 0.17 <= over_lag / trials <= 0.26


def test_the_missed_response_is_the_residuals_impulse_response_to_moves() -> None:
    """Residuals = 0.2 x the move three samples back + white noise: the least-squares fit
    on the lagged moves finds 0.2 at lag 3, 20 % of an instantaneous gain of 1 (and 10 %
    of a gain of 2)."""
    from czmpc.commissioning.check import missed_response_pct

    rng = np.random.default_rng(3)
    moves = np.where(rng.random(5000) < 0.1, rng.choice([-5.0, 5.0], 5000), 0.0)
    e = 0.2 * np.concatenate([np.zeros(3), moves[:-3]]) + 0.05 * rng.standard_normal(moves.size)
    # the coefficient's std error: 0.05 / (5 sqrt(0.1 x 5000)) = 4.5e-4, 0.2 % of 0.2
    pct, lag = missed_response_pct(e, moves, 1.0)
    assert lag == 3 and pct == pytest.approx(20.0, rel=0.01)
    assert missed_response_pct(e, moves, -2.0)[0] == pytest.approx(10.0, rel=0.01)


def test_the_missed_response_scale_does_not_depend_on_how_f_and_b_share_the_gain() -> None:
    """A fit may put a tiny f'(0) before a large B (seen: f'(0) = 0.0023, B = 1 + 454 q^-1
    - 454 q^-2): the scale of the missed response is the model's largest step response
    over lags 0..25, the same for both sharings, and against scipy's lfilter."""
    from scipy.signal import lfilter

    from czmpc.commissioning.check import MAX_LAG, largest_move_response

    model = load_model(SHIPPED_PATH)
    eps = 2e-3   # a first B coefficient of eps before the model's own, one sample later
    shared = model.with_updates(b=np.concatenate(([0.0, 1.0], model.b[1:] / eps)),
                                input_poly=eps * model.input_poly, covariance=None)
    expected = float(np.max(np.abs(lfilter(model.b, model.a, np.ones(MAX_LAG + 1))))) \
        * float(model.input_poly[0])
    assert largest_move_response(model) == pytest.approx(expected, rel=1e-12)
    # the same response one sample later, plus eps f'(0) times the step response of 1/A
    # (at most 26 eps = 5.2 % over lags 0..25): close to the model's, not to f'(0) = 0.2 %
    assert largest_move_response(shared) == pytest.approx(expected, rel=26 * eps)
    # the shipped model's first response is its instantaneous gain; over 25 samples its
    # slow mode adds a little (the scale stays within 20 % of f'(0))
    assert float(model.input_poly[0]) <= expected <= 1.2 * float(model.input_poly[0])


@pytest.mark.parametrize(("gain", "status"), [(1.01, "pass"), (1.15, "fail")])
def test_a_significant_input_correlation_fails_only_when_the_error_matters(
        gain: float, status: str) -> None:
    """Data from the shipped model with f scaled by ``gain`` and little noise (5 W): a 1 %
    gain error is highly significant and negligible (it misses 1 % of the response to a
    move), a 15 % one is neither (14 %)."""
    from sysid.simulate import simulate

    truth = SHIPPED.with_updates(input_poly=gain * np.asarray(SHIPPED.input_poly))
    rng = np.random.default_rng(5)
    clean = np.asarray(simulate(truth, EXPERIMENT), dtype=float)
    data = Dataset(time_s=EXPERIMENT.time_s, triac_pct=EXPERIMENT.triac_pct,
                   power_kw=clean + 0.005 * rng.standard_normal(clean.size), ts_s=EXPERIMENT.ts_s,
                   source=f"shipped model, gain x{gain:g}")
    check = check_model(SHIPPED, data, mc_runs=0)
    item = next(i for i in check.items if i.name == "input-residual correlation")
    assert item.value is not None and item.value > 3.0          # significant either way
    assert item.status == status, item.detail


def test_a_held_out_record_that_starts_at_a_step_is_scored_from_a_fitted_state() -> None:
    """Data from the shipped model itself (20 W noise), cut to start at the sample of an
    input step: the record's past is not its first sample held, so the held-past rule
    charges the right model with a wrong initial state (fit 80 %, a condition). The
    check fits the initial state, as MATLAB's compare and resid do: the right model
    passes the fit (99.4 %) and the input-residual correlation."""
    from sysid.criteria import fit_percent
    from sysid.simulate import simulate

    clean = np.asarray(simulate(SHIPPED, EXPERIMENT), dtype=float)
    noisy = clean + 0.02 * np.random.default_rng(5).standard_normal(clean.size)
    step = int(np.flatnonzero(np.diff(EXPERIMENT.triac_pct) != 0.0)[0]) + 1
    cut = slice(step, step + 3100)                   # three levels, two more steps
    data = Dataset(time_s=EXPERIMENT.time_s[cut], triac_pct=EXPERIMENT.triac_pct[cut],
                   power_kw=noisy[cut], ts_s=EXPERIMENT.ts_s, source="cut at a step")
    assert fit_percent(data.power_kw, simulate(SHIPPED, data)) < 90.0   # held past
    check = check_model(SHIPPED, data, mc_runs=0)
    fit = next(i for i in check.items if i.name == "validation fit")
    assert fit.status == "pass" and fit.value is not None and fit.value > 99.0, fit.detail
    assert "initial state fitted" in fit.detail
    assert _status(check, "input-residual correlation") == "pass"
