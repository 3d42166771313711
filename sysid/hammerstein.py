"""Gain-table initialisation of f(ds), re-identification and joint PEM of a Hammerstein model.

The paper's route (secs. 7.3-7.6), each step a pure function with a frozen result:

1. `initial_input_poly`: the coefficients of ``f`` by least squares from the input
   steps' instantaneous responses and an ARX model (eqs. 14-21, Table 3, Fig. 12);
2. `reidentify_linear_block`: ``f`` fixed, the linear block re-identified with input
   ``w = f(ds)`` by ARX or OE (sec. 7.4, Fig. 13);
3. `fit_hammerstein_oe`: all parameters at once in the normalized form of eq. 25
   (``b1 = 1``) by PEM on V, an instance of `sysid.greybox` with the structure of
   eq. 26 (sec. 7.5), from good initial values or from zeros;
4. `fit_hammerstein_armax`: the noise-model extension of eqs. 29-32 by PEM on W.

`fit_hammerstein` runs them all on a `Dataset` and returns an `IdentificationResult`.

Notation
--------
``y = dP = P - P_nom`` [kW], ``ds = s - s_nom`` [%] (deviation variables, sec. 5.1).
``f(ds) = sum_{i=1..n} p_i ds^i`` with no constant term (``input_poly = [p_1, ..., p_n]``,
the paper's ``d1, d2``). The linear block is ``A(q) y = B(q) f(ds) + C(q) e``, with
``B(q) = q^-nk (b_nk + b_{nk+1} q^-1 + ...)``: parameters are named by the lag they
multiply (``b2`` multiplies ``q^-2``), as in `sysid.linear`. In the normalized form
(eqs. 22-25) ``b_nk = 1``; the paper's ``b~2, d~1, d~2`` are ``b2, d1, d2`` here.

* OE block (eq. 27): ``C = A = F``; parameters ``b_{nk+1}.., d1..dn, f1..f_nf``.
* ARMAX block (eq. 30): parameters ``b.., d.., a1..a_na, k1..k_nc`` with
  ``c_i = a_i + k_i`` (eq. 32); ``k`` is the Kalman gain of eq. 29.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

import casadi as ca
import numpy as np
import numpy.typing as npt

from sysid._arrays import readonly_array as _readonly
from sysid._typing import FloatArray
from sysid.criteria import ballistic_mse, one_step_mse
from sysid.data import Dataset
from sysid.errors import IdentificationError, IdentificationWarning, UnstableModelError
from sysid.greybox import GreyBoxResult, GreyBoxStructure, fit_greybox, greybox_residuals
from sysid.linear import arx_least_squares, oe_pem
from sysid.model import Criteria, HammersteinModel, OperatingPoint, Provenance
from sysid.optimize import parameter_std_errors
from sysid.polynomials import reflect_unstable_roots
from sysid.result import IdentificationResult
from sysid.steps import InputStep, detect_steps

HammersteinBlock = Literal["arx", "oe", "armax"]
RowForm = Literal["eq21", "jump"]


# =========================================================================== values

@dataclass(frozen=True, kw_only=True, eq=False)
class HammersteinFit:
    """A Hammerstein model estimated on deviation arrays (one step of the route).

    Parameters
    ----------
    linear_block :
        ``"arx"``, ``"oe"`` or ``"armax"``.
    a, b, c :
        ``A(q)`` (``F`` for OE), ``B(q)`` normalized (first non-zero is 1, leading
        zeros are the delay), ``C(q)`` (``[1]`` for ARX, ``A`` for OE); ascending powers
        of q^-1.
    input_poly :
        ``[p_1, ..., p_n]``: ``f(ds) = sum p_i ds^i`` [kW-equivalent per %^i].
    parameter_names :
        Names of the estimated parameters (empty if nothing was estimated).
    parameters, std_errors :
        Their values and standard errors (``inf`` where the data do not determine one).
    residuals :
        Residuals of the minimized criterion, shape ``(n_samples,)`` or shorter for
        ARX equation errors [kW].
    criterion :
        ``"ballistic"`` (V, eq. 9), ``"one_step"`` (W, eq. 10) or ``"least_squares"``.
    cost :
        Mean square of `residuals` [kW^2].
    n_iterations, converged, message :
        From the optimizer (0, True, "least squares" for closed-form steps).
    method :
        Short label of the step that produced it (for provenance).
    greybox :
        The grey-box result behind a joint PEM, or None.
    """

    linear_block: HammersteinBlock
    a: FloatArray
    b: FloatArray
    c: FloatArray
    input_poly: FloatArray
    parameter_names: tuple[str, ...]
    parameters: FloatArray
    std_errors: FloatArray
    residuals: FloatArray = field(repr=False)
    criterion: Literal["ballistic", "one_step", "least_squares"]
    cost: float
    n_iterations: int
    converged: bool
    message: str
    method: str
    greybox: GreyBoxResult | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        for name in ("a", "b", "c", "input_poly", "parameters", "std_errors", "residuals"):
            object.__setattr__(self, name, _readonly(getattr(self, name)))

    @property
    def delay_steps(self) -> int:
        """Input delay ``nk`` [samples]."""
        return int(np.flatnonzero(self.b)[0])

    def values(self) -> dict[str, float]:
        """All model coefficients by the names `sysid.hammerstein` uses (for starts)."""
        nk = self.delay_steps
        out: dict[str, float] = {}
        for j in range(nk + 1, self.b.size):
            out[f"b{j}"] = float(self.b[j])
        for i, p in enumerate(self.input_poly, start=1):
            out[f"d{i}"] = float(p)
        letter = "f" if self.linear_block == "oe" else "a"
        for i in range(1, self.a.size):
            out[f"{letter}{i}"] = float(self.a[i])
        if self.linear_block == "armax":
            for i in range(1, self.c.size):
                a_i = float(self.a[i]) if i < self.a.size else 0.0
                out[f"k{i}"] = float(self.c[i]) - a_i
        return out

    def input_nonlinearity(self, ds_pct: FloatArray | float) -> FloatArray:
        """``f(ds)`` (eq. 28) for TRIAC deviations ``ds`` [%]."""
        return _poly_eval(self.input_poly, np.asarray(ds_pct, dtype=float))


def _poly_eval(input_poly: FloatArray, ds: FloatArray) -> FloatArray:
    out = np.zeros_like(ds, dtype=float)
    for coef in np.asarray(input_poly)[::-1]:
        out = (out + coef) * ds
    return out


def _features(ds: FloatArray, degree: int) -> FloatArray:
    """``[ds, ds^2, ..., ds^n]``, shape ``(N, n)``: the model input of eq. 26."""
    ds = np.asarray(ds, dtype=float)
    return np.column_stack([ds**i for i in range(1, degree + 1)])


def _check_int(name: str, value: object, minimum: int, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise IdentificationError(f"{where}: {name} must be an int >= {minimum}; got {value!r}")
    return int(value)


def _check_arrays(y: Any, ds: Any, where: str) -> tuple[FloatArray, FloatArray]:
    y_arr = np.asarray(y, dtype=float)
    ds_arr = np.asarray(ds, dtype=float)
    if y_arr.ndim != 1 or ds_arr.ndim != 1 or y_arr.size != ds_arr.size:
        raise IdentificationError(
            f"{where}: y and ds must be 1-D arrays of equal length; got shapes "
            f"{y_arr.shape} and {ds_arr.shape}"
        )
    if not (np.all(np.isfinite(y_arr)) and np.all(np.isfinite(ds_arr))):
        raise IdentificationError(f"{where}: y and ds must be finite (repair missing samples)")
    return y_arr, ds_arr


def _check_excitation(ds: FloatArray, degree: int, n_parameters: int, where: str) -> None:
    levels = np.unique(ds)
    if levels.size < degree + 1:
        raise IdentificationError(
            f"{where}: a degree-{degree} input polynomial needs the input at >= {degree + 1} "
            f"distinct levels; got {levels.size} (the record does not excite the "
            "nonlinearity)"
        )
    if ds.size < 10 * n_parameters:
        raise IdentificationError(
            f"{where}: {n_parameters} parameters need at least {10 * n_parameters} samples; "
            f"got {ds.size}"
        )


# =========================================================================== step 1
@dataclass(frozen=True, kw_only=True, eq=False)
class InputPolyInit:
    """Least-squares initial input polynomial from step responses (paper eq. 21).

    Parameters
    ----------
    input_poly :
        ``[d_1, ..., d_n]`` of ``f(ds) = sum d_i ds^i`` in the units of the ARX
        model's input, i.e. before normalization: the ARX ``b`` multiply ``f``.
    std_errors :
        Standard errors of `input_poly` from the least squares.
    regressor :
        The rows of eq. 21, one per step, shape ``(n_steps, n)``.
    target :
        Their left-hand sides, shape ``(n_steps,)`` [kW].
    residuals :
        ``target - regressor @ input_poly`` [kW].
    row_form :
        ``"eq21"`` or ``"jump"`` (see `initial_input_poly`).
    fit :
        The Hammerstein model of the paper's Fig. 12: the ARX polynomials with ``ds``
        replaced by ``f(ds)``, normalized (``B / b_first``, ``f * b_first``).
    """

    input_poly: FloatArray
    std_errors: FloatArray
    regressor: FloatArray = field(repr=False)
    target: FloatArray = field(repr=False)
    residuals: FloatArray
    row_form: RowForm
    fit: HammersteinFit


def initial_input_poly(
    steps: Sequence[InputStep],
    arx_a: npt.ArrayLike,
    arx_b: npt.ArrayLike,
    *,
    operating_point: OperatingPoint,
    degree: int = 2,
    row_form: RowForm = "eq21",
) -> InputPolyInit:
    """Estimate the input polynomial ``f`` from the input steps and an ARX model (eq. 21).

    Parameters
    ----------
    steps :
        Input steps with their instantaneous responses (`sysid.steps.detect_steps`,
        the rows of Table 3), in absolute units.
    arx_a :
        ARX ``A(q) = [1, a_1, ..]`` identified with ``ds`` as input (sec. 6).
    arx_b :
        ARX ``B(q) = [0]*nk + [b_nk, ..]`` (not normalized).
    operating_point :
        ``(s_nom, P_nom)`` the deviations are taken about.
    degree :
        Degree ``n`` of ``f`` (the paper: 2).
    row_form :
        ``"eq21"`` (default, the paper's literal rows) or ``"jump"`` (see Notes).

    Returns
    -------
    InputPolyInit
        The coefficients, their standard errors, the least-squares system and the
        Hammerstein model of Fig. 12.

    Raises
    ------
    IdentificationError
        Fewer steps than ``degree`` (or a rank-deficient system: the steps do not
        span enough input levels), bad polynomials or options.

    Notes
    -----
    Reading of eqs. 15-21. Eq. 20 at the sample ``k`` where a step of the input from
    ``ds_before`` to ``ds_after`` first shows in the output (``k = k_step + nk``) reads,
    with every earlier output at ``dP_before`` (the output just before the jump) and
    the input at ``ds_after`` for lag ``nk`` and ``ds_before`` for longer lags::

        dP_after + (a_1 + .. + a_na) dP_before
            = sum_i d_i (b_nk ds_after^i + (b_{nk+1} + .. ) ds_before^i)       (eq. 21)

    one row per step of Table 3 (for the paper's ``na = 1, nb = 2, nk = 1`` exactly the
    row ``dP_k + f_1 dP_{k-1} = [b_1 ds_{k-1}^2 + b_2 ds_{k-2}^2, b_1 ds_{k-1} + b_2
    ds_{k-2}] [d_2, d_1]'``). This is ``row_form = "eq21"``. If the output was at rest
    before the step under the ARX model, ``A(1) dP_before = (B(1) - ..)``, subtracting
    the rest equation leaves the instantaneous jump of eq. 18:
    ``dP_after - dP_before = b_nk (f(ds_after) - f(ds_before))``, which is
    ``row_form = "jump"`` (it ignores how far from rest the output was). The two agree
    when the steps start from rest. Solved by ordinary least squares (``n``
    unknowns, one row per step; the paper: four rows, two unknowns).
    """
    where = "initial_input_poly"
    degree = _check_int("degree", degree, 1, where)
    if row_form not in ("eq21", "jump"):
        raise IdentificationError(f"{where}: row_form must be 'eq21' or 'jump'; got {row_form!r}")
    a = np.asarray(arx_a, dtype=float)
    b = np.asarray(arx_b, dtype=float)
    if a.ndim != 1 or a.size < 1 or a[0] != 1.0 or not np.all(np.isfinite(a)):
        raise IdentificationError(f"{where}: arx_a must be [1, a1, ...] and finite; got {a.tolist()}")
    nonzero = np.flatnonzero(b)
    if b.ndim != 1 or nonzero.size == 0 or not np.all(np.isfinite(b)):
        raise IdentificationError(
            f"{where}: arx_b must be finite with a non-zero coefficient; got {b.tolist()}"
        )
    steps = tuple(steps)
    if len(steps) < degree:
        raise IdentificationError(
            f"{where}: a degree-{degree} polynomial needs at least {degree} steps; got "
            f"{len(steps)}"
        )
    nk = int(nonzero[0])
    b_first = float(b[nk])
    b_rest = float(np.sum(b[nk + 1 :]))
    a_rest = float(np.sum(a[1:]))
    powers = np.arange(1, degree + 1)
    rows = []
    target = []
    for step in steps:
        ds_before = step.triac_before_pct - operating_point.triac_pct
        ds_after = step.triac_after_pct - operating_point.triac_pct
        dp_before = step.power_before_kw - operating_point.power_kw
        dp_after = step.power_after_kw - operating_point.power_kw
        if row_form == "eq21":
            rows.append(b_first * ds_after**powers + b_rest * ds_before**powers)
            target.append(dp_after + a_rest * dp_before)
        else:
            rows.append(b_first * (ds_after**powers - ds_before**powers))
            target.append(dp_after - dp_before)
    phi = np.asarray(rows, dtype=float)
    rhs = np.asarray(target, dtype=float)
    scale = np.linalg.norm(phi, axis=0)
    if np.any(scale == 0.0):
        raise IdentificationError(f"{where}: the steps give an all-zero column; no information")
    sol, _, rank, _ = np.linalg.lstsq(phi / scale, rhs, rcond=None)
    if rank < degree:
        raise IdentificationError(
            f"{where}: the {len(steps)} steps determine only {rank} of {degree} coefficients "
            "(they do not span enough distinct input levels); lower the degree"
        )
    d = sol / scale
    residuals = rhs - phi @ d
    std = (
        parameter_std_errors(phi, residuals)
        if len(steps) > degree
        else np.full(degree, np.inf)
    )
    fit = HammersteinFit(
        linear_block="arx",
        a=a,
        b=b / b_first,
        c=np.array([1.0]),
        input_poly=d * b_first,
        parameter_names=tuple(f"d{i}" for i in powers),
        parameters=d * b_first,
        std_errors=np.asarray(std) * abs(b_first),
        residuals=residuals,
        criterion="least_squares",
        cost=float(np.mean(residuals**2)),
        n_iterations=0,
        converged=True,
        message="least squares on the step rows of eq. 21",
        method=f"hammerstein-eq21-{row_form}",
    )
    return InputPolyInit(
        input_poly=_readonly(d),
        std_errors=_readonly(std),
        regressor=_readonly(phi),
        target=_readonly(rhs),
        residuals=_readonly(residuals),
        row_form=row_form,
        fit=fit,
    )


# =========================================================================== step 2
def reidentify_linear_block(
    y: FloatArray,
    ds: FloatArray,
    input_poly: npt.ArrayLike,
    *,
    method: Literal["arx", "oe"] = "oe",
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    max_iterations: int = 100,
) -> HammersteinFit:
    """Re-identify the linear block with ``f`` fixed: input ``w = f(ds)`` (sec. 7.4).

    Parameters
    ----------
    y :
        Output deviation ``dP`` [kW], shape ``(N,)``.
    ds :
        Input deviation [%], shape ``(N,)``.
    input_poly :
        ``[d_1, ..., d_n]`` of the fixed ``f`` (for example `InputPolyInit.input_poly`).
    method :
        ``"arx"`` (least squares, ``A`` of order ``nf``) or ``"oe"`` (PEM on V).
    nb, nf, nk :
        Orders of ``B`` and ``F`` (or ``A``) and the delay.
    max_iterations :
        Iteration limit of the OE search.

    Returns
    -------
    HammersteinFit
        Normalized: ``B / b_nk`` and ``f * b_nk`` (eqs. 22-24). The OE residuals are
        the simulation errors (V); the ARX ones are equation errors.

    Raises
    ------
    IdentificationError
        Bad options or arrays, a constant input, or an estimated ``b_nk`` of zero.

    Warns
    -----
    IdentificationWarning
        The OE search did not converge (from `sysid.linear.oe_pem`).
    """
    where = "reidentify_linear_block"
    y_arr, ds_arr = _check_arrays(y, ds, where)
    poly = np.asarray(input_poly, dtype=float)
    if poly.ndim != 1 or poly.size == 0 or not np.all(np.isfinite(poly)):
        raise IdentificationError(f"{where}: input_poly must be a non-empty finite 1-D list")
    if method not in ("arx", "oe"):
        raise IdentificationError(f"{where}: method must be 'arx' or 'oe'; got {method!r}")
    w = _poly_eval(poly, ds_arr)
    if method == "arx":
        arx = arx_least_squares(y_arr, w, na=nf, nb=nb, nk=nk)
        a, b, c = arx.a, arx.b, np.array([1.0])
        names = arx.parameter_names
        theta, std, residuals = arx.theta, arx.std_errors, arx.residuals
        n_it, converged, message = 0, True, "least squares: exact solution"
        criterion: Literal["ballistic", "least_squares"] = "least_squares"
    else:
        pem = oe_pem(y_arr, w, nb=nb, nf=nf, nk=nk, max_iterations=max_iterations)
        a, b, c = pem.a, pem.b, pem.c
        names = pem.parameter_names
        theta, std, residuals = pem.theta, pem.std_errors, pem.residuals
        n_it, converged, message = pem.n_iterations, pem.converged, pem.message
        criterion = "ballistic"
    b_first = float(b[np.flatnonzero(b)[0]]) if np.any(b) else 0.0
    if b_first == 0.0:
        raise IdentificationError(f"{where}: the estimated B(q) is zero; f(ds) has no effect")
    return HammersteinFit(
        linear_block=method,
        a=a,
        b=b / b_first,
        c=c,
        input_poly=poly * b_first,
        parameter_names=names,
        parameters=theta,
        std_errors=std,
        residuals=residuals,
        criterion=criterion,
        cost=float(np.mean(np.asarray(residuals) ** 2)),
        n_iterations=n_it,
        converged=converged,
        message=message,
        method=f"hammerstein-reidentified-{method}",
    )


# =========================================================================== structures
def _observer_form(
    a: Sequence[Any], beta: Sequence[Any], kgain: Sequence[Any], n: int
) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX]:
    """Observer canonical form of ``A y = B w + C e``; ``beta[j]`` multiplies ``q^-j``.

    Returns ``(A, b_col, D, K)`` with ``x+ = A x + b_col w + K e``, ``y = x_1 + D w + e``;
    ``kgain[i-1] = c_i - a_i``.
    """
    a_full = [a[i] if i < len(a) else 0 for i in range(n + 1)]
    beta_full = [beta[j] if j < len(beta) else 0 for j in range(n + 1)]
    A = ca.SX.zeros(n, n)
    b_col = ca.SX.zeros(n, 1)
    K = ca.SX.zeros(n, 1)
    for i in range(1, n + 1):
        A[i - 1, 0] = -a_full[i]
        if i < n:
            A[i - 1, i] = 1
        b_col[i - 1] = beta_full[i] - a_full[i] * beta_full[0]
        K[i - 1] = kgain[i - 1] if i - 1 < len(kgain) else 0
    return A, b_col, ca.SX(beta_full[0]), K


def _names_b(nb: int, nk: int) -> tuple[str, ...]:
    return tuple(f"b{j}" for j in range(nk + 1, nk + nb))


def _check_orders(degree: int, nb: int, nf: int, nk: int, where: str) -> tuple[int, int, int, int]:
    return (
        _check_int("degree", degree, 1, where),
        _check_int("nb", nb, 1, where),
        _check_int("nf", nf, 0, where),
        _check_int("nk", nk, 0, where),
    )


def hammerstein_oe_structure(
    *,
    degree: int = 2,
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    initial_values: Mapping[str, float] | None = None,
) -> GreyBoxStructure:
    """The grey-box structure of eq. 26, generalized: Hammerstein with an OE block.

    ``y_k = B(q)/F(q) f(ds_k) + eps_k`` with ``B = q^-nk (1 + b_{nk+1} q^-1 + ..)``
    (normalized, eq. 25), ``f(ds) = sum_{i=1..n} d_i ds^i`` (no constant term: the
    thing MATLAB's ``nlhw`` could not express, sec. 7.5). The state-space form is the
    observer canonical form of ``B/F`` with input vector ``[ds, ds^2, .., ds^n]`` and
    ``B_ss = b_col [d_1 .. d_n]``; it has the same input-output map as eq. 26.

    Parameters
    ----------
    degree :
        ``n``, degree of ``f``.
    nb, nf, nk :
        Number of ``B`` coefficients (including the normalized 1), order of ``F``,
        delay [samples].
    initial_values :
        Starting values by name (``b2``, ``d1``, ``d2``, ``f1`` for the paper's
        orders); missing names start at 0. An unstable ``F`` is mirrored into the
        unit circle.

    Returns
    -------
    GreyBoxStructure
        Parameters ``b_{nk+1}..b_{nk+nb-1}, d1..dn, f1..f_nf``, all free; ``F`` kept
        stable by mirroring roots (`sysid.polynomials.reflect_unstable_roots`).

    Raises
    ------
    IdentificationError
        Bad orders or unknown names in `initial_values`.
    """
    where = "hammerstein_oe_structure"
    degree, nb, nf, nk = _check_orders(degree, nb, nf, nk, where)
    names_b = _names_b(nb, nk)
    names_d = tuple(f"d{i}" for i in range(1, degree + 1))
    names_f = tuple(f"f{i}" for i in range(1, nf + 1))
    names = names_b + names_d + names_f
    n = max(nf, nk + nb - 1, 1)

    def matrices(p: Mapping[str, Any]) -> tuple[Any, Any, Any, Any, Any]:
        beta = [0] * nk + [1] + [p[name] for name in names_b]
        a = [1] + [p[name] for name in names_f]
        A, b_col, D, K = _observer_form(a, beta, [], n)
        d_row = ca.horzcat(*[p[name] for name in names_d])
        C = ca.horzcat(ca.SX(1), ca.SX.zeros(1, n - 1))
        return A, b_col @ d_row, C, D @ d_row, None

    i_f = slice(len(names_b) + degree, len(names))

    def project(theta: FloatArray) -> FloatArray:
        out = np.array(theta, dtype=float, copy=True)
        if nf:
            out[i_f] = reflect_unstable_roots(np.concatenate([[1.0], out[i_f]]))[1:]
        return out

    return _structure(
        names, initial_values, matrices, degree, project, f"hammerstein-oe(nb={nb},nf={nf},"
        f"nk={nk},degree={degree})"
    )


def hammerstein_armax_structure(
    *,
    degree: int = 2,
    na: int = 1,
    nb: int = 2,
    nc: int = 1,
    nk: int = 1,
    initial_values: Mapping[str, float] | None = None,
) -> GreyBoxStructure:
    """The grey-box structure of eq. 29, generalized: Hammerstein with an ARMAX block.

    ``A(q) y_k = B(q) f(ds_k) + C(q) e_k`` (eq. 30) in innovations form
    ``x+ = A x + B_ss u + K e``, ``y = x_1 + e`` (observer canonical form), with
    ``K_i = c_i - a_i``: the parameters ``k_1..k_nc`` are the paper's Kalman gain and
    ``c_i = a_i + k_i`` (eq. 32).

    Parameters
    ----------
    degree :
        ``n``, degree of ``f``.
    na, nb, nc, nk :
        Orders of ``A``, ``B`` (including the normalized 1), ``C`` and the delay.
    initial_values :
        Starting values by name (``b2``, ``d1``, ``d2``, ``a1``, ``k1``); missing
        names start at 0. Unstable ``A`` or ``C`` are mirrored into the unit circle.

    Returns
    -------
    GreyBoxStructure
        Parameters ``b.., d1..dn, a1..a_na, k1..k_nc``; ``A`` and ``C`` kept stable by
        mirroring roots.

    Raises
    ------
    IdentificationError
        Bad orders or unknown names in `initial_values`.
    """
    where = "hammerstein_armax_structure"
    degree, nb, _, nk = _check_orders(degree, nb, 0, nk, where)
    na = _check_int("na", na, 0, where)
    nc = _check_int("nc", nc, 0, where)
    names_b = _names_b(nb, nk)
    names_d = tuple(f"d{i}" for i in range(1, degree + 1))
    names_a = tuple(f"a{i}" for i in range(1, na + 1))
    names_k = tuple(f"k{i}" for i in range(1, nc + 1))
    names = names_b + names_d + names_a + names_k
    n = max(na, nk + nb - 1, nc, 1)

    def matrices(p: Mapping[str, Any]) -> tuple[Any, Any, Any, Any, Any]:
        beta = [0] * nk + [1] + [p[name] for name in names_b]
        a = [1] + [p[name] for name in names_a]
        # K_i = c_i - a_i; c_i = a_i + k_i for i <= nc, c_i = 0 beyond
        kgain = [
            p[f"k{i}"] if i <= nc else (-p[f"a{i}"] if i <= na else 0)
            for i in range(1, n + 1)
        ]
        A, b_col, D, K = _observer_form(a, beta, kgain, n)
        d_row = ca.horzcat(*[p[name] for name in names_d])
        C = ca.horzcat(ca.SX(1), ca.SX.zeros(1, n - 1))
        return A, b_col @ d_row, C, D @ d_row, K

    i_a = slice(len(names_b) + degree, len(names_b) + degree + na)
    i_k = slice(len(names_b) + degree + na, len(names))

    def project(theta: FloatArray) -> FloatArray:
        out = np.array(theta, dtype=float, copy=True)
        a_old = np.zeros(max(na, nc) + 1)
        a_old[: na + 1] = np.concatenate([[1.0], out[i_a]])
        c = a_old[: nc + 1].copy()
        c[1:] += out[i_k]
        if na:
            out[i_a] = reflect_unstable_roots(np.concatenate([[1.0], out[i_a]]))[1:]
        if nc:
            a_new = np.zeros(max(na, nc) + 1)
            a_new[: na + 1] = np.concatenate([[1.0], out[i_a]])
            out[i_k] = reflect_unstable_roots(c)[1:] - a_new[1 : nc + 1]
        return out

    return _structure(
        names, initial_values, matrices, degree, project,
        f"hammerstein-armax(na={na},nb={nb},nc={nc},nk={nk},degree={degree})",
    )


def _structure(
    names: tuple[str, ...],
    initial_values: Mapping[str, float] | None,
    matrices: Any,
    degree: int,
    project: Any,
    label: str,
) -> GreyBoxStructure:
    given = dict(initial_values or {})
    unknown = set(given) - set(names)
    if unknown:
        raise IdentificationError(
            f"{label}: unknown parameter name(s) {sorted(unknown)}; expected some of "
            f"{list(names)}"
        )
    start = np.array([float(given.get(n, 0.0)) for n in names])
    start = project(start)
    return GreyBoxStructure(
        parameter_names=names,
        initial_values=tuple(float(v) for v in start),
        matrices=matrices,
        input_map=lambda ds: _features(ds, degree),
        project=project,
        name=label,
    )


# =========================================================================== steps 3 and 4
def _fit_from_greybox(
    result: GreyBoxResult,
    *,
    linear_block: Literal["oe", "armax"],
    degree: int,
    nb: int,
    na: int,
    nc: int,
    nk: int,
    start: str,
) -> HammersteinFit:
    values = result.as_dict()
    b = np.concatenate(
        [np.zeros(nk), [1.0], [values[f"b{j}"] for j in range(nk + 1, nk + nb)]]
    )
    poly = np.array([values[f"d{i}"] for i in range(1, degree + 1)])
    letter = "f" if linear_block == "oe" else "a"
    a = np.concatenate([[1.0], [values[f"{letter}{i}"] for i in range(1, na + 1)]])
    if linear_block == "oe":
        c = a
    else:
        a_pad = np.zeros(max(na, nc) + 1)
        a_pad[: na + 1] = a
        c = np.concatenate([[1.0], [a_pad[i] + values[f"k{i}"] for i in range(1, nc + 1)]])
    return HammersteinFit(
        linear_block=linear_block,
        a=a,
        b=b,
        c=c,
        input_poly=poly,
        parameter_names=result.parameter_names,
        parameters=result.parameters,
        std_errors=result.std_errors,
        residuals=result.residuals,
        criterion=result.criterion,
        cost=result.criterion_value,
        n_iterations=result.n_iterations,
        converged=result.converged,
        message=result.message,
        method=f"hammerstein-{linear_block}-pem-{result.criterion}-from-{start}",
        greybox=result,
    )


def _start_values(
    initial: HammersteinFit | Mapping[str, float] | None, names: tuple[str, ...]
) -> tuple[dict[str, float], str]:
    """Start values by name; a previous fit gives what it shares with ``names``.

    A user's mapping is passed on whole, so an unknown name is an error, not dropped.
    """
    if initial is None:
        return {}, "zeros"
    if isinstance(initial, HammersteinFit):
        values = {k: v for k, v in initial.values().items() if k in names}
    else:
        values = dict(initial)
    return {k: float(v) for k, v in values.items()}, "initial-values"


def fit_hammerstein_oe(
    y: FloatArray,
    ds: FloatArray,
    *,
    initial: HammersteinFit | Mapping[str, float] | None = None,
    degree: int = 2,
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    max_iterations: int = 100,
) -> HammersteinFit:
    """Estimate all parameters of the normalized Hammerstein-OE model by PEM on V (sec. 7.5).

    Parameters
    ----------
    y :
        Output deviation ``dP`` [kW], shape ``(N,)``.
    ds :
        Input deviation [%], shape ``(N,)``.
    initial :
        Start: a previous fit (for example the OE re-identification of step 2, whose
        ``F``, ``B`` and ``f`` give ``f1, b2, d1, d2``), a mapping by name, or None for
        all zeros (the paper's test: 3 iterations from good values, 17 from zeros).
    degree, nb, nf, nk :
        Degree of ``f``, number of ``B`` coefficients, order of ``F``, delay.
    max_iterations :
        Levenberg-Marquardt iteration limit.

    Returns
    -------
    HammersteinFit
        ``linear_block = "oe"``, ``C = A = F``, ``B = q^-nk (1 + b2 q^-1 ..)``,
        criterion ``"ballistic"`` with ``cost`` = V (held-past initial conditions, as
        `sysid.criteria.ballistic_mse`).

    Raises
    ------
    IdentificationError
        Bad options or arrays; fewer than ``degree + 1`` distinct input levels; fewer
        than 10 samples per parameter.

    Warns
    -----
    IdentificationWarning
        The search did not converge (the best iterate is returned, ``converged=False``).
    """
    where = "fit_hammerstein_oe"
    y_arr, ds_arr = _check_arrays(y, ds, where)
    structure = hammerstein_oe_structure(degree=degree, nb=nb, nf=nf, nk=nk)
    _check_excitation(ds_arr, degree, structure.n_parameters, where)
    start, label = _start_values(initial, structure.parameter_names)
    structure = hammerstein_oe_structure(
        degree=degree, nb=nb, nf=nf, nk=nk, initial_values=start
    )
    result = fit_greybox(
        structure, y_arr, ds_arr, criterion="ballistic", max_iterations=max_iterations,
        warn=False,
    )
    _warn_unconverged(result, where)
    return _fit_from_greybox(
        result, linear_block="oe", degree=degree, nb=nb, na=nf, nc=nf, nk=nk, start=label
    )


def fit_hammerstein_armax(
    y: FloatArray,
    ds: FloatArray,
    *,
    initial: HammersteinFit | Mapping[str, float] | None = None,
    degree: int = 2,
    na: int = 1,
    nb: int = 2,
    nc: int = 1,
    nk: int = 1,
    max_iterations: int = 100,
) -> HammersteinFit:
    """Estimate the Hammerstein model with an ARMAX noise model by PEM on W (sec. 7.6).

    Parameters
    ----------
    y :
        Output deviation ``dP`` [kW], shape ``(N,)``.
    ds :
        Input deviation [%], shape ``(N,)``.
    initial :
        Start: a previous fit (an OE fit gives ``a = f`` and ``k = 0``, i.e. ``C = A``;
        an ARMAX fit gives all), a mapping by name, or None for zeros.
    degree, na, nb, nc, nk :
        Degree of ``f`` and the orders of ``A``, ``B``, ``C`` and the delay.
    max_iterations :
        Levenberg-Marquardt iteration limit.

    Returns
    -------
    HammersteinFit
        ``linear_block = "armax"`` with ``c_i = a_i + k_i`` (eq. 32), criterion
        ``"one_step"``, ``cost`` = W (held-past initial conditions, zero past
        innovations, as `sysid.criteria.one_step_mse`).

    Raises
    ------
    IdentificationError
        Bad options or arrays; fewer than ``degree + 1`` distinct input levels; fewer
        than 10 samples per parameter.

    Warns
    -----
    IdentificationWarning
        The search did not converge (the best iterate is returned, ``converged=False``).
    """
    where = "fit_hammerstein_armax"
    y_arr, ds_arr = _check_arrays(y, ds, where)
    structure = hammerstein_armax_structure(degree=degree, na=na, nb=nb, nc=nc, nk=nk)
    _check_excitation(ds_arr, degree, structure.n_parameters, where)
    if isinstance(initial, HammersteinFit) and initial.linear_block != "armax":
        values = initial.values()
        for i in range(1, initial.a.size):
            if f"f{i}" in values:
                values[f"a{i}"] = values.pop(f"f{i}")
        names = structure.parameter_names
        start = {k: v for k, v in values.items() if k in names}
        label = "initial-values"
    else:
        start, label = _start_values(initial, structure.parameter_names)
    structure = hammerstein_armax_structure(
        degree=degree, na=na, nb=nb, nc=nc, nk=nk, initial_values=start
    )
    result = fit_greybox(
        structure, y_arr, ds_arr, criterion="one_step", max_iterations=max_iterations,
        warn=False,
    )
    _warn_unconverged(result, where)
    return _fit_from_greybox(
        result, linear_block="armax", degree=degree, nb=nb, na=na, nc=nc, nk=nk, start=label
    )


def _warn_unconverged(result: GreyBoxResult, where: str) -> None:
    if not result.converged:
        warnings.warn(
            f"{where}: the prediction-error search did not converge after "
            f"{result.n_iterations} iterations ({result.message}); the best iterate is kept",
            IdentificationWarning,
            stacklevel=3,
        )


def relative_parameter_difference(first: HammersteinFit, second: HammersteinFit) -> float:
    """Largest ``|p1 - p2| / max(|p1|, |p2|)`` over the shared parameters of two fits.

    Used for the paper's check that the final PEM from zeros reaches the same
    parameters as from good initial values (sec. 7.5).
    """
    v1, v2 = first.values(), second.values()
    shared = sorted(set(v1) & set(v2))
    if not shared:
        raise IdentificationError("relative_parameter_difference: the fits share no parameter")
    worst = 0.0
    for name in shared:
        scale = max(abs(v1[name]), abs(v2[name]))
        if scale > 0:
            worst = max(worst, abs(v1[name] - v2[name]) / scale)
    return worst


def hammerstein_criteria(fit: HammersteinFit, y: FloatArray, ds: FloatArray) -> Criteria:
    """V (eq. 9) and W (eq. 10) of a fit on deviation arrays (held-past rule).

    Returns a `Criteria` computed with the grey-box simulator, which matches
    `sysid.criteria` on the corresponding `HammersteinModel`.
    """
    y_arr, ds_arr = _check_arrays(y, ds, "hammerstein_criteria")
    structure = _fixed_structure(fit)
    eps = greybox_residuals(structure, y_arr, ds_arr, criterion="ballistic")
    e = greybox_residuals(structure, y_arr, ds_arr, criterion="one_step")
    return Criteria(
        ballistic_mse_kw2=float(np.mean(eps**2)), one_step_mse_kw2=float(np.mean(e**2))
    )


def _fixed_structure(fit: HammersteinFit) -> GreyBoxStructure:
    nk = fit.delay_steps
    na = fit.a.size - 1
    nb = fit.b.size - nk
    nc = fit.c.size - 1
    values = fit.values()
    if fit.linear_block == "armax":
        structure = hammerstein_armax_structure(
            degree=fit.input_poly.size, na=na, nb=nb, nc=nc, nk=nk
        )
    else:
        # OE and ARX predictors both fit the ARMAX form: OE has C = A, ARX has C = 1
        structure = hammerstein_armax_structure(
            degree=fit.input_poly.size, na=na, nb=nb, nc=na, nk=nk
        )
        for i in range(1, na + 1):
            values[f"a{i}"] = values.pop(f"f{i}", values.get(f"a{i}", 0.0))
            c_i = fit.c[i] if i < fit.c.size else 0.0
            values[f"k{i}"] = float(c_i - fit.a[i])
    return GreyBoxStructure(
        parameter_names=structure.parameter_names,
        initial_values=tuple(values[n] for n in structure.parameter_names),
        matrices=structure.matrices,
        input_map=structure.input_map,
        name=structure.name,
    )


# =========================================================================== models
def hammerstein_model(
    fit: HammersteinFit,
    data: Dataset,
    *,
    operating_point: OperatingPoint,
    extra: Mapping[str, Any] | None = None,
) -> HammersteinModel:
    """Turn a fit into a `HammersteinModel` with V, W, noise level and provenance.

    Parameters
    ----------
    fit :
        Any step of the route.
    data :
        The identification record (absolute units); gives ``ts_s``, the input range,
        the provenance and the criteria.
    operating_point :
        ``(s_nom, P_nom)`` the fit's deviations were taken about.
    extra :
        Extra provenance entries (JSON-able).

    Returns
    -------
    HammersteinModel
        ``kind = "hammerstein"``; ``noise_std_kw = sqrt(sum r^2 / (N - p))`` of the
        fit's residuals; criteria from `sysid.criteria`.

    Raises
    ------
    IdentificationError
        The fit's ``A`` or ``C`` is unstable (not a usable model).
    """
    n_par = len(fit.parameter_names)
    dof = max(fit.residuals.size - n_par, 1)
    noise_std = float(np.sqrt(float(fit.residuals @ fit.residuals) / dof))
    info: dict[str, Any] = {
        "parameter_names": list(fit.parameter_names),
        "parameters": [float(v) for v in fit.parameters],
        "std_errors": [float(v) if math.isfinite(v) else None for v in fit.std_errors],
        "n_iterations": fit.n_iterations,
        "converged": fit.converged,
    }
    info.update(extra or {})
    try:
        model = HammersteinModel(
            kind="hammerstein",
            linear_block=fit.linear_block,
            ts_s=data.ts_s,
            operating_point=operating_point,
            a=fit.a,
            b=fit.b,
            c=fit.c,
            input_poly=fit.input_poly,
            noise_std_kw=noise_std,
            input_range_pct=(float(np.min(data.triac_pct)), float(np.max(data.triac_pct))),
            provenance=Provenance(
                data_file=None if data.source is None else Path(data.source).name,
                data_sha256=data.sha256,
                preprocessing=data.preprocessing,
                method=fit.method,
                created_utc=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
                extra=info,
            ),
        )
    except UnstableModelError as exc:
        raise IdentificationError(
            f"hammerstein_model: the {fit.method} estimate is not a usable model ({exc})"
        ) from None
    return model.with_updates(
        criteria=Criteria(
            ballistic_mse_kw2=ballistic_mse(model, data),
            one_step_mse_kw2=one_step_mse(model, data),
        )
    )


# =========================================================================== public entry
@dataclass(frozen=True, kw_only=True, eq=False)
class HammersteinRoute:
    """Every step of the paper's Hammerstein route on one record (secs. 7.3-7.6).

    Parameters
    ----------
    arx :
        The linear ARX fit on ``ds`` that eq. 21 uses (as a `HammersteinFit` with
        ``f(ds) = b_nk ds``).
    steps :
        The input steps used in eq. 21.
    initial_poly :
        Step 1 (eq. 21, Fig. 12), or None when skipped (fewer steps than the degree).
    arx_reidentified, oe_reidentified :
        Step 2 (Fig. 13).
    final_oe :
        Step 3 from the good initial values (eq. 27).
    final_oe_from_zeros :
        Step 3 from zeros, or None if not run.
    noise_model :
        Step 4 (eq. 30), or None if not run.
    skipped :
        What was skipped and why, in words.
    """

    arx: HammersteinFit
    steps: tuple[InputStep, ...]
    initial_poly: InputPolyInit | None
    arx_reidentified: HammersteinFit
    oe_reidentified: HammersteinFit
    final_oe: HammersteinFit
    final_oe_from_zeros: HammersteinFit | None
    noise_model: HammersteinFit | None
    skipped: tuple[str, ...] = ()


def run_hammerstein_route(
    y: FloatArray,
    ds: FloatArray,
    *,
    steps: Sequence[InputStep],
    operating_point: OperatingPoint,
    degree: int = 2,
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    noise_model: bool = True,
    nc: int | None = None,
    from_zeros: bool = False,
    row_form: RowForm = "eq21",
    max_iterations: int = 100,
) -> HammersteinRoute:
    """Run steps 1-4 of the paper's route on deviation arrays.

    Parameters
    ----------
    y, ds :
        Output and input deviations, shape ``(N,)`` [kW], [%].
    steps :
        Input steps (absolute units) for eq. 21.
    operating_point :
        The operating point the deviations are about (converts the steps).
    degree, nb, nf, nk :
        Degree of ``f`` and the orders of the linear block (the ARX uses ``na = nf``).
    noise_model :
        Also fit the ARMAX-block model on W (step 4), with ``na = nf`` and ``nc``.
    nc :
        Order of ``C``; default ``nf`` (the paper takes ``nc = na``).
    from_zeros :
        Also run step 3 from all-zero initial values.
    row_form :
        Rows of eq. 21 (see `initial_input_poly`).
    max_iterations :
        Iteration limit of every search.

    Returns
    -------
    HammersteinRoute
        With fewer steps than ``degree`` (or steps that do not determine ``f``), step 1
        is skipped and ``f(ds) = ds`` starts step 2 (said in `skipped`).

    Raises
    ------
    IdentificationError
        As the individual steps.
    """
    where = "run_hammerstein_route"
    y_arr, ds_arr = _check_arrays(y, ds, where)
    degree, nb, nf, nk = _check_orders(degree, nb, nf, nk, where)
    nc_used = nf if nc is None else _check_int("nc", nc, 0, where)
    skipped: list[str] = []
    arx_fit = arx_least_squares(y_arr, ds_arr, na=nf, nb=nb, nk=nk)
    b_first = float(arx_fit.b[nk])
    arx = HammersteinFit(
        linear_block="arx",
        a=arx_fit.a,
        b=arx_fit.b / b_first,
        c=np.array([1.0]),
        input_poly=np.array([b_first]),
        parameter_names=arx_fit.parameter_names,
        parameters=arx_fit.theta,
        std_errors=arx_fit.std_errors,
        residuals=arx_fit.residuals,
        criterion="least_squares",
        cost=float(np.mean(arx_fit.residuals**2)),
        n_iterations=0,
        converged=True,
        message="least squares: exact solution",
        method="arx-least-squares",
    )
    steps = tuple(steps)
    init: InputPolyInit | None = None
    try:
        init = initial_input_poly(
            steps, arx_fit.a, arx_fit.b, operating_point=operating_point, degree=degree,
            row_form=row_form,
        )
        poly = np.asarray(init.input_poly)
    except IdentificationError as exc:
        skipped.append(f"eq. 21 initial polynomial skipped ({exc}); f(ds) = ds used instead")
        poly = np.zeros(degree)
        poly[0] = 1.0
    arx_re = reidentify_linear_block(y_arr, ds_arr, poly, method="arx", nb=nb, nf=nf, nk=nk)
    oe_re = reidentify_linear_block(
        y_arr, ds_arr, poly, method="oe", nb=nb, nf=nf, nk=nk, max_iterations=max_iterations
    )
    final = fit_hammerstein_oe(
        y_arr, ds_arr, initial=oe_re, degree=degree, nb=nb, nf=nf, nk=nk,
        max_iterations=max_iterations,
    )
    zeros = None
    if from_zeros:
        zeros = fit_hammerstein_oe(
            y_arr, ds_arr, initial=None, degree=degree, nb=nb, nf=nf, nk=nk,
            max_iterations=max_iterations,
        )
    noise = None
    if noise_model:
        noise = fit_hammerstein_armax(
            y_arr, ds_arr, initial=final, degree=degree, na=nf, nb=nb, nc=nc_used, nk=nk,
            max_iterations=max_iterations,
        )
    return HammersteinRoute(
        arx=arx,
        steps=steps,
        initial_poly=init,
        arx_reidentified=arx_re,
        oe_reidentified=oe_re,
        final_oe=final,
        final_oe_from_zeros=zeros,
        noise_model=noise,
        skipped=tuple(skipped),
    )


def fit_hammerstein(
    data: Dataset,
    *,
    operating_point: OperatingPoint,
    degree: int = 2,
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    noise_model: bool = True,
    nc: int | None = None,
    steps: Sequence[InputStep] | None = None,
    max_iterations: int = 100,
) -> IdentificationResult:
    """Identify a Hammerstein model of a heater log by the paper's route (secs. 7.3-7.6).

    Parameters
    ----------
    data :
        The (preprocessed) identification record, absolute units.
    operating_point :
        ``(s_nom, P_nom)`` for the deviation variables (sec. 5.1).
    degree :
        Degree ``n`` of ``f(ds) = sum_{i=1..n} p_i ds^i`` (no constant term).
    nb, nf, nk :
        Number of ``B`` coefficients (the first normalized to 1), order of ``F``
        (``A``), delay [samples]. The paper: 2, 1, 1.
    noise_model :
        True: the ARMAX-block model of eq. 30, optimized for W (the model for
        control). False: the OE-block model of eq. 27, optimized for V.
    nc :
        Order of ``C`` for the noise model; default ``nf``.
    steps :
        Input steps for eq. 21; default `sysid.steps.detect_steps` with delay ``nk``.
    max_iterations :
        Iteration limit of every search.

    Returns
    -------
    IdentificationResult
        ``model.kind = "hammerstein"``, ``linear_block = "armax"`` (``C = [1, c1]``) or
        ``"oe"`` (``C = A``), ``B = [0, 1, b2]``, ``input_poly = [d1, d2]``, criteria V
        and W on `data`, ``noise_std_kw``, ``input_range_pct`` and provenance; the
        parameters and standard errors of the last search; ``raw`` is the
        `HammersteinRoute` with every intermediate step.

    Raises
    ------
    IdentificationError
        Bad options, a record too short or not exciting enough, or an unusable
        estimate.

    Warns
    -----
    IdentificationWarning
        A search did not converge (its best iterate is kept).

    Examples
    --------
    >>> import numpy as np
    >>> from sysid.data import Dataset
    >>> from sysid.model import OperatingPoint
    >>> rng = np.random.default_rng(0)
    >>> s = 45.0 + np.repeat(rng.uniform(-10, 15, 20), 100)
    >>> ds = s - 45.0
    >>> w = 1.3 * ds - 0.007 * ds**2
    >>> p = np.zeros_like(ds)
    >>> for k in range(2, ds.size):
    ...     p[k] = 0.99 * p[k - 1] + w[k - 1] - 0.98 * w[k - 2]
    >>> data = Dataset(time_s=2.0 * np.arange(ds.size), triac_pct=s,
    ...                power_kw=45.0 + p + 0.01 * rng.standard_normal(ds.size), ts_s=2.0)
    >>> result = fit_hammerstein(data, operating_point=OperatingPoint(triac_pct=45.0,
    ...                          power_kw=45.0), noise_model=False)
    >>> np.round(result.model.input_poly, 2).tolist()
    [1.3, -0.01]
    """
    where = "fit_hammerstein"
    if not isinstance(data, Dataset):
        raise IdentificationError(f"{where}: data must be a sysid Dataset; got {type(data)}")
    if not isinstance(operating_point, OperatingPoint):
        raise IdentificationError(
            f"{where}: operating_point must be an OperatingPoint; got {operating_point!r}"
        )
    nk = _check_int("nk", nk, 0, where)
    used_steps = tuple(detect_steps(data, delay_steps=nk) if steps is None else steps)
    y = data.power_kw - operating_point.power_kw
    ds = data.triac_pct - operating_point.triac_pct
    route = run_hammerstein_route(
        y, ds, steps=used_steps, operating_point=operating_point, degree=degree, nb=nb,
        nf=nf, nk=nk, noise_model=noise_model, nc=nc, max_iterations=max_iterations,
    )
    fit = route.noise_model if route.noise_model is not None else route.final_oe
    model = hammerstein_model(
        fit, data, operating_point=operating_point,
        extra={"route_skipped": list(route.skipped), "n_steps_eq21": len(used_steps)},
    )
    return IdentificationResult(
        model=model,
        converged=fit.converged,
        message=fit.message,
        n_iterations=fit.n_iterations,
        criterion="one_step" if fit.criterion == "one_step" else "ballistic",
        parameter_names=fit.parameter_names,
        parameters=fit.parameters,
        std_errors=fit.std_errors,
        residuals_kw=fit.residuals,
        raw=route,
    )


__all__ = [
    "HammersteinBlock",
    "HammersteinFit",
    "HammersteinRoute",
    "InputPolyInit",
    "RowForm",
    "fit_hammerstein",
    "fit_hammerstein_armax",
    "fit_hammerstein_oe",
    "hammerstein_armax_structure",
    "hammerstein_criteria",
    "hammerstein_model",
    "hammerstein_oe_structure",
    "initial_input_poly",
    "reidentify_linear_block",
    "relative_parameter_difference",
    "run_hammerstein_route",
]
