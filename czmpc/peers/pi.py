"""Gain-scheduled PI with anti-windup: the hand-tuned controller the MPC is compared with.

The rule and the controller are those of `czmpc.pid`: `PIController` is a
`czmpc.pid.controller.ScheduledPID` (velocity form, anti-windup at the TRIAC and rate
limits) whose tuning is one PI, and `PIController.tuned_for` tunes it by
`czmpc.pid.rules.gain_delay_sampled`. What is the peer's own is the continuous schedule:
gain scheduling (the paper's sec. 7.3 suggestion) divides the gain by the instantaneous
gain of the identified nonlinearity at the input last applied::

    K_c(s) = K_c0 f'(ds_0) / f'(ds),   ds = s - s_nom clipped to the model's valid range

so the loop gain at the heater's instantaneous response, ``K_c f'``, stays constant. A new
gain acts only on changes of the error (``bumpless=True`` of `ScheduledPID`, the law a
``czmpc tune-pid`` table runs), so the input does not step when the gain changes; the
benchmark's recorded results (tests/golden) were re-recorded with it. With the default
``lambda`` the integral time is one sampling time: at a fixed gain this forward-Euler PI
is the integral-only law ``u_k = u_{k-1} + K_c e_k`` (`czmpc.pid.design.SampledIntegral`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from czmpc.errors import SettingsError
from czmpc.inversion import build_input_map, slope
from czmpc.pid.controller import ScheduledPID
from czmpc.pid.rules import GAIN_DELAY_LOOP_GAIN, PIDTuning, gain_delay_sampled
from sysid.model import HammersteinModel

#: Cap on the proportional loop gain at the instantaneous response, ``K_c f'(ds)``
#: (`czmpc.pid.rules.GAIN_DELAY_LOOP_GAIN`).
MAX_INSTANT_LOOP_GAIN = GAIN_DELAY_LOOP_GAIN
#: Default closed-loop time constant ``lambda`` of `PIController.tuned_for` [s]: three
#: samples of 2 s, so ``T_i = lambda beta / (1 + beta) = ts_s``, the fastest integral
#: action the rule allows (measured, shipped model's staircase, seed 1: IAE 299 / 465 /
#: 1012 kW s at 6 / 20 / 60 s, overshoot below 2 % of each 5 kW step for all).
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

    def slope_kw_per_pct(self, triac_pct: float) -> float:
        """``f'(ds)`` at ``s`` clipped to the valid range [kW/%]."""
        lo, hi = self.valid_triac_pct
        s = min(hi, max(lo, triac_pct))
        return slope(self.coefficients, s - self.operating_triac_pct)

    def gain_factor(self, triac_pct: float) -> float:
        """``f'(ds_0) / f'(ds)`` [-] at input ``s`` [%]."""
        return self.slope_kw_per_pct(self.reference_triac_pct) / self.slope_kw_per_pct(triac_pct)


@dataclass(frozen=True, slots=True, kw_only=True)
class _ScaledTuning:
    """The schedule of `PIController`: one PI, its gain scaled by a `GainSchedule`."""

    base: PIDTuning
    gain_schedule: GainSchedule | None

    def tuning_at(self, triac_pct: float) -> PIDTuning:
        if self.gain_schedule is None:
            return self.base
        return self.base.scaled(self.gain_schedule.gain_factor(triac_pct))


class PIController(ScheduledPID):
    """PI control of heater power with TRIAC limits, anti-windup and optional gain
    scheduling on ``f'`` (module notes).

    Parameters
    ----------
    gain_pct_per_kw :
        Proportional gain ``K_c`` [%/kW], > 0 (``K_c0`` at the schedule's reference input).
    integral_time_s :
        Integral time ``T_i`` [s], > 0.
    ts_s :
        Sampling time [s].
    initial_triac_pct :
        Input at start [%] (the controller starts at rest there).
    triac_limits_pct :
        ``(min, max)`` input [%].
    max_move_pct_per_step :
        Largest input change per sample [%], or None.
    gain_schedule :
        Scale ``K_c`` by `GainSchedule.gain_factor` of the input last applied; None: fixed.

    Raises
    ------
    PIDTuningError
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
        gain_schedule: GainSchedule | None = None,
    ) -> None:
        base = PIDTuning(kc_pct_per_kw=gain_pct_per_kw, ti_s=integral_time_s)
        super().__init__(schedule=_ScaledTuning(base=base, gain_schedule=gain_schedule),
                         ts_s=ts_s, initial_triac_pct=initial_triac_pct,
                         triac_limits_pct=triac_limits_pct,
                         max_move_pct_per_step=max_move_pct_per_step, bumpless=True)
        self.gain_pct_per_kw = base.kc_pct_per_kw
        self.integral_time_s = base.ti_s
        self.gain_schedule = gain_schedule

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

        The paper's heater answers a step in ``s`` at once with ``f'(ds)`` (Table 3) and
        then drifts only by the factor ``B(1)/A(1)`` (about 0.9), so it is tuned as a
        gain ``g = f'(ds_0)`` with one sample of delay by
        `czmpc.pid.rules.gain_delay_sampled` (``K_c = beta/g``,
        ``T_i = lambda beta/(1 + beta)``, ``beta = MAX_INSTANT_LOOP_GAIN``: a gain margin
        of 2). With ``gain_scheduled`` the gain follows ``f'`` (module notes), so the
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
            schedule = GainSchedule(coefficients=input_map.coefficients,
                                    operating_triac_pct=s_nom,
                                    reference_triac_pct=min(hi, max(lo, s0)),
                                    valid_triac_pct=(lo, hi))
            g = schedule.slope_kw_per_pct(s0)
        else:
            g = slope(coefficients, s0 - s_nom)
        if not g > 0.0:
            raise SettingsError(
                f"PIController.tuned_for: expected f'(ds_0) > 0 at s_0 = {s0:g} %; got {g:.4g}"
            )
        tuning = gain_delay_sampled(g, lambda_s=closed_loop_time_constant_s,
                                    loop_gain=MAX_INSTANT_LOOP_GAIN)
        return cls(gain_pct_per_kw=tuning.kc_pct_per_kw, integral_time_s=tuning.ti_s,
                   ts_s=model.ts_s, initial_triac_pct=s0, triac_limits_pct=triac_limits_pct,
                   max_move_pct_per_step=max_move_pct_per_step, gain_schedule=schedule)


__all__ = [
    "DEFAULT_PI_TIME_CONSTANT_S",
    "MAX_INSTANT_LOOP_GAIN",
    "GainSchedule",
    "PIController",
]
