"""f and its inverse on the monotone branch (stable root formula).

Notation
--------
``ds`` [%]
    TRIAC deviation from the operating point, ``ds = s - s_nom`` (paper sec. 5.1).
``w`` [kW-equivalent]
    Output of the input nonlinearity, ``w = f(ds) = sum_i p_i ds^i`` (paper eq. 28;
    ``p = (d1, d2)`` in the paper's final models, eqs. 27 and 30).
monotone branch
    The largest open interval around ``ds = 0`` with ``f'(ds) > 0`` (for a quadratic,
    bounded by the vertex ``ds = -d1 / (2 d2)``). The MPC plans in ``w`` and maps back
    through ``f^-1`` on it, exact while the allowed input range stays on it
    (docs/theory.rst, C5).

The quadratic inverse is ``ds = 2 w / (d1 + sqrt(d1^2 + 4 d2 w))``: the root of
``d2 ds^2 + d1 ds - w = 0`` through 0 without the cancellation of
``(-d1 + sqrt(...)) / (2 d2)`` for small ``d2``; ``w / d1`` for ``d2 = 0``
(docs/theory.rst, C6).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from czmpc.errors import DesignError
from sysid.model import HammersteinModel

#: Newton/bisection stops when the bracket is this small relative to its scale.
INVERSE_RTOL = 1e-13
#: Iteration cap of the safeguarded Newton inverse for degree > 2 (bisection needs ~50).
INVERSE_MAX_ITER = 100


def clamp(value: float, lo: float, hi: float) -> float:
    """``min(hi, max(lo, value))``, exactly (NaN and signed zeros too): 0.04 us instead of 0.2 us."""
    value = value if value > lo else lo  # what max(lo, value) returns
    return value if value < hi else hi   # what min(hi, value) returns


def evaluate(coefficients: tuple[float, ...], ds_pct: float) -> float:
    """Return ``f(ds) = sum_i p_i ds^i`` for a scalar (Horner) [kW-equivalent].

    Parameters
    ----------
    coefficients :
        ``(p_1, ..., p_n)`` [kW per %^i]; no constant term.
    ds_pct :
        TRIAC deviation [%].
    """
    out = 0.0
    for coef in reversed(coefficients):
        out = (out + coef) * ds_pct
    return out


def slope(coefficients: tuple[float, ...], ds_pct: float) -> float:
    """Return ``f'(ds)`` for a scalar [kW/%]."""
    out = 0.0
    for i in range(len(coefficients), 0, -1):
        out = out * ds_pct + i * coefficients[i - 1]
    return out


def _real_roots_ascending(poly_ascending: list[float]) -> list[float]:
    """Real roots of ``sum_i c_i x^i`` given ascending coefficients."""
    c = np.trim_zeros(np.asarray(poly_ascending, dtype=float), trim="b")
    if c.size <= 1:
        return []
    r = np.roots(c[::-1])
    real = r[np.abs(r.imag) <= 1e-9 * np.maximum(1.0, np.abs(r.real))].real
    return sorted(float(v) for v in real)


def _slope_critical_points(coefficients: tuple[float, ...], ds_lo: float,
                           ds_hi: float) -> tuple[float, ...]:
    """Roots of ``f''`` strictly inside ``(ds_lo, ds_hi)``."""
    second = [(i + 1) * i * coefficients[i] for i in range(1, len(coefficients))]
    return tuple(r for r in _real_roots_ascending(second) if ds_lo < r < ds_hi)


def monotone_branch(coefficients: tuple[float, ...]) -> tuple[float, float]:
    """Return the monotone branch ``(ds_lo, ds_hi)`` of ``f`` around ``ds = 0`` [%].

    The ends are the nearest roots of ``f'`` below and above 0 (``-inf``/``inf`` if
    none); ``f`` increases strictly inside.

    Parameters
    ----------
    coefficients :
        ``(p_1, ..., p_n)``.

    Raises
    ------
    DesignError
        If ``f'(0) = p_1 <= 0`` (no increasing branch through the operating point).
    """
    if not coefficients or not coefficients[0] > 0.0:
        p1 = coefficients[0] if coefficients else None
        raise DesignError(
            "input nonlinearity: expected f'(0) = p_1 > 0 (power rising with the TRIAC "
            f"input at the operating point); got p_1 = {p1!r}"
        )
    derivative = [i * c for i, c in enumerate(coefficients, start=1)]
    roots = _real_roots_ascending(derivative)
    lo = max((r for r in roots if r < 0.0), default=-math.inf)
    hi = min((r for r in roots if r > 0.0), default=math.inf)
    return lo, hi


def min_slope(coefficients: tuple[float, ...], ds_lo_pct: float, ds_hi_pct: float) -> float:
    """Smallest ``f'`` over the closed interval ``[ds_lo, ds_hi]`` [kW/%].

    Exact for any degree (the ends and the roots of ``f''`` inside). A move of at most
    ``m * delta`` in ``w``, ``m`` the smallest slope over the reachable inputs, is a move
    of at most ``delta`` in ``ds`` (the later moves' rate limits, docs/theory.rst, C5).

    Parameters
    ----------
    coefficients :
        ``(p_1, ..., p_n)``.
    ds_lo_pct, ds_hi_pct :
        Interval ends [%], ``ds_lo <= ds_hi``.
    """
    candidates = (ds_lo_pct, ds_hi_pct, *_slope_critical_points(coefficients, ds_lo_pct, ds_hi_pct))
    return min(slope(coefficients, v) for v in candidates)


@dataclass(frozen=True, eq=False, kw_only=True)
class InputMap:
    """``f`` restricted to the allowed TRIAC range (strictly increasing), with its inverse.

    Parameters
    ----------
    coefficients :
        ``(p_1, ..., p_n)`` of ``f`` [kW per %^i].
    operating_triac_pct :
        ``s_nom`` [%].
    ds_min_pct, ds_max_pct :
        Allowed deviation range [%].
    w_min, w_max :
        ``f(ds_min)`` and ``f(ds_max)`` [kW-equivalent]: exact bounds on ``w``.
    slope_critical_points_pct :
        Roots of ``f''`` strictly inside the allowed range (``f'``'s interior minima).
    """

    coefficients: tuple[float, ...]
    operating_triac_pct: float
    ds_min_pct: float
    ds_max_pct: float
    w_min: float
    w_max: float
    slope_critical_points_pct: tuple[float, ...]

    def f(self, ds_pct: float) -> float:
        """``f(ds)`` for a scalar [kW-equivalent]."""
        return evaluate(self.coefficients, ds_pct)

    def inverse(self, w: float) -> float:
        """``f^-1(w)`` on the allowed range [%]; ``w`` outside ``[w_min, w_max]`` maps to the nearer end.

        Degree <= 2: the stable root formula (module notes); higher: Newton safeguarded by
        bisection on ``[ds_min, ds_max]``. NaN in gives NaN out.

        Parameters
        ----------
        w :
            Nonlinearity output [kW-equivalent].
        """
        if w <= self.w_min:
            return self.ds_min_pct
        if w >= self.w_max:
            return self.ds_max_pct
        if w != w:  # NaN
            return math.nan
        c = self.coefficients
        if len(c) <= 2:
            d1 = c[0]
            d2 = c[1] if len(c) == 2 else 0.0
            ds = 2.0 * w / (d1 + math.sqrt(d1 * d1 + 4.0 * d2 * w))
            return clamp(ds, self.ds_min_pct, self.ds_max_pct)
        return self._newton_inverse(w)

    def _newton_inverse(self, w: float) -> float:
        c = self.coefficients
        lo, hi = self.ds_min_pct, self.ds_max_pct
        ds = clamp(w / c[0], lo, hi)
        scale = max(1.0, abs(lo), abs(hi))
        for _ in range(INVERSE_MAX_ITER):
            residual = evaluate(c, ds) - w
            if residual == 0.0:
                return ds
            if residual > 0.0:
                hi = ds
            else:
                lo = ds
            if hi - lo <= INVERSE_RTOL * scale:
                break
            step = residual / slope(c, ds)
            candidate = ds - step
            ds = candidate if lo < candidate < hi else 0.5 * (lo + hi)
            if abs(step) <= INVERSE_RTOL * scale:
                break
        return clamp(ds, self.ds_min_pct, self.ds_max_pct)

    def min_slope(self, ds_lo_pct: float, ds_hi_pct: float) -> float:
        """Smallest ``f'`` over ``[ds_lo, ds_hi]`` (as the module's `min_slope`)."""
        best = min(slope(self.coefficients, ds_lo_pct), slope(self.coefficients, ds_hi_pct))
        for r in self.slope_critical_points_pct:
            if ds_lo_pct < r < ds_hi_pct:
                best = min(best, slope(self.coefficients, r))
        return best


def allowed_triac_range(
    model: HammersteinModel, *, triac_min_pct: float, triac_max_pct: float,
    validity_margin_pct: float,
) -> tuple[float, float]:
    """Allowed TRIAC range [%]: the identified range widened by the margin, within limits.

    Parameters
    ----------
    model :
        Supplies ``input_range_pct``.
    triac_min_pct, triac_max_pct :
        Hard TRIAC limits [%].
    validity_margin_pct :
        Margin around the identified range [%].

    Raises
    ------
    DesignError
        If the intersection is empty.
    """
    lo = max(triac_min_pct, model.input_range_pct[0] - validity_margin_pct)
    hi = min(triac_max_pct, model.input_range_pct[1] + validity_margin_pct)
    if not lo < hi:
        raise DesignError(
            "allowed TRIAC range: the model's validity range "
            f"[{model.input_range_pct[0]:g}, {model.input_range_pct[1]:g}] % widened by "
            f"{validity_margin_pct:g} % must overlap the TRIAC limits [{triac_min_pct:g}, "
            f"{triac_max_pct:g}] %; got an empty intersection"
        )
    return lo, hi


def build_input_map(
    model: HammersteinModel, *, triac_min_pct: float, triac_max_pct: float,
    validity_margin_pct: float,
) -> InputMap:
    """Build the `InputMap` of ``model`` on its allowed TRIAC range.

    Parameters
    ----------
    model :
        The identified model (``input_poly`` and ``operating_point`` are used).
    triac_min_pct, triac_max_pct :
        Hard TRIAC limits [%].
    validity_margin_pct :
        Margin around the identified input range [%].

    Raises
    ------
    DesignError
        If ``f'(0) <= 0``, or the allowed range is empty or leaves the monotone branch.
    """
    coefficients = tuple(float(v) for v in model.input_poly)
    s_nom = model.operating_point.triac_pct
    s_lo, s_hi = allowed_triac_range(
        model, triac_min_pct=triac_min_pct, triac_max_pct=triac_max_pct,
        validity_margin_pct=validity_margin_pct,
    )
    ds_lo, ds_hi = s_lo - s_nom, s_hi - s_nom
    branch_lo, branch_hi = monotone_branch(coefficients)
    if not (branch_lo < ds_lo and ds_hi < branch_hi):
        raise DesignError(
            f"allowed TRIAC range [{s_lo:g}, {s_hi:g}] % must lie on the monotone branch "
            f"of f, s in ({branch_lo + s_nom:.4g}, {branch_hi + s_nom:.4g}) %, where the "
            "power rises with the input; lower the validity margin or the TRIAC limits"
        )
    return InputMap(
        coefficients=coefficients,
        operating_triac_pct=s_nom,
        ds_min_pct=ds_lo,
        ds_max_pct=ds_hi,
        w_min=evaluate(coefficients, ds_lo),
        w_max=evaluate(coefficients, ds_hi),
        slope_critical_points_pct=_slope_critical_points(coefficients, ds_lo, ds_hi),
    )


__all__ = [
    "InputMap",
    "allowed_triac_range",
    "build_input_map",
    "clamp",
    "evaluate",
    "min_slope",
    "monotone_branch",
    "slope",
]
