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

Fed forward, the reading's own noise reaches the power at once: ``2 sigma_v W0`` per
sample (0.01 kW at ``sigma_v = 1e-4`` on the CZ heater, as much as its power sensor's
noise), while the grid's slow wander (0.08 %) is what the disturbance estimate removes
anyway. `VoltageDeadband` therefore moves the factor in use only when the reading leaves
it by more than `VOLTAGE_DEADBAND`: a sag acts from the sample in which it is measured,
noise and wander do not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from czmpc.inversion import InputMap

#: Plausible range of a measured voltage factor [-]: a thyristor unit trips far inside
#: it; outside it (0, negative, 1e200) the reading is a fault and 1 is used.
VOLTAGE_FACTOR_RANGE = (0.5, 1.5)

#: Change of the reading [-] that moves the factor in use (`VoltageDeadband`): 0.2 %,
#: 20 times a 2-s line-voltage reading's noise and 2.5 times the grid's slow wander.
VOLTAGE_DEADBAND = 2e-3

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


class VoltageDeadband:
    """The voltage factor in use: 1 until measured, then moved only by changes beyond a deadband.

    Parameters
    ----------
    deadband :
        ``VOLTAGE_DEADBAND`` by default [-].
    """

    def __init__(self, deadband: float = VOLTAGE_DEADBAND) -> None:
        self.deadband = deadband
        self.reset()

    def reset(self) -> None:
        """Back to 1."""
        self._in_use = 1.0

    def take(self, grid_voltage_factor: float | None) -> tuple[float, str]:
        """The factor to use now [-] and the reading's `voltage_verdict`.

        A reading that is not valid gives 1 (and the next valid one moves from 1)."""
        verdict = voltage_verdict(grid_voltage_factor)
        if verdict is not VALID:
            self._in_use = 1.0
        elif abs(grid_voltage_factor - self._in_use) > self.deadband:  # type: ignore[operator]
            self._in_use = float(grid_voltage_factor)  # type: ignore[arg-type]
        return self._in_use, verdict


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


@dataclass(frozen=True, kw_only=True)
class VoltageCharacterizer:
    """What a DCS puts after a PID's output: the TRIAC input that gives, at voltage ``v``,
    the drive the PID's output gives at nominal voltage (module notes).

    Parameters
    ----------
    input_map :
        ``f`` on the allowed range.
    w0_kw :
        ``W0 = P_nom / g`` [kW-equivalent] (`absolute_drive_kw`).
    """

    input_map: InputMap
    w0_kw: float

    def applied_pct(self, nominal_triac_pct: float, v: float) -> float:
        """TRIAC input [%] at voltage ``v`` for an input [%] meant at nominal voltage:
        ``f^-1((W0 + f(ds)) / v^2 - W0)``, within the allowed range."""
        im = self.input_map
        s_nom = im.operating_triac_pct
        if v == 1.0:
            return nominal_triac_pct
        w = (self.w0_kw + im.f(nominal_triac_pct - s_nom)) / (v * v) - self.w0_kw
        return s_nom + im.inverse(w)

    def nominal_pct(self, applied_triac_pct: float, v: float) -> float:
        """The inverse of `applied_pct`: ``f^-1(v^2 (W0 + f(ds)) - W0)`` [%], within the allowed range."""
        im = self.input_map
        s_nom = im.operating_triac_pct
        if v == 1.0:
            return applied_triac_pct
        w = v * v * (self.w0_kw + im.f(applied_triac_pct - s_nom)) - self.w0_kw
        return s_nom + im.inverse(w)


__all__ = ["IMPLAUSIBLE", "MISSING", "NOT_MEASURED", "VALID", "VOLTAGE_DEADBAND",
           "VOLTAGE_FACTOR_RANGE", "VoltageCharacterizer", "VoltageDeadband", "absolute_drive_kw",
           "voltage_verdict"]
