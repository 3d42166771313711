"""V (ballistic MSE) and W (one-step MSE) criteria, paper eqs. 9-10, and the fit percentage.

Notation
--------
``eps_k = P_k - Psim_k`` is the ballistic simulation error and ``e_k = P_k - Ppred_k`` the
one-step-ahead prediction error [kW] (Table 1). Both criteria average over every sample
of the record, ``k = 0 .. N-1``, with the held-past initial conditions of
`sysid.simulate`.
"""

from __future__ import annotations

import numpy as np

from sysid._typing import FloatArray
from sysid.data import Dataset
from sysid.errors import IdentificationError
from sysid.model import HammersteinModel
from sysid.optimize import sum_of_squares
from sysid.simulate import predict_one_step, simulate


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


def ballistic_mse(model: HammersteinModel, data: Dataset) -> float:
    """``V``: mean squared ballistic simulation error of a model on a record (eq. 9).

    Parameters
    ----------
    model :
        The model to simulate.
    data :
        The record (absolute units).

    Returns
    -------
    float
        ``V`` [kW^2].

    Raises
    ------
    SamplingTimeError
        ``data.ts_s`` differs from ``model.ts_s``.
    """
    return mean_squared_error(data.power_kw, simulate(model, data))


def one_step_mse(model: HammersteinModel, data: Dataset) -> float:
    """``W``: mean squared one-step-ahead prediction error on a record (eq. 10).

    Parameters
    ----------
    model :
        The model; its noise model ``C`` forms the predictor (OE: ``W = V``).
    data :
        The record (absolute units).

    Returns
    -------
    float
        ``W`` [kW^2].

    Raises
    ------
    SamplingTimeError
        ``data.ts_s`` differs from ``model.ts_s``.
    """
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


__all__ = ["ballistic_mse", "fit_percent", "mean_squared_error", "one_step_mse"]
