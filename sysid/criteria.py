"""V (ballistic MSE) and W (one-step MSE) criteria, paper eqs. 9-10, and the fit percentage.

Notation
--------
``eps_k = P_k - Psim_k`` is the ballistic simulation error and ``e_k = P_k - Ppred_k`` the
one-step-ahead prediction error [kW] (Table 1). Both criteria average over every sample
of the record, ``k = 0 .. N-1``, by default with the held-past initial conditions of
`sysid.simulate`. A record of several segments (``Dataset.segment_starts``) is scored
segment by segment, each restarted with its own initial state under the same policy,
and the squared errors are pooled over all samples; ``initial_state="estimate"``
scores the model with its initial state (each segment's) fitted by least squares (the
errors are affine in it), as MATLAB's ``compare`` with ``'InitialCondition',
'estimate'``, which is fair to records that do not start at rest.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy.signal import lfilter

from sysid._typing import FloatArray
from sysid.data import Dataset
from sysid.errors import IdentificationError
from sysid.model import HammersteinModel
from sysid.optimize import sum_of_squares
from sysid.simulate import predict_one_step, simulate

#: Initial-state policies of the criteria.
CriterionInitialState = Literal["held", "estimate"]


def _check_policy(value: object, where: str) -> CriterionInitialState:
    if value == "held":
        return "held"
    if value == "estimate":
        return "estimate"
    raise IdentificationError(
        f"{where}: initial_state must be 'held' or 'estimate'; got {value!r}"
    )


def estimated_state_errors(
    num: FloatArray, den: FloatArray, x: FloatArray, target: FloatArray, n_state: int
) -> FloatArray:
    """``target - (num/den) x`` with the ``n_state`` initial transients fitted by least squares.

    Kernel: the output of ``num/den`` driven by ``x`` from a zero past, plus the free
    response ``(1/den)`` of a transient in the first ``n_state`` samples (what any
    initial state of the observer form adds), the transient chosen to minimize the sum
    of squared errors.
    """
    base = target - lfilter(num, den, x)
    if n_state == 0:
        out: FloatArray = base
        return out
    pulses = np.zeros((x.size, n_state))
    m = min(n_state, x.size)
    pulses[np.arange(m), np.arange(m)] = 1.0
    free = lfilter([1.0], den, pulses, axis=0)
    coef = np.linalg.lstsq(free, base, rcond=None)[0]
    out = base - free @ coef
    return out


def errors_with_fitted_state(model: HammersteinModel, data: Dataset, *,
                             one_step: bool = False) -> FloatArray:
    """Ballistic (or one-step) errors with each segment's initial state fitted [kW].

    ``P_k - Psim_k`` (or ``P_k - Ppred_k`` with ``one_step``) for every sample, each
    segment's initial state fitted by least squares (the errors are affine in it), as
    MATLAB's ``compare`` and ``resid`` with ``'InitialCondition', 'estimate'``. Use it
    to score a record that may start in a transient, such as the held-out end of a test
    cut in the middle of a ramp: the held-past rule (`sysid.simulate`) would charge the
    model with the wrong initial state (seen: one 5.9 kW one-step error at the start of
    a 900-sample validation record, ten times the whole record's other residuals).

    Raises
    ------
    SamplingTimeError
        ``data.ts_s`` differs from ``model.ts_s``.
    """
    model.check_ts(data.ts_s)
    op = model.operating_point
    y = data.power_kw - op.power_kw
    w = np.asarray(model.input_nonlinearity(data.triac_pct - op.triac_pct), dtype=float)
    parts = [_segment_estimated_errors(model, y[lo:hi], w[lo:hi], one_step)
             for lo, hi in data.segment_bounds()]
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _segment_estimated_errors(
    model: HammersteinModel, y: FloatArray, w: FloatArray, one_step: bool
) -> FloatArray:
    a, b = model.a, model.b
    if not one_step or model.linear_block == "oe":
        return estimated_state_errors(b, a, w, y, max(a.size, b.size) - 1)
    c = np.array([1.0]) if model.linear_block == "arx" else model.c
    v = lfilter(a, [1.0], y) - lfilter(b, [1.0], w)
    # C e = v + g: the same fit with num = 1, den = C, input v, target 0, sign flipped
    n_state = max(a.size, b.size, c.size) - 1
    return -estimated_state_errors(np.array([1.0]), c, v, np.zeros_like(v), n_state)


def _pair(measured: FloatArray, modelled: FloatArray, where: str) -> tuple[FloatArray, FloatArray]:
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


__all__ = ["ballistic_mse", "errors_with_fitted_state", "fit_percent", "mean_squared_error",
           "one_step_mse"]
