"""The measured grid voltage as a known multiplicative input of the drive.

Notation
--------
``v`` [-] grid voltage relative to nominal; ``w = f(ds)`` [kW-equivalent] the
nonlinearity's output at nominal voltage (paper eq. 28); ``g = B(1)/A(1)`` the static
gain; ``P_nom`` [kW] the operating point's power.

The heater's drive goes with the square of the voltage: ``drive = v^2 phi(s)``. The
model is identified about the operating point in deviations, so its absolute drive is
``W0 + f(ds)`` with ``W0 = P_nom / g`` (zero drive gives zero power in steady state).
Under ``v`` the linear block sees the effective input (``docs/theory.rst``, C8)::

    w_eff = v^2 (W0 + f(ds)) - W0 = v^2 f(ds) + (v^2 - 1) W0

and the input that gives a planned ``w_eff`` is ``ds = f^-1((w_eff - (v^2 - 1) W0) / v^2)``.
At ``v = 1`` both are the identity.
"""

from __future__ import annotations

import math

#: Plausible range of a measured voltage factor [-]: a thyristor unit trips far inside
#: it; outside it (0, negative, 1e200) the reading is a fault and 1 is used.
VOLTAGE_FACTOR_RANGE = (0.5, 1.5)

#: `voltage_verdict` values.
NOT_MEASURED = "not measured"
VALID = "valid"
MISSING = "missing"
IMPLAUSIBLE = "implausible"


def voltage_verdict(grid_voltage_factor: float | None) -> str:
    """Whether a measured voltage factor can be used.

    Parameters
    ----------
    grid_voltage_factor :
        Grid voltage relative to nominal [-]; None when no voltage is measured.

    Returns
    -------
    str
        ``"not measured"`` (None), ``"missing"`` (NaN), ``"implausible"`` (outside
        `VOLTAGE_FACTOR_RANGE`, infinite, or not a number at all) or ``"valid"``.
    """
    if grid_voltage_factor is None:
        return NOT_MEASURED
    try:
        v = float(grid_voltage_factor)
    except (TypeError, ValueError):
        return IMPLAUSIBLE
    if math.isnan(v):
        return MISSING
    lo, hi = VOLTAGE_FACTOR_RANGE
    return VALID if lo <= v <= hi else IMPLAUSIBLE


def absolute_drive_kw(power_nom_kw: float, static_gain: float) -> float:
    """``W0 = P_nom / g`` [kW-equivalent]: the nonlinearity's absolute output at the operating point.

    Parameters
    ----------
    power_nom_kw :
        ``P_nom`` [kW].
    static_gain :
        ``g = B(1)/A(1)`` [kW per kW-equivalent], nonzero.
    """
    return power_nom_kw / static_gain


__all__ = ["IMPLAUSIBLE", "MISSING", "NOT_MEASURED", "VALID", "VOLTAGE_FACTOR_RANGE",
           "absolute_drive_kw", "voltage_verdict"]
