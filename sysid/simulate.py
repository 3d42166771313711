"""Ballistic simulation and one-step-ahead prediction of a model (paper eqs. 5-7, 9-10).

Notation
--------
``y = dP = P - P_nom`` [kW], ``u = w = f(ds)`` [kW-equivalent input] with ``ds = s - s_nom``
[%]; ``A``, ``B``, ``C``, ``F`` are q^-1 polynomials (ascending powers, paper eqs. 1-4).
The ``*_arrays`` kernels work on deviation arrays; `simulate` and `predict_one_step` take
a `HammersteinModel` and a `Dataset` in absolute units.

* Ballistic simulation (OE, eq. 7): ``F(q) yhat_k = B(q) u_k``, blind to the measured
  output after the start (the ``eps`` of eq. 9).
* One-step prediction (eqs. 5-6): ``C(q) yhat_k = (C(q) - A(q)) y_k + B(q) u_k``, so the
  error ``e = y - yhat`` obeys ``C(q) e_k = A(q) y_k - B(q) u_k`` (the ``e`` of eq. 10).
  ARX has ``C = 1``; OE (``C = A``) gives the simulation.

Initial conditions (the *held-past* rule)
-----------------------------------------
No filter starts from a zero state (its transient would dominate V and W). Before the
record (``k < 0``) the inputs are held at ``u_0``, the measured and the simulated outputs
at ``y_0`` (the first sample is taken as a rest point), and past prediction errors are
zero (so the OE predictor reproduces the OE simulation). `filter_state` turns these pasts
into the `scipy.signal.lfilter` state; the kernels also take explicit pasts (``y_past``,
``e_past``, most recent first: ``[y_{-1}, y_{-2}, ...]``). Models and their V and W always
use this rule, so they are reproducible from the model and the data alone (the
identification kernels of `sysid.linear` can instead estimate the initial state).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.signal import lfilter

from sysid._typing import FloatArray
from sysid.data import Dataset
from sysid.model import HammersteinModel
from sysid.voltage import model_input


def filter_state(b: FloatArray, a: FloatArray, y_past: FloatArray,
                 x_past: FloatArray | None = None) -> FloatArray:
    """The `scipy.signal.lfilter` state that past outputs and inputs leave (``lfiltic``).

    ``zi[m] = (sum_{i>m} b_i x_{m-i} - sum_{i>m} a_i y_{m-i}) / a_0`` with the pasts most
    recent first (``[y_{-1}, y_{-2}, ..]``, missing values zero): what ``lfiltic``
    returns, on Python floats, a twentieth of its time for these low orders (every
    simulation and every OE residual evaluation needs one).
    """
    bl = [float(v) for v in np.asarray(b, dtype=float).reshape(-1)]
    al = [float(v) for v in np.asarray(a, dtype=float).reshape(-1)]
    m_b, n_a = len(bl) - 1, len(al) - 1
    xs = [] if x_past is None else [float(v) for v in np.asarray(x_past, dtype=float).reshape(-1)]
    ys = [float(v) for v in np.asarray(y_past, dtype=float).reshape(-1)]
    xs = (xs + [0.0] * m_b)[:m_b]
    ys = (ys + [0.0] * n_a)[:n_a]
    zi = [0.0] * max(m_b, n_a)
    for m in range(m_b):
        zi[m] = sum(bl[m + 1 + i] * xs[i] for i in range(m_b - m))
    for m in range(n_a):
        zi[m] -= sum(al[m + 1 + i] * ys[i] for i in range(n_a - m))
    return np.array(zi) / al[0]


def _past(values: FloatArray | float | None, fill: float, n: int) -> FloatArray:
    if values is None:
        return np.full(n, fill)
    arr = np.asarray(values, dtype=float)
    return np.full(n, float(arr)) if arr.ndim == 0 else arr


def simulate_arrays(
    b: FloatArray,
    f: FloatArray,
    u: FloatArray,
    *,
    y_past: FloatArray | float,
) -> FloatArray:
    """Ballistic simulation ``F(q) yhat = B(q) u`` (paper eq. 7) on deviation arrays.

    Parameters
    ----------
    b :
        ``B(q)`` coefficients, ascending powers of q^-1 (leading zeros = delay).
    f :
        ``F(q)`` coefficients, ``f[0] = 1``; must be stable for a bounded output.
    u :
        Input samples, shape ``(N,)``; the past is held at ``u[0]``.
    y_past :
        Simulated outputs before the record, ``[yhat_{-1}, ..., yhat_{-nf}]``, or one
        value held for all of them: the first measured output ``y_0`` under the
        held-past rule.

    Returns
    -------
    FloatArray
        ``yhat``, shape ``(N,)``.

    Notes
    -----
    Implemented as ``lfilter(b, f, u, zi=filter_state(b, f, y_past, [u_0]*(len(b)-1)))``.
    Kernel: trusts its inputs (finite, 1-D, ``f[0] = 1``).
    """
    nf = len(f) - 1
    zi = filter_state(b, f, _past(y_past, 0.0, nf), np.full(max(len(b) - 1, 0), u[0]))
    out: FloatArray = lfilter(b, f, u, zi=zi)[0]
    return out


def _held_fir(coef: FloatArray, x: FloatArray) -> FloatArray:
    """``sum_j coef_j x_{k-j}`` with the past held at ``x_0``: a convolution of the padded record."""
    c = np.asarray(coef, dtype=float)
    padded = np.concatenate([np.full(c.size - 1, x[0]), x]) if c.size > 1 else x
    out: FloatArray = np.convolve(padded, c, mode="valid")
    return out


def equation_errors(a: FloatArray, b: FloatArray, y: FloatArray, u: FloatArray) -> FloatArray:
    """``v_k = A(q) y_k - B(q) u_k`` with the past of ``y`` and ``u`` held at their first values.

    By `numpy.convolve` (a tenth of ``lfilter``'s time for these short FIRs): every
    ARMAX residual evaluation has two.
    """
    return _held_fir(a, y) - _held_fir(b, u)


def prediction_errors_arrays(
    a: FloatArray,
    b: FloatArray,
    c: FloatArray,
    y: FloatArray,
    u: FloatArray,
    *,
    e_past: FloatArray | None = None,
) -> FloatArray:
    """One-step prediction errors ``e`` of ``A y = B u + C e`` (paper eqs. 5-6, 10).

    Parameters
    ----------
    a, b, c :
        ``A(q)``, ``B(q)``, ``C(q)``, ascending powers of q^-1; ``a[0] = c[0] = 1``;
        ``C`` must be stable.
    y, u :
        Measured output and input, shape ``(N,)``; their pasts are held at ``y[0]``
        and ``u[0]``.
    e_past :
        Prediction errors before the record, ``[e_{-1}, ..., e_{-nc}]``; default zeros.

    Returns
    -------
    FloatArray
        ``e = y - yhat``, shape ``(N,)``, from ``C(q) e_k = A(q) y_k - B(q) u_k``.
    """
    nc = len(c) - 1
    v = equation_errors(a, b, y, u)
    zi = filter_state(np.ones(1), c, _past(e_past, 0.0, nc))
    out: FloatArray = lfilter([1.0], c, v, zi=zi)[0]
    return out


def predict_one_step_arrays(
    a: FloatArray,
    b: FloatArray,
    c: FloatArray,
    y: FloatArray,
    u: FloatArray,
    *,
    e_past: FloatArray | None = None,
) -> FloatArray:
    """One-step-ahead prediction ``C yhat = (C - A) y + B u`` on deviation arrays.

    Same arguments as `prediction_errors_arrays`; returns ``yhat = y - e``, shape ``(N,)``.
    """
    return np.asarray(y, dtype=float) - prediction_errors_arrays(a, b, c, y, u, e_past=e_past)


def _per_segment(model: HammersteinModel, data: Dataset,
                 kernel: Callable[[FloatArray, FloatArray], FloatArray]) -> FloatArray:
    """``P_nom + kernel(dP, f(ds))`` [kW], the kernel restarted on each segment."""
    model.check_ts(data.ts_s)
    op = model.operating_point
    dp_kw = data.power_kw - op.power_kw
    w = model_input(model, data)
    yhat = np.empty_like(dp_kw)
    for lo, hi in data.segment_bounds():
        yhat[lo:hi] = kernel(dp_kw[lo:hi], w[lo:hi])
    return yhat + op.power_kw


def simulate(model: HammersteinModel, data: Dataset) -> FloatArray:
    """Ballistic simulation of the model's power over a data set [kW] (paper eq. 7).

    Parameters
    ----------
    model :
        The model; ``dP = B/A f(ds)`` is simulated whatever its noise model.
    data :
        The record: its TRIAC input drives the model; its first measured power sets
        the initial condition (held-past rule, see the module docstring). A record of
        several segments is simulated segment by segment, each restarted from its own
        first sample by the same rule.

    Returns
    -------
    FloatArray
        Simulated power ``P_nom + yhat`` [kW], shape ``(n_samples,)``.

    Raises
    ------
    SamplingTimeError
        ``data.ts_s`` differs from ``model.ts_s``.
    """
    return _per_segment(model, data, lambda y, w: simulate_arrays(model.b, model.a, w,
                                                                  y_past=float(y[0])))


def predict_one_step(model: HammersteinModel, data: Dataset) -> FloatArray:
    """One-step-ahead predicted power over a data set [kW] (paper eqs. 5-6, 10).

    Uses the model's noise model ``C``: ``C yhat = (C - A) dP + B f(ds)``. For
    ``linear_block = "oe"`` (stored with ``C = A``) this is the ballistic simulation,
    and `simulate` is returned exactly; for ``"arx"`` ``C = 1``.

    Parameters
    ----------
    model :
        The model.
    data :
        The record (measured power and TRIAC input), held-past initial conditions;
        restarted at the first sample of each segment.

    Returns
    -------
    FloatArray
        Predicted power ``P_nom + yhat`` [kW], shape ``(n_samples,)``.

    Raises
    ------
    SamplingTimeError
        ``data.ts_s`` differs from ``model.ts_s``.
    """
    if model.linear_block == "oe":
        return simulate(model, data)
    c = np.array([1.0]) if model.linear_block == "arx" else model.c
    return _per_segment(model, data, lambda y, w: predict_one_step_arrays(model.a, model.b, c, y, w))


__all__ = [
    "equation_errors",
    "filter_state",
    "predict_one_step",
    "predict_one_step_arrays",
    "prediction_errors_arrays",
    "simulate",
    "simulate_arrays",
]
