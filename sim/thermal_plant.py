"""ThermalPlant: an electrically heated furnace zone, a plant of another kind than the CZ heater.

Its output is a zone temperature [degC] reported in the output role (``power_kw`` in
`sim.protocols.Plant`; a model identified from it says ``units = {"output": "degC"}``,
docs/theory.rst, "Facts that bite": identification is general). It differs from the CZ heater where the
controller's defaults could have been fitted to the heater: two lags (element about
20 s, zone about 140 s) and no direct feed-through, so the output starts to move only
slowly after a step; a slow mode of 70 samples at 2 s; a quantised sensor.

Notation
--------
==============  ======================================================  =======
symbol          meaning                                                 unit
==============  ======================================================  =======
``s``           heater input (``triac_pct``)                            %
``u``           ``s / 100``                                             -
``phi(s)``      fraction of the rated heating power, ``phi(100) = 1``   -
``v``           grid voltage relative to nominal (``grid_voltage_factor``) -
``x1``          element temperature rise over ambient                   degC
``x2``          zone temperature rise over ambient                      degC
``y``           measured zone temperature (what `step` returns)         degC
==============  ======================================================  =======

The model, with the input held constant over each sample (zero-order hold)::

    phi(s)         = u (1 + beta (1 - u))                  (mild: slope 1 + beta .. 1 - beta)
    tau1 dx1/dt    = K v^2 phi(s) - x1
    tau2 dx2/dt    = x1 - x2
    T(t)           = T_amb + x2(t) + T_offset
    y_{k+1}        = q round((T(t_{k+1}) + n_{k+1}) / q),   n ~ N(0, sensor_noise_std^2)

so the step response of ``T`` to a step of ``K v^2 phi`` of size 1 is
``1 - (tau1 e^{-t/tau1} - tau2 e^{-t/tau2}) / (tau1 - tau2)``. The two states are
advanced by the exact zero-order-hold discretization (matrix exponential), so the
sampled response has no integration error. The inputs of sample ``k`` act over
``(t_k, t_{k+1}]``: one sample of delay, as on `sim.heater.VirtualHeater`.

``Exogenous.power_offset_kw`` is an additive shift of the true output [degC] (the
output role's level shift, as on the heater); ``Exogenous.grid_voltage_factor`` scales
the heating power by ``v^2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from sim.errors import PlantError
from sim.loop import spawn_streams
from sim.protocols import NOMINAL, Exogenous


@dataclass(frozen=True, kw_only=True)
class ThermalParams:
    """Parameters of the furnace zone (defaults: a small electric furnace).

    Parameters
    ----------
    ts_s :
        Sampling time [s].
    gain_degc :
        ``K``: steady temperature rise over ambient at full input and nominal voltage [degC].
    ambient_degc :
        ``T_amb``: temperature at zero input [degC].
    element_time_s :
        ``tau1``: time constant of the element [s].
    zone_time_s :
        ``tau2``: time constant of the zone [s].
    nonlinearity :
        ``beta`` in ``[0, 1)``: droop of ``phi`` below proportional (slope ``1 + beta`` at
        0 %, ``1 - beta`` at 100 %) [-].
    sensor_noise_std_degc :
        Std of the sensor's white noise before quantisation [degC].
    sensor_quantum_degc :
        Resolution of the sensor [degC]; 0 for none.
    initial_triac_pct :
        Input at whose steady state every run starts [%].

    Raises
    ------
    PlantError
        A parameter not finite or outside its range.
    """

    ts_s: float = 2.0
    gain_degc: float = 500.0
    ambient_degc: float = 25.0
    element_time_s: float = 20.0
    zone_time_s: float = 140.0
    nonlinearity: float = 0.25
    sensor_noise_std_degc: float = 0.08
    sensor_quantum_degc: float = 0.1
    initial_triac_pct: float = 50.0

    def __post_init__(self) -> None:
        positive = ("ts_s", "gain_degc", "element_time_s", "zone_time_s")
        non_negative = ("sensor_noise_std_degc", "sensor_quantum_degc")
        for name in positive + non_negative + ("ambient_degc", "nonlinearity", "initial_triac_pct"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise PlantError(f"ThermalParams.{name} must be a number; got {value!r}")
            if not math.isfinite(value):
                raise PlantError(f"ThermalParams.{name} must be finite; got {value!r}")
            object.__setattr__(self, name, float(value))
        ranges = [(name, getattr(self, name) > 0, "> 0") for name in positive]
        ranges += [(name, getattr(self, name) >= 0, ">= 0") for name in non_negative]
        ranges += [
            ("nonlinearity", 0.0 <= self.nonlinearity < 1.0, "in [0, 1)"),
            ("initial_triac_pct", 0.0 <= self.initial_triac_pct <= 100.0, "in [0, 100]"),
        ]
        for name, inside, expected in ranges:
            if not inside:
                raise PlantError(f"ThermalParams.{name} must be {expected}; got {getattr(self, name)!r}")
        if self.element_time_s == self.zone_time_s:
            raise PlantError("ThermalParams: element_time_s and zone_time_s must differ (two distinct "
                             f"lags); got {self.element_time_s!r} for both")


def heating_fraction(triac_pct: float, params: ThermalParams) -> float:
    """Fraction ``phi`` of the rated heating power at input ``s`` (module notes) [-].

    Parameters
    ----------
    triac_pct :
        Input ``s`` [%], in ``[0, 100]``.
    params :
        Supplies ``beta``.
    """
    u = triac_pct / 100.0
    return u * (1.0 + params.nonlinearity * (1.0 - u))


def steady_state_degc(triac_pct: float, params: ThermalParams, *,
                      grid_voltage_factor: float = 1.0) -> float:
    """Steady zone temperature [degC] for a constant input and voltage (no offset).

    Parameters
    ----------
    triac_pct :
        Constant input ``s`` [%], in ``[0, 100]``.
    params :
        Plant parameters.
    grid_voltage_factor :
        Constant relative grid voltage ``v`` [-], > 0.

    Raises
    ------
    PlantError
        An input outside ``[0, 100]`` or a non-positive voltage factor.
    """
    _check_input(triac_pct, Exogenous(grid_voltage_factor=grid_voltage_factor))
    drive = params.gain_degc * grid_voltage_factor**2 * heating_fraction(triac_pct, params)
    return params.ambient_degc + drive


def steady_state_triac_pct(temp_degc: float, params: ThermalParams) -> float:
    """Input [%] whose steady temperature at nominal voltage is ``temp_degc``.

    ``phi`` is a concave quadratic increasing on ``[0, 100]``, so the root is closed-form.

    Raises
    ------
    PlantError
        ``temp_degc`` outside the range of steady temperatures at 0..100 %.
    """
    fraction = (temp_degc - params.ambient_degc) / params.gain_degc
    if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
        top = params.ambient_degc + params.gain_degc
        raise PlantError(f"ThermalPlant: expected a steady temperature in [{params.ambient_degc:g}, "
                         f"{top:g}] degC (0..100 % input); got {temp_degc!r}")
    beta = params.nonlinearity
    if beta == 0.0:
        return 100.0 * fraction
    # beta u^2 - (1 + beta) u + fraction = 0, the smaller root, stable form
    b = 1.0 + beta
    u = 2.0 * fraction / (b + math.sqrt(b * b - 4.0 * beta * fraction))
    return min(100.0, 100.0 * u)


def _check_input(triac_pct: float, exogenous: Exogenous) -> None:
    if (isinstance(triac_pct, bool) or not isinstance(triac_pct, int | float | np.floating)
            or not 0.0 <= triac_pct <= 100.0):  # also refuses NaN
        raise PlantError(f"ThermalPlant: triac_pct must be a number in [0, 100]; got {triac_pct!r}")
    v = exogenous.grid_voltage_factor
    if not (math.isfinite(v) and v > 0.0):
        raise PlantError(f"ThermalPlant: Exogenous.grid_voltage_factor must be finite and > 0; got {v!r}")
    if not math.isfinite(exogenous.power_offset_kw):
        raise PlantError("ThermalPlant: Exogenous.power_offset_kw must be finite; got "
                         f"{exogenous.power_offset_kw!r}")


def _zoh_matrices(params: ThermalParams) -> tuple[np.ndarray, np.ndarray]:
    """``(Ad, Bd)`` of the two lags discretized exactly with a zero-order hold."""
    t1, t2 = params.element_time_s, params.zone_time_s
    a = np.array([[-1.0 / t1, 0.0], [1.0 / t2, -1.0 / t2]])
    b = np.array([1.0 / t1, 0.0])
    block = np.zeros((3, 3))
    block[:2, :2] = a
    block[:2, 2] = b
    phi = expm(block * params.ts_s)
    return phi[:2, :2], phi[:2, 2]


class ThermalPlant:
    """The furnace zone: heater input in, measured temperature out (the `Plant` protocol).

    Parameters
    ----------
    params :
        Plant parameters; default `ThermalParams()`.
    rng :
        Seed or generator for the first run (passed to `reset`).

    Attributes
    ----------
    ts_s :
        Sampling time [s].
    params :
        The parameters in use.

    Examples
    --------
    >>> plant = ThermalPlant(rng=1)
    >>> round(plant.true_power_kw, 1)      # degC: the output role
    306.2
    >>> _ = plant.step(60.0)               # two lags: one sample later it has barely moved
    >>> round(plant.true_power_kw - 306.25, 3)
    0.034
    """

    def __init__(self, params: ThermalParams | None = None, *,
                 rng: np.random.Generator | int | None = None) -> None:
        self.params = ThermalParams() if params is None else params
        if not isinstance(self.params, ThermalParams):
            raise PlantError(f"ThermalPlant: params must be a ThermalParams; got {params!r}")
        self.ts_s = self.params.ts_s
        self._ad, self._bd = _zoh_matrices(self.params)
        self._state = np.zeros(2)
        self._true_degc = self.params.ambient_degc
        self._voltage = 1.0
        self._noise_rng = np.random.default_rng(0)
        self.reset(rng)

    def reset(self, rng: np.random.Generator | int | None = None) -> float:
        """Start a new run at the steady state of `ThermalParams.initial_triac_pct`.

        Parameters
        ----------
        rng :
            Seed or generator of the sensor noise; None: fresh entropy.

        Returns
        -------
        float
            The first measured temperature ``y_0`` [degC].
        """
        _, self._noise_rng, _ = spawn_streams(rng)
        p = self.params
        rise = p.gain_degc * heating_fraction(p.initial_triac_pct, p)
        self._state = np.array([rise, rise])
        self._voltage = 1.0
        self._true_degc = p.ambient_degc + rise
        return self._measure()

    def step(self, triac_pct: float, exogenous: Exogenous = NOMINAL) -> float:
        """Hold ``triac_pct`` over one sample under ``exogenous``; return the next measurement.

        Parameters
        ----------
        triac_pct :
            Input ``s_k`` [%], in ``[0, 100]``.
        exogenous :
            Grid voltage factor (heating power scales with its square) and an additive
            output offset [degC] acting over this sample.

        Returns
        -------
        float
            Measured temperature ``y_{k+1}`` [degC], quantised.

        Raises
        ------
        PlantError
            ``triac_pct`` not in ``[0, 100]``, or a non-finite or non-positive exogenous.
        """
        _check_input(triac_pct, exogenous)
        p = self.params
        v = exogenous.grid_voltage_factor
        drive = p.gain_degc * v * v * heating_fraction(float(triac_pct), p)
        self._state = self._ad @ self._state + self._bd * drive
        self._voltage = v
        self._true_degc = p.ambient_degc + float(self._state[1]) + exogenous.power_offset_kw
        return self._measure()

    @property
    def true_power_kw(self) -> float:
        """Noise-free zone temperature [degC] at the latest sample (the output role)."""
        return self._true_degc

    @property
    def grid_voltage_factor(self) -> float:
        """Grid voltage factor ``v`` [-] applied over the last step (1 after `reset`)."""
        return self._voltage

    def _measure(self) -> float:
        p = self.params
        value = self._true_degc + p.sensor_noise_std_degc * float(self._noise_rng.standard_normal())
        if p.sensor_quantum_degc > 0.0:
            value = p.sensor_quantum_degc * round(value / p.sensor_quantum_degc)
        return value


__all__ = ["ThermalParams", "ThermalPlant", "heating_fraction", "steady_state_degc",
           "steady_state_triac_pct"]
