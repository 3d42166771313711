"""Plants that differ from the shipped model, and drift while they run: gain, time constant, delay.

A `PlantVariation` says how the plant differs from its nominal self from the start
(``gain_factor``, ``tau_s``, ``extra_delay_samples``) and how it drifts later
(`DriftEvent`: a step change of the gain factor or the time constant, such as a new
crucible or an aged element). `vary_model_plant` and `vary_heater` build a
`DriftingPlant` (a `sim.protocols.Plant`) from a model plant or the virtual heater.

On a model plant the gain and time constant move as `sim.perturbed.perturb_model`
says. On the virtual heater:

* **gain factor** ``g``: ``P_rated = V^2 / R_ref`` is multiplied by ``g`` (an aged
  element's ``R_ref`` changed by ``1/g``); as the power moves the temperature, a small
  step's static gain scales by ``g`` only to within a few per cent.
* **time constant** ``tau_s`` [s] (None: the plant's own): ``C`` is scaled so that the
  linearized sag time constant at the initial input (`heater_time_constant_s`) is
  ``tau_s``.

An **extra delay** of ``n`` samples holds the input in a first-in first-out line that
starts full of the initial input: the undelayed response shifted by exactly ``n``.
A drift changes the parameters between samples, keeping the plant's state: the first
sample with ``k * ts_s >= at_s`` runs with the new value.
"""

from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from sim.errors import PlantError
from sim.heater import (
    STEFAN_BOLTZMANN_KW_PER_M2_K4,
    HeaterParams,
    VirtualHeater,
    _relative_resistance,
    steady_state,
)
from sim.model_plant import ModelPlant
from sim.perturbed import perturb_model, slow_pole
from sim.protocols import NOMINAL, Exogenous, Plant
from sysid.model import HammersteinModel

DriftQuantity = Literal["gain", "tau"]

_DRIFT_RE = re.compile(r"^\s*(gain|tau)\s*=\s*([^@\s]+)\s*@\s*([^@\s]+)\s*$")


@dataclass(frozen=True, slots=True, kw_only=True)
class DriftEvent:
    """A step change of the plant at a plant time.

    Parameters
    ----------
    quantity :
        ``"gain"`` (``value``: gain factor relative to nominal [-]) or ``"tau"``
        (``value``: time constant [s]).
    value :
        The new value (> 0, finite).
    at_s :
        Plant time [s] from which the new value holds (>= 0).

    Raises
    ------
    PlantError
        An unknown quantity, a value that is not finite and > 0, a negative time.
    """

    quantity: DriftQuantity
    value: float
    at_s: float

    def __post_init__(self) -> None:
        if self.quantity not in ("gain", "tau"):
            raise PlantError(f"DriftEvent.quantity: expected 'gain' or 'tau'; got {self.quantity!r}")
        if not (math.isfinite(self.value) and self.value > 0.0):
            raise PlantError(f"DriftEvent.value: expected a finite number > 0; got {self.value!r}")
        if not (math.isfinite(self.at_s) and self.at_s >= 0.0):
            raise PlantError(f"DriftEvent.at_s: expected a plant time >= 0 [s]; got {self.at_s!r}")


def parse_drift(text: str) -> DriftEvent:
    """Read a drift written as ``QUANTITY=VALUE@TIME_S``.

    Parameters
    ----------
    text :
        ``gain=0.75@3600`` (gain x0.75 of nominal from 3600 s of plant time) or
        ``tau=1200@3600`` (time constant 1200 s from 3600 s).

    Returns
    -------
    DriftEvent

    Raises
    ------
    PlantError
        Text of another shape, or numbers out of range.

    Examples
    --------
    >>> parse_drift("gain=0.75@3600")
    DriftEvent(quantity='gain', value=0.75, at_s=3600.0)
    """
    match = _DRIFT_RE.match(text)
    if match is None:
        raise PlantError(
            "drift: expected QUANTITY=VALUE@TIME_S with QUANTITY gain (factor) or tau (seconds), "
            f"e.g. gain=0.75@3600; got {text!r}")
    quantity, value_text, at_text = match.groups()
    try:
        value, at_s = float(value_text), float(at_text)
    except ValueError:
        raise PlantError(f"drift: expected numbers in QUANTITY=VALUE@TIME_S; got {text!r}") from None
    return DriftEvent(quantity="gain" if quantity == "gain" else "tau", value=value, at_s=at_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class PlantVariation:
    """How a plant differs from its nominal self, and how it drifts (module docstring).

    Parameters
    ----------
    gain_factor :
        Gain relative to the nominal plant at the start [-] (> 0).
    tau_s :
        Time constant of the slow mode at the start [s]; None keeps the plant's own.
    extra_delay_samples :
        Samples of input delay added to the plant's own (>= 0).
    drifts :
        Step changes at later plant times, applied in time order.

    Raises
    ------
    PlantError
        A value out of range.
    """

    gain_factor: float = 1.0
    tau_s: float | None = None
    extra_delay_samples: int = 0
    drifts: tuple[DriftEvent, ...] = ()

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gain_factor) and self.gain_factor > 0.0):
            raise PlantError(
                f"PlantVariation.gain_factor: expected a finite number > 0; got {self.gain_factor!r}")
        if self.tau_s is not None and not (math.isfinite(self.tau_s) and self.tau_s > 0.0):
            raise PlantError(
                f"PlantVariation.tau_s: expected a finite time constant > 0 [s]; got {self.tau_s!r}")
        if (isinstance(self.extra_delay_samples, bool)
                or not isinstance(self.extra_delay_samples, int) or self.extra_delay_samples < 0):
            raise PlantError("PlantVariation.extra_delay_samples: expected an integer >= 0; got "
                             f"{self.extra_delay_samples!r}")
        object.__setattr__(self, "drifts",
                           tuple(sorted(self.drifts, key=lambda event: event.at_s)))

    @property
    def is_nominal(self) -> bool:
        """True if the plant is left exactly as it is."""
        return (self.gain_factor == 1.0 and self.tau_s is None and self.extra_delay_samples == 0
                and not self.drifts)

    def describe(self) -> str:
        """One line for logs: ``gain x0.8, tau 600 s, +2 samples delay, gain->x0.75 @ 3600 s``."""
        parts = []
        if self.gain_factor != 1.0:
            parts.append(f"gain x{self.gain_factor:g}")
        if self.tau_s is not None:
            parts.append(f"tau {self.tau_s:g} s")
        if self.extra_delay_samples:
            parts.append(f"+{self.extra_delay_samples} samples delay")
        for event in self.drifts:
            new = f"x{event.value:g}" if event.quantity == "gain" else f"{event.value:g} s"
            parts.append(f"{event.quantity}->{new} @ {event.at_s:g} s")
        return ", ".join(parts) if parts else "nominal"


#: Sets the plant's gain factor [-] and time constant [s] (None: its own), keeping its state.
DynamicsSetter = Callable[[float, float | None], None]


class DriftingPlant:
    """A plant with a `PlantVariation` applied (build it with `vary_model_plant` / `vary_heater`).

    Parameters
    ----------
    plant :
        The plant to vary.
    set_dynamics :
        Sets the inner plant's gain factor and time constant without touching its state.
    variation :
        The variation.
    initial_triac_pct :
        The input the plant starts in steady state at [%]; it fills the delay line.
    """

    def __init__(self, plant: Plant, *, set_dynamics: DynamicsSetter, variation: PlantVariation,
                 initial_triac_pct: float) -> None:
        self.plant = plant
        self.variation = variation
        self.ts_s = float(plant.ts_s)
        self.initial_triac_pct = float(initial_triac_pct)
        self._set = set_dynamics
        self._rewind()

    def _rewind(self) -> None:
        """The starting variation, no drift applied, the delay line full of the initial input."""
        self._k = 0
        self._next_event = 0
        self.gain_factor = self.variation.gain_factor
        self.tau_s = self.variation.tau_s
        self._line: deque[float] = deque([self.initial_triac_pct] * self.variation.extra_delay_samples)

    def reset(self, rng: np.random.Generator | int | None = None) -> float:
        """Start a new run with the starting variation (drifts not yet applied).

        Parameters
        ----------
        rng :
            Seed or generator of the inner plant's noise.

        Returns
        -------
        float
            The first measured power [kW].
        """
        self._rewind()
        self._set(self.gain_factor, self.tau_s)
        return float(self.plant.reset(rng))

    def step(self, triac_pct: float, exogenous: Exogenous = NOMINAL) -> float:
        """Apply any drift due now, delay the input, step the inner plant.

        Parameters
        ----------
        triac_pct :
            TRIAC input [%] decided at this sample.
        exogenous :
            Disturbances acting over this sample.

        Returns
        -------
        float
            Measured power at the next sample [kW].
        """
        events = self.variation.drifts
        changed = False
        while (self._next_event < len(events)
               and events[self._next_event].at_s <= self._k * self.ts_s + 1e-9 * self.ts_s):
            event = events[self._next_event]
            if event.quantity == "gain":
                self.gain_factor = event.value
            else:
                self.tau_s = event.value
            self._next_event += 1
            changed = True
        if changed:
            self._set(self.gain_factor, self.tau_s)
        applied = float(triac_pct)
        if self.variation.extra_delay_samples:
            self._line.append(applied)
            applied = self._line.popleft()
        self._k += 1
        return float(self.plant.step(applied, exogenous))

    @property
    def true_power_kw(self) -> float:
        """Noise-free power of the inner plant at the latest sample [kW]."""
        return float(self.plant.true_power_kw)


def model_time_constant_s(model: HammersteinModel) -> float:
    """Time constant of the slow pole of the model's ``A(q)`` [s] (`sim.perturbed.slow_pole`)."""
    return slow_pole(model.a, ts_s=model.ts_s)[1]


def vary_model_plant(model: HammersteinModel, variation: PlantVariation, *, noise: bool = True,
                     initial_triac_pct: float | None = None) -> DriftingPlant:
    """A `ModelPlant` of ``model`` with ``variation`` applied.

    Parameters
    ----------
    model :
        The nominal model.
    variation :
        Gain, time constant, delay and drifts.
    noise :
        Inject the model's noise (`ModelPlant`).
    initial_triac_pct :
        Steady input at the start [%]; None: the model's operating point.

    Returns
    -------
    DriftingPlant

    Raises
    ------
    PlantError
        A time constant on a model without a real slow pole (`sim.perturbed.slow_pole`).
    """
    tau0_s = None
    if variation.tau_s is not None or any(e.quantity == "tau" for e in variation.drifts):
        tau0_s = model_time_constant_s(model)
    inner = ModelPlant(model, noise=noise, initial_triac_pct=initial_triac_pct)

    def set_dynamics(gain_factor: float, tau_s: float | None) -> None:
        factor = 1.0 if tau_s is None or tau0_s is None else tau_s / tau0_s
        inner.set_model(perturb_model(model, gain_factor=gain_factor,
                                      time_constant_factor=factor))

    return DriftingPlant(inner, set_dynamics=set_dynamics, variation=variation,
                         initial_triac_pct=inner.initial_triac_pct)


def heater_time_constant_s(params: HeaterParams, triac_pct: float | None = None) -> float:
    """Linearized time constant of the heater's power sag at a steady input [s].

    Parameters
    ----------
    params :
        Heater parameters.
    triac_pct :
        Steady input [%]; None: ``params.initial_triac_pct``.

    Returns
    -------
    float
        ``C / (4 eps A sigma T^3 + P alpha / rho(T))`` at the steady state (`sim.heater`).
    """
    s = params.initial_triac_pct if triac_pct is None else triac_pct
    power_kw, temp_k = steady_state(s, params)
    rho = _relative_resistance(temp_k, params)
    conductance_kw_per_k = (4.0 * params.emissivity_area_m2 * STEFAN_BOLTZMANN_KW_PER_M2_K4
                            * temp_k**3 + power_kw * params.resistance_tc_per_k / rho)
    return params.heat_capacity_kj_per_k / conductance_kw_per_k


def vary_heater(variation: PlantVariation, params: HeaterParams | None = None, *,
                rng: np.random.Generator | int | None = None) -> DriftingPlant:
    """A `VirtualHeater` with ``variation`` applied (module docstring for the meaning).

    Parameters
    ----------
    variation :
        Gain, time constant, delay and drifts.
    params :
        Nominal heater parameters; None: `HeaterParams()`.
    rng :
        Seed or generator of the first run.

    Returns
    -------
    DriftingPlant
    """
    base = HeaterParams() if params is None else params
    heater = VirtualHeater(base, rng=rng)

    def set_dynamics(gain_factor: float, tau_s: float | None) -> None:
        p = replace(base, rated_power_kw=base.rated_power_kw * gain_factor)
        if tau_s is not None:
            scale = tau_s / heater_time_constant_s(p)
            p = replace(p, heat_capacity_kj_per_k=p.heat_capacity_kj_per_k * scale)
        heater.params = p

    plant = DriftingPlant(heater, set_dynamics=set_dynamics, variation=variation,
                          initial_triac_pct=base.initial_triac_pct)
    plant.reset(rng)
    return plant


__all__ = ["DriftEvent", "DriftingPlant", "PlantVariation", "heater_time_constant_s",
           "model_time_constant_s", "parse_drift", "vary_heater", "vary_model_plant"]
