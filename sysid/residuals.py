"""Residual analysis: whiteness and input independence of prediction errors (paper Figs. 3, 6, 18).

A model explains the data when its one-step-ahead prediction errors ``e`` are white and
uncorrelated with the input, both judged with the 99 % bound ``2.58 / sqrt(N)`` on the
normalized sample correlations (Ljung, *System Identification*, 2nd ed., sec. 16.6;
MATLAB ``resid``).

Notation
--------
``e`` : residuals (prediction errors) [output unit, kW for the CZ heater].
``u`` : input [input unit, % for the CZ heater].
``N`` : number of samples.  ``tau`` : lag [samples].

Sample correlations, means removed, biased (divided by ``N``, not ``N - tau``)::

    R_e(tau)    = 1/N sum_{k=tau}^{N-1} (e_k - mean e)(e_{k-tau} - mean e)
    r_e(tau)    = R_e(tau) / R_e(0)                         tau = 0..M
    R_eu(tau)   = 1/N sum_k (e_k - mean e)(u_{k-tau} - mean u)
    r_eu(tau)   = R_eu(tau) / sqrt(R_e(0) R_u(0))           tau = -M..M

A positive ``tau`` in ``r_eu`` pairs ``e_k`` with the *earlier* input ``u_{k-tau}``
(missing dynamics); a negative ``tau`` pairs it with later inputs (feedback).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import numpy.typing as npt

from sysid._arrays import readonly_array as _readonly
from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.errors import IdentificationError

#: Two-sided 99 % quantile of the standard normal distribution: a white-noise
#: correlation estimate stays within ``Z_99 / sqrt(N)`` with probability 0.99 at each lag.
Z_99 = 2.58

#: Default largest lag [samples], as in MATLAB ``resid``.
DEFAULT_MAX_LAG = 25

CorrelationKind = Literal["auto", "cross"]


@dataclass(frozen=True, kw_only=True, eq=False)
class CorrelationResult:
    """Normalized sample correlation at a range of lags, with its 99 % bound.

    Parameters
    ----------
    kind :
        ``"auto"`` (autocorrelation of the residuals, lags ``0..max_lag``) or
        ``"cross"`` (residuals against input, lags ``-max_lag..max_lag``).
    lags :
        Lags [samples], shape ``(n_lags,)``.
    values :
        Normalized correlations at `lags`, in ``[-1, 1]``; ``1`` at lag 0 for ``"auto"``.
    bound :
        99 % confidence bound ``2.58 / sqrt(N)``.
    n_samples :
        ``N``, the length of the residual record.
    n_tested :
        Lags compared with the bound (all but lag 0 for ``"auto"``).
    n_outside :
        Tested lags whose ``|value|`` exceeds `bound`.
    within_bound :
        True if no tested lag lies outside the bound: the residuals look white
        (``"auto"``) or independent of the input (``"cross"``).

    Notes
    -----
    At the 99 % level about 1 tested lag in 100 falls outside by chance, so with
    25 lags a white sequence passes ``within_bound`` about 78 % of the time; look
    at `fraction_outside` and at *which* lags fail before rejecting a model.
    """

    kind: CorrelationKind
    lags: npt.NDArray[np.int64] = field(repr=False)
    values: FloatArray = field(repr=False)
    bound: float
    n_samples: int
    n_tested: int
    n_outside: int
    within_bound: bool

    def __post_init__(self) -> None:
        lags = np.array(self.lags, dtype=np.int64, copy=True)
        lags.setflags(write=False)
        object.__setattr__(self, "lags", lags)
        object.__setattr__(self, "values", _readonly(self.values))

    @property
    def fraction_outside(self) -> float:
        """Share of the tested lags outside the bound, in ``[0, 1]``."""
        return self.n_outside / self.n_tested

    @property
    def lags_outside(self) -> tuple[int, ...]:
        """The tested lags whose correlation lies outside the bound."""
        return tuple(int(lag) for lag in self.lags[self._outside_mask()])

    @property
    def is_white(self) -> bool:
        """True for an autocorrelation with every lag ``!= 0`` inside the bound."""
        return self.kind == "auto" and self.within_bound

    @property
    def is_independent(self) -> bool:
        """True for a cross-correlation with every lag inside the bound."""
        return self.kind == "cross" and self.within_bound

    def _outside_mask(self) -> npt.NDArray[np.bool_]:
        return _tested(self.kind, self.lags) & (np.abs(self.values) > self.bound)


def _tested(kind: CorrelationKind, lags: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """Lags compared with the bound: all but lag 0 of an autocorrelation (which is 1)."""
    return lags != 0 if kind == "auto" else np.ones(lags.size, dtype=bool)


def _signal(values: FloatArray, name: str) -> FloatArray:
    """``values`` with its mean removed, refused unless 1-D and finite."""
    arr: FloatArray = np.asarray(values, dtype=float)
    if arr.ndim != 1:
        raise IdentificationError(f"{name} must be a 1-D array; got shape {arr.shape}")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise IdentificationError(
            f"{name} must hold finite numbers; got {arr[bad[0]]} at sample {bad[0]}"
        )
    centred: FloatArray = arr - arr.mean()
    return centred


def _check_max_lag(max_lag: int, n: int) -> None:
    checked_int(max_lag, 1, "max_lag")
    if max_lag >= n:
        raise IdentificationError(
            f"max_lag must be smaller than the number of samples ({n}); got {max_lag}"
        )


def _lagged_products(x: FloatArray, z: FloatArray, lags: npt.NDArray[np.int64]) -> FloatArray:
    """``sum_k x_k z_{k-tau}`` for each ``tau`` in `lags` (biased, not divided)."""
    n = x.size
    out = np.empty(lags.size)
    for i, tau in enumerate(lags):
        t = int(tau)
        out[i] = x[t:] @ z[: n - t] if t >= 0 else x[: n + t] @ z[-t:]
    return out


def _result(kind: CorrelationKind, lags: npt.NDArray[np.int64], values: FloatArray,
            n: int) -> CorrelationResult:
    """The result at `lags`, compared with the bound ``Z_99 / sqrt(n)``."""
    bound = Z_99 / math.sqrt(n)
    tested = _tested(kind, lags)
    n_outside = int(np.count_nonzero(tested & (np.abs(values) > bound)))
    return CorrelationResult(
        kind=kind, lags=lags, values=values, bound=bound, n_samples=n,
        n_tested=int(np.count_nonzero(tested)), n_outside=n_outside,
        within_bound=n_outside == 0,
    )


def autocorrelation(e: FloatArray, *, max_lag: int = DEFAULT_MAX_LAG) -> CorrelationResult:
    """Normalized autocorrelation of residuals at lags ``0..max_lag`` (whiteness test).

    Parameters
    ----------
    e :
        Residuals, shape ``(N,)`` [output unit]; finite.
    max_lag :
        Largest lag [samples], ``1 <= max_lag < N``.

    Returns
    -------
    CorrelationResult
        ``kind="auto"``; ``values[0] == 1``; ``is_white`` if every lag ``1..max_lag``
        lies within ``2.58 / sqrt(N)``.

    Raises
    ------
    IdentificationError
        `e` not 1-D, non-finite, constant (no variance to normalize by), or
        `max_lag` not an int in ``1..N-1``.

    Notes
    -----
    ``r_e(tau)`` of the module docstring (biased), as plotted in paper Figs. 3, 6, 18.
    """
    x = _signal(e, "e")
    _check_max_lag(max_lag, x.size)
    energy = float(x @ x)
    if energy == 0.0:
        raise IdentificationError("e must vary to normalize its autocorrelation; got a constant")
    lags = np.arange(0, int(max_lag) + 1, dtype=np.int64)
    return _result("auto", lags, _lagged_products(x, x, lags) / energy, x.size)


def cross_correlation(
    e: FloatArray, u: FloatArray, *, max_lag: int = DEFAULT_MAX_LAG
) -> CorrelationResult:
    """Normalized cross-correlation of residuals and input at lags ``-max_lag..max_lag``.

    Parameters
    ----------
    e :
        Residuals, shape ``(N,)`` [output unit]; finite.
    u :
        Input over the same samples, shape ``(N,)`` [input unit]; finite.
    max_lag :
        Largest lag [samples], ``1 <= max_lag < N``.

    Returns
    -------
    CorrelationResult
        ``kind="cross"``; ``values[i]`` pairs ``e_k`` with ``u_{k - lags[i]}``;
        ``is_independent`` if every lag lies within ``2.58 / sqrt(N)``.

    Raises
    ------
    IdentificationError
        `e` or `u` not 1-D or non-finite, lengths differ, either constant, or
        `max_lag` not an int in ``1..N-1``.

    Notes
    -----
    The bound ``2.58 / sqrt(N)`` assumes white ``e``: then ``r_eu(tau)`` has variance
    ``1/N`` whatever the colour of ``u``. With coloured residuals it is too tight;
    test whiteness first.
    """
    x = _signal(e, "e")
    z = _signal(u, "u")
    if x.size != z.size:
        raise IdentificationError(
            f"e and u must have equal lengths; got {x.size} and {z.size}"
        )
    _check_max_lag(max_lag, x.size)
    scale = math.sqrt(float(x @ x) * float(z @ z))
    if scale == 0.0:
        which = "e" if float(x @ x) == 0.0 else "u"
        raise IdentificationError(
            f"{which} must vary to normalize the cross-correlation; got a constant"
        )
    lags = np.arange(-int(max_lag), int(max_lag) + 1, dtype=np.int64)
    return _result("cross", lags, _lagged_products(x, z, lags) / scale, x.size)


__all__ = [
    "DEFAULT_MAX_LAG",
    "Z_99",
    "CorrelationKind",
    "CorrelationResult",
    "autocorrelation",
    "cross_correlation",
]
