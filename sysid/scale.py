"""The range of signal magnitudes identification can represent, checked before any fit.

A log may be in any unit (kW or W, degC or mV), but the fits square the output (V and W)
and raise the input to the polynomial's degree (up to 3): a span of 1e200 overflows, one
of 1e-200 underflows to zero. Such a log is refused before any fit, with a message that
asks to rescale the column instead of a traceback.
"""

from __future__ import annotations

import numpy as np

from sysid.data import Dataset
from sysid.errors import IdentificationError

#: Accepted span (max - min) of each signal, in its own unit: the cube of the input's
#: span and the square of the output's (V, W and their covariances) stay normal
#: floats with room for the products of the fits (1e30^3 = 1e90).
MIN_SPAN = 1e-30
MAX_SPAN = 1e30


def check_representable(data: Dataset, *, where: str) -> None:
    """Refuse a log whose input or output span identification cannot represent.

    Parameters
    ----------
    data :
        The log, in its own units (`Dataset.input_unit`, `Dataset.output_unit`).
    where :
        The caller's name, for the message.

    Raises
    ------
    IdentificationError
        The input or the output spans less than `MIN_SPAN` or more than `MAX_SPAN` of
        its unit (a constant signal, span 0, is left to the identifiability checks).
    """
    for name, values, unit in (("input", data.triac_pct, data.input_unit),
                               ("output", data.power_kw, data.output_unit)):
        finite = values[np.isfinite(values)]
        if finite.size == 0:
            continue
        with np.errstate(over="ignore"):
            span = float(np.max(finite) - np.min(finite))   # inf if it overflows
        if span == 0.0:
            continue
        if not (MIN_SPAN <= span <= MAX_SPAN):
            raise IdentificationError(
                f"{where}: the {name} spans {span:.3g} {unit}; identification represents "
                f"spans of {MIN_SPAN:g} to {MAX_SPAN:g} of a signal's unit (its squares and "
                f"cubes must stay normal floating-point numbers); rescale the {name} column "
                "to a unit in which it spans an ordinary range (for example kW instead of W, "
                "mV instead of V) and run again")


__all__ = ["MAX_SPAN", "MIN_SPAN", "check_representable"]
