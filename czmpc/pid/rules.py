"""PID tuning rules on a first- or second-order-plus-dead-time plant, in the ideal ISA form.

Every rule returns a `PIDTuning` for the ideal (ISA, non-interacting) form in engineering
units::

    u = Kc (b r - y) + (Kc/Ti) integral(r - y) dt - Kc Td dy_f/dt,
    Td_f dy_f/dt + y_f = y                       (derivative on the filtered measurement)

with ``u`` the TRIAC input [%], ``r, y`` setpoint and power [kW], ``Kc`` [%/kW],
``Ti, Td, Td_f`` [s] and the setpoint weight ``b`` [-].

Rules
-----
* `simc`: Skogestad (2003), one knob ``tau_c``; with ``delay_dominant=True`` the
  correction ``tau1 -> tau1 + theta/3`` of the PI (Grimholt and Skogestad 2012), which
  gives a PI instead of the pure integral control SIMC gives a plant without lag.
* `lambda_imc`: internal model control with a first-order filter of time constant
  ``lambda``; the delay by a first-order Pade approximation (first-order plant) or a
  first-order Taylor expansion (second-order plant).
* `amigo`: Astrom and Hagglund's AMIGO rules (no knob; they aim at Ms about 1.4).
* `gain_delay_sampled`: the sampled-loop rule for a gain with one sample of delay that
  places the dominant closed-loop pole at ``lambda`` (the benchmark peer's rule).

A second-order plant is reduced to first order by Skogestad's half rule where a rule needs
first order (``tau1 + tau2/2``, ``theta + tau2/2``).

References
----------
S. Skogestad, "Simple analytic rules for model reduction and PID controller tuning",
J. Process Control 13 (2003) 291-309.
C. Grimholt, S. Skogestad, "Optimal PI-control and verification of the SIMC tuning rule",
IFAC PID 2012.
K. J. Astrom, T. Hagglund, "Advanced PID Control", ISA 2006, ch. 7 (AMIGO).
D. E. Rivera, M. Morari, S. Skogestad, "Internal model control. 4. PID controller
design", Ind. Eng. Chem. Process Des. Dev. 25 (1986) 252-265.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

from czmpc.pid.errors import PIDTuningError
from czmpc.pid.plant import RulePlant

ControllerType = Literal["pi", "pid"]

#: ``Td / Td_f`` of the derivative filter the rules set for a PID [-] (a common default;
#: the filter enters the margins, which are computed with it).
DERIVATIVE_FILTER_RATIO = 10.0


@dataclass(frozen=True, slots=True, kw_only=True)
class PIDTuning:
    """Ideal (ISA) PID parameters in engineering units (module notes).

    Parameters
    ----------
    kc_pct_per_kw :
        Proportional gain ``Kc`` [% TRIAC per kW], > 0.
    ti_s :
        Integral time ``Ti`` [s], > 0.
    td_s :
        Derivative time ``Td`` [s], >= 0 (0: a PI).
    td_filter_s :
        Time constant of the measurement filter of the derivative [s], >= 0 (> 0 when
        ``td_s > 0``).
    setpoint_weight :
        ``b`` of the proportional term [-], in [0, 1].
    """

    kc_pct_per_kw: float
    ti_s: float
    td_s: float = 0.0
    td_filter_s: float = 0.0
    setpoint_weight: float = 1.0

    def __post_init__(self) -> None:
        checks = (("kc_pct_per_kw", self.kc_pct_per_kw, self.kc_pct_per_kw > 0),
                  ("ti_s", self.ti_s, self.ti_s > 0),
                  ("td_s", self.td_s, self.td_s >= 0),
                  ("td_filter_s", self.td_filter_s,
                   self.td_filter_s > 0 if self.td_s > 0 else self.td_filter_s >= 0),
                  ("setpoint_weight", self.setpoint_weight, 0 <= self.setpoint_weight <= 1))
        for name, value, ok in checks:
            if not (isinstance(value, float | int) and math.isfinite(value) and ok):
                raise PIDTuningError(
                    f"PIDTuning.{name}: expected a finite value (Kc > 0, Ti > 0, Td >= 0, "
                    f"filter > 0 with Td > 0, 0 <= b <= 1); got {value!r}")

    def scaled(self, factor: float) -> PIDTuning:
        """The same tuning with ``Kc`` multiplied by ``factor`` (times unchanged)."""
        return replace(self, kc_pct_per_kw=self.kc_pct_per_kw * factor)


def series_to_ideal(kc: float, ti_s: float, td_s: float) -> tuple[float, float, float]:
    """Series (interacting) ``Kc'(1 + 1/(Ti' s))(1 + Td' s)`` to ideal ``(Kc, Ti, Td)``.

    ``Kc = Kc'(1 + Td'/Ti')``, ``Ti = Ti' + Td'``, ``Td = Ti' Td'/(Ti' + Td')``.
    """
    return kc * (1.0 + td_s / ti_s), ti_s + td_s, ti_s * td_s / (ti_s + td_s)


def _with_filter(kc: float, ti_s: float, td_s: float, setpoint_weight: float = 1.0) -> PIDTuning:
    return PIDTuning(kc_pct_per_kw=kc, ti_s=ti_s, td_s=td_s,
                     td_filter_s=td_s / DERIVATIVE_FILTER_RATIO, setpoint_weight=setpoint_weight)


def _half_rule(plant: RulePlant) -> tuple[float, float]:
    """``(tau1, theta)`` of the first-order reduction by the half rule [s]."""
    return plant.tau1_s + plant.tau2_s / 2.0, plant.dead_time_s + plant.tau2_s / 2.0


def _positive_knob(name: str, value: float) -> float:
    if not (math.isfinite(value) and value > 0):
        raise PIDTuningError(f"{name}: expected a time > 0 [s]; got {value!r}")
    return float(value)


def simc(plant: RulePlant, *, tau_c_s: float, controller: ControllerType = "pi",
         delay_dominant: bool = False) -> PIDTuning:
    """SIMC tuning (Skogestad 2003) with closed-loop time constant ``tau_c``.

    PI (a second-order plant first reduced by the half rule)::

        Kc = tau1 / (k (tau_c + theta)),   Ti = min(tau1, 4 (tau_c + theta))

    PID on a second-order plant: the series PID with those ``Kc, Ti`` and ``Td = tau2``,
    converted to the ideal form (`series_to_ideal`); on a first-order plant ``Td = 0``.
    ``tau_c = theta`` is SIMC's "tight" choice.

    Parameters
    ----------
    plant :
        The plant.
    tau_c_s :
        ``tau_c`` [s], > 0.
    controller :
        ``"pi"`` or ``"pid"``.
    delay_dominant :
        Replace ``tau1`` by ``tau1 + theta/3`` in the PI (Grimholt and Skogestad 2012).

    Raises
    ------
    PIDTuningError
        ``tau_c_s`` not > 0, or a plant without lag and no delay-dominant correction
        (SIMC then gives pure integral control, which the ISA form cannot hold).
    """
    tau_c = _positive_knob("simc: tau_c_s", tau_c_s)
    k = plant.gain_kw_per_pct
    if controller == "pid" and plant.tau2_s > 0:
        tau1, theta = plant.tau1_s, plant.dead_time_s
        kc_s = tau1 / (k * (tau_c + theta))
        return _with_filter(*series_to_ideal(kc_s, min(tau1, 4.0 * (tau_c + theta)), plant.tau2_s))
    tau1, theta = _half_rule(plant)
    if delay_dominant:
        tau1 += theta / 3.0
    if tau1 <= 0.0:
        raise PIDTuningError(
            "simc: the plant has no lag (tau1 = 0), so SIMC gives pure integral control "
            f"Ki = 1/(k (tau_c + theta)) = {1.0 / (k * (tau_c + theta)):.4g} %/(kW s), "
            "which an ISA PI cannot hold; use the delay-dominant correction")
    return PIDTuning(kc_pct_per_kw=tau1 / (k * (tau_c + theta)),
                     ti_s=min(tau1, 4.0 * (tau_c + theta)))


def lambda_imc(plant: RulePlant, *, lambda_s: float,
               controller: ControllerType = "pi") -> PIDTuning:
    """Lambda (IMC) tuning with closed-loop time constant ``lambda``.

    First-order plant, delay by Pade ``e^{-theta s} ~ (1 - theta s/2)/(1 + theta s/2)``:
    the IMC controller is ``(tau1 s + 1)(theta s/2 + 1) / (k (lambda + theta/2) s)``.
    Its PID is that controller exactly (ideal form)::

        Kc = (tau1 + theta/2) / (k (lambda + theta/2)),   Ti = tau1 + theta/2,
        Td = tau1 theta / (2 tau1 + theta)

    and its PI keeps ``Kc`` and ``Ti`` and drops ``Td``. Second-order plant (PID), delay by
    ``e^{-theta s} ~ 1 - theta s``: ``(tau1 s + 1)(tau2 s + 1) / (k (lambda + theta) s)``,
    i.e. ``Kc = (tau1 + tau2)/(k (lambda + theta))``, ``Ti = tau1 + tau2``,
    ``Td = tau1 tau2/(tau1 + tau2)``; its PI first reduces the plant by the half rule.

    Parameters
    ----------
    plant :
        The plant.
    lambda_s :
        ``lambda`` [s], > 0.
    controller :
        ``"pi"`` or ``"pid"``.

    Raises
    ------
    PIDTuningError
        ``lambda_s`` not > 0.
    """
    lam = _positive_knob("lambda: lambda_s", lambda_s)
    k = plant.gain_kw_per_pct
    if controller == "pid" and plant.tau2_s > 0:
        t1, t2 = plant.tau1_s, plant.tau2_s
        return _with_filter((t1 + t2) / (k * (lam + plant.dead_time_s)), t1 + t2,
                            t1 * t2 / (t1 + t2))
    tau1, theta = _half_rule(plant)
    half = theta / 2.0
    kc = (tau1 + half) / (k * (lam + half))
    if controller == "pid" and tau1 > 0:
        return _with_filter(kc, tau1 + half, tau1 * half / (tau1 + half))
    return PIDTuning(kc_pct_per_kw=kc, ti_s=tau1 + half)


def amigo(plant: RulePlant, *, controller: ControllerType = "pi") -> PIDTuning:
    """AMIGO tuning (Astrom and Hagglund) of a first-order plant ``K e^{-L s}/(T s + 1)``.

    PI::

        Kc = 0.15/K + (0.35 - L T/(L + T)^2) T/(K L)
        Ti = 0.35 L + 13 L T^2 / (T^2 + 12 L T + 7 L^2)

    PID::

        Kc = (0.2 + 0.45 T/L)/K,   Ti = L (0.4 L + 0.8 T)/(L + 0.1 T),
        Td = 0.5 L T/(0.3 L + T)

    Setpoint weight ``b = 0`` for a lag-dominant plant (``L/(L + T) <= 0.5``), else 1.
    A second-order plant is first reduced by the half rule.

    Parameters
    ----------
    plant :
        The plant.
    controller :
        ``"pi"`` or ``"pid"``.
    """
    t, lag = _half_rule(plant)
    kp = plant.gain_kw_per_pct
    b = 0.0 if lag / (lag + t) <= 0.5 else 1.0
    if controller == "pid":
        kc = (0.2 + 0.45 * t / lag) / kp
        ti = lag * (0.4 * lag + 0.8 * t) / (lag + 0.1 * t)
        td = 0.5 * lag * t / (0.3 * lag + t)
        if td > 0:
            return _with_filter(kc, ti, td, b)
        return PIDTuning(kc_pct_per_kw=kc, ti_s=ti, setpoint_weight=b)
    kc = 0.15 / kp + (0.35 - lag * t / (lag + t) ** 2) * t / (kp * lag)
    ti = 0.35 * lag + 13.0 * lag * t**2 / (t**2 + 12.0 * lag * t + 7.0 * lag**2)
    return PIDTuning(kc_pct_per_kw=kc, ti_s=ti, setpoint_weight=b)


#: Proportional loop gain ``g Kc`` of `gain_delay_sampled` [-]. With one sample of delay the
#: loop ``y+ = -g Kc y`` oscillates for ``g Kc >= 1``; 0.5 leaves a gain margin of 2.
GAIN_DELAY_LOOP_GAIN = 0.5


def gain_delay_sampled(gain_kw_per_pct: float, *, lambda_s: float,
                       loop_gain: float = GAIN_DELAY_LOOP_GAIN) -> PIDTuning:
    """Sampled-loop lambda rule for a gain ``g`` with one sample of delay.

    With the forward-Euler PI of `czmpc.pid.controller`, ``Kc = beta/g`` and
    ``Ti = lambda beta/(1 + beta)`` put the dominant root of
    ``z^2 + (beta - 1) z + beta (Ts/Ti - 1) = 0`` near ``z = 1`` at the time constant
    ``lambda``; ``beta = loop_gain``.

    Parameters
    ----------
    gain_kw_per_pct :
        ``g`` [kW/%], > 0.
    lambda_s :
        ``lambda`` [s], > 0.
    loop_gain :
        ``beta = g Kc`` [-], in (0, 1).

    Raises
    ------
    PIDTuningError
        A non-positive gain or ``lambda``, or ``beta`` outside (0, 1).
    """
    lam = _positive_knob("gain_delay_sampled: lambda_s", lambda_s)
    if not (math.isfinite(gain_kw_per_pct) and gain_kw_per_pct > 0):
        raise PIDTuningError(
            f"gain_delay_sampled: expected a gain > 0 [kW/%]; got {gain_kw_per_pct!r}")
    if not 0.0 < loop_gain < 1.0:
        raise PIDTuningError(f"gain_delay_sampled: expected loop_gain in (0, 1); got {loop_gain!r}")
    return PIDTuning(kc_pct_per_kw=loop_gain / gain_kw_per_pct,
                     ti_s=lam * loop_gain / (1.0 + loop_gain))


__all__ = ["DERIVATIVE_FILTER_RATIO", "GAIN_DELAY_LOOP_GAIN", "ControllerType", "PIDTuning", "amigo",
           "gain_delay_sampled", "lambda_imc", "series_to_ideal", "simc"]
