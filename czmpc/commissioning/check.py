"""Go/no-go before switch-on: `check_model` judges a model `ready`, `ready with conditions` or `not ready`.

Each check gives ``pass``, ``condition`` (the MPC may run, with the stated caveat),
``fail`` (it must not) or ``skipped``; the verdict is ``not ready`` if any check fails,
``ready with conditions`` if any gives a condition or was skipped, else ``ready``. Every
non-pass check is a reason. The checks (stability, static gain, input range; with data
the validation fit, residual whiteness and input-residual correlation, each with the
record's initial state fitted; the static gain's uncertainty by the delta method; a
closed-loop Monte Carlo of the MPC against plants drawn from the parameter covariance,
through a staircase of three `MC_SEGMENT_S` steps across the input range) and why their
limits (the constants below) are where they are: docs/guides/commission.rst, step 5.

The verdict is stored beside the model as ``MODEL.check.json`` (`write_check`), with the
SHA-256 of the model file, so a run can tell a checked model from an unchecked or
since-changed one (`czmpc.runtime.session.read_check`, for the switch-on rule).
"""

from __future__ import annotations

import datetime as dt
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy.signal import lfilter

from czmpc.runtime.session import CHECK_FORMAT, Verdict, check_path
from czmpc.settings import MPCSettings
from sysid.data import Dataset
from sysid.errors import ModelFileError
from sysid.model import HammersteinModel
from sysid.polynomials import roots_z
from sysid.structure import MAX_GAIN_RSD
from sysid.uncertainty import ParameterError, model_with_parameters, parameter_distribution

ItemStatus = Literal["pass", "condition", "fail", "skipped"]
#: Parameter names, values and covariance of a model (`_covariance`).
_Covariance = tuple[tuple[str, ...], np.ndarray, np.ndarray]

#: Input range [%] narrower than this: the MPC could hardly move (fail).
MIN_RANGE_PCT = 5.0
#: Input range [%] narrower than this: a condition (the MPC is confined to it).
GOOD_RANGE_PCT = 15.0
#: Validation fit [%] below this fails.
FAIL_FIT_PCT = 70.0
#: Validation fit [%] below this is a condition.
GOOD_FIT_PCT = 90.0
#: Share of autocorrelation lags outside the 99 % bound above which whiteness is a condition.
MAX_WHITE_OUTSIDE = 0.25
#: Largest lag of the residual correlations [samples] (as MATLAB ``resid``).
MAX_LAG = 25
#: Input-move cross-correlation beyond this many 99 % bounds fails.
FAIL_CROSS_BOUNDS = 3.0
#: Largest missed response to an input move [% of the model's instantaneous gain] below
#: which a significant input-residual correlation is negligible: a quarter of the static
#: gain's relative std that the parameter-uncertainty check passes (`GOOD_GAIN_RSD`).
NEGLIGIBLE_MISSED_PCT = 5.0
#: Relative std of the static gain above this is a condition.
GOOD_GAIN_RSD = 0.2
#: Relative std of the static gain above this fails (the bound the order search
#: chooses within, `sysid.structure.MAX_GAIN_RSD`).
FAIL_GAIN_RSD = MAX_GAIN_RSD
#: |mean error| [kW] over the last 20 samples of a segment for offset-free (the issue's).
OFFSET_LIMIT_KW = 0.1
#: Samples at the end of a segment the offset is measured over.
OFFSET_SAMPLES = 20
#: A Monte Carlo run's IAE may be at most this times the nominal plant's.
MAX_IAE_RATIO = 2.0
#: Share of good Monte Carlo runs needed for a condition rather than a failure.
GOOD_MC_FRACTION = 0.8
#: Length of one staircase segment of the Monte Carlo [s].
MC_SEGMENT_S = 600.0


@dataclass(frozen=True, slots=True, kw_only=True)
class CheckItem:
    """The outcome of one check.

    Parameters
    ----------
    name :
        Short name of the check.
    status :
        ``pass``, ``condition``, ``fail`` or ``skipped``.
    detail :
        What was found, with numbers and units.
    value :
        The check's main number (unit in ``detail``), or None.
    """

    name: str
    status: ItemStatus
    detail: str
    value: float | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class MonteCarloSummary:
    """What the closed-loop Monte Carlo found.

    Parameters
    ----------
    n_runs :
        Plants run.
    n_good :
        Runs offset-free with IAE at most `MAX_IAE_RATIO` times the nominal.
    n_offset_free :
        Runs offset-free.
    n_redrawn :
        Draws refused as unstable (or without delay) and drawn again.
    iae_ratios :
        IAE over the nominal plant's, per run [-].
    nominal_iae_kw_s :
        IAE on the model's own plant [kW s].
    seed :
        Seed of the draws.
    """

    n_runs: int
    n_good: int
    n_offset_free: int
    n_redrawn: int
    iae_ratios: tuple[float, ...]
    nominal_iae_kw_s: float
    seed: int


@dataclass(frozen=True, kw_only=True)
class ModelCheck:
    """The verdict on a model and every reason for it (module docstring).

    Parameters
    ----------
    verdict :
        ``ready``, ``ready with conditions`` or ``not ready``.
    reasons :
        The detail of every check that did not pass, failures first.
    items :
        Every check, in order.
    monte_carlo :
        The closed-loop Monte Carlo, or None if skipped.
    data_source :
        The validation record's source, or None.
    model_sha256 :
        SHA-256 of the model file checked, or None (model in memory).
    created_utc :
        When the check ran (ISO 8601).
    """

    verdict: Verdict
    reasons: tuple[str, ...]
    items: tuple[CheckItem, ...]
    monte_carlo: MonteCarloSummary | None = None
    data_source: str | None = None
    model_sha256: str | None = None
    created_utc: str = ""

    @property
    def exit_code(self) -> int:
        """0 for ``ready``, 1 otherwise (the CLI's exit code)."""
        return 0 if self.verdict == "ready" else 1

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (the check file's content)."""
        mc = self.monte_carlo
        return {
            "format": CHECK_FORMAT, "verdict": self.verdict, "reasons": list(self.reasons),
            "items": [asdict(i) for i in self.items],
            "monte_carlo": None if mc is None else {**asdict(mc), "iae_ratios": list(mc.iae_ratios)},
            "data_source": self.data_source, "model_sha256": self.model_sha256,
            "created_utc": self.created_utc,
        }

    def format_text(self) -> str:
        """The verdict and every check, one line each, for a terminal."""
        lines = [f"verdict: {self.verdict}", *(f"  [{i.status:>9}] {i.name}: {i.detail}" for i in self.items)]
        return "\n".join(lines) + "\n"


def write_check(check: ModelCheck, model_path: str | Path) -> Path:
    """Write ``check`` beside the model (`check_path`); return the path."""
    from sysid.atomic import atomic_write_text

    target = check_path(model_path)
    atomic_write_text(target, json.dumps(check.to_dict(), indent=2) + "\n")
    return target


# --- the checks ------------------------------------------------------------------------

def _stability(model: HammersteinModel) -> CheckItem:
    top_a, top_c = (float(np.max(np.abs(roots_z(p)), initial=0.0)) for p in (model.a, model.c))
    if top_a >= 1.0 or top_c >= 1.0:
        return CheckItem(name="stability", status="fail", value=max(top_a, top_c),
                         detail=f"largest root |z| of A {top_a:.6f}, of C {top_c:.6f}: not "
                                "inside the unit circle")
    tau = -model.ts_s / math.log(top_a) if 0.0 < top_a < 1.0 else 0.0
    return CheckItem(name="stability", status="pass", value=top_a,
                     detail=f"A's largest root |z| = {top_a:.6f} (slow time constant "
                            f"{tau:.0f} s), C's {top_c:.4f}")


def _grade(fail: bool, condition: bool) -> ItemStatus:
    return "fail" if fail else "condition" if condition else "pass"


def _static_gain(model: HammersteinModel) -> CheckItem:
    lo, hi = model.input_range_pct
    s = np.linspace(lo, hi, 201)
    gain = model.linear_static_gain * model.input_nonlinearity_slope(
        s - model.operating_point.triac_pct)
    positive = gain > 0.0
    if not np.any(positive):
        return CheckItem(name="static gain", status="fail", value=float(np.max(gain)),
                         detail=f"steady-state gain not positive anywhere in {lo:g}..{hi:g} % "
                                f"(largest {np.max(gain):.3g} kW/%); the MPC needs a positive "
                                "gain")
    if not np.all(positive):
        ok = s[positive]
        return CheckItem(name="static gain", status="condition", value=float(np.min(gain)),
                         detail=f"steady-state gain positive only on {ok.min():.1f}..{ok.max():.1f} "
                                f"% of {lo:g}..{hi:g} %: the MPC keeps to that part")
    return CheckItem(name="static gain", status="pass", value=float(np.min(gain)),
                     detail=f"steady-state gain {gain.max():.3g}..{gain.min():.3g} kW/% over "
                            f"{lo:g}..{hi:g} %, positive and f monotone")


def _input_range(model: HammersteinModel) -> CheckItem:
    lo, hi = model.input_range_pct
    width = hi - lo
    status = _grade(width < MIN_RANGE_PCT, width < GOOD_RANGE_PCT)
    words = {"fail": "too narrow for the MPC to move (the model is valid only there)",
             "condition": "narrow: the MPC is confined to it",
             "pass": "the MPC keeps to it"}[status]
    return CheckItem(name="input range", status=status, value=width,
                     detail=f"identification data visited s = {lo:g}..{hi:g} % ({width:g} % "
                            f"wide): {words}")


def _data_checks(model: HammersteinModel, data: Dataset | None) -> list[CheckItem]:
    from sysid.criteria import errors_with_fitted_state, fit_percent
    from sysid.residuals import autocorrelation, cross_correlation

    if data is None:
        return [CheckItem(name="validation fit", status="skipped",
                          detail="no held-out data given (--data): fit, whiteness and input "
                                 "correlation not checked")]
    model.check_ts(data.ts_s, what=f"validation data {data.source}")
    measured = np.asarray(data.power_kw, dtype=float)
    if measured.size < 2 * MAX_LAG + 2:
        return [CheckItem(name="validation fit", status="skipped",
                          detail=f"validation data {data.source} has only {measured.size} "
                                 "samples")]
    # the record's initial state is fitted (as `compare` and `resid` do): a held-out part
    # cut from a test mid-ramp does not start at rest
    eps = np.asarray(errors_with_fitted_state(model, data), dtype=float)
    fit = fit_percent(measured, measured - eps)
    status = _grade(fit < FAIL_FIT_PCT, fit < GOOD_FIT_PCT)
    items = [CheckItem(name="validation fit", status=status, value=fit,
                       detail=f"simulation fit {fit:.1f} % on {data.source or 'the held-out data'} "
                              f"({data.n_samples} samples, initial state fitted; pass >= "
                              f"{GOOD_FIT_PCT:g} %, fail < {FAIL_FIT_PCT:g} %)")]
    e = np.asarray(errors_with_fitted_state(model, data, one_step=True), dtype=float)
    # the input *moves*, a pre-whitened input: the raw staircase would colour the test
    du = np.diff(np.asarray(data.triac_pct, dtype=float), prepend=float(data.triac_pct[0]))
    ac = autocorrelation(e, max_lag=MAX_LAG)
    white: ItemStatus = "condition" if ac.fraction_outside > MAX_WHITE_OUTSIDE else "pass"
    items.append(CheckItem(
        name="residual whiteness", status=white, value=ac.fraction_outside,
        detail=f"{ac.n_outside} of {ac.n_tested} autocorrelation lags outside the 99 % bound "
               f"{ac.bound:.3g} (condition above {MAX_WHITE_OUTSIDE:.0%}: the noise model is off)"))
    if float(du @ du) == 0.0:
        items.append(CheckItem(name="input-residual correlation", status="skipped",
                               detail="the validation input never moves"))
        return items
    cc = cross_correlation(e, du, max_lag=MAX_LAG)
    past = cc.lags >= 0
    worst = float(np.max(np.abs(cc.values[past])))
    lag = int(cc.lags[past][int(np.argmax(np.abs(cc.values[past])))])
    family = family_bound(int(np.count_nonzero(past)), measured.size)
    ratio = worst / family
    missed, missed_lag = missed_response_pct(e, du, largest_move_response(model))
    matters = missed >= NEGLIGIBLE_MISSED_PCT
    cross = _grade(matters and worst > FAIL_CROSS_BOUNDS * cc.bound, matters and ratio > 1.0)
    items.append(CheckItem(
        name="input-residual correlation", status=cross, value=ratio,
        detail=f"largest |r(e, ds moves)| at lags 0..{MAX_LAG} is {ratio:.2f} x the 99 % bound "
               f"for the largest of {MAX_LAG + 1} lags ({worst / cc.bound:.2f} x one lag's; at "
               f"lag {lag}; fail above {FAIL_CROSS_BOUNDS:g} x one lag's: gain, delay or "
               f"dynamics wrong); the response it misses is {missed:.2g} % of the model's own "
               f"largest at lag {missed_lag} (negligible below {NEGLIGIBLE_MISSED_PCT:g} %)"))
    return items


def largest_move_response(model: HammersteinModel) -> float:
    """The model's largest response to a unit input move within lags 0..`MAX_LAG`.

    ``max_k |s_k|`` of the step response ``s`` of ``f'(0) B(q) / A(q)`` [kW/%]: the scale
    of `missed_response_pct`. For a model normalized with its first ``B`` coefficient 1
    and a fast first response (the heater's electrical power) it is about ``f'(0)``; it
    does not depend on how the gain is shared between ``f`` and ``B`` (a fit can put a
    tiny ``f'(0)`` before a large ``B``).
    """
    step = lfilter(np.asarray(model.b, dtype=float), np.asarray(model.a, dtype=float),
                   np.ones(MAX_LAG + 1))
    return float(np.max(np.abs(step))) * abs(float(model.input_nonlinearity_slope(0.0)))


def missed_response_pct(residuals: np.ndarray, moves: np.ndarray,
                        response_scale: float) -> tuple[float, int]:
    """The model's largest missed response to an input move, in % of ``response_scale``.

    The residuals are fitted by least squares on the input moves at lags 0..`MAX_LAG`
    (the step response that the model misses, [output unit / input unit]); returns
    ``100 |g_max| / |response_scale|`` and the lag of ``g_max``. With the model's own
    largest response as the scale (`largest_move_response`): a model right to within
    noise gives about 0; one sample of delay wrong about 100 (its whole first response
    lands one lag off); a gain wrong by x % about x at the delay.
    """
    e = np.asarray(residuals, dtype=float)
    du = np.asarray(moves, dtype=float)
    lagged = np.column_stack([np.concatenate([np.zeros(lag), du[:du.size - lag]])
                              for lag in range(MAX_LAG + 1)])
    coef, *_ = np.linalg.lstsq(lagged, e, rcond=None)
    lag = int(np.argmax(np.abs(coef)))
    if response_scale == 0.0:
        return math.inf, lag
    return 100.0 * float(abs(coef[lag])) / abs(response_scale), lag


def family_bound(n_lags: int, n_samples: int, confidence: float = 0.99) -> float:
    """Bound on the largest of `n_lags` correlations of white residuals, at `confidence`.

    Each normalized correlation of white residuals is about ``N(0, 1/N)``; the largest of
    ``L`` (nearly) independent ones stays within ``z / sqrt(N)`` with probability
    `confidence` when each stays within it with probability ``confidence^(1/L)``
    (Sidak): ``z = Phi^-1((1 + confidence^(1/L)) / 2)``; 3.55 for 26 lags at 99 %. A
    per-lag bound (2.58, MATLAB ``resid``'s plot) taken as a verdict over 26 lags would
    flag about 23 % of correct models.

    Parameters
    ----------
    n_lags :
        Lags tested, >= 1.
    n_samples :
        Samples the correlations were taken over, >= 1.
    confidence :
        Probability that a correct model passes, in (0, 1).
    """
    from scipy.stats import norm

    per_lag = confidence ** (1.0 / n_lags)
    return float(norm.ppf(0.5 * (1.0 + per_lag))) / math.sqrt(n_samples)


def _covariance(model: HammersteinModel) -> _Covariance | None:
    """`sysid.uncertainty.parameter_distribution` as a tuple, None when it has none or NaN."""
    try:
        dist = parameter_distribution(model)
    except ParameterError:
        return None
    if not (np.all(np.isfinite(dist.theta)) and np.all(np.isfinite(dist.covariance))):
        return None
    return dist.names, dist.theta, dist.covariance


def _with_parameters(model: HammersteinModel, names: tuple[str, ...],
                     theta: np.ndarray) -> HammersteinModel | None:
    """`sysid.uncertainty.model_with_parameters`, None for a draw the model type refuses."""
    try:
        return model_with_parameters(model, names, theta)
    except (ParameterError, ModelFileError):
        return None


def _gain_uncertainty(model: HammersteinModel, cov: _Covariance | None) -> CheckItem:
    if cov is None:
        return CheckItem(name="parameter uncertainty", status="condition",
                         detail="no parameter covariance or standard errors recorded: the "
                                "uncertainty is unknown and the Monte Carlo is skipped")
    names, theta, sigma = cov
    base = model.linear_static_gain * float(model.input_nonlinearity_slope(0.0))
    grad = np.zeros(len(theta))
    for i in range(len(theta)):
        h = 1e-6 * max(1.0, abs(theta[i]))
        up = theta.copy()
        up[i] += h
        m = _with_parameters(model, names, up)
        if m is None:
            return CheckItem(name="parameter uncertainty", status="condition",
                             detail="the parameters cannot be mapped to the model's "
                                    "polynomials; uncertainty unknown")
        grad[i] = (m.linear_static_gain * float(m.input_nonlinearity_slope(0.0)) - base) / h
    var = float(grad @ sigma @ grad)
    rsd = math.sqrt(max(var, 0.0)) / abs(base) if base != 0.0 else math.inf
    status = _grade(rsd > FAIL_GAIN_RSD, rsd > GOOD_GAIN_RSD)
    return CheckItem(name="parameter uncertainty", status=status, value=rsd,
                     detail=f"static gain at the operating point {base:.3g} kW/% +- {rsd:.1%} "
                            f"(1 std; condition above {GOOD_GAIN_RSD:.0%}, fail above "
                            f"{FAIL_GAIN_RSD:.0%})")


def _mc_scenario(model: HammersteinModel) -> Any:
    from sim.scenario import Scenario, SetpointStep

    lo, hi = model.input_range_pct
    width = hi - lo

    def power(frac: float) -> float:
        return float(model.steady_state_power_kw(lo + frac * width))

    levels = [power(0.5), power(0.3), power(0.7), power(0.5)]
    return Scenario(name="check-model staircase", duration_s=MC_SEGMENT_S * len(levels),
                    ts_s=model.ts_s, initial_setpoint_kw=levels[0], plant_noise=False,
                    setpoints=tuple(SetpointStep(at_s=MC_SEGMENT_S * i, power_kw=p)
                                    for i, p in enumerate(levels) if i > 0))


def _closed_loop(model: HammersteinModel, plant_model: HammersteinModel, scenario: Any,
                 settings: MPCSettings | None, seed: int) -> tuple[bool, float]:
    """(offset-free, IAE [kW s]) of the MPC of ``model`` on the noise-free ``plant_model``."""
    from czmpc.campaigns.build import build_controller, build_plant
    from sim.loop import run_closed_loop

    # a model plant of another model, at its own steady state for the first setpoint
    plant, s0, _ = build_plant("perturbed", plant_model, scenario, noise=False)
    mpc = build_controller("mpc", model, scenario, initial_triac_pct=s0, settings=settings)
    run = run_closed_loop(plant, mpc, scenario, rng=seed)
    err = np.asarray(run.power_true_kw, dtype=float) - np.asarray(run.setpoint_kw, dtype=float)
    n_seg = int(round(MC_SEGMENT_S / model.ts_s))
    offset_free = all(abs(float(np.mean(err[end - OFFSET_SAMPLES:end]))) < OFFSET_LIMIT_KW
                      for end in range(n_seg, len(err) + 1, n_seg))
    return offset_free, float(np.sum(np.abs(err)) * model.ts_s)


def _monte_carlo(model: HammersteinModel, cov: _Covariance | None, settings: MPCSettings | None,
                 n_runs: int, seed: int) -> tuple[CheckItem, MonteCarloSummary | None]:
    from czmpc.errors import CzmpcError
    from sim.errors import SimError

    if n_runs < 1:
        return CheckItem(name="closed-loop Monte Carlo", status="skipped",
                         detail="skipped (no runs asked for)"), None
    scenario = _mc_scenario(model)
    try:
        _, nominal_iae = _closed_loop(model, model, scenario, settings, seed)
    except (SimError, CzmpcError) as exc:   # no delay, a gain the MPC refuses, ...
        return CheckItem(name="closed-loop Monte Carlo", status="fail",
                         detail=f"the MPC cannot run on the model's own plant: {exc}"), None
    if cov is None:
        return CheckItem(name="closed-loop Monte Carlo", status="skipped",
                         detail="skipped (no parameter covariance)"), None
    names, theta, sigma = cov
    rng = np.random.default_rng(seed)
    ratios: list[float] = []
    n_good = n_free = n_redrawn = 0
    while len(ratios) < n_runs and n_redrawn <= 3 * n_runs:
        draw = rng.multivariate_normal(theta, sigma, method="eigh")
        plant_model = _with_parameters(model, names, draw)
        if plant_model is None or plant_model.delay_steps < 1:
            n_redrawn += 1
            continue
        try:
            free, iae = _closed_loop(model, plant_model, scenario, settings, seed)
        except SimError:
            n_redrawn += 1   # a plant that cannot hold the start setpoint
            continue
        ratio = iae / nominal_iae if nominal_iae > 0 else math.inf
        ratios.append(ratio)
        n_free += int(free)
        n_good += int(free and ratio <= MAX_IAE_RATIO)
    summary = MonteCarloSummary(n_runs=len(ratios), n_good=n_good, n_offset_free=n_free,
                                n_redrawn=n_redrawn, iae_ratios=tuple(ratios),
                                nominal_iae_kw_s=nominal_iae, seed=seed)
    if not ratios:
        return CheckItem(name="closed-loop Monte Carlo", status="fail",
                         detail=f"no usable plant in {n_redrawn} draws from the covariance"), summary
    share = n_good / len(ratios)
    status: ItemStatus = ("pass" if n_good == len(ratios)
                          else "condition" if share >= GOOD_MC_FRACTION else "fail")
    detail = (f"{n_good} of {len(ratios)} plants drawn from the covariance tracked offset-free "
              f"with IAE <= {MAX_IAE_RATIO:g} x nominal ({n_free} offset-free; IAE ratio median "
              f"{np.median(ratios):.2f}, max {max(ratios):.2f}; {n_redrawn} draws redrawn; "
              f"seed {seed})")
    return CheckItem(name="closed-loop Monte Carlo", status=status, value=share,
                     detail=detail), summary


def check_model(model: HammersteinModel, data: Dataset | None = None,
                settings: MPCSettings | None = None, *, mc_runs: int = 20, seed: int = 0,
                model_sha256: str | None = None) -> ModelCheck:
    """Judge whether the MPC may be switched on with ``model`` (module docstring).

    Parameters
    ----------
    model :
        The model to check.
    data :
        Held-out validation record (same sampling time), or None.
    settings :
        The controller settings the MPC will run with; None: `MPCSettings.default_for`.
    mc_runs :
        Plants of the closed-loop Monte Carlo (0: skip it).
    seed :
        Seed of the Monte Carlo draws (fixed: the same check gives the same verdict).
    model_sha256 :
        SHA-256 of the model file, recorded with the verdict.

    Returns
    -------
    ModelCheck

    Raises
    ------
    SamplingTimeError
        The validation data's sampling time differs from the model's.
    """
    cov = _covariance(model)
    items = [_stability(model), _static_gain(model), _input_range(model),
             *_data_checks(model, data), _gain_uncertainty(model, cov)]
    hopeless = any(i.status == "fail" and i.name in ("stability", "static gain", "input range")
                   for i in items)
    mc_item, mc = ((CheckItem(name="closed-loop Monte Carlo", status="skipped",
                              detail="skipped (the model already fails a structural check)"), None)
                   if hopeless else _monte_carlo(model, cov, settings, mc_runs, seed))
    items.append(mc_item)
    order = {"fail": 0, "condition": 1, "skipped": 2, "pass": 3}
    reasons = tuple(f"{i.name}: {i.detail}" for i in sorted(items, key=lambda i: order[i.status])
                    if i.status != "pass")
    verdict: Verdict = ("not ready" if any(i.status == "fail" for i in items)
                        else "ready with conditions" if reasons else "ready")
    return ModelCheck(verdict=verdict, reasons=reasons, items=tuple(items), monte_carlo=mc,
                      data_source=None if data is None else data.source,
                      model_sha256=model_sha256,
                      created_utc=dt.datetime.now(dt.UTC).replace(microsecond=0).isoformat())


__all__ = ["CheckItem", "ItemStatus", "ModelCheck", "MonteCarloSummary", "check_model",
           "family_bound", "largest_move_response", "missed_response_pct", "write_check"]
