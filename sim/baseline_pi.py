"""A PI controller with back-calculation anti-windup, to exercise the loop and metrics.

Only for testing `sim` (closing the loop on `ModelPlant` without the MPC); the
comparison baselines live in `czmpc.baselines`.

Notation
--------
``e_k = r_k - y_k`` [kW]; ``K_c`` [%/kW]; ``T_i`` [s]; ``T_t`` tracking time [s]::

    v_k = I_k + K_c e_k                       (unsaturated input [%])
    u_k = sat(v_k)                            (TRIAC and rate limits)
    I_{k+1} = I_k + K_c ts/T_i e_k + ts/T_t (u_k - v_k)    (back-calculation)

With ``T_t = ts_s`` (the default) the integrator is reset each sample to exactly what
the limits allowed, which removes windup completely.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sim.errors import SimError
from sysid.model import HammersteinModel

#: Cap on the proportional loop gain at the instantaneous response, ``K_c f'(0)``. With
#: one sample of delay the loop ``y+ = -g K_c y`` oscillates for ``g K_c >= 1``; 0.5
#: leaves a gain margin of 2.
MAX_INSTANT_LOOP_GAIN = 0.5


@dataclass(frozen=True, slots=True, kw_only=True)
class PIStep:
    """Diagnostics of one PI step.

    Parameters
    ----------
    measurement_used :
        False when the power sample was missing (NaN) and the input was held.
    error_kw :
        ``r - y`` [kW] (NaN when the sample was missing).
    unsaturated_pct :
        ``v_k`` before the limits [%].
    triac_pct :
        What `PIController.step` returned [%].
    saturated :
        True when a limit changed the input.
    fallback :
        Always ``"none"``: the PI never falls back (the field the metrics count).
    """

    measurement_used: bool
    error_kw: float
    unsaturated_pct: float
    triac_pct: float
    saturated: bool
    fallback: str = "none"


class PIController:
    """PI control of heater power with TRIAC limits and back-calculation anti-windup.

    Parameters
    ----------
    gain_pct_per_kw :
        Proportional gain ``K_c`` [%/kW], > 0.
    integral_time_s :
        Integral time ``T_i`` [s], > 0.
    ts_s :
        Sampling time [s].
    initial_triac_pct :
        Input at start (the integrator's initial value, for a bumpless start) [%].
    triac_limits_pct :
        ``(min, max)`` input [%].
    max_move_pct_per_step :
        Largest input change per sample [%], or None.
    tracking_time_s :
        Anti-windup tracking time ``T_t`` [s]; None: ``ts_s``.

    Raises
    ------
    SimError
        Non-positive gains or times, inverted limits.
    """

    def __init__(
        self,
        *,
        gain_pct_per_kw: float,
        integral_time_s: float,
        ts_s: float,
        initial_triac_pct: float,
        triac_limits_pct: tuple[float, float] = (0.0, 100.0),
        max_move_pct_per_step: float | None = None,
        tracking_time_s: float | None = None,
    ) -> None:
        tracking = ts_s if tracking_time_s is None else tracking_time_s
        for name, value in (("gain_pct_per_kw", gain_pct_per_kw),
                            ("integral_time_s", integral_time_s), ("ts_s", ts_s),
                            ("tracking_time_s", tracking)):
            if not (math.isfinite(value) and value > 0):
                raise SimError(f"PIController.{name}: expected a number > 0; got {value!r}")
        lo, hi = (float(v) for v in triac_limits_pct)
        if not lo < hi:
            raise SimError(
                f"PIController.triac_limits_pct: expected min < max [%]; got {triac_limits_pct!r}"
            )
        if max_move_pct_per_step is not None and not max_move_pct_per_step > 0:
            raise SimError(
                f"PIController.max_move_pct_per_step: expected a number > 0; "
                f"got {max_move_pct_per_step!r}"
            )
        self.gain_pct_per_kw = float(gain_pct_per_kw)
        self.integral_time_s = float(integral_time_s)
        self.ts_s = float(ts_s)
        self.initial_triac_pct = float(initial_triac_pct)
        self.triac_limits_pct = (lo, hi)
        self.max_move_pct_per_step = max_move_pct_per_step
        self.tracking_time_s = float(tracking)
        self._ki = self.gain_pct_per_kw * self.ts_s / self.integral_time_s
        self._kt = self.ts_s / self.tracking_time_s
        self.reset()

    @classmethod
    def tuned_for(
        cls,
        model: HammersteinModel,
        *,
        closed_loop_time_constant_s: float = 60.0,
        initial_triac_pct: float | None = None,
        triac_limits_pct: tuple[float, float] = (0.0, 100.0),
        max_move_pct_per_step: float | None = None,
    ) -> PIController:
        """Tune on the instantaneous gain ``f'(ds_0)``, which dominates the heater's response.

        The paper's heater answers a step in ``s`` at once with ``f'(ds)`` (Table 3) and
        then drifts only by the factor ``B(1)/A(1)`` (about 0.9). Treating it as the static
        gain ``g = f'(ds_0)`` with one sample of delay, a PI with ``K_c = beta / g`` and
        ``T_i = lambda beta / (1 + beta)`` puts the dominant closed-loop pole at the time
        constant ``lambda`` (from ``z^2 + (beta - 1) z + beta (ts/T_i - 1) = 0`` near
        ``z = 1``), and ``beta = MAX_INSTANT_LOOP_GAIN = 0.5`` keeps a gain margin of 2.

        Parameters
        ----------
        model :
            The model to tune on.
        closed_loop_time_constant_s :
            ``lambda``: time constant of the dominant closed-loop pole [s], > 0.
        initial_triac_pct :
            Start input [%], where ``f'`` is taken; None: the operating point.
        triac_limits_pct, max_move_pct_per_step :
            Input limits, as in the constructor.
        """
        s0 = model.operating_point.triac_pct if initial_triac_pct is None else initial_triac_pct
        slope = float(model.input_nonlinearity_slope(s0 - model.operating_point.triac_pct))
        beta = MAX_INSTANT_LOOP_GAIN
        return cls(gain_pct_per_kw=beta / slope,
                   integral_time_s=closed_loop_time_constant_s * beta / (1.0 + beta),
                   ts_s=model.ts_s, initial_triac_pct=s0, triac_limits_pct=triac_limits_pct,
                   max_move_pct_per_step=max_move_pct_per_step)

    def reset(self) -> None:
        """Forget all state: integrator back at ``initial_triac_pct``."""
        self._integral = self.initial_triac_pct
        self._last = self.initial_triac_pct
        self._last_step: PIStep | None = None

    @property
    def last_step(self) -> PIStep | None:
        """Diagnostics of the latest `step`, None before the first."""
        return self._last_step

    def step(self, power_kw: float, setpoint_kw: float) -> float:
        """Return the TRIAC input [%] for this sample; a NaN ``power_kw`` holds the input.

        Parameters
        ----------
        power_kw :
            Measured power [kW]; NaN marks a missing sample.
        setpoint_kw :
            Desired power [kW].
        """
        if math.isnan(power_kw):
            self._last_step = PIStep(measurement_used=False, error_kw=math.nan,
                                     unsaturated_pct=self._last, triac_pct=self._last,
                                     saturated=False)
            return self._last
        error = setpoint_kw - power_kw
        v = self._integral + self.gain_pct_per_kw * error
        lo, hi = self.triac_limits_pct
        if self.max_move_pct_per_step is not None:
            lo = max(lo, self._last - self.max_move_pct_per_step)
            hi = min(hi, self._last + self.max_move_pct_per_step)
        u = lo if v < lo else hi if v > hi else v
        self._integral += self._ki * error + self._kt * (u - v)
        self._last = u
        self._last_step = PIStep(measurement_used=True, error_kw=error, unsaturated_pct=v,
                                 triac_pct=u, saturated=u != v)
        return u


__all__ = ["MAX_INSTANT_LOOP_GAIN", "PIController", "PIStep"]
