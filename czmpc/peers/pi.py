"""Gain-scheduled PI with anti-windup: the hand-tuned controller the MPC is compared with.

Every controller here has ``ts_s``, ``step(power_kw, setpoint_kw) -> triac_pct``,
``reset()`` and ``last_step`` (diagnostics of the latest step), so `sim.loop` runs them
like the MPC. The nonlinear MPC reference lives in `czmpc.peers.nmpc`; the linear MPC
baseline is `OffsetFreeMPC` on a ``kind = "linear"`` model and needs no code here.

PI notation
-----------
``e_k = r_k - y_k`` [kW]; ``K_c`` [%/kW]; ``T_i`` [s]; ``T_t`` tracking time [s]::

    v_k = I_k + K_c(s_{k-1}) e_k                 (unsaturated input [%])
    u_k = sat(v_k)                               (TRIAC and rate limits)
    I_{k+1} = I_k + K_c(s_{k-1}) ts/T_i e_k + ts/T_t (u_k - v_k)   (back-calculation)

With ``T_t = ts_s`` (the default) the integrator is reset each sample to exactly what
the limits allowed, which removes windup completely (the law is then the velocity form
``u_k = u_{k-1} + K_c,k e_k - K_c,k-1 e_{k-1} (1 - ts/T_i)``, so a changing gain causes
no bump). Gain scheduling (the paper's sec. 7.3 suggestion) divides the gain by the
instantaneous gain of the identified nonlinearity at the input last applied::

    K_c(s) = K_c0 f'(ds_0) / f'(ds),   ds = s - s_nom clipped to the model's valid range

so the loop gain at the heater's instantaneous response, ``K_c f'``, stays constant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from czmpc.errors import SettingsError
from czmpc.inversion import InputMap, build_input_map, slope
from sysid.model import HammersteinModel

#: Cap on the proportional loop gain at the instantaneous response, ``K_c f'(ds)``. With
#: one sample of delay the loop ``y+ = -g K_c y`` oscillates for ``g K_c >= 1``; 0.5
#: leaves a gain margin of 2.
MAX_INSTANT_LOOP_GAIN = 0.5
#: Default closed-loop time constant ``lambda`` of `PIController.tuned_for` [s]: three
#: samples of 2 s, so ``T_i = lambda beta / (1 + beta) = ts_s``, the fastest integral
#: action the rule allows. Measured on the shipped model's staircase (exact model plant,
#: seed 1): IAE 299 kW s at 6 s, 465 at 20 s, 1012 at 60 s, with overshoot below 2 % of
#: each 5 kW step for all of them, so the fastest is the fair choice.
DEFAULT_PI_TIME_CONSTANT_S = 6.0


@dataclass(frozen=True, slots=True, kw_only=True)
class GainSchedule:
    """``K_c(s) = K_c0 f'(ds_0) / f'(ds)`` from an identified input nonlinearity.

    Parameters
    ----------
    coefficients :
        ``(p_1, ..., p_n)`` of ``f(ds)`` [kW per %^i].
    operating_triac_pct :
        ``s_nom`` of the model [%].
    reference_triac_pct :
        ``s_0``, where the nominal gain ``K_c0`` applies [%].
    valid_triac_pct :
        ``(min, max)`` input range where ``f'`` is trusted and positive [%]; inputs
        outside are clipped to it before ``f'`` is evaluated.
    """

    coefficients: tuple[float, ...]
    operating_triac_pct: float
    reference_triac_pct: float
    valid_triac_pct: tuple[float, float]

    def __post_init__(self) -> None:
        lo, hi = self.valid_triac_pct
        if not lo <= self.reference_triac_pct <= hi:
            raise SettingsError(
                f"GainSchedule.reference_triac_pct: expected a value in [{lo:g}, {hi:g}] %; "
                f"got {self.reference_triac_pct!r}"
            )
        for s in (lo, hi, self.reference_triac_pct):
            if not self.slope_kw_per_pct(s) > 0.0:
                raise SettingsError(
                    f"GainSchedule: expected f'(ds) > 0 on the valid range [{lo:g}, {hi:g}] %; "
                    f"got f'({s - self.operating_triac_pct:g}) = "
                    f"{self.slope_kw_per_pct(s):.4g} kW/%"
                )

    @classmethod
    def from_input_map(cls, input_map: InputMap, *, reference_triac_pct: float) -> GainSchedule:
        """Schedule on ``f`` restricted to the allowed range of ``input_map``."""
        s_nom = input_map.operating_triac_pct
        return cls(coefficients=input_map.coefficients, operating_triac_pct=s_nom,
                   reference_triac_pct=reference_triac_pct,
                   valid_triac_pct=(input_map.ds_min_pct + s_nom, input_map.ds_max_pct + s_nom))

    def slope_kw_per_pct(self, triac_pct: float) -> float:
        """``f'(ds)`` at ``s`` clipped to the valid range [kW/%]."""
        lo, hi = self.valid_triac_pct
        s = min(hi, max(lo, triac_pct))
        return slope(self.coefficients, s - self.operating_triac_pct)

    def gain_factor(self, triac_pct: float) -> float:
        """``f'(ds_0) / f'(ds)`` [-] at input ``s`` [%]."""
        return self.slope_kw_per_pct(self.reference_triac_pct) / self.slope_kw_per_pct(triac_pct)


@dataclass(frozen=True, slots=True, kw_only=True)
class PIStep:
    """Diagnostics of one PI step.

    Parameters
    ----------
    measurement_used :
        False when the power sample was missing (NaN or infinite) and the input was held.
    error_kw :
        ``r - y`` [kW] (NaN when the sample was missing).
    gain_pct_per_kw :
        ``K_c`` used in this step [%/kW] (scheduled or fixed).
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
    gain_pct_per_kw: float
    unsaturated_pct: float
    triac_pct: float
    saturated: bool
    fallback: str = "none"


class PIController:
    """PI control of heater power with TRIAC limits, back-calculation anti-windup and
    optional gain scheduling (module notes).

    Parameters
    ----------
    gain_pct_per_kw :
        Proportional gain ``K_c`` [%/kW], > 0 (``K_c0`` at the schedule's reference input).
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
    gain_schedule :
        Scale ``K_c`` by `GainSchedule.gain_factor` of the input last applied; None: fixed.

    Raises
    ------
    SettingsError
        Non-positive gains or times, inverted limits, a start outside the limits.
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
        gain_schedule: GainSchedule | None = None,
    ) -> None:
        tracking = ts_s if tracking_time_s is None else tracking_time_s
        for name, value in (("gain_pct_per_kw", gain_pct_per_kw),
                            ("integral_time_s", integral_time_s), ("ts_s", ts_s),
                            ("tracking_time_s", tracking)):
            if not (math.isfinite(value) and value > 0):
                raise SettingsError(
                    f"PIController.{name}: expected a number > 0; got {value!r}")
        lo, hi = (float(v) for v in triac_limits_pct)
        if not lo < hi:
            raise SettingsError(
                f"PIController.triac_limits_pct: expected min < max [%]; got {triac_limits_pct!r}"
            )
        if not lo <= initial_triac_pct <= hi:
            raise SettingsError(
                f"PIController.initial_triac_pct: expected a value in [{lo:g}, {hi:g}] %; "
                f"got {initial_triac_pct!r}"
            )
        if max_move_pct_per_step is not None and not max_move_pct_per_step > 0:
            raise SettingsError(
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
        self.gain_schedule = gain_schedule
        self._kt = self.ts_s / self.tracking_time_s
        self.reset()

    @classmethod
    def tuned_for(
        cls,
        model: HammersteinModel,
        *,
        closed_loop_time_constant_s: float = DEFAULT_PI_TIME_CONSTANT_S,
        gain_scheduled: bool = False,
        initial_triac_pct: float | None = None,
        triac_limits_pct: tuple[float, float] = (0.0, 100.0),
        max_move_pct_per_step: float | None = None,
        validity_margin_pct: float = 5.0,
    ) -> PIController:
        """Tune on the instantaneous gain ``f'(ds_0)``, which dominates the heater's response.

        Rule (lambda tuning on a gain-plus-delay model): the paper's heater answers a
        step in ``s`` at once with ``f'(ds)`` (Table 3) and then drifts only by the
        factor ``B(1)/A(1)`` (about 0.9). Treating it as the static gain
        ``g = f'(ds_0)`` with one sample of delay, a PI with ``K_c = beta / g`` and
        ``T_i = lambda beta / (1 + beta)`` puts the dominant closed-loop pole at the
        time constant ``lambda`` (from ``z^2 + (beta - 1) z + beta (ts/T_i - 1) = 0``
        near ``z = 1``), and ``beta = MAX_INSTANT_LOOP_GAIN = 0.5`` keeps a gain margin
        of 2. With ``gain_scheduled`` the gain follows ``f'`` (module notes), so the
        margin holds at every input, not only at ``s_0``.

        Parameters
        ----------
        model :
            The model to tune on (Hammerstein or linear).
        closed_loop_time_constant_s :
            ``lambda``: time constant of the dominant closed-loop pole [s], > 0.
        gain_scheduled :
            Schedule ``K_c`` on ``f'`` of the input last applied.
        initial_triac_pct :
            Start input [%], where ``f'`` is taken; None: the operating point.
        triac_limits_pct, max_move_pct_per_step :
            Input limits, as in the constructor.
        validity_margin_pct :
            The schedule trusts ``f'`` on the model's identified input range widened by
            this margin [%] (as `czmpc.settings.MPCSettings.validity_margin_pct`).

        Raises
        ------
        SettingsError
            A non-positive time constant or ``f'(ds_0) <= 0``.
        DesignError
            The schedule's range leaves the monotone branch of ``f``.
        """
        if not (math.isfinite(closed_loop_time_constant_s) and closed_loop_time_constant_s > 0):
            raise SettingsError(
                f"PIController.tuned_for: closed_loop_time_constant_s expected > 0; "
                f"got {closed_loop_time_constant_s!r}"
            )
        s_nom = model.operating_point.triac_pct
        s0 = s_nom if initial_triac_pct is None else float(initial_triac_pct)
        coefficients = tuple(float(v) for v in model.input_poly)
        schedule: GainSchedule | None = None
        if gain_scheduled:
            input_map = build_input_map(model, triac_min_pct=triac_limits_pct[0],
                                        triac_max_pct=triac_limits_pct[1],
                                        validity_margin_pct=validity_margin_pct)
            lo = input_map.ds_min_pct + s_nom
            hi = input_map.ds_max_pct + s_nom
            schedule = GainSchedule.from_input_map(
                input_map, reference_triac_pct=min(hi, max(lo, s0)))
            g = schedule.slope_kw_per_pct(s0)
        else:
            g = slope(coefficients, s0 - s_nom)
        if not g > 0.0:
            raise SettingsError(
                f"PIController.tuned_for: expected f'(ds_0) > 0 at s_0 = {s0:g} %; got {g:.4g}"
            )
        beta = MAX_INSTANT_LOOP_GAIN
        return cls(gain_pct_per_kw=beta / g,
                   integral_time_s=closed_loop_time_constant_s * beta / (1.0 + beta),
                   ts_s=model.ts_s, initial_triac_pct=s0, triac_limits_pct=triac_limits_pct,
                   max_move_pct_per_step=max_move_pct_per_step, gain_schedule=schedule)

    def reset(self) -> None:
        """Forget all state: integrator back at ``initial_triac_pct``."""
        self._integral = self.initial_triac_pct
        self._last = self.initial_triac_pct
        self._last_step: PIStep | None = None

    @property
    def last_step(self) -> PIStep | None:
        """Diagnostics of the latest `step`, None before the first."""
        return self._last_step

    def gain_at(self, triac_pct: float) -> float:
        """``K_c`` [%/kW] the controller uses when ``triac_pct`` was the last input."""
        if self.gain_schedule is None:
            return self.gain_pct_per_kw
        return self.gain_pct_per_kw * self.gain_schedule.gain_factor(triac_pct)

    def step(self, power_kw: float, setpoint_kw: float) -> float:
        """Return the TRIAC input [%] for this sample; a missing ``power_kw`` holds the input.

        Parameters
        ----------
        power_kw :
            Measured power [kW]; NaN (or inf) marks a missing sample.
        setpoint_kw :
            Desired power [kW]; a non-finite value holds the input.
        """
        gain = self.gain_at(self._last)
        if not (math.isfinite(power_kw) and math.isfinite(setpoint_kw)):
            self._last_step = PIStep(measurement_used=False, error_kw=math.nan,
                                     gain_pct_per_kw=gain, unsaturated_pct=self._last,
                                     triac_pct=self._last, saturated=False)
            return self._last
        error = setpoint_kw - power_kw
        v = self._integral + gain * error
        lo, hi = self.triac_limits_pct
        if self.max_move_pct_per_step is not None:
            lo = max(lo, self._last - self.max_move_pct_per_step)
            hi = min(hi, self._last + self.max_move_pct_per_step)
        u = lo if v < lo else hi if v > hi else v
        self._integral += gain * self.ts_s / self.integral_time_s * error + self._kt * (u - v)
        self._last = u
        self._last_step = PIStep(measurement_used=True, error_kw=error, gain_pct_per_kw=gain,
                                 unsaturated_pct=v, triac_pct=u, saturated=u != v)
        return u


__all__ = [
    "DEFAULT_PI_TIME_CONSTANT_S",
    "MAX_INSTANT_LOOP_GAIN",
    "GainSchedule",
    "PIController",
    "PIStep",
]
