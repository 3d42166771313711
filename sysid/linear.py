"""ARX (least squares), OE and ARMAX (prediction-error method) identification.

Notation
--------
``y`` = ``dP`` [kW] and ``u`` = ``ds`` [%] (or any input ``w = f(ds)`` of a Hammerstein
model) are deviation variables, 1-D arrays indexed by sample ``k``. Polynomials in
q^-1 hold ascending powers (paper eqs. 1-4); ``b`` holds ``nk`` leading zeros (the
delay) followed by ``b_nk .. b_{nk+nb-1}``:

* ARX (eq. 5):   ``A y = B u + e``
* ARMAX (eq. 6): ``A y = B u + C e``      (minimizes W, eq. 10)
* OE (eq. 7):    ``y = B/F u + eps``      (minimizes V, eq. 9)

Parameters are named after the paper's eq. 8 with the index of ``b`` equal to its lag:
``a1..a_na``, ``b_nk..b_{nk+nb-1}``, ``c1..c_nc``, ``f1..f_nf``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import partial
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.linalg import solve_triangular
from scipy.signal import lfilter

from sysid._arrays import readonly_array
from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.criteria import model_criteria
from sysid.data import Dataset
from sysid.errors import IdentificationError, IdentificationWarning, UnstableModelError
from sysid.model import (
    HammersteinModel,
    LinearBlock,
    OperatingPoint,
    Provenance,
    normalize_input_gain,
)
from sysid.optimize import (
    DEFAULT_FTOL,
    DEFAULT_XTOL,
    MAX_ITERATIONS,
    LMResult,
    levenberg_marquardt,
    parameter_std_errors,
    sum_of_squares,
    triangular_factor,
)
from sysid.polynomials import impulse_response, is_stable, reflect_unstable_roots
from sysid.result import CriterionName, IdentificationResult
from sysid.simulate import equation_errors, filter_state, simulate_arrays

InitialConditions = Literal["held", "estimated"]


def _indexed_names(letter: str, indices: range) -> tuple[str, ...]:
    """``("<letter><i>", ..)``: the names of one polynomial's coefficients (paper eq. 8)."""
    return tuple(f"{letter}{i}" for i in indices)


def _oe_polynomials(theta: FloatArray, nb: int, nf: int,
                    nk: int) -> tuple[FloatArray, FloatArray]:
    """``(B, F)`` of ``theta = [b_nk..b_{nk+nb-1}, f1..f_nf, ..]`` (paper eq. 7).

    ``B`` with ``nk`` leading zeros, ``F`` monic; entries after ``f_nf`` are ignored.
    """
    b = np.concatenate([np.zeros(nk), theta[:nb]])
    f = np.concatenate([[1.0], theta[nb : nb + nf]])
    return b, f


def _armax_polynomials(theta: FloatArray, na: int, nb: int, nc: int,
                       nk: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(A, B, C)`` of ``theta = [a1..a_na, b_nk..b_{nk+nb-1}, c1..c_nc, ..]`` (eqs. 5-6).

    ``A`` and ``C`` monic, ``B`` with ``nk`` leading zeros; entries after ``c_nc`` are
    ignored. ARX is the case ``nc = 0`` (``C = 1``).
    """
    a = np.concatenate([[1.0], theta[:na]])
    b = np.concatenate([np.zeros(nk), theta[na : na + nb]])
    c = np.concatenate([[1.0], theta[na + nb : na + nb + nc]])
    return a, b, c


def _check_signals(y: FloatArray, u: FloatArray, where: str) -> tuple[FloatArray, FloatArray]:
    y_arr = np.asarray(y, dtype=float)
    u_arr = np.asarray(u, dtype=float)
    if y_arr.ndim != 1 or u_arr.ndim != 1 or y_arr.size != u_arr.size:
        raise IdentificationError(
            f"{where}: y and u must be 1-D arrays of equal length; got shapes "
            f"{y_arr.shape} and {u_arr.shape}"
        )
    for name, arr in (("y", y_arr), ("u", u_arr)):
        if not np.all(np.isfinite(arr)):
            bad = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise IdentificationError(
                f"{where}: {name} must be finite; got {arr[bad]} at sample {bad}"
            )
    if np.ptp(u_arr) == 0.0:
        raise IdentificationError(
            f"{where}: the input is constant ({u_arr[0]:g}) over the whole record, so it "
            "does not excite the system; use a record in which the input changes"
        )
    return y_arr, u_arr


def lagged(x: FloatArray, lag: int) -> FloatArray:
    """``x`` delayed by ``lag`` samples, the past held at the first value ``x[0]``.

    Returns ``z`` with ``z[k] = x[k - lag]`` for ``k >= lag`` and ``z[k] = x[0]`` for
    ``k < lag`` (the held-past initial condition of `sysid.simulate`).
    """
    if lag == 0:
        return np.array(x, dtype=float, copy=True)
    z = np.empty_like(x, dtype=float)
    z[:lag] = x[0]
    if lag < x.size:   # else x[: size - lag] would count from the end
        z[lag:] = x[: x.size - lag]
    return z


def segment_bounds(
    n: int, segment_starts: tuple[int, ...] | list[int] | None, where: str
) -> tuple[tuple[int, int], ...]:
    """``(start, stop)`` of each segment of an ``n``-sample record (one segment for None).

    Raises
    ------
    IdentificationError
        `segment_starts` not starting at 0 or not strictly increasing below ``n``.
    """
    if segment_starts is None:
        return ((0, n),)
    starts = [int(v) for v in segment_starts]
    if not starts or starts[0] != 0 or starts[-1] >= n or any(
            b <= a for a, b in zip(starts, starts[1:], strict=False)):
        raise IdentificationError(
            f"{where}: segment_starts must start at 0 and increase strictly below {n}; got "
            f"{starts}"
        )
    bounds = [*starts, n]
    return tuple(zip(bounds[:-1], bounds[1:], strict=True))


@dataclass(frozen=True, kw_only=True, eq=False)
class ArxFit:
    """Least-squares ARX estimate ``A y = B u + e`` (paper eq. 5) on plain arrays.

    Parameters
    ----------
    a :
        ``[1, a1, ..., a_na]``, shape ``(na + 1,)``.
    b :
        ``[0]*nk + [b_nk, ..., b_{nk+nb-1}]``, shape ``(nk + nb,)``.
    theta :
        ``[a1..a_na, b_nk..b_{nk+nb-1}]``, shape ``(na + nb,)``.
    std_errors :
        Standard errors of `theta`, ``sqrt(diag(s^2 (Phi'Phi)^-1))``.
    residuals :
        Equation errors ``e_k = A y_k - B u_k`` of the samples with a complete regressor,
        ``k >= first_sample`` of each segment, concatenated.
    first_sample :
        ``max(na, nk + nb - 1)``.
    na, nb, nk :
        The orders used.
    """

    a: FloatArray
    b: FloatArray
    theta: FloatArray
    std_errors: FloatArray
    residuals: FloatArray
    first_sample: int
    na: int
    nb: int
    nk: int

    def __post_init__(self) -> None:
        for name in ("a", "b", "theta", "std_errors", "residuals"):
            object.__setattr__(self, name, readonly_array(getattr(self, name)))

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """``("a1", ..., "b<nk>", ...)`` in the order of `theta`."""
        return _indexed_names("a", range(1, self.na + 1)) + _indexed_names(
            "b", range(self.nk, self.nk + self.nb))


def arx_regressor(
    y: FloatArray, u: FloatArray, *, na: int, nb: int, nk: int
) -> tuple[FloatArray, FloatArray, int]:
    """Regression ``y_k = phi_k' theta + e_k`` on the samples with complete regressors.

    Returns ``(Phi, y[n0:], n0)``, ``n0 = max(na, nk + nb - 1)``, with column-major
    ``Phi`` of shape ``(N - n0, na + nb)``, rows ``[-y_{k-1} .. -y_{k-na}, u_{k-nk} ..
    u_{k-nk-nb+1}]``. Trusts its inputs.
    """
    n = y.size
    n0 = max(na, nk + nb - 1)
    phi = np.empty((n - n0, na + nb), order="F")
    for i in range(1, na + 1):
        np.negative(y[n0 - i : n - i], out=phi[:, i - 1])
    for col, j in enumerate(range(nk, nk + nb), start=na):
        phi[:, col] = u[n0 - j : n - j]
    return phi, y[n0:].copy(), n0


#: Iterations of the simplified refined IV estimate (`sriv_oe`) from its start.
SRIV_ITERATIONS = 4


def _as_oe_start(theta: FloatArray, nb: int, nf: int) -> FloatArray | None:
    """``[a1..a_nf, b..]`` of a regression as an OE start ``[b.., f1..]``, or None."""
    if not np.all(np.isfinite(theta)):
        return None
    f = reflect_unstable_roots(np.concatenate([[1.0], theta[:nf]]))
    return np.concatenate([theta[nf:], f[1:]])


def arx_oe_start(y: FloatArray, u: FloatArray, *, nb: int, nf: int,
                 nk: int) -> FloatArray | None:
    """The ARX least squares as an OE start ``[b_nk.., f1..f_nf]`` (``F`` = ``A`` made stable).

    None where the regression has no finite solution. Trusts its inputs (1-D, one length).
    """
    phi, target, _ = arx_regressor(y, u, na=nf, nb=nb, nk=nk)
    theta, *_ = np.linalg.lstsq(phi, target, rcond=None)
    return _as_oe_start(np.asarray(theta, dtype=float), nb, nf)


def sriv_oe(y: FloatArray, u: FloatArray, *, nb: int, nf: int, nk: int,
            start: FloatArray) -> FloatArray | None:
    """Simplified refined instrumental-variable estimate of ``y = B/F u`` from `start`.

    Each of `SRIV_ITERATIONS` passes prefilters ``y`` and ``u`` by the current ``1/F``
    and solves the ARX normal equations with instruments from the noise-free output
    ``B/F u`` (Young 1976; Ljung 1999, sec. 7.6): unbiased by coloured noise, unlike ARX.

    Parameters
    ----------
    y, u :
        Output and input, 1-D of one length (trusted).
    nb, nf, nk :
        ``B`` coefficients, poles and delay [samples].
    start :
        ``[b_nk.., f1..f_nf]`` with a stable ``F`` (for example `arx_oe_start`).

    Returns
    -------
    FloatArray or None
        ``[b_nk.., f1..f_nf]`` with ``F`` made stable, or None where the instruments are
        singular or the estimate is not finite.
    """
    theta = start
    for _ in range(SRIV_ITERATIONS):
        b, f = _oe_polynomials(theta, nb, nf, nk)
        x = lfilter(b, f, u)                               # noise-free output: instruments
        yf, uf, xf = (lfilter([1.0], f, s) for s in (y, u, x))
        phi, target, _ = arx_regressor(yf, uf, na=nf, nb=nb, nk=nk)
        zeta, _, _ = arx_regressor(xf, uf, na=nf, nb=nb, nk=nk)
        try:
            est = np.linalg.solve(zeta.T @ phi, zeta.T @ target)
        except np.linalg.LinAlgError:
            return None
        nxt = _as_oe_start(np.asarray(est, dtype=float), nb, nf)
        if nxt is None:
            return None
        theta = nxt
    return theta


def arx_least_squares(
    y: FloatArray,
    u: FloatArray,
    *,
    na: int,
    nb: int,
    nk: int,
    segment_starts: tuple[int, ...] | list[int] | None = None,
) -> ArxFit:
    """Fit ``A(q) y = B(q) u + e`` (paper eq. 5) by ordinary least squares.

    Parameters
    ----------
    y :
        Output samples (deviation variables, e.g. ``dP`` [kW]), shape ``(N,)``.
    u :
        Input samples (e.g. ``ds`` [%] or ``f(ds)``), shape ``(N,)``.
    na :
        Order of ``A`` (>= 0).
    nb :
        Number of ``B`` coefficients (>= 1).
    nk :
        Input delay [samples] (>= 0).
    segment_starts :
        First sample of each segment (experiment), starting with 0; default one segment.
        No regressor reaches across a boundary: each segment contributes its samples
        ``k >= max(na, nk + nb - 1)`` from its start.

    Returns
    -------
    ArxFit
        Polynomials, parameters, standard errors and the equation errors of the
        samples with a complete regressor (no initial conditions assumed).

    Raises
    ------
    IdentificationError
        Orders that are not ints in range; arrays of unequal length or non-finite;
        a constant input; fewer samples than ``max(na, nk + nb - 1) + na + nb + 1``;
        a rank-deficient regressor (the data do not determine every parameter).

    Examples
    --------
    >>> u = np.sin(np.arange(50.0)) + np.arange(50.0) % 3
    >>> y = np.zeros(50)
    >>> for k in range(2, 50):
    ...     y[k] = 0.5 * y[k - 1] + 1.0 * u[k - 1] - 0.3 * u[k - 2]
    >>> fit = arx_least_squares(y, u, na=1, nb=2, nk=1)
    >>> np.round(fit.theta, 9).tolist()
    [-0.5, 1.0, -0.3]
    """
    na = checked_int(na, 0, "na")
    nb = checked_int(nb, 1, "nb")
    nk = checked_int(nk, 0, "nk")
    y, u = _check_signals(y, u, "arx_least_squares")
    bounds = segment_bounds(y.size, segment_starts, "arx_least_squares")
    n0 = max(na, nk + nb - 1)
    n_par = na + nb
    n_rows = sum(max(hi - lo - n0, 0) for lo, hi in bounds)
    if n_rows < n_par + 1:
        raise IdentificationError(
            f"arx_least_squares: na={na}, nb={nb}, nk={nk} need at least {n0 + n_par + 1} "
            f"samples ({n0} to fill the regressor, then more than {n_par} equations); got "
            f"{y.size}"
            + ("" if len(bounds) == 1 else
               f" in {len(bounds)} segments ({n_rows} complete regressors)")
            + "; use a longer record or lower orders"
        )
    if len(bounds) == 1:
        phi, target, n0 = arx_regressor(y, u, na=na, nb=nb, nk=nk)
    else:
        parts = [arx_regressor(y[lo:hi], u[lo:hi], na=na, nb=nb, nk=nk)
                 for lo, hi in bounds if hi - lo > n0]
        phi = np.asfortranarray(np.vstack([p[0] for p in parts]))
        target = np.concatenate([p[1] for p in parts])
    col_scale = np.sqrt(np.einsum("ij,ij->j", phi, phi))
    if np.any(col_scale == 0.0):
        raise IdentificationError(
            "arx_least_squares: a regressor column is identically zero (the output or "
            "input is zero over the fitted samples); the data do not determine every "
            "parameter"
        )
    # R of [Phi / scale, target] (last column Q'target); the rank from the small R's
    # singular values: numpy's lstsq cut-off, at a third of its time
    aug = np.empty((phi.shape[0], n_par + 1), order="F")
    np.divide(phi, col_scale, out=aug[:, :n_par])
    aug[:, n_par] = target
    r_aug = triangular_factor(aug, overwrite=True)
    r_mat = r_aug[:n_par, :n_par]
    sing = np.linalg.svd(r_mat, compute_uv=False)
    rank = int(np.count_nonzero(sing > np.finfo(float).eps * max(phi.shape) * sing[0]))
    if rank < n_par:
        raise IdentificationError(
            f"arx_least_squares: the regressor has rank {rank} < {n_par} parameters, so the "
            "data do not determine every parameter (the input does not excite the system "
            "enough for these orders); use a more exciting record or lower orders"
        )
    theta = solve_triangular(r_mat, r_aug[:n_par, n_par]) / col_scale
    residuals = target - phi @ theta
    a, b, _ = _armax_polynomials(theta, na, nb, 0, nk)
    return ArxFit(
        a=a,
        b=b,
        theta=theta,
        std_errors=parameter_std_errors(phi, residuals, factor=r_mat * col_scale),
        residuals=residuals,
        first_sample=n0,
        na=na,
        nb=nb,
        nk=nk,
    )


# --- prediction-error method: OE (V, eq. 9) and ARMAX (W, eq. 10) -------------------


@dataclass(frozen=True, kw_only=True, eq=False)
class PemFit:
    """Prediction-error estimate of an OE or ARMAX model on plain arrays.

    Parameters
    ----------
    structure :
        ``"oe"`` (``y = B/F u + eps``, minimizes V, eq. 9) or ``"armax"``
        (``A y = B u + C e``, minimizes W, eq. 10).
    a :
        ``A(q)``; for OE this is ``F(q)``.
    b :
        ``B(q)`` with ``nk`` leading zeros (not normalized).
    c :
        ``C(q)``; for OE ``C = F`` (the model-file convention, so the one-step predictor
        is the simulation).
    theta :
        Model parameters: OE ``[b_nk.., f1..f_nf]``, ARMAX ``[a1.., b_nk.., c1..]``.
    parameter_names :
        Names of `theta` entries (``"b1"``, ``"f1"``, ...).
    std_errors :
        Standard errors of `theta` (`parameter_std_errors`, estimated initial states in
        the covariance).
    residuals :
        Simulation errors ``eps`` (OE) or prediction errors ``e`` (ARMAX), shape ``(N,)``.
    cost :
        ``mean(residuals**2)``: V (OE) or W (ARMAX) on the arrays.
    initial_conditions :
        ``"held"`` (the rule of `sysid.simulate`) or ``"estimated"``.
    initial_state :
        ``w``: the `scipy.signal.lfilter` state of ``1/F`` (OE, length ``nf``) or ``1/C``
        (ARMAX, ``nc``) that the past leaves; held: OE ``filter_state([1], F, [y_0]*nf)``,
        ARMAX zeros; estimated: fitted. Each segment's, concatenated.
    converged, message, n_iterations :
        From the optimizer.
    lm :
        The optimizer's full result.
    """

    structure: Literal["oe", "armax"]
    a: FloatArray
    b: FloatArray
    c: FloatArray
    theta: FloatArray
    parameter_names: tuple[str, ...]
    std_errors: FloatArray
    residuals: FloatArray
    cost: float
    initial_conditions: InitialConditions
    initial_state: FloatArray
    converged: bool
    message: str
    n_iterations: int
    lm: LMResult

    def __post_init__(self) -> None:
        for name in ("a", "b", "c", "theta", "std_errors", "residuals", "initial_state"):
            object.__setattr__(self, name, readonly_array(getattr(self, name)))


def _shift_into(out: FloatArray, x: FloatArray, lags: range) -> FloatArray:
    """Fill column ``i`` of `out` with ``q^-lags[i] x`` (zeros before the record); return `out`."""
    for col, lag in enumerate(lags):
        out[:lag, col] = 0.0
        if lag < x.size:   # else x[: size - lag] would count from the end
            out[lag:, col] = x[: x.size - lag]
    return out


def _held_lag_responses(x: FloatArray, den: FloatArray, lags: range,
                        step: FloatArray, out: FloatArray) -> FloatArray:
    """Columns ``lagged(x, j) / den`` from a zero filter state, one per lag ``j``, into `out`.

    ``lagged(x, j) = x_0 + q^-j (x - x_0)`` and ``1/den`` commutes with ``q^-j`` from rest,
    so each column is ``x_0 g + q^-j v`` with the step response ``g`` of ``1/den`` and
    ``v = (x - x_0)/den``: one filtering for all lags (Ljung 1999, sec. 10.3).
    """
    x0 = float(x[0])
    _shift_into(out, lfilter([1.0], den, x - x0), lags)
    out += (x0 * step)[:, None]
    return out


def _stabilizer(blocks: tuple[slice, ...]) -> Callable[[FloatArray], FloatArray]:
    """Projection that mirrors unstable roots of the monic polynomials ``[1, theta[blk]]``."""

    def project(theta: FloatArray) -> FloatArray:
        out = np.array(theta, dtype=float, copy=True)
        for blk in blocks:
            poly = np.concatenate([[1.0], out[blk]])
            if not is_stable(poly):
                out[blk] = reflect_unstable_roots(poly)[1:]
        return out

    return project


def _check_theta0(theta0: FloatArray | None, n_model: int, where: str) -> FloatArray | None:
    if theta0 is None:
        return None
    arr = np.array(theta0, dtype=float, copy=True).reshape(-1)
    if arr.size != n_model or not np.all(np.isfinite(arr)):
        raise IdentificationError(
            f"{where}: theta0 must hold {n_model} finite numbers (the model parameters in "
            f"the order of parameter_names); got {theta0!r}"
        )
    return arr


Problem = Callable[[FloatArray], tuple[FloatArray, Callable[[], FloatArray]]]


def _stacked_problem(problems: list[Problem], n_model: int, n_state: int) -> Problem:
    """Residuals of several segments, concatenated: shared model, own initial states.

    ``theta = [model (n_model), state of segment 0 (n_state), ..]``; each segment sees
    ``[model, its state]``.
    """
    if len(problems) == 1:
        return problems[0]
    n_theta = n_model + len(problems) * n_state

    def fun(theta: FloatArray) -> tuple[FloatArray, Callable[[], FloatArray]]:
        parts = []
        for s, problem in enumerate(problems):
            lo = n_model + s * n_state
            parts.append(problem(np.concatenate([theta[:n_model], theta[lo : lo + n_state]])))

        def jacobian() -> FloatArray:
            full = np.zeros((sum(r.size for r, _ in parts), n_theta), order="F")
            row = 0
            for s, (r, make) in enumerate(parts):
                jac = make()
                lo = n_model + s * n_state
                full[row : row + r.size, :n_model] = jac[:, :n_model]
                full[row : row + r.size, lo : lo + n_state] = jac[:, n_model:]
                row += r.size
            return full

        return np.concatenate([r for r, _ in parts]), jacobian

    return fun


def _oe_problem(
    y: FloatArray, u: FloatArray, nb: int, nf: int, nk: int, estimate: bool
) -> Problem:
    """Residuals ``eps = y - B/F u`` and their exact Jacobian via sensitivity filters.

    ``d yhat/d b_j = u_{k-j} / F`` (past input held), ``d yhat/d f_i = -yhat_{k-i} / F``
    with the past held at ``y_0`` or, with the state ``w`` of ``1/F`` estimated, zero;
    ``d yhat/d w_j`` is the free response of ``1/F``. The Jacobian is made on request
    from three filterings: ``(u - u_0)/F``, ``yhat/F`` and the impulse response of ``1/F``.
    """
    n = y.size
    held = np.full(nf, y[0])
    u_held = np.full(nk + nb - 1, u[0])
    y0 = float(y[0])

    def fun(theta: FloatArray) -> tuple[FloatArray, Callable[[], FloatArray]]:
        b, f = _oe_polynomials(theta, nb, nf, nk)
        if estimate:
            zi = filter_state(b, f, np.zeros(nf), u_held)
            zi[:nf] += theta[nb + nf :]
            yhat = lfilter(b, f, u, zi=zi)[0]
        else:
            yhat = simulate_arrays(b, f, u, y_past=held)

        def jacobian() -> FloatArray:
            h = impulse_response(f, n)
            step = np.cumsum(h)
            jac = np.empty((n, nb + nf + (nf if estimate else 0)), order="F")
            b_cols, f_cols, w_cols = jac[:, :nb], jac[:, nb : nb + nf], jac[:, nb + nf :]
            np.negative(_held_lag_responses(u, f, range(nk, nk + nb), step, b_cols),
                        out=b_cols)
            if nf:
                # d eps/d f_i = (q^-i yhat)/F: zero past (estimated) or y_0 held
                yf = lfilter([1.0], f, yhat if estimate else yhat - y0)
                _shift_into(f_cols, yf, range(1, nf + 1))
                if not estimate:
                    f_cols += (y0 * step)[:, None]
            if estimate:
                np.negative(_shift_into(w_cols, h, range(nf)), out=w_cols)
            return jac

        return y - yhat, jacobian

    return fun


def _armax_problem(
    y: FloatArray, u: FloatArray, na: int, nb: int, nc: int, nk: int, estimate: bool
) -> Problem:
    """Prediction errors ``e = (A y - B u)/C`` and their exact Jacobian.

    ``de/da_i = y_{k-i}/C``, ``de/db_j = -u_{k-j}/C`` (pasts held), ``de/dc_i =
    -e_{k-i}/C`` with a zero past (the estimated past lives in the state ``w`` of
    ``1/C``); ``de/dw_j`` is the free response of ``1/C``. Made on request, each signal's
    lags as shifts of one filtering.
    """
    n = y.size
    n_model = na + nb + nc
    zero_state = np.zeros(nc)

    def fun(theta: FloatArray) -> tuple[FloatArray, Callable[[], FloatArray]]:
        a, b, c = _armax_polynomials(theta, na, nb, nc, nk)
        state = theta[n_model:] if estimate else zero_state
        v = equation_errors(a, b, y, u)
        e = lfilter([1.0], c, v, zi=state)[0]

        def jacobian() -> FloatArray:
            h = impulse_response(c, n)
            step = np.cumsum(h)
            jac = np.empty((n, n_model + (nc if estimate else 0)), order="F")
            a_cols, b_cols = jac[:, :na], jac[:, na : na + nb]
            c_cols, w_cols = jac[:, na + nb : n_model], jac[:, n_model:]
            if na:
                _held_lag_responses(y, c, range(1, na + 1), step, a_cols)
            np.negative(_held_lag_responses(u, c, range(nk, nk + nb), step, b_cols),
                        out=b_cols)
            if nc:
                ef = lfilter([1.0], c, e)
                np.negative(_shift_into(c_cols, ef, range(1, nc + 1)), out=c_cols)
            if estimate:
                _shift_into(w_cols, h, range(nc))
            return jac

        return e, jacobian

    return fun


@dataclass(frozen=True, kw_only=True, eq=False)
class _PemSetup:
    """The checked data and options of one OE or ARMAX fit (what `_pem_fit` runs on).

    ``bounds``: `segment_bounds`; ``n_model``: the size of `PemFit.theta`; ``estimate``:
    whether the initial states are searched, ``n_searched_state`` of them per segment.
    """

    y: FloatArray
    u: FloatArray
    bounds: tuple[tuple[int, int], ...]
    initial_conditions: InitialConditions
    n_model: int
    estimate: bool
    n_searched_state: int


def _pem_setup(
    y: FloatArray,
    u: FloatArray,
    *,
    initial_conditions: object,
    segment_starts: tuple[int, ...] | list[int] | None,
    n_model: int,
    n_state: int,
    max_lag: int,
    where: str,
) -> _PemSetup:
    """Check the data and options of an OE or ARMAX fit (orders already checked).

    `n_state`: a segment's initial-state parameters when estimated (``nf`` or ``nc``);
    `max_lag`: the structure's longest lag [samples]; `where`: the public name in messages.
    """
    if initial_conditions not in ("held", "estimated"):
        raise IdentificationError(
            f"initial_conditions must be 'held' or 'estimated'; got {initial_conditions!r}"
        )
    y, u = _check_signals(y, u, where)
    bounds = segment_bounds(y.size, segment_starts, where)
    estimate = initial_conditions == "estimated"
    setup = _PemSetup(y=y, u=u, bounds=bounds, initial_conditions=initial_conditions,
                      n_model=n_model, estimate=estimate,
                      n_searched_state=n_state if estimate else 0)
    n_total = n_model + len(bounds) * setup.n_searched_state
    if y.size < max_lag + n_total + 1:
        raise IdentificationError(
            f"{where}: these orders need at least {max_lag + n_total + 1} samples ({n_total} "
            f"parameters and lags up to {max_lag}); got {y.size}; use a longer record or "
            "lower orders"
        )
    return setup


def _pem_fit(
    structure: Literal["oe", "armax"],
    setup: _PemSetup,
    start: FloatArray,
    *,
    segment_problem: Callable[[FloatArray, FloatArray], Problem],
    project: Callable[[FloatArray], FloatArray],
    held_state: Callable[[FloatArray], FloatArray],
    polynomials: Callable[[FloatArray], tuple[FloatArray, FloatArray, FloatArray]],
    names: tuple[str, ...],
    max_iterations: int,
    tolerance: float | None = None,
) -> PemFit:
    """Minimize the stacked residuals of the segments from `start` and make the `PemFit`.

    `segment_problem`: ``(y, u) -> Problem`` of one segment; `project`: the stabilizing
    projection of every trial point; `held_state`: ``theta -> w``, every segment's held
    initial state, concatenated (with estimated ones the search starts there, from the
    projected `start`); `polynomials`: ``theta -> (a, b, c)``; `tolerance`: LM's ``ftol``
    and ``xtol`` both, None for its tight defaults.
    """
    if setup.estimate:
        start = np.concatenate([start, held_state(project(start))])
    problem = _stacked_problem(
        [segment_problem(setup.y[lo:hi], setup.u[lo:hi]) for lo, hi in setup.bounds],
        setup.n_model, setup.n_searched_state)
    lm = levenberg_marquardt(problem, start, project=project, max_iterations=max_iterations,
                             ftol=DEFAULT_FTOL if tolerance is None else tolerance,
                             xtol=DEFAULT_XTOL if tolerance is None else tolerance)
    n_model = setup.n_model
    n_theta = lm.theta.size
    std = parameter_std_errors(lm.jacobian, lm.residuals,
                               factor=lm.factor[:n_theta, :n_theta])[:n_model]
    a, b, c = polynomials(lm.theta)
    return PemFit(
        structure=structure,
        a=a,
        b=b,
        c=c,
        theta=lm.theta[:n_model],
        parameter_names=names,
        std_errors=std,
        residuals=lm.residuals,
        cost=lm.cost,
        initial_conditions=setup.initial_conditions,
        initial_state=lm.theta[n_model:] if setup.estimate else held_state(lm.theta),
        converged=lm.converged,
        message=lm.message,
        n_iterations=lm.n_iterations,
        lm=lm,
    )


def _warn_unless_converged(fit: PemFit, where: str, *, stacklevel: int) -> None:
    """Issue an `IdentificationWarning` naming `where` if the search did not converge.

    `stacklevel` counts as in `warnings.warn`, from the caller of this function.
    """
    if not fit.converged:
        warnings.warn(f"{where} did not converge: {fit.message}", IdentificationWarning,
                      stacklevel=stacklevel + 1)


def _oe_pem(
    y: FloatArray,
    u: FloatArray,
    *,
    nb: int,
    nf: int,
    nk: int,
    theta0: FloatArray | None,
    initial_conditions: object,
    max_iterations: int,
    segment_starts: tuple[int, ...] | list[int] | None = None,
    tolerance: float | None = None,
) -> PemFit:
    """`oe_pem` without its warning (`fit_oe` warns in its own name)."""
    nb = checked_int(nb, 1, "nb")
    nf = checked_int(nf, 0, "nf")
    nk = checked_int(nk, 0, "nk")
    setup = _pem_setup(y, u, initial_conditions=initial_conditions,
                       segment_starts=segment_starts, n_model=nb + nf, n_state=nf,
                       max_lag=max(nf, nk + nb - 1), where="oe_pem")
    start = _check_theta0(theta0, setup.n_model, "oe_pem")
    if start is None:
        arx = arx_least_squares(setup.y, setup.u, na=nf, nb=nb, nk=nk,
                                segment_starts=segment_starts)
        start = np.concatenate([arx.b[nk:], arx.a[1:]])

    def polynomials(theta: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        b, f = _oe_polynomials(theta, nb, nf, nk)
        return f, b, f                                     # A = C = F (model-file form)

    def held_state(theta: FloatArray) -> FloatArray:
        """The state of ``1/F`` that a past output held at each segment's first ``y``."""
        if not nf:
            return np.zeros(0)
        f = polynomials(theta)[0]
        return np.concatenate(
            [filter_state(np.ones(1), f, np.full(nf, setup.y[lo])) for lo, _ in setup.bounds])

    return _pem_fit(
        "oe", setup, start,
        segment_problem=lambda ys, us: _oe_problem(ys, us, nb, nf, nk, setup.estimate),
        project=_stabilizer((slice(nb, nb + nf),)), held_state=held_state,
        polynomials=polynomials,
        names=_indexed_names("b", range(nk, nk + nb)) + _indexed_names("f", range(1, nf + 1)),
        max_iterations=max_iterations, tolerance=tolerance)


def oe_pem(
    y: FloatArray,
    u: FloatArray,
    *,
    nb: int,
    nf: int,
    nk: int,
    theta0: FloatArray | None = None,
    initial_conditions: InitialConditions = "held",
    max_iterations: int = MAX_ITERATIONS,
    segment_starts: tuple[int, ...] | list[int] | None = None,
) -> PemFit:
    """Output-error model ``y = B/F u + eps`` minimizing V (paper eqs. 7, 9).

    Parameters
    ----------
    y :
        Output samples (deviation variables), shape ``(N,)``.
    u :
        Input samples (``ds`` or a Hammerstein input ``f(ds)``), shape ``(N,)``.
    nb :
        Number of ``B`` coefficients (>= 1).
    nf :
        Order of ``F`` (>= 0).
    nk :
        Input delay [samples] (>= 0).
    theta0 :
        Start ``[b_nk.., f1..f_nf]``; default: the ARX(na=nf, nb, nk) least-squares
        estimate (its ``A`` as ``F``, its ``B``), as the paper's sec. 7.3 does.
    initial_conditions :
        ``"held"``: the held-past rule of `sysid.simulate` (past simulated output
        ``= y[0]``, past input ``= u[0]``). ``"estimated"``: past input held, and the
        ``nf`` states of ``1/F`` that the past outputs leave (`PemFit.initial_state`)
        are extra parameters, for records that do not start at rest.
    max_iterations :
        Levenberg-Marquardt iteration limit.
    segment_starts :
        First sample of each segment (experiment), starting with 0; default one
        segment. Each segment is filtered from its own start (held past, or its own
        estimated initial state); `PemFit.initial_state` then holds each segment's.

    Returns
    -------
    PemFit
        ``structure = "oe"``, ``a = c = F``; not converged: the best iterate,
        ``converged = False`` and an `IdentificationWarning`.

    Raises
    ------
    IdentificationError
        Bad orders or options, non-finite or mismatched arrays, a constant input, too
        few samples for the orders, or a rank-deficient ARX start.

    Notes
    -----
    Levenberg-Marquardt (`sysid.optimize`) with the exact Jacobian from the sensitivity
    filters ``u_{k-j}/F`` and ``-yhat_{k-i}/F``; unstable roots of ``F`` are mirrored
    into the unit circle at every trial point.
    """
    fit = _oe_pem(y, u, nb=nb, nf=nf, nk=nk, theta0=theta0,
                  initial_conditions=initial_conditions, max_iterations=max_iterations,
                  segment_starts=segment_starts)
    _warn_unless_converged(fit, "oe_pem", stacklevel=2)
    return fit


def _armax_pem(
    y: FloatArray,
    u: FloatArray,
    *,
    na: int,
    nb: int,
    nc: int,
    nk: int,
    theta0: FloatArray | None,
    initial_conditions: object,
    max_iterations: int,
    segment_starts: tuple[int, ...] | list[int] | None = None,
    tolerance: float | None = None,
) -> PemFit:
    """`armax_pem` without its warning (`fit_armax` warns in its own name)."""
    na = checked_int(na, 0, "na")
    nb = checked_int(nb, 1, "nb")
    nc = checked_int(nc, 0, "nc")
    nk = checked_int(nk, 0, "nk")
    setup = _pem_setup(y, u, initial_conditions=initial_conditions,
                       segment_starts=segment_starts, n_model=na + nb + nc, n_state=nc,
                       max_lag=max(na, nc, nk + nb - 1), where="armax_pem")
    start = _check_theta0(theta0, setup.n_model, "armax_pem")
    project = _stabilizer((slice(0, na), slice(na + nb, setup.n_model)))
    if start is None:
        arx = arx_least_squares(setup.y, setup.u, na=na, nb=nb, nk=nk,
                                segment_starts=segment_starts)
        start = project(np.concatenate([arx.theta, np.zeros(nc)]))
    return _pem_fit(
        "armax", setup, start,
        segment_problem=lambda ys, us: _armax_problem(ys, us, na, nb, nc, nk, setup.estimate),
        project=project,
        # held: the past prediction errors are zero, so is the state of 1/C
        held_state=lambda theta: np.zeros(len(setup.bounds) * nc),
        polynomials=lambda theta: _armax_polynomials(theta, na, nb, nc, nk),
        names=(_indexed_names("a", range(1, na + 1)) + _indexed_names("b", range(nk, nk + nb))
               + _indexed_names("c", range(1, nc + 1))),
        max_iterations=max_iterations, tolerance=tolerance)


def armax_pem(
    y: FloatArray,
    u: FloatArray,
    *,
    na: int,
    nb: int,
    nc: int,
    nk: int,
    theta0: FloatArray | None = None,
    initial_conditions: InitialConditions = "held",
    max_iterations: int = MAX_ITERATIONS,
    segment_starts: tuple[int, ...] | list[int] | None = None,
) -> PemFit:
    """ARMAX model ``A y = B u + C e`` minimizing W (paper eqs. 6, 10).

    Parameters
    ----------
    y, u :
        Output and input samples, shape ``(N,)``, as in `oe_pem`.
    na, nc :
        Orders of ``A`` and ``C`` (>= 0).
    nb :
        Number of ``B`` coefficients (>= 1).
    nk :
        Input delay [samples] (>= 0).
    theta0 :
        Start ``[a1.., b_nk.., c1..]``; default: the ARX(na, nb, nk) least-squares
        estimate with ``C = 1`` (a Hannan-Rissanen two-stage start was tried and cost
        more time than the iterations it saved on heater-like data).
    initial_conditions :
        ``"held"``: past ``y``, ``u`` held at their first values, past prediction errors
        zero (`sysid.simulate`). ``"estimated"``: past ``y``, ``u`` held, and the ``nc``
        states of ``1/C`` that the past prediction errors leave
        (`PemFit.initial_state`) are extra parameters.
    max_iterations, segment_starts :
        As in `oe_pem`.

    Returns
    -------
    PemFit
        ``structure = "armax"``; not converged: the best iterate, ``converged = False``
        and an `IdentificationWarning`.

    Raises
    ------
    IdentificationError
        As `oe_pem`.

    Notes
    -----
    Levenberg-Marquardt with the exact Jacobian from the sensitivity filters
    ``y_{k-i}/C``, ``-u_{k-j}/C`` and ``-e_{k-i}/C``; unstable roots of ``A`` and ``C``
    are mirrored into the unit circle at every trial point (``C`` keeps the predictor
    stable; ``A`` keeps the model storable).
    """
    fit = _armax_pem(y, u, na=na, nb=nb, nc=nc, nk=nk, theta0=theta0,
                     initial_conditions=initial_conditions, max_iterations=max_iterations,
                     segment_starts=segment_starts)
    _warn_unless_converged(fit, "armax_pem", stacklevel=2)
    return fit


# --- public fits on a Dataset ---------------------------------------------------------


def _deviation_arrays(
    data: Dataset, operating_point: OperatingPoint, where: str
) -> tuple[FloatArray, FloatArray]:
    if not isinstance(data, Dataset):
        raise IdentificationError(f"{where}: data must be a sysid Dataset; got {type(data)}")
    if not isinstance(operating_point, OperatingPoint):
        raise IdentificationError(
            f"{where}: operating_point must be an OperatingPoint; got {operating_point!r}"
        )
    return (
        data.power_kw - operating_point.power_kw,
        data.triac_pct - operating_point.triac_pct,
    )


def _linear_model(
    data: Dataset,
    operating_point: OperatingPoint,
    *,
    block: LinearBlock,
    a: FloatArray,
    b: FloatArray,
    c: FloatArray,
    residuals: FloatArray,
    n_parameters: int,
    method: str,
    where: str,
) -> HammersteinModel:
    b_norm, input_poly = normalize_input_gain(b, np.array([1.0]))
    dof = max(residuals.size - n_parameters, 1)
    try:
        model = HammersteinModel(
            kind="linear",
            linear_block=block,
            ts_s=data.ts_s,
            operating_point=operating_point,
            a=a,
            b=b_norm,
            c=c,
            input_poly=input_poly,
            noise_std_kw=float(np.sqrt(sum_of_squares(residuals) / dof)),
            input_range_pct=(float(np.min(data.triac_pct)), float(np.max(data.triac_pct))),
            provenance=Provenance(
                data_file=None if data.source is None else Path(data.source).name,
                data_sha256=data.sha256,
                preprocessing=data.preprocessing,
                method=method,
                created_utc=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
            ),
        )
    except UnstableModelError as exc:
        raise IdentificationError(
            f"{where}: the estimate is not a usable model ({exc}); check the data and the "
            "orders"
        ) from None
    return model.with_updates(criteria=model_criteria(model, data))


def _fit_result(
    data: Dataset,
    operating_point: OperatingPoint,
    fit: ArxFit | PemFit,
    *,
    block: LinearBlock,
    c: FloatArray,
    converged: bool,
    message: str,
    n_iterations: int,
    criterion: CriterionName,
    method: str,
    where: str,
) -> IdentificationResult:
    """The model of `fit` (with noise polynomial `c`) on `data` and its result."""
    model = _linear_model(
        data, operating_point, block=block, a=fit.a, b=fit.b, c=c, residuals=fit.residuals,
        n_parameters=fit.theta.size, method=method, where=where,
    )
    return IdentificationResult(
        model=model,
        converged=converged,
        message=message,
        n_iterations=n_iterations,
        criterion=criterion,
        parameter_names=fit.parameter_names,
        parameters=fit.theta,
        std_errors=fit.std_errors,
        residuals_kw=fit.residuals,
        raw=fit,
    )


def fit_arx(
    data: Dataset,
    *,
    operating_point: OperatingPoint,
    na: int = 1,
    nb: int = 2,
    nk: int = 1,
) -> IdentificationResult:
    """Fit a linear ARX model ``A dP = B ds + e`` by least squares (paper eq. 5, sec. 6).

    Parameters
    ----------
    data :
        The identification record (absolute units).
    operating_point :
        ``(s_nom, P_nom)`` for the deviation variables (paper sec. 5.1).
    na :
        Order of ``A`` (>= 0).
    nb :
        Number of ``B`` coefficients (>= 1).
    nk :
        Input delay [samples] (>= 0); the paper's data have ``nk = 1``.

    Returns
    -------
    IdentificationResult
        ``kind = "linear"``, ``linear_block = "arx"``, ``C = 1``, ``B`` normalized with
        ``input_poly = [b_first]``, criteria V and W on `data`, ``criterion =
        "least_squares"``; the residuals are the equation errors of the samples with a
        complete regressor.

    Raises
    ------
    IdentificationError
        Bad orders, a constant input, too short a record, a rank-deficient regressor, or
        an unstable estimated ``A``.
    """
    dy, du = _deviation_arrays(data, operating_point, "fit_arx")
    fit = arx_least_squares(dy, du, na=na, nb=nb, nk=nk, segment_starts=data.segment_starts)
    return _fit_result(
        data, operating_point, fit, block="arx", c=np.array([1.0]), converged=True,
        message="least squares: exact solution", n_iterations=0, criterion="least_squares",
        method="arx-least-squares", where="fit_arx",
    )


def _pem_result(
    data: Dataset, operating_point: OperatingPoint, kernel: Callable[..., PemFit], *,
    block: Literal["oe", "armax"], criterion: Literal["ballistic", "one_step"], method: str,
    where: str,
) -> IdentificationResult:
    """Run an OE/ARMAX `kernel` on the deviations of `data` and its segments.

    `kernel` is `_oe_pem` or `_armax_pem` with every argument but ``y``, ``u`` and
    ``segment_starts`` bound. Warns (at the public caller) if the search did not converge.
    """
    dy, du = _deviation_arrays(data, operating_point, where)
    fit = kernel(dy, du, segment_starts=data.segment_starts)
    _warn_unless_converged(fit, where, stacklevel=3)
    return _fit_result(
        data, operating_point, fit, block=block, c=fit.c, converged=fit.converged,
        message=fit.message, n_iterations=fit.n_iterations, criterion=criterion,
        method=method, where=where,
    )


def fit_oe(
    data: Dataset,
    *,
    operating_point: OperatingPoint,
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    initial_conditions: InitialConditions = "held",
    max_iterations: int = MAX_ITERATIONS,
    tolerance: float | None = None,
) -> IdentificationResult:
    """Fit a linear OE model ``dP = B/F ds + eps`` minimizing V (paper eqs. 7, 9, sec. 6).

    Parameters
    ----------
    data, operating_point :
        As in `fit_arx`.
    nb, nf, nk, initial_conditions, max_iterations :
        As in `oe_pem`.
    tolerance :
        Levenberg-Marquardt's ``ftol`` and ``xtol``; None: its tight defaults (a final
        fit). A comparison fit may stop sooner (`sysid.pipeline.COMPARISON_TOLERANCE`).

    Returns
    -------
    IdentificationResult
        ``kind = "linear"``, ``linear_block = "oe"`` stored with ``A = C = F``, ``B``
        normalized, criteria V and W (equal for OE with held initial conditions),
        ``criterion = "ballistic"``; not converged as `oe_pem`.

    Raises
    ------
    IdentificationError
        See `oe_pem`.
    """
    kernel = partial(_oe_pem, nb=nb, nf=nf, nk=nk, theta0=None,
                     initial_conditions=initial_conditions, max_iterations=max_iterations,
                     tolerance=tolerance)
    return _pem_result(data, operating_point, kernel, block="oe", criterion="ballistic",
                       method="oe-pem-ballistic", where="fit_oe")


def fit_armax(
    data: Dataset,
    *,
    operating_point: OperatingPoint,
    na: int = 1,
    nb: int = 2,
    nc: int = 1,
    nk: int = 1,
    initial_conditions: InitialConditions = "held",
    max_iterations: int = MAX_ITERATIONS,
    tolerance: float | None = None,
) -> IdentificationResult:
    """Fit a linear ARMAX model ``A dP = B ds + C e`` minimizing W (eqs. 6, 10, sec. 6).

    Parameters
    ----------
    data, operating_point :
        As in `fit_arx`.
    na, nb, nc, nk, initial_conditions, max_iterations :
        As in `armax_pem`; the paper takes ``nc = na``.
    tolerance :
        As in `fit_oe`.

    Returns
    -------
    IdentificationResult
        ``kind = "linear"``, ``linear_block = "armax"``, ``B`` normalized, criteria V
        and W, ``criterion = "one_step"``; not converged as `armax_pem`.

    Raises
    ------
    IdentificationError
        See `armax_pem`.
    """
    kernel = partial(_armax_pem, na=na, nb=nb, nc=nc, nk=nk, theta0=None,
                     initial_conditions=initial_conditions, max_iterations=max_iterations,
                     tolerance=tolerance)
    return _pem_result(data, operating_point, kernel, block="armax", criterion="one_step",
                       method="armax-pem-one-step", where="fit_armax")


__all__ = [
    "ArxFit",
    "InitialConditions",
    "PemFit",
    "armax_pem",
    "arx_least_squares",
    "arx_oe_start",
    "arx_regressor",
    "fit_armax",
    "fit_arx",
    "fit_oe",
    "lagged",
    "oe_pem",
    "segment_bounds",
    "sriv_oe",
]
