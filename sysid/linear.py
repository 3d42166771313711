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

from dataclasses import dataclass

import numpy as np

from sysid._typing import FloatArray
from sysid.errors import IdentificationError
from sysid.optimize import parameter_std_errors


def _check_order(name: str, value: object, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise IdentificationError(f"{name} must be an int >= {minimum}; got {value!r}")
    return int(value)


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
    z[lag:] = x[: x.size - lag]
    return z


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
        Equation errors ``e_k = A y_k - B u_k`` for the samples with a complete
        regressor only, ``k = first_sample .. N-1``; shape ``(N - first_sample,)``.
    first_sample :
        ``max(na, nk + nb - 1)``: index of the sample `residuals` starts at.
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
            arr = np.array(getattr(self, name), dtype=float, copy=True)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """``("a1", ..., "b<nk>", ...)`` in the order of `theta`."""
        return tuple(f"a{i}" for i in range(1, self.na + 1)) + tuple(
            f"b{j}" for j in range(self.nk, self.nk + self.nb)
        )


def arx_regressor(
    y: FloatArray, u: FloatArray, *, na: int, nb: int, nk: int
) -> tuple[FloatArray, FloatArray, int]:
    """Regression ``y_k = phi_k' theta + e_k`` on the samples with complete regressors.

    Returns ``(Phi, target, first_sample)`` with ``Phi`` of shape ``(N - n0, na + nb)``,
    rows ``phi_k = [-y_{k-1} .. -y_{k-na}, u_{k-nk} .. u_{k-nk-nb+1}]`` and
    ``target = y[n0:]``, ``n0 = max(na, nk + nb - 1)``. Trusts its inputs.
    """
    n = y.size
    n0 = max(na, nk + nb - 1)
    cols = [-y[n0 - i : n - i] for i in range(1, na + 1)]
    cols += [u[n0 - j : n - j] for j in range(nk, nk + nb)]
    return np.column_stack(cols), y[n0:].copy(), n0


def arx_least_squares(
    y: FloatArray, u: FloatArray, *, na: int, nb: int, nk: int
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

    Returns
    -------
    ArxFit
        Polynomials, parameters, standard errors and equation errors on the samples
        ``k >= max(na, nk + nb - 1)`` (those whose regressor is complete; no initial
        conditions are assumed).

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
    na = _check_order("na", na, 0)
    nb = _check_order("nb", nb, 1)
    nk = _check_order("nk", nk, 0)
    y, u = _check_signals(y, u, "arx_least_squares")
    n0 = max(na, nk + nb - 1)
    n_par = na + nb
    if y.size < n0 + n_par + 1:
        raise IdentificationError(
            f"arx_least_squares: na={na}, nb={nb}, nk={nk} need at least {n0 + n_par + 1} "
            f"samples ({n0} to fill the regressor, then more than {n_par} equations); got "
            f"{y.size}; use a longer record or lower orders"
        )
    phi, target, n0 = arx_regressor(y, u, na=na, nb=nb, nk=nk)
    col_scale = np.linalg.norm(phi, axis=0)
    if np.any(col_scale == 0.0):
        raise IdentificationError(
            "arx_least_squares: a regressor column is identically zero (the output or "
            "input is zero over the fitted samples); the data do not determine every "
            "parameter"
        )
    scaled = phi / col_scale
    sol, _, rank, _ = np.linalg.lstsq(scaled, target, rcond=None)
    if rank < n_par:
        raise IdentificationError(
            f"arx_least_squares: the regressor has rank {rank} < {n_par} parameters, so the "
            "data do not determine every parameter (the input does not excite the system "
            "enough for these orders); use a more exciting record or lower orders"
        )
    theta = sol / col_scale
    residuals = target - phi @ theta
    a = np.concatenate([[1.0], theta[:na]])
    b = np.concatenate([np.zeros(nk), theta[na:]])
    return ArxFit(
        a=a,
        b=b,
        theta=theta,
        std_errors=parameter_std_errors(phi, residuals),
        residuals=residuals,
        first_sample=n0,
        na=na,
        nb=nb,
        nk=nk,
    )


__all__ = ["ArxFit", "arx_least_squares", "arx_regressor", "lagged"]
