"""Controller and Plant protocols, and the exogenous inputs a plant receives each sample.

The closed loop (`sim.loop`) talks to any controller and plant only through these.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True, slots=True, kw_only=True)
class Exogenous:
    """Process disturbances acting on a plant during one sample.

    Parameters
    ----------
    grid_voltage_factor :
        Grid voltage relative to nominal [-]; heater power scales with its square.
    power_offset_kw :
        Additive shift of the true heater power [kW].
    """

    grid_voltage_factor: float = 1.0
    power_offset_kw: float = 0.0


#: No disturbance: nominal grid voltage, no offset.
NOMINAL = Exogenous()


@runtime_checkable
class Controller(Protocol):
    """Anything that maps a measured power and a setpoint to a TRIAC input."""

    #: Sampling time [s] of the controller's steps (`run_closed_loop` refuses another than the scenario's).
    ts_s: float

    def step(self, power_kw: float, setpoint_kw: float) -> float:
        """Return the TRIAC input [%] to apply now; ``power_kw`` may be NaN (missing).

        A scenario with ``setpoint_preview_s`` or ``measured_voltage`` also passes the
        keywords ``setpoint_preview_kw`` (the next samples' setpoints [kW]) and
        ``grid_voltage_factor`` (measured over the last sample [-]); a controller that
        runs such scenarios takes them."""
        ...

    def reset(self) -> None:
        """Forget all state, as if newly constructed."""
        ...


@runtime_checkable
class Plant(Protocol):
    """A heater: TRIAC input in, measured power out, one sample per call."""

    #: Sampling time [s]: the plant time one call of `step` advances.
    ts_s: float

    def reset(self, rng: np.random.Generator | int | None = None) -> float:
        """Start a new run (at the plant's initial steady state); return the first
        measured power [kW]."""
        ...

    def step(self, triac_pct: float, exogenous: Exogenous = NOMINAL) -> float:
        """Apply ``triac_pct`` [%] for one sample under ``exogenous``; return the next
        measured power [kW]."""
        ...

    @property
    def true_power_kw(self) -> float:
        """Noise-free heater power [kW] at the latest sample."""
        ...


__all__ = ["NOMINAL", "Controller", "Exogenous", "Plant"]
