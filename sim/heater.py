"""VirtualHeater: grey-box physics stand-in for the CZ puller's heating element.

A TRIAC power controller feeds a graphite element whose resistance rises as it heats
(paper sec. 3): a step up in ``s`` steps the power up at once, then it sags by about
12 % of the step with a time constant of about 200 s (at 45 kW). Defaults are
calibrated to the paper: ``s = 45 %`` gives ``P = 45 kW``, and the steps of
`sim.experiment` reproduce Table 3.

Notation
--------
==============  ======================================================  =======
symbol          meaning                                                 unit
==============  ======================================================  =======
``s``           TRIAC input signal (``triac_pct``)                      %
``phi(s)``      fraction of the rated power the controller passes       -
``v``           grid voltage relative to nominal (``grid_voltage_factor``) -
``w``           slow grid-voltage wander, ``v = v_exo (1 + w)``         -
``T``           lumped element temperature                              K
``rho(T)``      element resistance relative to ``R_ref``                -
``P``           true electric heater power (``true_power_kw``)          kW
``y``           measured heater power (what `step` returns)             kW
``C``           lumped heat capacity of the element                     kJ/K
``eps A``       emissivity times radiating area of the element          m^2
``sigma``       Stefan-Boltzmann constant                               kW/(m^2 K^4)
``k``           sample index; ``t_k = k * ts_s``                        -
==============  ======================================================  =======

The model, with the input held constant over each sample (zero-order hold)::

    u       = (s - s_0) / (100 - s_0)
    phi(s)  = u^gamma (1 - kappa u) / (1 - kappa)   for s > s_0, else 0
    rho(T)  = 1 + alpha (T - T_ref)
    P(T)    = max(0, phi(s) v^2 P_rated / rho(T) + P_offset)
    C dT/dt = P(T) - eps A sigma (T^4 - T_wall^4)
    y_{k+1} = max(0, P(t_{k+1}) + n_{k+1}),     n ~ N(0, sensor_noise_std_kw^2)

``phi`` is the empirical part of the grey box: a firing unit that does not fire below
``s_0``, starts softly (``gamma``) and droops below proportional (``kappa``), so that
the instantaneous gain falls linearly with ``s`` as the paper's quadratic ``f(ds)``
implies (eqs. 14-17). The element radiates to the water-cooled chamber.

The inputs of sample ``k`` act over ``(t_k, t_{k+1}]``: one sample of delay (paper
sec. 6.1). ``T`` cannot jump, so a step in ``s`` steps ``P`` at once by
``v^2 P_rated dphi / rho(T)`` (the gain ``r`` of Table 3). Linearized, the sag has time
constant ``C / (4 eps A sigma T^3 + P alpha / rho)`` and the static gain is
``1 / (1 + P alpha / (rho 4 eps A sigma T^3))``, about 0.88, of the instantaneous one.

The wander ``w`` is an exactly discretized Ornstein-Uhlenbeck process
(`HeaterParams.grid_wander_std`, `HeaterParams.grid_wander_time_s`): a few tenths of a
percent of power, so even a perfect model leaves ballistic errors (the paper's best
``V = 0.007 kW^2`` against one-step errors of std 0.013 kW). `VirtualHeater.reset`
spawns independent streams for the sensor noise and the wander, so switching one off
never shifts the other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from sim.errors import PlantError
from sim.loop import spawn_streams
from sim.protocols import NOMINAL, Exogenous

#: Stefan-Boltzmann constant [kW/(m^2 K^4)].
STEFAN_BOLTZMANN_KW_PER_M2_K4 = 5.670374419e-11


@dataclass(frozen=True, kw_only=True)
class HeaterParams:
    """Physical parameters of the virtual heater (defaults calibrated to the paper).

    Parameters
    ----------
    ts_s :
        Sampling time [s] (the paper's logger: 2 s).
    rated_power_kw :
        ``P_rated = V_nom^2 / R_ref``: power at full input (``phi = 1``), nominal grid
        voltage and the reference temperature [kW].
    firing_threshold_pct :
        ``s_0``: input below which the TRIAC controller does not fire [%].
    firing_droop :
        ``kappa``: droop below proportional at full input, ``0 <= kappa < 1`` [-].
    firing_exponent :
        ``gamma >= 1``: softness of the start above the threshold [-].
    resistance_tc_per_k :
        ``alpha``: temperature coefficient of the element's resistance, relative to
        ``R_ref`` [1/K].
    reference_temp_k :
        ``T_ref``: temperature at which the resistance is ``R_ref`` [K].
    wall_temp_k :
        ``T_wall``: temperature of the water-cooled chamber the element radiates to [K].
    emissivity_area_m2 :
        ``eps A``: emissivity times radiating area [m^2] (about 1500 K at 45 kW).
    heat_capacity_kj_per_k :
        ``C``: lumped heat capacity of the element [kJ/K]; sets the sag time constant.
    sensor_noise_std_kw :
        Std of the power transducer's white noise [kW].
    grid_wander_std :
        Std of the relative grid-voltage wander ``w`` [-] (0: off).
    grid_wander_time_s :
        Correlation time of the wander [s].
    initial_triac_pct :
        Input at whose steady state every run starts [%].

    Raises
    ------
    PlantError
        A parameter not finite or outside its physical range.
    """

    ts_s: float = 2.0
    rated_power_kw: float = 100.5
    firing_threshold_pct: float = 13.0
    firing_droop: float = 0.412
    firing_exponent: float = 1.17
    resistance_tc_per_k: float = 3.5e-4
    reference_temp_k: float = 1500.0
    wall_temp_k: float = 300.0
    emissivity_area_m2: float = 0.157
    heat_capacity_kj_per_k: float = 27.0
    sensor_noise_std_kw: float = 0.0105
    grid_wander_std: float = 0.0008
    grid_wander_time_s: float = 1000.0
    initial_triac_pct: float = 45.0

    def __post_init__(self) -> None:
        positive = ("ts_s", "rated_power_kw", "reference_temp_k", "wall_temp_k",
                    "emissivity_area_m2", "heat_capacity_kj_per_k", "grid_wander_time_s")
        non_negative = ("resistance_tc_per_k", "sensor_noise_std_kw", "grid_wander_std")
        for name in positive + non_negative + ("firing_threshold_pct", "firing_droop",
                                               "firing_exponent", "initial_triac_pct"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise PlantError(f"HeaterParams.{name} must be a number; got {value!r}")
            if not math.isfinite(value):
                raise PlantError(f"HeaterParams.{name} must be finite; got {value!r}")
            object.__setattr__(self, name, float(value))
        ranges = [(name, getattr(self, name) > 0, "> 0") for name in positive]
        ranges += [(name, getattr(self, name) >= 0, ">= 0") for name in non_negative]
        ranges += [
            ("firing_threshold_pct", 0.0 <= self.firing_threshold_pct < 100.0, "in [0, 100)"),
            ("firing_exponent", self.firing_exponent >= 1.0, ">= 1"),
            ("firing_droop", 0.0 <= self.firing_droop < 1.0, "in [0, 1)"),
            ("initial_triac_pct", 0.0 <= self.initial_triac_pct <= 100.0, "in [0, 100]"),
        ]
        for name, inside, expected in ranges:
            if not inside:
                raise PlantError(f"HeaterParams.{name} must be {expected}; got {getattr(self, name)!r}")
        rho_wall = _relative_resistance(self.wall_temp_k, self)
        if rho_wall <= 0.0:
            raise PlantError("HeaterParams: the relative resistance at the wall temperature, 1 + "
                             "resistance_tc_per_k * (wall_temp_k - reference_temp_k), must be > 0; "
                             f"got {rho_wall!r}")


def power_fraction(triac_pct: float, params: HeaterParams) -> float:
    """Fraction ``phi`` of the rated power the TRIAC controller passes at input ``s``.

    Parameters
    ----------
    triac_pct :
        TRIAC input ``s`` [%], in ``[0, 100]``.
    params :
        Heater parameters (``s_0``, ``kappa``, ``gamma``).

    Returns
    -------
    float
        ``phi`` of the module notes [-]; ``phi(100) = 1``.
    """
    s0 = params.firing_threshold_pct
    if triac_pct <= s0:
        return 0.0
    u = (triac_pct - s0) / (100.0 - s0)
    kappa = params.firing_droop
    return float(u**params.firing_exponent * (1.0 - kappa * u) / (1.0 - kappa))


def _relative_resistance(temp_k: float, params: HeaterParams) -> float:
    """``R(T) / R_ref = 1 + alpha (T - T_ref)``."""
    return 1.0 + params.resistance_tc_per_k * (temp_k - params.reference_temp_k)


def _electric_power_kw(
    temp_k: float, drive_kw: float, offset_kw: float, params: HeaterParams
) -> float:
    """True power ``P(T)`` for ``drive_kw = phi * v^2 * P_rated`` (clamped at 0)."""
    return max(0.0, drive_kw / _relative_resistance(temp_k, params) + offset_kw)


def _heat_loss_kw(temp_k: float, params: HeaterParams) -> float:
    """Radiated power ``eps A sigma (T^4 - T_wall^4)`` [kW]."""
    return (params.emissivity_area_m2 * STEFAN_BOLTZMANN_KW_PER_M2_K4
            * (temp_k**4 - params.wall_temp_k**4))


def steady_state(
    triac_pct: float,
    params: HeaterParams,
    *,
    grid_voltage_factor: float = 1.0,
    power_offset_kw: float = 0.0,
) -> tuple[float, float]:
    """Steady true power and element temperature for a constant input.

    Parameters
    ----------
    triac_pct :
        Constant TRIAC input ``s`` [%].
    params :
        Heater parameters.
    grid_voltage_factor :
        Constant relative grid voltage ``v`` [-].
    power_offset_kw :
        Constant additive power offset [kW].

    Returns
    -------
    tuple of float
        ``(power_kw, temp_k)`` [kW], [K]: the unique root of
        ``P(T) = eps A sigma (T^4 - T_wall^4)``.

    Raises
    ------
    PlantError
        `triac_pct` outside ``[0, 100]`` or a non-positive voltage factor.
    """
    _check_input(triac_pct, Exogenous(grid_voltage_factor=grid_voltage_factor,
                                      power_offset_kw=power_offset_kw))
    drive_kw = power_fraction(triac_pct, params) * grid_voltage_factor**2 * params.rated_power_kw

    def balance_kw(temp_k: float) -> float:
        return _electric_power_kw(temp_k, drive_kw, power_offset_kw, params) - _heat_loss_kw(temp_k, params)

    low_k = params.wall_temp_k
    if balance_kw(low_k) <= 0.0:  # no net heating: the element sits at the wall temperature
        return _electric_power_kw(low_k, drive_kw, power_offset_kw, params), low_k
    high_k = 2.0 * low_k
    while balance_kw(high_k) > 0.0:
        high_k *= 2.0
    temp_k = float(brentq(balance_kw, low_k, high_k, xtol=1e-12, rtol=4 * np.finfo(float).eps))
    return _electric_power_kw(temp_k, drive_kw, power_offset_kw, params), temp_k


def _check_input(triac_pct: float, exogenous: Exogenous) -> None:
    if (isinstance(triac_pct, bool) or not isinstance(triac_pct, int | float | np.floating)
            or not 0.0 <= triac_pct <= 100.0):  # also refuses NaN
        raise PlantError(f"VirtualHeater: triac_pct must be a number in [0, 100]; got {triac_pct!r}")
    v = exogenous.grid_voltage_factor
    if not (math.isfinite(v) and v > 0.0):
        raise PlantError(f"VirtualHeater: Exogenous.grid_voltage_factor must be finite and > 0; got {v!r}")
    if not math.isfinite(exogenous.power_offset_kw):
        raise PlantError("VirtualHeater: Exogenous.power_offset_kw must be finite; got "
                         f"{exogenous.power_offset_kw!r}")


class VirtualHeater:
    """The virtual CZ heater: TRIAC input in, measured power out (the `Plant` protocol).

    Parameters
    ----------
    params :
        Physical parameters; default: `HeaterParams()` (calibrated to the paper).
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
    >>> heater = VirtualHeater(rng=1)
    >>> round(heater.true_power_kw)
    45
    >>> p_next = heater.step(50.0)   # the step shows at once, one sample later
    >>> round(heater.true_power_kw, 0)
    52.0
    """

    def __init__(
        self, params: HeaterParams | None = None, *, rng: np.random.Generator | int | None = None
    ) -> None:
        self.params = HeaterParams() if params is None else params
        if not isinstance(self.params, HeaterParams):
            raise PlantError(f"VirtualHeater: params must be a HeaterParams; got {params!r}")
        self.ts_s = self.params.ts_s
        p = self.params
        self._wander_decay = math.exp(-p.ts_s / p.grid_wander_time_s)
        self._wander_innovation_std = p.grid_wander_std * math.sqrt(1.0 - self._wander_decay**2)
        self._temp_k = p.wall_temp_k
        self._true_power_kw = 0.0
        self._wander = 0.0
        self._voltage = 1.0
        self._noise_rng = np.random.default_rng(0)
        self._wander_rng = np.random.default_rng(0)
        self.reset(rng)

    def reset(self, rng: np.random.Generator | int | None = None) -> float:
        """Start a new run at the steady state of `HeaterParams.initial_triac_pct`.

        Parameters
        ----------
        rng :
            Seed or generator of the two streams (module notes); None: fresh entropy.

        Returns
        -------
        float
            The first measured power ``y_0`` [kW].
        """
        _, self._noise_rng, self._wander_rng = spawn_streams(rng)
        p = self.params
        self._wander = p.grid_wander_std * float(self._wander_rng.standard_normal())
        self._voltage = 1.0 + self._wander
        self._true_power_kw, self._temp_k = steady_state(p.initial_triac_pct, p,
                                                         grid_voltage_factor=self._voltage)
        return self._measure()

    def step(self, triac_pct: float, exogenous: Exogenous = NOMINAL) -> float:
        """Hold `triac_pct` over one sample under `exogenous`; return the next measurement.

        Parameters
        ----------
        triac_pct :
            TRIAC input ``s_k`` [%], in ``[0, 100]``.
        exogenous :
            Grid voltage factor and power offset acting over this sample.

        Returns
        -------
        float
            Measured power ``y_{k+1}`` [kW], never negative.

        Raises
        ------
        PlantError
            `triac_pct` not in ``[0, 100]``, or a non-finite or non-positive exogenous.
        """
        _check_input(triac_pct, exogenous)
        p = self.params
        v = self._voltage = exogenous.grid_voltage_factor * (1.0 + self._wander)
        drive_kw = power_fraction(triac_pct, p) * v * v * p.rated_power_kw
        offset_kw = exogenous.power_offset_kw
        self._temp_k = self._integrate_temp(self._temp_k, drive_kw, offset_kw)
        self._true_power_kw = _electric_power_kw(self._temp_k, drive_kw, offset_kw, p)
        innovation = self._wander_innovation_std * float(self._wander_rng.standard_normal())
        self._wander = self._wander_decay * self._wander + innovation
        return self._measure()

    @property
    def true_power_kw(self) -> float:
        """Noise-free heater power ``P`` [kW] at the latest sample."""
        return self._true_power_kw

    @property
    def grid_voltage_factor(self) -> float:
        """Grid voltage relative to nominal [-] over the latest sample (the step's
        `Exogenous` factor times the slow grid wander; after `reset`, the wander alone)."""
        return self._voltage

    @property
    def element_temp_k(self) -> float:
        """Lumped element temperature ``T`` [K] at the latest sample."""
        return self._temp_k

    def _measure(self) -> float:
        noise_kw = self.params.sensor_noise_std_kw * float(self._noise_rng.standard_normal())
        return max(0.0, self._true_power_kw + noise_kw)

    def _integrate_temp(self, temp_k: float, drive_kw: float, offset_kw: float) -> float:
        """One RK4 step of ``C dT/dt = P(T) - loss(T)`` (ts_s is 1 % of the sag: ~1e-10 K)."""
        p = self.params

        def rate(temp: float) -> float:
            heat_kw = _electric_power_kw(temp, drive_kw, offset_kw, p)
            return (heat_kw - _heat_loss_kw(temp, p)) / p.heat_capacity_kj_per_k

        h = p.ts_s
        k1 = rate(temp_k)
        k2 = rate(temp_k + 0.5 * h * k1)
        k3 = rate(temp_k + 0.5 * h * k2)
        k4 = rate(temp_k + h * k3)
        return temp_k + h * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0


__all__ = ["HeaterParams", "VirtualHeater", "power_fraction", "steady_state"]
