"""V (ballistic MSE) and W (one-step MSE) criteria, paper eqs. 9-10, and the fit percentage.

Notation
--------
``eps_k = P_k - Psim_k`` is the ballistic simulation error and ``e_k = P_k - Ppred_k`` the
one-step-ahead prediction error [kW] (Table 1). Both criteria average over every sample
``k = 0 .. N-1``, by default with the held-past initial conditions of `sysid.simulate`;
each segment (``Dataset.segment_starts``) restarts with its own initial state and the
squared errors are pooled. ``initial_state="estimate"`` fits each segment's initial
state by least squares (the errors are affine in it), as MATLAB's ``compare`` with
``'InitialCondition', 'estimate'``: fair to records that do not start at rest, which
`start_at_rest` judges; `output_clipping` says when the output saturates, and
`output_held` when a sensor or logger holds each value for several samples.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from scipy.signal import lfilter

from sysid._arrays import CLIP_MIN_RUN_SAMPLES, clipped_samples, robust_std
from sysid._typing import FloatArray
from sysid.data import Dataset
from sysid.errors import IdentificationError
from sysid.identifiability import Check
from sysid.model import Criteria, HammersteinModel
from sysid.optimize import sum_of_squares
from sysid.simulate import predict_one_step, simulate
from sysid.voltage import model_input

#: The input holds its first value, within this share of its span, until its first change.
REST_INPUT_RTOL = 0.01
#: Fewest samples before the first input change for `start_at_rest` to judge a start.
REST_MIN_SAMPLES = 5
#: A start is not at rest when, while the input holds its first value, the output's
#: straight-line trend moves it by more than this share of its recorded span ...
REST_DRIFT_SHARE = 0.05
#: ... and by more than this many standard errors (noise: the larger of the window's
#: residual and the record's, from second differences).
REST_DRIFT_Z = 3.0

#: `output_held` judges a log whose output changes at least this many times ...
HELD_MIN_CHANGES = 20
#: ... and calls it held when this share of the changes falls on one sample in ``m``.
#: Measured: held logs 1.00; the real logs as recorded and quantised to 50 or 200
#: levels at most 0.53 (0.5 is one sample in 2 by chance).
HELD_MIN_SHARE = 0.9

#: Initial-state policies of the criteria.
CriterionInitialState = Literal["held", "estimate"]


def _check_policy(value: object, where: str) -> CriterionInitialState:
    if value not in ("held", "estimate"):
        raise IdentificationError(f"{where}: initial_state must be 'held' or 'estimate'; got {value!r}")
    return "held" if value == "held" else "estimate"


def estimated_state_errors(
    num: FloatArray, den: FloatArray, x: FloatArray, target: FloatArray, n_state: int
) -> FloatArray:
    """``target - (num/den) x`` with the ``n_state`` initial transients fitted by least squares.

    The free response ``1/den`` of pulses in the first ``n_state`` samples spans what any
    initial state of the observer form adds to the zero-past output.
    """
    base: FloatArray = target - lfilter(num, den, x)
    if n_state == 0:
        return base
    pulses = np.zeros((x.size, n_state))
    m = min(n_state, x.size)
    pulses[np.arange(m), np.arange(m)] = 1.0
    free = lfilter([1.0], den, pulses, axis=0)
    fitted: FloatArray = base - free @ np.linalg.lstsq(free, base, rcond=None)[0]
    return fitted


def errors_with_fitted_state(model: HammersteinModel, data: Dataset, *,
                             one_step: bool = False) -> FloatArray:
    """Ballistic (or one-step) errors with each segment's initial state fitted [kW].

    ``P_k - Psim_k`` (or ``P_k - Ppred_k`` with ``one_step``) for every sample, each
    segment's initial state fitted by least squares, as MATLAB's ``compare`` and
    ``resid`` with ``'InitialCondition', 'estimate'``: for a record that may start in a
    transient, which the held past (`sysid.simulate`) misreads (seen: one 5.9 kW
    one-step error at the start of a 900-sample validation record, ten times the
    record's other residuals).

    Raises
    ------
    SamplingTimeError
        ``data.ts_s`` differs from ``model.ts_s``.
    """
    model.check_ts(data.ts_s)
    op = model.operating_point
    y = data.power_kw - op.power_kw
    w = model_input(model, data)
    parts = [_segment_estimated_errors(model, y[lo:hi], w[lo:hi], one_step)
             for lo, hi in data.segment_bounds()]
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _segment_estimated_errors(
    model: HammersteinModel, y: FloatArray, w: FloatArray, one_step: bool
) -> FloatArray:
    """`errors_with_fitted_state` of one segment: output ``y``, ``w = f(ds)``."""
    a, b = model.a, model.b
    if not one_step or model.linear_block == "oe":
        return estimated_state_errors(b, a, w, y, max(a.size, b.size) - 1)
    c = np.array([1.0]) if model.linear_block == "arx" else model.c
    v = lfilter(a, [1.0], y) - lfilter(b, [1.0], w)
    # C e = v + g: the same fit with num = 1, den = C, input v, target 0, sign flipped
    n_state = max(a.size, b.size, c.size) - 1
    return -estimated_state_errors(np.array([1.0]), c, v, np.zeros_like(v), n_state)


def _pair(measured: FloatArray, modelled: FloatArray, where: str) -> tuple[FloatArray, FloatArray]:
    """Both as float arrays, refused unless non-empty, 1-D and of equal length."""
    y = np.asarray(measured, dtype=float)
    yhat = np.asarray(modelled, dtype=float)
    if y.ndim != 1 or y.shape != yhat.shape or y.size == 0:
        raise IdentificationError(
            f"{where}: measured and modelled must be non-empty 1-D arrays of equal length; "
            f"got shapes {y.shape} and {yhat.shape}"
        )
    return y, yhat


def mean_squared_error(measured: FloatArray, modelled: FloatArray) -> float:
    """``(1/N) sum (measured - modelled)^2``: V or W on arrays (eqs. 9-10) [unit^2].

    Raises
    ------
    IdentificationError
        Arrays that are not 1-D, empty, or of unequal length.
    """
    y, yhat = _pair(measured, modelled, "mean_squared_error")
    err = y - yhat
    return sum_of_squares(err) / err.size


def ballistic_mse(
    model: HammersteinModel, data: Dataset, *, initial_state: CriterionInitialState = "held"
) -> float:
    """``V``: mean squared ballistic simulation error of a model on a record (eq. 9).

    Parameters
    ----------
    model :
        The model to simulate.
    data :
        The record (absolute units).
    initial_state :
        ``"held"`` (the past held at the first sample) or ``"estimate"`` (fitted by
        least squares).

    Returns
    -------
    float
        ``V`` [kW^2].

    Raises
    ------
    SamplingTimeError
        ``data.ts_s`` differs from ``model.ts_s``.
    """
    if _check_policy(initial_state, "ballistic_mse") == "estimate":
        err = errors_with_fitted_state(model, data)
        return sum_of_squares(err) / err.size
    return mean_squared_error(data.power_kw, simulate(model, data))


def one_step_mse(
    model: HammersteinModel, data: Dataset, *, initial_state: CriterionInitialState = "held"
) -> float:
    """``W``: mean squared one-step-ahead prediction error on a record (eq. 10).

    Parameters
    ----------
    model :
        The model; its noise model ``C`` forms the predictor (OE: ``W = V``).
    data :
        The record (absolute units).
    initial_state :
        ``"held"`` (past held at the first sample, past errors zero) or ``"estimate"``
        (the predictor's initial state fitted by least squares).

    Returns
    -------
    float
        ``W`` [kW^2].

    Raises
    ------
    SamplingTimeError
        ``data.ts_s`` differs from ``model.ts_s``.
    """
    if _check_policy(initial_state, "one_step_mse") == "estimate":
        err = errors_with_fitted_state(model, data, one_step=True)
        return sum_of_squares(err) / err.size
    return mean_squared_error(data.power_kw, predict_one_step(model, data))


def model_criteria(model: HammersteinModel, data: Dataset) -> Criteria:
    """V (eq. 9) and W (eq. 10) of a model on a record, held past: `ballistic_mse` and
    `one_step_mse`, the simulation run once for an OE model (whose predictor is it)."""
    v = ballistic_mse(model, data)
    w = v if model.linear_block == "oe" else one_step_mse(model, data)
    return Criteria(ballistic_mse_kw2=v, one_step_mse_kw2=w)


def fit_percent(measured: FloatArray, simulated: FloatArray) -> float:
    """NRMSE fit [%] as MATLAB's ``compare``: ``100 (1 - |y - yhat| / |y - mean(y)|)``.

    Parameters
    ----------
    measured :
        Measured output ``y``, shape ``(N,)``.
    simulated :
        Simulated or predicted output ``yhat``, same shape and unit.

    Returns
    -------
    float
        100 for a perfect fit, 0 for the mean as a model, negative for worse.

    Raises
    ------
    IdentificationError
        Arrays that are not 1-D, empty, or of unequal length, or a constant `measured`
        (the fit is undefined).

    Examples
    --------
    >>> fit_percent(np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0, 3.0]))
    100.0
    """
    y, yhat = _pair(measured, simulated, "fit_percent")
    spread = float(np.linalg.norm(y - np.mean(y)))
    if spread == 0.0:
        raise IdentificationError(
            "fit_percent: the measured signal is constant, so the normalized fit is "
            "undefined; use a record in which the output varies"
        )
    return 100.0 * (1.0 - float(np.linalg.norm(y - yhat)) / spread)


def start_at_rest(data: Dataset) -> Check:
    """Whether each segment of a record starts at rest: a warning check when one does not.

    While the input holds its first value (within `REST_INPUT_RTOL` of its span), a
    process at rest keeps its output within noise. The start is not at rest when the
    straight line fitted to the output over those samples moves it by more than
    `REST_DRIFT_SHARE` of the segment's output span and by more than `REST_DRIFT_Z`
    standard errors: the record begins inside a transient, which the held past of V
    (eq. 9) and any simulation from rest misread, and may not determine the static
    gain (seen: the TCLab log cut by 5 % at its start moves by 99 % of its span before
    its first input change; no model fitted to it, initial state and offset estimated,
    comes within 3.8 times the full log's model on the full log).

    Parameters
    ----------
    data :
        The record (absolute units), one or more segments.

    Returns
    -------
    Check
        ``start_at_rest``, a warning: measured the largest share of the output span moved
        over the segments' first samples [-]; passed (measured NaN) when no segment holds
        its input for `REST_MIN_SAMPLES` samples.
    """
    where, worst = "", (-1.0, 0.0, 0.0, 0)
    for i, (lo, hi) in enumerate(data.segment_bounds()):
        u, y = data.triac_pct[lo:hi], data.power_kw[lo:hi]
        moved = np.flatnonzero(np.abs(u - u[0]) > REST_INPUT_RTOL * np.ptp(u))
        m = int(moved[0]) if moved.size else u.size
        if m < REST_MIN_SAMPLES or np.ptp(y) == 0.0:
            continue
        k = np.arange(m) - (m - 1) / 2.0
        slope = float(k @ y[:m]) / float(k @ k)
        d2 = np.diff(y, 2)
        noise = max(robust_std(d2) / np.sqrt(6.0),
                    float(np.std(y[:m] - np.mean(y[:m]) - slope * k)))
        drift = slope * (m - 1)
        z = abs(slope) * float(np.sqrt(k @ k)) / noise if noise > 0 else math.inf
        share = abs(drift) / float(np.ptp(y))
        if share > worst[0]:
            worst = (share, z, drift, m)
            where = f" of segment {i + 1}" if data.n_segments > 1 else ""
    share, z, drift, m = worst
    if share < 0:
        return Check(name="start_at_rest", passed=True, severity="warning", measured=math.nan,
                     threshold=REST_DRIFT_SHARE,
                     message=(f"start at rest: not judged, the input changes within the "
                              f"first {REST_MIN_SAMPLES} samples of every segment"))
    at_rest = share <= REST_DRIFT_SHARE or z <= REST_DRIFT_Z
    return Check(
        name="start_at_rest", passed=at_rest, severity="warning", measured=share,
        threshold=REST_DRIFT_SHARE,
        message=(f"start at rest: while the input holds its first value for the first {m} "
                 f"samples{where}, the output's trend moves it by {drift:.4g} "
                 f"{data.output_unit} ({100 * share:.3g} % of its recorded span, "
                 f"{z:.3g} standard errors; a start at rest moves at most "
                 f"{100 * REST_DRIFT_SHARE:g} % or {REST_DRIFT_Z:g} standard errors)"
                 + ("" if at_rest else
                    "; the record does not start at rest but inside a transient that an "
                    "input change before it caused, which the record does not show: a "
                    "model simulated from rest at the first sample misreads that "
                    "transient, and the record alone may not determine the static gain "
                    "(see gain_significance); log from a steady state before the first "
                    "input change")))


def output_clipping(data: Dataset) -> Check:
    """Whether the output saturates: a warning check when it sits at its extreme.

    Samples in exactly constant runs of at least `sysid._arrays.CLIP_MIN_RUN_SAMPLES` at
    the output's recorded maximum or minimum (per segment) are a saturated sensor or
    process (the cascaded tanks overflow at 10 V): the models identified here, linear in
    their dynamics, cannot follow the output there, and those samples pull the fit. A run
    from a segment's first sample is the level it starts at, not clipping.

    Parameters
    ----------
    data :
        The record (absolute units), one or more segments.

    Returns
    -------
    Check
        ``output_clipping``, a warning: measured the clipped samples [-], threshold 0.
    """
    clipped = [(lo + k, float(data.power_kw[lo + k]))
               for lo, hi in data.segment_bounds() for k in clipped_samples(data.power_kw[lo:hi])]
    n = len(clipped)
    values = ", ".join(f"{v:.6g}" for v in sorted({v for _, v in clipped}))
    return Check(
        name="output_clipping", passed=n == 0, severity="warning", measured=float(n),
        threshold=0.0,
        message=(f"output clipping: no run of {CLIP_MIN_RUN_SAMPLES} or more samples at the "
                 "output's extreme" if n == 0 else
                 f"output clipping: {n} sample(s) ({100 * n / data.n_samples:.3g} % of the "
                 f"record, from t = {data.time_s[clipped[0][0]]:g} s) sit in runs of "
                 f"{CLIP_MIN_RUN_SAMPLES} or more at the output's extreme ({values} "
                 f"{data.output_unit}): a saturated sensor or process, which the model cannot "
                 "follow and whose samples pull its fit; log inside the sensor's range, or "
                 "blank those rows and identify with --gaps split"))


def output_held(data: Dataset) -> Check:
    """Whether a sensor or logger holds the output: a warning check when it changes only
    every ``m``-th sample, in step with the stamps.

    A sensor that updates every ``m Ts``, logged every ``Ts``, repeats each value ``m``
    times: its changes all fall on one sample in ``m``. Quantisation repeats values too,
    but at irregular samples. ``m`` is the most common number of samples between changes;
    the log is held when ``m >= 2`` and at least `HELD_MIN_SHARE` of the changes (of at
    least `HELD_MIN_CHANGES`) fall on one residue modulo ``m`` in each segment.

    Parameters
    ----------
    data :
        The record (absolute units), one or more segments.

    Returns
    -------
    Check
        ``output_held``, a warning: measured ``m``, the samples each value is held (1: the
        output moves at the log's own rate; NaN: not judged), threshold 1.
    """
    changes = [np.flatnonzero(np.diff(data.power_kw[lo:hi]) != 0.0) + 1
               for lo, hi in data.segment_bounds()]
    n = sum(c.size for c in changes)
    if n < HELD_MIN_CHANGES:
        return Check(name="output_held", passed=True, severity="warning", measured=math.nan,
                     threshold=1.0,
                     message=(f"output held: not judged, the output changes {n} times (fewer "
                              f"than {HELD_MIN_CHANGES})"))
    gaps = np.concatenate([np.diff(c) for c in changes])
    m = int(np.argmax(np.bincount(gaps))) if gaps.size else 1
    on_one = sum(int(np.max(np.bincount(c % m))) for c in changes if c.size) if m >= 2 else 0
    share = on_one / n
    held = m >= 2 and share >= HELD_MIN_SHARE
    ts = data.ts_s
    return Check(
        name="output_held", passed=not held, severity="warning", measured=float(m if held else 1),
        threshold=1.0,
        message=(f"output held: the output changes at the log's own rate ({n} changes)"
                 if not held else
                 f"output held: the output changes only once in {m} samples ({100 * share:.3g} % "
                 f"of its {n} changes fall on one sample in {m}): the sensor or logger updates "
                 f"every {m * ts:g} s while the log is stamped every {ts:g} s, so each held "
                 "value is a step the process did not make and the model's sampling time and "
                 f"delay are the stamps'; export the log at the sensor's rate (one sample in "
                 f"{m}) or log the sensor itself"))


__all__ = ["HELD_MIN_CHANGES", "HELD_MIN_SHARE", "REST_DRIFT_SHARE", "REST_DRIFT_Z",
           "REST_INPUT_RTOL", "REST_MIN_SAMPLES",
           "ballistic_mse", "errors_with_fitted_state", "fit_percent", "mean_squared_error",
           "model_criteria", "one_step_mse", "output_clipping", "output_held", "start_at_rest"]
