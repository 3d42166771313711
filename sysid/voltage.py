"""Grid-voltage compensation: the effective input ``w_eff`` and the terms of the W0 iteration.

The heater's drive goes with the square of the grid voltage relative to nominal, ``v``:
in absolute terms ``drive = v^2 phi(s)``. About the operating point ``(s_nom, P_nom)``
the identified model is ``A dP = B f(ds) + C e``; the absolute nonlinearity output at
the operating point is ``W0 = P_nom / G1`` with ``G1 = B(1)/A(1)`` (``B(1)/F(1)`` for an
OE block; zero drive gives zero power in steady state), so under voltage ``v`` the
linear block sees (the controller's form, issue 40)::

    w_eff = v^2 (W0 + f(ds)) - W0 = v^2 f(ds) + (v^2 - 1) W0

A fit compensates the voltage by regressing on ``v^2 ds^i`` with the known input
``(v^2 - 1) W0`` (`sysid.hammerstein.filtering.Drive`); since ``W0`` depends on the
``G1`` being fitted, `sysid.hammerstein.fitting` iterates until ``W0`` settles
(`W0_RTOL`, at most `MAX_W0_ITERATIONS` refits).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from sysid._arrays import readonly_array as _readonly
from sysid._typing import FloatArray
from sysid.data import GRID_VOLTAGE_COLUMN, GRID_VOLTAGE_RANGE
from sysid.errors import IdentificationError

if TYPE_CHECKING:
    from sysid.data import Dataset
    from sysid.model import HammersteinModel, OperatingPoint

#: A segment's ``(v^2, (v^2 - 1) W0)``, as `sysid.hammerstein.filtering.Drive`.
Drive = tuple[FloatArray, FloatArray]

#: ``W0`` has settled when a refit moves it by less than this, relative.
W0_RTOL = 1e-6
#: Most refits with the voltage compensated after the first, uncompensated fit.
MAX_W0_ITERATIONS = 10
#: The provenance key of a model's voltage record.
PROVENANCE_KEY = "grid_voltage"


@dataclass(frozen=True, kw_only=True, eq=False)
class GridVoltage:
    """A record's grid voltage, for fits that compensate it.

    Parameters
    ----------
    factor :
        Grid voltage relative to nominal ``v`` [-] at each sample of the whole record
        (all segments), shape ``(N,)``, each within `sysid.data.GRID_VOLTAGE_RANGE`.
    power_nom_kw :
        ``P_nom``, the operating point's output [kW] the deviations are taken about.

    Raises
    ------
    IdentificationError
        A factor that is not 1-D, not finite or out of range; a non-finite ``P_nom``.
    """

    factor: FloatArray
    power_nom_kw: float

    def __post_init__(self) -> None:
        v = _readonly(self.factor)
        lo, hi = GRID_VOLTAGE_RANGE
        if v.ndim != 1 or not bool(np.all(np.isfinite(v) & (v >= lo) & (v <= hi))):
            raise IdentificationError(
                f"GridVoltage: {GRID_VOLTAGE_COLUMN} must be a 1-D array of finite values "
                f"within {lo:g}..{hi:g}; got shape {v.shape}, range "
                f"{float(np.min(v)) if v.size else math.nan:g}.."
                f"{float(np.max(v)) if v.size else math.nan:g}")
        if not math.isfinite(self.power_nom_kw):
            raise IdentificationError(
                f"GridVoltage: power_nom_kw must be finite; got {self.power_nom_kw!r}")
        object.__setattr__(self, "factor", v)
        object.__setattr__(self, "power_nom_kw", float(self.power_nom_kw))

    def drives(self, bounds: Sequence[tuple[int, int]], nominal_drive_kw: float) -> list[Drive]:
        """Each segment's ``(v^2, (v^2 - 1) W0)`` for the kernels, ``bounds`` as
        `sysid.linear.segment_bounds`."""
        v2 = self.factor**2
        off = (v2 - 1.0) * nominal_drive_kw
        if bounds and bounds[-1][1] != v2.size:
            raise IdentificationError(
                f"GridVoltage: the factor has {v2.size} samples; the record has {bounds[-1][1]}")
        return [(v2[lo:hi], off[lo:hi]) for lo, hi in bounds]


@dataclass(frozen=True, kw_only=True)
class VoltageCompensation:
    """How a fit compensated the grid voltage (recorded in the model's provenance).

    Parameters
    ----------
    nominal_drive_kw :
        ``W0 = P_nom / G1`` used in the final refit [kW-equivalent].
    history_kw :
        ``W0`` after the uncompensated fit and after each refit, in order.
    n_refits :
        Refits with the voltage compensated.
    settled :
        True if the last refit moved ``W0`` by less than `W0_RTOL` (else the cap of
        `MAX_W0_ITERATIONS` refits was reached).
    """

    nominal_drive_kw: float
    history_kw: tuple[float, ...]
    n_refits: int
    settled: bool

    def record(self) -> dict[str, Any]:
        """JSON-ready provenance entry."""
        return {"compensated": True, "column": GRID_VOLTAGE_COLUMN,
                "form": "w_eff = v^2 * f(ds) + (v^2 - 1) * W0, W0 = P_nom / G1",
                "nominal_drive_kw": self.nominal_drive_kw,
                "w0_history_kw": list(self.history_kw), "n_refits": self.n_refits,
                "settled": self.settled, "w0_rtol": W0_RTOL}


def not_compensated_record(reason: str) -> dict[str, Any]:
    """Provenance entry of a model fitted on a log with the voltage but without compensation."""
    return {"compensated": False, "column": GRID_VOLTAGE_COLUMN, "reason": reason}


def static_gain(a: FloatArray, b: FloatArray) -> float:
    """``G1 = B(1)/A(1)`` (``A`` is ``F`` for an OE block)."""
    return float(np.sum(b)) / float(np.sum(a))


def nominal_drive_kw(power_nom_kw: float, a: FloatArray, b: FloatArray) -> float:
    """``W0 = P_nom / G1`` [kW-equivalent], the nonlinearity's absolute output at the
    operating point.

    Raises
    ------
    IdentificationError
        ``G1`` zero or not finite (no steady state through which to compensate).
    """
    gain = static_gain(a, b)
    w0 = power_nom_kw / gain if gain != 0.0 and math.isfinite(gain) else math.nan
    if not math.isfinite(w0):
        raise IdentificationError(
            f"voltage compensation needs a finite, non-zero static gain G1 = B(1)/A(1); got "
            f"{gain!r} (W0 = P_nom / G1 is undefined)")
    return w0


def effective_input(w: FloatArray, factor: FloatArray, w0_kw: float) -> FloatArray:
    """``w_eff = v^2 w + (v^2 - 1) W0``: the linear block's input under grid voltage ``v``."""
    v2 = np.asarray(factor, dtype=float) ** 2
    out: FloatArray = v2 * np.asarray(w, dtype=float) + (v2 - 1.0) * w0_kw
    return out


def compensated_drive_kw(provenance_extra: Mapping[str, Any]) -> float | None:
    """``W0`` of a model whose fit compensated the voltage (its provenance), else None."""
    entry = provenance_extra.get(PROVENANCE_KEY)
    if isinstance(entry, Mapping) and entry.get("compensated") is True:
        w0 = entry.get("nominal_drive_kw")
        if isinstance(w0, (int, float)) and math.isfinite(w0):
            return float(w0)
    return None


def grid_voltage(data: Dataset, operating_point: OperatingPoint) -> GridVoltage | None:
    """The record's `GridVoltage` about ``P_nom``, or None if it carries no voltage."""
    if data.grid_voltage_factor is None:
        return None
    return GridVoltage(factor=data.grid_voltage_factor, power_nom_kw=operating_point.power_kw)


def model_input(model: HammersteinModel, data: Dataset) -> FloatArray:
    """The input the model's linear block sees over a record [kW-equivalent].

    ``f(ds)`` about the model's operating point; ``w_eff = v^2 f(ds) + (v^2 - 1) W0``
    (with the ``W0`` its fit used) when the model's fit compensated the grid voltage and
    the record carries it. A model fitted without compensation sees ``f(ds)`` as it was
    fitted, whatever the record carries.
    """
    w = np.asarray(model.input_nonlinearity(data.triac_pct - model.operating_point.triac_pct),
                   dtype=float)
    w0 = compensated_drive_kw(model.provenance.extra)
    if w0 is None or data.grid_voltage_factor is None:
        return w
    return effective_input(w, data.grid_voltage_factor, w0)


__all__ = [
    "GridVoltage",
    "MAX_W0_ITERATIONS",
    "PROVENANCE_KEY",
    "VoltageCompensation",
    "W0_RTOL",
    "compensated_drive_kw",
    "effective_input",
    "grid_voltage",
    "model_input",
    "nominal_drive_kw",
    "not_compensated_record",
    "static_gain",
]
