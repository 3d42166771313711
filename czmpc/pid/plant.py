"""The local plant at a TRIAC breakpoint and its first-order-plus-dead-time reduction.

A Hammerstein model ``A(q) dP = B(q) f(ds) + C(q) e`` linearised at the input ``s0``
is ``f'(s0 - s_nom) B(q)/A(q)``: only the gain moves with the operating point, the
dynamics (and the delay, the leading zeros of ``B``) stay. `LocalPlant` is that sampled
plant, exactly; the tuning rules need a continuous first- or second-order-plus-dead-time
plant (`RulePlant`), which `reduce_to_rule_plant` derives from it.

Notation
--------
``g = f'(ds0)`` instantaneous gain of the nonlinearity [kW/%]; ``q^-1`` the one-sample
shift; ``Ts`` sampling time [s]; ``nk`` delay [samples]; ``a`` the pole of a first-order
``A`` (``A = 1 - a q^-1``); ``k`` gain [kW/%]; ``tau`` time constants [s]; ``theta``
dead time [s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from czmpc.inversion import slope
from czmpc.pid.errors import PIDTuningError
from sysid._typing import FloatArray
from sysid.model import HammersteinModel

#: B coefficients after the first one below this fraction of it count as zero (a pure lag).
_ZERO_COEFFICIENT_RTOL = 1e-12


@dataclass(frozen=True, slots=True, kw_only=True)
class LocalPlant:
    """The sampled plant ``g B(q)/A(q)`` at one TRIAC input, from TRIAC [%] to power [kW].

    Parameters
    ----------
    triac_pct :
        The TRIAC input it is linearised at [%].
    power_kw :
        The model's steady power at that input [kW].
    gain_kw_per_pct :
        ``g = f'(s - s_nom)``, the instantaneous gain of the input nonlinearity [kW/%].
    a :
        ``A(q^-1)`` coefficients, ascending powers, ``a[0] == 1``.
    b :
        ``B(q^-1)`` coefficients, ascending powers; leading zeros are the delay.
    ts_s :
        Sampling time [s].
    """

    triac_pct: float
    power_kw: float
    gain_kw_per_pct: float
    a: tuple[float, ...]
    b: tuple[float, ...]
    ts_s: float

    @property
    def delay_steps(self) -> int:
        """``nk``: leading zeros of ``B`` [samples]."""
        return int(np.flatnonzero(self.b)[0])

    @property
    def static_gain_kw_per_pct(self) -> float:
        """``g B(1)/A(1)``: steady-state gain [kW/%]."""
        return self.gain_kw_per_pct * sum(self.b) / sum(self.a)

    def frequency_response(self, w_rad_per_s: FloatArray) -> FloatArray:
        """``G(e^{j w Ts})`` [kW/%] at angular frequencies ``w`` [rad/s], below ``pi/Ts``."""
        zinv = np.exp(-1j * np.asarray(w_rad_per_s, dtype=float) * self.ts_s)
        num = np.polynomial.polynomial.polyval(zinv, self.b)
        den = np.polynomial.polynomial.polyval(zinv, self.a)
        return np.asarray(self.gain_kw_per_pct * num / den)


def local_plant(model: HammersteinModel, triac_pct: float) -> LocalPlant:
    """Linearise ``model`` at the TRIAC input ``triac_pct`` [%].

    Parameters
    ----------
    model :
        A Hammerstein (or linear) model; ``B/A`` is its input-to-power block.
    triac_pct :
        The input to linearise at [%].

    Raises
    ------
    PIDTuningError
        ``f'`` is not positive at that input (the loop would change sign), or ``B`` has
        no delay (a sampled loop reads, computes and writes: it needs ``B(0) = 0``).
    """
    if model.delay_steps < 1:
        raise PIDTuningError(
            f"local plant: expected at least one sample of delay (B starting with 0) for a "
            f"sampled loop; got B = {[float(v) for v in model.b]}")
    ds = float(triac_pct) - model.operating_point.triac_pct
    g = slope(tuple(float(v) for v in model.input_poly), ds)
    if not (math.isfinite(g) and g > 0.0):
        raise PIDTuningError(
            f"local plant at s = {triac_pct:g} %: expected a positive gain f'(ds) [kW/%]; "
            f"got {g:.4g} (the input nonlinearity is not increasing there: choose "
            "breakpoints inside the model's monotone range)")
    return LocalPlant(triac_pct=float(triac_pct),
                      power_kw=float(model.steady_state_power_kw(triac_pct)),
                      gain_kw_per_pct=g, a=tuple(float(v) for v in model.a),
                      b=tuple(float(v) for v in model.b), ts_s=model.ts_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class RulePlant:
    """``k e^{-theta s} / ((tau1 s + 1)(tau2 s + 1))``: the plant the tuning rules take.

    Parameters
    ----------
    gain_kw_per_pct :
        ``k`` [kW/%], > 0.
    tau1_s :
        Dominant time constant [s], >= 0 (0: a gain with dead time).
    tau2_s :
        Second time constant [s], 0 <= ``tau2_s`` <= ``tau1_s`` (0: first order).
    dead_time_s :
        ``theta`` [s], > 0; for a sampled loop it includes half a sample for the hold.
    """

    gain_kw_per_pct: float
    tau1_s: float
    dead_time_s: float
    tau2_s: float = 0.0

    def __post_init__(self) -> None:
        checks = (("gain_kw_per_pct", self.gain_kw_per_pct, self.gain_kw_per_pct > 0),
                  ("tau1_s", self.tau1_s, self.tau1_s >= 0),
                  ("dead_time_s", self.dead_time_s, self.dead_time_s > 0),
                  ("tau2_s", self.tau2_s, 0 <= self.tau2_s <= self.tau1_s))
        for name, value, ok in checks:
            if not (math.isfinite(value) and ok):
                raise PIDTuningError(
                    f"RulePlant.{name}: expected a finite value (gain > 0, dead time > 0, "
                    f"0 <= tau2 <= tau1) [s or kW/%]; got {value!r}")

    def frequency_response(self, w_rad_per_s: FloatArray) -> FloatArray:
        """``G(j w)`` [kW/%] at angular frequencies ``w`` [rad/s]."""
        s = 1j * np.asarray(w_rad_per_s, dtype=float)
        return np.asarray(self.gain_kw_per_pct * np.exp(-self.dead_time_s * s)
                          / ((self.tau1_s * s + 1.0) * (self.tau2_s * s + 1.0)))


def reduce_to_rule_plant(plant: LocalPlant) -> RulePlant:
    """The first-order-plus-dead-time plant a tuning rule sees for ``plant``.

    For ``A = 1 - a q^-1`` and ``B = q^-nk (b0 + b1 q^-1)`` (the paper's structures), the
    sampled plant is a zero-order-hold sampled lead-lag
    ``k (T0 s + 1)/(tau0 s + 1) e^{-nk Ts s}`` with ``tau0 = -Ts/ln a``, ``k`` the
    static gain and ``T0 = tau0 g b0 / k`` (its first sample is the high-frequency gain
    ``k T0/tau0``). The lead-lag is then simplified as Skogestad (2003) does:

    * ``b1 = 0``: the sampled first-order lag with delay ``(nk - 1) Ts``, exactly;
    * ``T0 >= tau0`` (the heater: the power jumps to ``g`` and then sags slowly):
      ``(T0 s + 1)/(tau0 s + 1) ~ T0/tau0``, a gain ``g b0`` with dead time ``nk Ts``;
    * ``0 <= T0 < tau0``: ``1/((tau0 - T0) s + 1)`` with dead time ``nk Ts - T0``
      (floored at zero before the hold is added);
    * ``T0 < 0`` (inverse response): the zero's time constant adds to the dead time.

    The hold of the sampled loop adds ``Ts/2`` to the dead time (Skogestad 2003, the
    sampling rule), so the rule tunes on the loop as sampled, not on an ideal process.

    Parameters
    ----------
    plant :
        The local plant.

    Raises
    ------
    PIDTuningError
        ``A`` not of first order, ``B`` with more than two coefficients after its delay,
        an unstable or oscillating pole, or a non-positive static gain.
    """
    a = np.asarray(plant.a)
    b = np.trim_zeros(np.asarray(plant.b), "b")
    nk = plant.delay_steps
    ts = plant.ts_s
    tail = b[nk:]
    if a.size != 2 or tail.size > 2:
        raise PIDTuningError(
            f"tuning rule: expected A of order 1 and B with at most two coefficients after "
            f"its delay (the paper's structures); got A {list(a)}, B {list(plant.b)}. "
            "Use --rule ms, which tunes on the sampled model of any order")
    pole = -float(a[1])
    if not 0.0 < pole < 1.0:
        raise PIDTuningError(
            f"tuning rule: expected the pole of A in (0, 1) (a stable, non-oscillating "
            f"lag); got {pole:.6g}")
    k = plant.static_gain_kw_per_pct
    if not k > 0.0:
        raise PIDTuningError(
            f"tuning rule: expected a positive static gain at s = {plant.triac_pct:g} %; "
            f"got {k:.4g} kW/%")
    tau0 = -ts / math.log(pole)
    b0 = float(tail[0])
    b1 = float(tail[1]) if tail.size == 2 else 0.0
    half_hold = ts / 2.0
    if abs(b1) <= _ZERO_COEFFICIENT_RTOL * abs(b0):
        return RulePlant(gain_kw_per_pct=k, tau1_s=tau0, dead_time_s=(nk - 1) * ts + half_hold)
    t0 = tau0 * plant.gain_kw_per_pct * b0 / k
    if t0 >= tau0:
        return RulePlant(gain_kw_per_pct=plant.gain_kw_per_pct * b0, tau1_s=0.0,
                         dead_time_s=nk * ts + half_hold)
    if t0 >= 0.0:
        return RulePlant(gain_kw_per_pct=k, tau1_s=tau0 - t0,
                         dead_time_s=max(nk * ts - t0, 0.0) + half_hold)
    return RulePlant(gain_kw_per_pct=k, tau1_s=tau0, dead_time_s=nk * ts - t0 + half_hold)


__all__ = ["LocalPlant", "RulePlant", "local_plant", "reduce_to_rule_plant"]
