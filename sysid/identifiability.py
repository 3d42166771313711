"""Judge whether a log, and the model fitted to it, carry information about the input.

A negative gain, a long delay or an integrating process can be the process: *warnings*
(the user decides). A log that carries no information about the input no fit can
repair: *refusals* (docs/theory.rst, "Facts that bite").

Checks on the data (before a fit, `assess_data`, and again with the fitted model's
orders in `assess_model`), each a refusal when it fails:

* ``input_excitation``: the input's standard deviation against its scale;
* ``input_levels``: distinct input levels: fewer than 2 is a refusal; fewer than the
  polynomial degree + 1 only a warning (with as many levels away from the operating point
  as the degree, ``f`` passes exactly through them; with fewer, the Hammerstein fits
  refuse the degree and the pipeline writes a lower-order model, which the data support);
* ``persistent_excitation``: the input's order of persistent excitation against the
  number of ``B`` coefficients;
* ``samples_per_parameter``: samples against estimated parameters;
* ``input_information`` (with a model's orders): an F-test that the input explains
  the output at all.

Checks on the fitted model (`assess_model`), each a warning when it fails:

* ``gain_significance``: the static gain over the input range against its standard
  deviation (delta method on the stored covariance);
* ``pole_at_one``: the distance of the pole nearest to z = 1 against its standard
  deviation (a model the data cannot tell from an integrator);
* ``slow_pole``: the slowest time constant against the record (steady gain extrapolated);
* ``gain_sign``: a static gain that is not positive (the MPC refuses it), or a local
  gain that changes sign inside the input range;
* ``long_delay``: the delay against the record and against the time constant.

Notation
--------
``s`` input [input unit], ``ds = s - s_nom``; ``y`` output deviation [output unit];
the model ``A(q) y = B(q) f(ds) + C(q) e`` of `sysid.model`, with ``K = B(1)/A(1)``.
The static gain over the input range ``[s_lo, s_hi]`` is the secant slope of the
steady-state map, ``g = K (f(ds_hi) - f(ds_lo)) / (ds_hi - ds_lo)`` [output unit per
input unit] (for a quadratic ``f`` the local gain at the middle of the range).

References
----------
.. [1] L. Ljung, *System Identification: Theory for the User*, 2nd ed., Prentice Hall,
   1999: ch. 9 (asymptotic covariance of prediction-error estimates and the Gauss
   approximation formula, i.e. the delta method), ch. 13 (persistent excitation,
   informative experiments).
.. [2] T. Soderstrom and P. Stoica, *System Identification*, Prentice Hall, 1989:
   sec. 5.4 (persistent excitation), ch. 11 (F-test between nested model structures).
.. [3] F. E. Harrell, *Regression Modeling Strategies*, 2nd ed., Springer, 2015,
   sec. 4.4 (about ten observations per estimated parameter).
.. [4] K. J. Astrom and T. Hagglund, *Advanced PID Control*, ISA, 2006, sec. 2.7
   (normalized dead time ``L / (L + T)``; above 0.5 a process is delay-dominated).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from scipy import stats

from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.data import Dataset
from sysid.errors import IdentificationError
from sysid.model import HammersteinModel

Severity = Literal["refusal", "warning"]

#: The input's standard deviation must be at least this share of its largest magnitude
#: (0.1 %: about one step of a 10-bit actuator); below it the input is constant but for
#: noise or quantization.
INPUT_STD_RTOL = 1e-3
#: The order of persistent excitation is measured up to ``nb`` plus this (a report shows
#: the margin).
PE_ORDER_MARGIN = 2
#: Samples per estimated parameter, at least ([3]; `sysid.hammerstein` applies the same).
SAMPLES_PER_PARAMETER = 10
#: A singular value of the input's lag matrix below this share of the largest is zero in
#: its numerical rank (far above rounding, ~1e-16 N; far below one step's ~1/sqrt(N)).
PE_RANK_RTOL = 1e-8
#: Largest p-value of the F-test "the input terms explain nothing" that counts as
#: information about the input (a log of pure noise passes once in 1000).
INFORMATION_P_VALUE = 1e-3
#: Smallest ``|g| / std(g)`` of a significant static gain (a zero gain exceeds it by
#: chance with probability 0.27 %, normal approximation).
GAIN_Z_MIN = 3.0
#: A pole closer to z = 1 than this many standard deviations is an integrator's.
POLE_Z_MIN = 3.0
#: Distance to z = 1 below which a pole is at z = 1 whatever its covariance says.
POLE_AT_ONE_ATOL = 1e-9
#: Normalized dead time ``L / (L + T)`` above which a process is delay-dominated ([4]).
DELAY_DOMINANCE_MAX = 0.5
#: Largest delay as a share of the record's duration.
DELAY_RECORD_MAX = 0.1
#: Largest slowest-time-constant as a multiple of the record's duration.
TIME_CONSTANT_RECORD_MAX = 1.0

_ADVICE_TEST = (
    "record a longer or better excited test: steps across the whole input range that "
    "each settle ('czmpc design-test' designs one)"
)


@dataclass(frozen=True, kw_only=True)
class Check:
    """One identifiability check and what it measured.

    Parameters
    ----------
    name :
        The check (module docstring), e.g. ``"gain_significance"``.
    passed :
        Whether the measurement met the threshold.
    severity :
        What a failure means: ``"refusal"`` (the data cannot support a model) or
        ``"warning"`` (the model may be right but is unusual).
    measured, threshold :
        The measured value (units in `message`) and the threshold it was compared with.
    message :
        What was checked, the value, the threshold, and (when failed) what to do.
    """

    name: str
    passed: bool
    severity: Severity
    measured: float
    threshold: float
    message: str

    def __post_init__(self) -> None:
        # a verdict compared from numpy floats is a numpy bool, which json cannot write
        object.__setattr__(self, "passed", bool(self.passed))

    def as_dict(self) -> dict[str, Any]:
        """JSON-able form (for the model's provenance)."""
        return {"check": self.name, "passed": self.passed, "severity": self.severity,
                "measured": _json_number(self.measured),
                "threshold": _json_number(self.threshold), "message": self.message}


def _json_number(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _check(name: str, passed: bool, severity: Severity, *, measured: float, threshold: float,
           finding: str, advice: str) -> Check:
    """A `Check` whose message is `finding`, with `advice` appended when it failed."""
    return Check(name=name, passed=passed, severity=severity, measured=measured,
                 threshold=threshold, message=finding + ("" if passed else advice))


@dataclass(frozen=True, kw_only=True)
class IdentifiabilityAssessment:
    """Every check run on a log (and a model), passed or not.

    Parameters
    ----------
    checks :
        The checks in the order run; a later check of a name replaces an earlier one.
    """

    checks: tuple[Check, ...]

    @property
    def refusals(self) -> tuple[Check, ...]:
        """Failed checks that mean the data cannot support a model."""
        return tuple(c for c in self._latest() if not c.passed and c.severity == "refusal")

    @property
    def warnings(self) -> tuple[Check, ...]:
        """Failed checks that mean the model is unusual (the user decides)."""
        return tuple(c for c in self._latest() if not c.passed and c.severity == "warning")

    @property
    def is_identifiable(self) -> bool:
        """No refusal."""
        return not self.refusals

    def check(self, name: str) -> Check:
        """The latest check called ``name``.

        Raises
        ------
        KeyError
            No check of that name was run.
        """
        for c in reversed(self.checks):
            if c.name == name:
                return c
        raise KeyError(f"no check named {name!r}; have {sorted({c.name for c in self.checks})}")

    def _latest(self) -> tuple[Check, ...]:
        latest: dict[str, Check] = {}
        for c in self.checks:
            latest.pop(c.name, None)
            latest[c.name] = c
        return tuple(latest.values())

    def __add__(self, other: IdentifiabilityAssessment) -> IdentifiabilityAssessment:
        return IdentifiabilityAssessment(checks=self.checks + other.checks)

    def as_dicts(self) -> list[dict[str, Any]]:
        """Every (latest) check as a JSON-able mapping."""
        return [c.as_dict() for c in self._latest()]

    def markdown(self) -> str:
        """A report section: verdict, then one row per check."""
        verdict = ("**refused**: the data cannot support a model" if self.refusals else
                   "**warnings**: the model may be right but is unusual; read them before "
                   "using it for control" if self.warnings else "every check passed")
        rows = ["## Identifiability", "", f"Verdict: {verdict}.", "",
                "| check | result | measured | threshold | finding |", "|---|---|---|---|---|"]
        for c in self._latest():
            result = "pass" if c.passed else c.severity
            rows.append(f"| {c.name} | {result} | {c.measured:.4g} | {c.threshold:.4g} | "
                        f"{c.message.replace('|', '/')} |")
        return "\n".join(rows) + "\n"


# =========================================================================== measurements
def input_std_ratio(triac_pct: FloatArray) -> float:
    """``std(s) / max|s|`` of the finite input samples (0 for a constant or all-zero input).

    Parameters
    ----------
    triac_pct :
        Input samples [input unit]; NaN are ignored.
    """
    s = np.asarray(triac_pct, dtype=float)
    s = s[np.isfinite(s)]
    scale = float(np.max(np.abs(s))) if s.size else 0.0
    return float(np.std(s)) / scale if scale > 0 else 0.0


def distinct_levels(triac_pct: FloatArray) -> int:
    """Number of distinct finite values of the input."""
    s = np.asarray(triac_pct, dtype=float)
    return int(np.unique(s[np.isfinite(s)]).size)


def persistent_excitation_order(
    segments: Sequence[FloatArray], max_order: int, *, rtol: float = PE_RANK_RTOL
) -> int:
    """Order of persistent excitation of an input, up to `max_order` ([1] ch. 13, [2] 5.4).

    The input is persistently exciting of order ``n`` when the ``n x n`` covariance of its
    lagged values is positive definite: here the numerical rank (singular values above
    `rtol` times the largest) of the lag matrix ``[u_t, u_{t-1}, .., u_{t-n+1}]`` of the
    centred input, rows inside each segment only (padding would add excitation). A
    constant input has order 0, a sinusoid order 2.

    Parameters
    ----------
    segments :
        The input [input unit] of each segment.
    max_order :
        Largest order tested (>= 1).
    rtol :
        Relative singular-value threshold of the rank.

    Returns
    -------
    int
        The order, ``0..max_order``.
    """
    if max_order < 1:
        raise IdentificationError(f"persistent_excitation_order: max_order must be >= 1; got {max_order}")
    finite = [np.asarray(u, dtype=float) for u in segments]
    values = np.concatenate([u[np.isfinite(u)] for u in finite]) if finite else np.zeros(0)
    if values.size == 0:
        return 0
    mean = float(np.mean(values))
    rows = []
    for u in finite:
        c = u - mean
        if c.size < max_order:
            continue
        lagged = np.column_stack([c[max_order - 1 - j: c.size - j] for j in range(max_order)])
        rows.append(lagged[np.all(np.isfinite(lagged), axis=1)])
    if not rows or sum(r.shape[0] for r in rows) == 0:
        return 0
    sv = np.linalg.svd(np.vstack(rows), compute_uv=False)
    if sv[0] == 0.0:
        return 0
    return int(np.sum(sv > rtol * sv[0]))


def input_information_test(
    data: Dataset, *, degree: int, na: int, nb: int, nk: int,
    operating_triac_pct: float | None = None,
) -> tuple[float, float]:
    """F-test that the input explains the output at all ([2] ch. 11).

    Least squares of the output on a constant and ``y_{t-1..t-na}`` (restricted) against
    the same plus ``ds^i_{t-nk-j}``, ``i = 1..degree``, ``j = 0..nb-1`` (full), on the
    rows inside each segment with every value finite. If the input terms are all zero
    and the equation errors white, ``F = ((RSS_r - RSS_f) / q) / (RSS_f / (n - p_f))``
    follows ``F(q, n - p_f)``.

    Parameters
    ----------
    data :
        The log.
    degree, na, nb, nk :
        Polynomial degree, output lags, input lags and delay of the regression.
    operating_triac_pct :
        ``s_nom`` [input unit] the features are taken about; default the input's mean.

    Returns
    -------
    (F, p_value)
        The statistic and the probability of an F at least as large if the input
        carried no information (NaN, 1.0 when too few rows for the regression).
    """
    na = max(int(na), 1)
    s_nom = float(np.nanmean(data.triac_pct)) if operating_triac_pct is None else operating_triac_pct
    start = max(na, nk + nb - 1)
    full_rows: list[FloatArray] = []
    for lo, hi in data.segment_bounds():
        s, y = data.triac_pct[lo:hi], data.power_kw[lo:hi]
        if y.size <= start:
            continue
        ds = s - s_nom
        cols = [np.ones(y.size - start)]
        cols += [y[start - i: y.size - i] for i in range(1, na + 1)]
        cols += [ds[start - nk - j: ds.size - nk - j] ** p
                 for p in range(1, degree + 1) for j in range(nb)]
        block = np.column_stack([*cols, y[start:]])
        full_rows.append(block[np.all(np.isfinite(block), axis=1)])
    if not full_rows:
        return math.nan, 1.0
    stacked = np.vstack(full_rows)
    phi_full, target = stacked[:, :-1], stacked[:, -1]
    n, p_full = phi_full.shape
    q = degree * nb
    if n <= p_full + 1:
        return math.nan, 1.0
    scale = np.max(np.abs(phi_full), axis=0)
    scale[scale == 0] = 1.0
    rss = []
    for phi in (phi_full[:, : 1 + na], phi_full):
        theta, *_ = np.linalg.lstsq(phi / scale[: phi.shape[1]], target, rcond=None)
        r = target - (phi / scale[: phi.shape[1]]) @ theta
        rss.append(float(r @ r))
    rss_r, rss_f = rss
    if rss_f <= 0.0:
        return math.inf, 0.0
    f_stat = max(rss_r - rss_f, 0.0) / q / (rss_f / (n - p_full))
    return float(f_stat), float(stats.f.sf(f_stat, q, n - p_full))


def static_gain(model: HammersteinModel) -> tuple[float, float]:
    """Static gain over the input range and its standard deviation (delta method, [1] ch. 9).

    ``g`` as in the module Notation over the model's input range; ``std(g) = sqrt(grad'
    Sigma grad)`` with the analytic gradient of ``g`` in ``b_j``, ``d_i``, ``a_i``/``f_i``
    (the noise parameters ``k_i`` do not enter) and ``Sigma`` the stored covariance
    (`HammersteinModel.covariance`, in the order of ``provenance.parameter_names``).

    Parameters
    ----------
    model :
        The model (its covariance and parameter names give the deviation).

    Returns
    -------
    (gain, std)
        ``g`` [output unit per input unit] and its standard deviation (NaN when the
        model stores no covariance or its parameter names are not the ones above).
    """
    lo, hi = (v - model.operating_point.triac_pct for v in model.input_range_pct)
    a1 = float(np.sum(model.a))
    k = float(np.sum(model.b)) / a1 if a1 != 0.0 else math.inf
    secant = [(hi ** i - lo ** i) / (hi - lo) for i in range(1, model.input_degree + 1)]
    slope = float(np.dot(model.input_poly, secant))
    gain = k * slope
    names = model.provenance.parameter_names
    cov = model.covariance_matrix
    if names is None or cov is None or not math.isfinite(gain):
        return gain, math.nan
    grad = np.zeros(len(names))
    for j, name in enumerate(names):
        letter, index = name[:1], name[1:]
        if not index.isdigit():
            return gain, math.nan
        i = int(index)
        if letter == "b":
            grad[j] = slope / a1
        elif letter in ("a", "f"):
            grad[j] = -gain / a1
        elif letter == "d" and model.kind == "hammerstein" and 1 <= i <= len(secant):
            grad[j] = k * secant[i - 1]
        elif letter == "k":
            grad[j] = 0.0
        else:
            return gain, math.nan
    var = float(grad @ cov @ grad)
    return gain, math.sqrt(max(var, 0.0))


def pole_nearest_one(model: HammersteinModel) -> tuple[complex, float]:
    """The pole of ``A`` (``F``) nearest to z = 1 and the standard deviation of ``|1 - p|``.

    ``dp/da_i = -p^(n-i) / A'(p)`` for the monic ``A(z) = z^n + a_1 z^(n-1) + ..``, and
    ``d|1 - p| = Re(conj(p - 1) dp) / |1 - p|`` (delta method, [1] ch. 9).

    Returns
    -------
    (pole, std)
        The pole (``0j`` for a model without poles) and the standard deviation of its
        distance to 1 (NaN without covariance).
    """
    a = np.asarray(model.a, dtype=float)
    n = a.size - 1
    if n == 0:
        return 0j, math.nan
    roots = np.roots(a)
    pole = complex(roots[int(np.argmin(np.abs(1.0 - roots)))])
    names = model.provenance.parameter_names
    cov = model.covariance_matrix
    if names is None or cov is None:
        return pole, math.nan
    dpoly = np.polyder(a)
    derivative = complex(np.polyval(dpoly, pole))
    distance = abs(1.0 - pole)
    if derivative == 0 or distance == 0:
        return pole, math.nan
    grad = np.zeros(len(names))
    letter = "f" if model.linear_block == "oe" else "a"
    for j, name in enumerate(names):
        if name[:1] == letter and name[1:].isdigit() and 1 <= int(name[1:]) <= n:
            dp = -pole ** (n - int(name[1:])) / derivative
            grad[j] = float(((pole - 1.0).conjugate() * dp).real) / distance
    var = float(grad @ cov @ grad)
    return pole, math.sqrt(max(var, 0.0))


def slowest_time_constant_s(model: HammersteinModel) -> float:
    """``-ts_s / ln|p|`` of the pole of largest modulus [s] (0 without poles, inf at |p| = 1)."""
    if model.a.size == 1:
        return 0.0
    rho = float(np.max(np.abs(np.roots(model.a))))
    if rho == 0.0:
        return 0.0
    return math.inf if rho >= 1.0 else -model.ts_s / math.log(rho)


# =========================================================================== the checks
def _n_parameters(model: HammersteinModel) -> int:
    """The model's estimated parameters (its names, else counted from its orders)."""
    names = model.provenance.parameter_names
    if names is not None:
        return len(names)
    nb = model.b.size - model.delay_steps
    noise = model.c.size - 1 if model.linear_block == "armax" else 0
    return (nb - 1) + model.input_degree + (model.a.size - 1) + noise


def _data_checks(data: Dataset, *, degree: int, nb: int, n_parameters: int,
                 what: str) -> list[Check]:
    unit = data.input_unit
    ratio = input_std_ratio(data.triac_pct)
    levels = distinct_levels(data.triac_pct)
    pe = persistent_excitation_order(
        [data.triac_pct[lo:hi] for lo, hi in data.segment_bounds()], nb + PE_ORDER_MARGIN)
    n = int(np.sum(np.isfinite(data.triac_pct) & np.isfinite(data.power_kw)))
    need = SAMPLES_PER_PARAMETER * n_parameters
    return [
        _check("input_excitation", ratio >= INPUT_STD_RTOL, "refusal", measured=ratio,
               threshold=INPUT_STD_RTOL,
               finding=(f"input excitation: std(s)/max|s| = {ratio:.3g}, at least "
                        f"{INPUT_STD_RTOL:g} needed (the input must move by more than 0.1 % "
                        f"of its scale [{unit}])"),
               advice=f"; the input is constant but for noise: {_ADVICE_TEST}"),
        _check("input_levels", levels >= degree + 1, "refusal" if levels < 2 else "warning",
               measured=float(levels), threshold=float(degree + 1),
               finding=(f"input levels: {levels} distinct input value(s), at least "
                        f"{degree + 1} needed for the degree-{degree} input polynomial of "
                        f"{what} ({degree} coefficient(s) of f and the output at the operating "
                        "point)"),
               advice=((f"; {_ADVICE_TEST}" if levels < 2 else
                        f"; a degree-{degree} f is at best drawn exactly through these "
                        "levels, its shape between them unchecked; with fewer levels away "
                        "from the operating point than its degree it is not fitted, and the "
                        "model written is of lower order (the terminal says which); for "
                        f"the nonlinearity, {_ADVICE_TEST}")
                       + (", or a lower degree (--orders)" if degree > 1 else ""))),
        _check("persistent_excitation", pe >= nb, "refusal", measured=float(pe),
               threshold=float(nb),
               finding=(f"persistent excitation: the input is persistently exciting of order "
                        f"{pe}, at least {nb} needed for the {nb} B coefficient(s) of {what}"),
               advice=f"; {_ADVICE_TEST}" + (", or fewer B coefficients (--orders)" if nb > 1 else "")),
        _check("samples_per_parameter", n >= need, "refusal", measured=float(n),
               threshold=float(need),
               finding=(f"samples: {n} usable samples for the {n_parameters} parameters of "
                        f"{what}, at least {need} needed ({SAMPLES_PER_PARAMETER} per parameter)"),
               advice="; record a longer test, or choose lower orders (--orders)")]


def assess_data(
    data: Dataset, *, degree: int, nb: int, n_parameters: int, what: str = "the model"
) -> IdentifiabilityAssessment:
    """Checks a log must pass before any fit of the given structure (all refusals).

    Parameters
    ----------
    data :
        The log (absolute units; NaN samples are left out).
    degree :
        Degree of the input polynomial to be fitted (>= 1).
    nb :
        Number of ``B`` coefficients, the normalized one included (>= 1).
    n_parameters :
        Number of parameters to be estimated (>= 1).
    what :
        Name of the structure in the messages, e.g. ``"the paper's structure"``.

    Returns
    -------
    IdentifiabilityAssessment
        ``input_excitation``, ``input_levels``, ``persistent_excitation`` and
        ``samples_per_parameter``.

    Raises
    ------
    IdentificationError
        `data` is not a `Dataset`, or an order below 1.
    """
    if not isinstance(data, Dataset):
        raise IdentificationError(f"assess_data: data must be a sysid Dataset; got {type(data).__name__}")
    degree, nb, n_parameters = (checked_int(value, 1, f"assess_data: {name}") for name, value
                                in (("degree", degree), ("nb", nb), ("n_parameters", n_parameters)))
    return IdentifiabilityAssessment(checks=tuple(
        _data_checks(data, degree=degree, nb=nb, n_parameters=n_parameters, what=what)))


def assess_model(model: HammersteinModel, data: Dataset) -> IdentifiabilityAssessment:
    """Every check of the module docstring on a fitted model and the log it was fitted to.

    The data checks of `assess_data` with the model's orders, the refusal
    ``input_information`` and the warnings ``gain_significance``, ``pole_at_one``,
    ``slow_pole``, ``gain_sign`` and ``long_delay``.

    Parameters
    ----------
    model :
        The fitted model (without its covariance the significance checks are warnings
        that say they could not be judged).
    data :
        The (preprocessed) log the model was fitted to.

    Returns
    -------
    IdentifiabilityAssessment

    Raises
    ------
    IdentificationError
        Arguments of the wrong type.
    """
    if not isinstance(model, HammersteinModel):
        raise IdentificationError(
            f"assess_model: model must be a HammersteinModel; got {type(model).__name__}")
    if not isinstance(data, Dataset):
        raise IdentificationError(f"assess_model: data must be a sysid Dataset; got {type(data).__name__}")
    units = model.effective_units
    gain_unit = f"{units.output}/{units.input}"
    nk = model.delay_steps
    nb = model.b.size - nk
    degree = model.input_degree
    na = model.a.size - 1
    checks = _data_checks(data, degree=degree, nb=nb, n_parameters=_n_parameters(model),
                          what="this model")

    f_stat, p_value = input_information_test(
        data, degree=degree, na=na, nb=nb, nk=nk,
        operating_triac_pct=model.operating_point.triac_pct)
    informative = p_value <= INFORMATION_P_VALUE
    checks.append(_check(
        "input_information", informative, "refusal", measured=p_value,
        threshold=INFORMATION_P_VALUE,
        finding=(f"information about the input: F-test of the input terms (degree {degree}, "
                 f"{nb} lag(s) from delay {nk}) against the output's own past: F = "
                 f"{f_stat:.3g}, p = {p_value:.3g}, at most {INFORMATION_P_VALUE:g} needed"),
        advice=("; the output does not depend on the input in these data (a wrong "
                f"column, a loop that was open, a dead actuator?): {_ADVICE_TEST}")))

    gain, gain_std = static_gain(model)
    z = abs(gain) / gain_std if gain_std > 0 else (math.inf if gain_std == 0 else math.nan)
    lo, hi = model.input_range_pct
    if math.isnan(z):
        checks.append(Check(
            name="gain_significance", passed=False, severity="warning", measured=math.nan,
            threshold=GAIN_Z_MIN,
            message=(f"static gain: g = {gain:.4g} {gain_unit} over s in [{lo:g}, {hi:g}]; "
                     "its significance cannot be judged (the model stores no covariance)")))
    else:
        checks.append(_check(
            "gain_significance", z >= GAIN_Z_MIN, "warning", measured=z, threshold=GAIN_Z_MIN,
            finding=(f"static gain: g = {gain:.4g} +- {gain_std:.3g} {gain_unit} over s in "
                     f"[{lo:g}, {hi:g}], |g|/std(g) = {z:.3g}, at least {GAIN_Z_MIN:g} needed"),
            advice=("; the data do not determine this model's steady-state gain (not "
                    f"even its sign): do not control with it; {_ADVICE_TEST}, or try "
                    "other orders (--orders paper)")))

    pole, pole_std = pole_nearest_one(model)
    distance = abs(1.0 - pole)
    pole_z = distance / pole_std if pole_std > 0 else math.inf
    at_one = distance < POLE_AT_ONE_ATOL or pole_z < POLE_Z_MIN
    checks.append(_check(
        "pole_at_one", not at_one, "warning", measured=pole_z, threshold=POLE_Z_MIN,
        finding=(f"pole nearest to z = 1: p = {pole:.6g}, |1 - p| = {distance:.3g} = "
                 f"{pole_z:.3g} standard deviations, at least {POLE_Z_MIN:g} needed"),
        advice=("; the data cannot tell this model from an integrator, so its "
                f"steady-state gain is not finite for control; {_ADVICE_TEST}")))

    duration_s = data.n_samples * data.ts_s
    tau_s = slowest_time_constant_s(model)
    slow = tau_s > TIME_CONSTANT_RECORD_MAX * duration_s
    checks.append(_check(
        "slow_pole", not slow, "warning", measured=tau_s / duration_s,
        threshold=TIME_CONSTANT_RECORD_MAX,
        finding=(f"slowest time constant: {tau_s:.4g} s = {tau_s / duration_s:.3g} x the "
                 f"record ({duration_s:.4g} s), at most {TIME_CONSTANT_RECORD_MAX:g} x"),
        advice=("; the record does not show the model settle, so its steady-state "
                "gain is an extrapolation; record steps that each settle")))

    ds = np.linspace(lo, hi, 201) - model.operating_point.triac_pct
    local = model.linear_static_gain * model.input_nonlinearity_slope(ds)
    sign_changes = bool(np.any(local > 0) and np.any(local < 0))
    positive = math.isfinite(gain) and gain > 0 and not sign_changes
    if not positive:
        detail = ("the local gain changes sign inside the input range (the steady-state map "
                  "is not monotone)" if sign_changes else "the gain is negative or zero")
    checks.append(Check(
        name="gain_sign", passed=positive, severity="warning", measured=gain, threshold=0.0,
        message=(f"gain sign: static gain g = {gain:.4g} {gain_unit} over s in [{lo:g}, {hi:g}]"
                 + (", positive on the whole range" if positive else
                    f"; {detail}. That can be the process (a cooling loop, a dilution), but "
                    "the MPC ('czmpc simulate', 'czmpc run') refuses a model whose static "
                    "gain over its input range is not positive"))))

    delay_s = nk * model.ts_s
    dominance = delay_s / (delay_s + tau_s) if delay_s + tau_s > 0 else 0.0
    share = delay_s / duration_s
    long_delay = dominance > DELAY_DOMINANCE_MAX or share > DELAY_RECORD_MAX
    checks.append(_check(
        "long_delay", not long_delay, "warning", measured=dominance,
        threshold=DELAY_DOMINANCE_MAX,
        finding=(f"delay: {nk} sample(s) = {delay_s:g} s; normalized dead time L/(L+T) = "
                 f"{dominance:.3g} (at most {DELAY_DOMINANCE_MAX:g}), {100 * share:.3g} % of "
                 f"the record (at most {100 * DELAY_RECORD_MAX:g} %)"),
        advice=("; a delay-dominated process: check the delay against the process, and "
                "record a test several delays long")))
    return IdentifiabilityAssessment(checks=tuple(checks))


class UnidentifiableDataError(IdentificationError):
    """The data cannot support a model: at least one refusal of an identifiability check.

    Attributes
    ----------
    assessment :
        Every check run, passed or not; ``assessment.refusals`` are the reasons.
    """

    def __init__(self, assessment: IdentifiabilityAssessment, *, where: str = "identify") -> None:
        self.assessment = assessment
        reasons = "; ".join(c.message for c in assessment.refusals)
        super().__init__(f"{where}: the data cannot support a model: {reasons}")


def structure_before_fit(
    orders: str | tuple[int, ...], *, degree: int = 2
) -> tuple[int, int, int, str]:
    """``(degree, nb, n_parameters, name)`` of the smallest structure an identification fits.

    Parameters
    ----------
    orders :
        ``"auto"`` (the search's smallest: degree 1, ``nb = 1``, one pole and its noise
        model), ``"paper"`` (degree 2, ``nb = 2``, ``nf = nc = 1``) or
        ``(nb, nf, nk[, nc])``, ``nc = nf`` by default (`czmpc identify --orders`).
    degree :
        Input-polynomial degree used with ``"paper"`` and explicit orders.

    Raises
    ------
    IdentificationError
        Orders of another form.
    """
    if orders == "auto":
        return 1, 1, 3, "the smallest structure of the order search (degree 1, nb 1, nf 1)"
    if orders == "paper":
        return degree, 2, degree + 3, "the paper's structure (degree 2, nb 2, nf 1, nc 1)"
    if isinstance(orders, tuple) and len(orders) in (3, 4) and all(
            isinstance(v, int) and v >= 0 for v in orders):
        nb, nf = orders[0], orders[1]
        nc = orders[3] if len(orders) == 4 else nf
        return (degree, max(nb, 1), (max(nb, 1) - 1) + degree + nf + nc,
                f"the given orders (degree {degree}, nb {nb}, nf {nf}, nc {nc})")
    raise IdentificationError(
        f"structure_before_fit: orders must be 'auto', 'paper' or (nb, nf, nk[, nc]); got {orders!r}")


__all__ = [
    "DELAY_DOMINANCE_MAX", "DELAY_RECORD_MAX", "GAIN_Z_MIN", "INFORMATION_P_VALUE",
    "INPUT_STD_RTOL", "PE_ORDER_MARGIN", "PE_RANK_RTOL", "POLE_AT_ONE_ATOL", "POLE_Z_MIN",
    "SAMPLES_PER_PARAMETER", "TIME_CONSTANT_RECORD_MAX", "Check", "IdentifiabilityAssessment",
    "Severity", "UnidentifiableDataError", "assess_data", "assess_model", "distinct_levels",
    "input_information_test", "input_std_ratio", "persistent_excitation_order", "pole_nearest_one",
    "slowest_time_constant_s", "static_gain", "structure_before_fit"
]
