"""Put a sample-mean operating point on the steady-state curve (paper sec. 5.1).

Without a steady window the operating point is the sample means ``(mean s, mean P)``
(the paper's fallback). For a Hammerstein plant that point is off its steady-state
curve: the mean of ``f(ds)`` is not ``f`` of the mean, so ``mean P`` misses the steady
power at ``mean s`` by about ``B(1)/A(1) * (d2 var(ds) + ...)``, 0.2 kW for a quadratic
heater over a 36..54 % staircase. ``f`` has no constant term, so the models cannot
represent that offset; with the initial state estimated a pole at ``z = 1`` can, and the
order search then prefers a pole-zero pair near ``z = 1`` whose static gain is meaningless.

`steady_state_offset_kw` estimates the offset from the data by a polynomial ARX with
a constant term (linear least squares, no search),

    A(q) dP_k = sum_{j=nk}^{nk+nb-1} sum_{p=1}^{degree} beta_jp ds_{k-j}^p + c + e_k,

whose steady state at ``ds = 0`` is ``dP = c / A(1)``; the operating point's power is
moved by that much, making ``(s_nom, P_nom)`` a steady state of the record.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.errors import IdentificationError

#: Orders of the offset ARX: two poles (a fast and a slow mode), two input lags.
OFFSET_NA = 2
OFFSET_NB = 2
#: ``|A(1)|`` below this: the ARX has a pole at z = 1 and no steady state; no offset.
MIN_STEADY_GAIN_DENOMINATOR = 1e-3


def steady_state_offset_kw(
    segments: Sequence[tuple[FloatArray, FloatArray]], *, degree: int, nk: int
) -> float | None:
    """Steady output deviation at ``ds = 0`` of a polynomial ARX with a constant term.

    Parameters
    ----------
    segments :
        ``(dP, ds)`` deviation arrays from the sample-mean operating point, per segment
        (experiment) [output unit], [input unit]; no regressor reaches across segments.
    degree :
        Degree of the input polynomial (1..3).
    nk :
        Input delay [samples] (>= 0).

    Returns
    -------
    float or None
        ``c / A(1)`` [output unit]; None if the ARX has no steady state
        (``|A(1)| < MIN_STEADY_GAIN_DENOMINATOR``) or too few samples for its
        ``OFFSET_NA + OFFSET_NB * degree + 1`` parameters.

    Raises
    ------
    IdentificationError
        `degree` not in 1..3 or `nk` negative.
    """
    if degree not in (1, 2, 3):
        raise IdentificationError(f"steady_state_offset_kw: degree must be 1, 2 or 3; got {degree!r}")
    nk = checked_int(nk, 0, "steady_state_offset_kw: nk")
    lag0 = max(OFFSET_NA, nk + OFFSET_NB - 1)
    rows: list[FloatArray] = []
    targets: list[FloatArray] = []
    for dp, ds in segments:
        dp, ds = np.asarray(dp, dtype=float), np.asarray(ds, dtype=float)
        n = dp.size
        if n <= lag0:
            continue
        k = np.arange(lag0, n)
        cols = [-dp[k - i] for i in range(1, OFFSET_NA + 1)]
        cols += [ds[k - j] ** p for j in range(nk, nk + OFFSET_NB) for p in range(1, degree + 1)]
        cols.append(np.ones(k.size))
        rows.append(np.column_stack(cols))
        targets.append(dp[k])
    n_par = OFFSET_NA + OFFSET_NB * degree + 1
    if not rows or sum(t.size for t in targets) < 2 * n_par:
        return None
    theta = np.linalg.lstsq(np.vstack(rows), np.concatenate(targets), rcond=None)[0]
    a_at_1 = 1.0 + float(np.sum(theta[:OFFSET_NA]))
    if not math.isfinite(a_at_1) or abs(a_at_1) < MIN_STEADY_GAIN_DENOMINATOR:
        return None
    return float(theta[-1]) / a_at_1


__all__ = ["MIN_STEADY_GAIN_DENOMINATOR", "OFFSET_NA", "OFFSET_NB", "steady_state_offset_kw"]
