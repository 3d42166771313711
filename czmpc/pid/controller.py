"""The scheduled PID that runs: velocity form, bumpless gain changes, anti-windup at limits.

`ScheduledPID` satisfies the controller protocol of `sim.protocols.Controller`
(``ts_s``, ``step(power_kw, setpoint_kw) -> triac_pct``, ``reset()``, ``last_step``), so
`sim.loop`, ``czmpc simulate``, campaigns and regression suites run it like the MPC.
`czmpc.pid.discretization.controller_frequency_response` (``form="forward"``) is the same
law as a transfer function, for the margins.

Notation
--------
``y_k`` measured power [kW], ``r_k`` setpoint [kW], ``u_k`` TRIAC input [%],
``e_k = r_k - y_k``, ``p_k = b r_k - y_k``; ``Kc, Ti, Td, Tf, b`` of the tuning in force
at step ``k`` (`PIDTuning`, chosen by the schedule from ``u_{k-1}``)::

    d_k  = (Tf d_{k-1} - Td (y_k - y_{k-1})) / (Tf + Ts)       (filtered -Td dy/dt)
    du_k = Kc_k (p_k - p_{k-1} + d_k - d_{k-1}) + (Kc Ts/Ti)_{k-1} e_{k-1}
    u_k  = sat(u_{k-1} + du_k)                                  (TRIAC and rate limits)

The integral is forward Euler. Because the gain multiplies only the *change* of the
proportional and derivative terms, a new row of the schedule takes over without a step
in the input, and because ``u_{k-1}`` is the value the limits allowed, the integral
cannot wind up at the TRIAC or rate limits. As a transfer function from ``-y`` to ``u``::

    C(z) = Kc [1 + (Ts/Ti) z^-1/(1 - z^-1) + Td (1 - z^-1)/(Tf + Ts - Tf z^-1)]
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Protocol

from czmpc.pid.errors import PIDTuningError
from czmpc.pid.rules import PIDTuning
from czmpc.voltage import VoltageCharacterizer, VoltageDeadband


class TuningSchedule(Protocol):
    """Which tuning is in force when the last applied input was ``triac_pct``."""

    def tuning_at(self, triac_pct: float) -> PIDTuning:
        """The tuning for the last applied TRIAC input [%]."""


@dataclass(frozen=True, slots=True, kw_only=True)
class TableSchedule:
    """Piecewise-constant schedule: row ``i`` holds from ``breakpoints_pct[i]`` to the next.

    Below the first breakpoint the first row holds.

    Parameters
    ----------
    breakpoints_pct :
        Strictly increasing TRIAC inputs [%] where each row starts.
    tunings :
        One tuning per breakpoint.

    Raises
    ------
    PIDTuningError
        Empty, unsorted or of different lengths.
    """

    breakpoints_pct: tuple[float, ...]
    tunings: tuple[PIDTuning, ...]

    def __post_init__(self) -> None:
        n = len(self.breakpoints_pct)
        if n == 0 or n != len(self.tunings):
            raise PIDTuningError(
                f"TableSchedule: expected one tuning per breakpoint, at least one; got "
                f"{n} breakpoints and {len(self.tunings)} tunings")
        if any(not b < c for b, c in zip(self.breakpoints_pct, self.breakpoints_pct[1:],
                                          strict=False)):
            raise PIDTuningError(
                f"TableSchedule.breakpoints_pct: expected strictly increasing inputs [%]; "
                f"got {list(self.breakpoints_pct)}")

    def row_at(self, triac_pct: float) -> int:
        """Index of the row in force at ``triac_pct`` [%]."""
        return max(0, bisect.bisect_right(self.breakpoints_pct, triac_pct) - 1)

    def tuning_at(self, triac_pct: float) -> PIDTuning:
        """The tuning of the row in force at ``triac_pct`` [%]."""
        return self.tunings[self.row_at(triac_pct)]


@dataclass(frozen=True, slots=True, kw_only=True)
class PIDStep:
    """Diagnostics of one step of `ScheduledPID`.

    Parameters
    ----------
    measurement_used :
        False when the power or setpoint was missing (not finite): the input was held.
    error_kw :
        ``r - y`` [kW] (NaN when missing).
    gain_pct_per_kw :
        ``Kc`` in force [%/kW].
    integral_time_s :
        ``Ti`` in force [s].
    unsaturated_pct :
        ``u_{k-1} + du_k`` before the limits [%].
    triac_pct :
        What `ScheduledPID.step` returned [%].
    saturated :
        True when a TRIAC or rate limit changed the input.
    fallback :
        Always ``"none"``: the PID never falls back (the field the metrics count).
    """

    measurement_used: bool
    error_kw: float
    gain_pct_per_kw: float
    integral_time_s: float
    unsaturated_pct: float
    triac_pct: float
    saturated: bool
    fallback: str = "none"


class ScheduledPID:
    """Gain-scheduled PID in velocity form with TRIAC and rate limits (module notes).

    Parameters
    ----------
    schedule :
        Gives the tuning for the last applied input (`TableSchedule` or any
        `TuningSchedule`).
    ts_s :
        Sampling time [s], > 0.
    initial_triac_pct :
        Input at start [%]; the controller starts as if at rest there with zero error.
    triac_limits_pct :
        ``(min, max)`` input [%].
    max_move_pct_per_step :
        Largest input change per sample [%], or None.
    bumpless :
        True (default): a gain change acts only on changes of the error (module notes).
        False: the new gain acts on the whole proportional term, ``Kc_k p_k - Kc_{k-1}
        p_{k-1}``, the law the ``pi_gs`` benchmark peer ran before issue 41 (it now runs bumpless).
    voltage_characterizer :
        With a measured grid voltage (`step`'s ``grid_voltage_factor``), the law's output
        is the input meant at nominal voltage and this maps it to the TRIAC input that
        gives the same drive (`czmpc.voltage.VoltageCharacterizer`: divides the drive by
        ``v^2``, as a DCS's characterizer would); limits act on the applied input.
        None: the voltage is ignored.

    Raises
    ------
    PIDTuningError
        A non-positive ``ts_s``, inverted limits, a start outside them, a non-positive
        rate limit.
    """

    def __init__(
        self,
        *,
        schedule: TuningSchedule,
        ts_s: float,
        initial_triac_pct: float,
        triac_limits_pct: tuple[float, float] = (0.0, 100.0),
        max_move_pct_per_step: float | None = None,
        bumpless: bool = True,
        voltage_characterizer: VoltageCharacterizer | None = None,
    ) -> None:
        if not (math.isfinite(ts_s) and ts_s > 0):
            raise PIDTuningError(f"ScheduledPID.ts_s: expected a time > 0 [s]; got {ts_s!r}")
        lo, hi = (float(v) for v in triac_limits_pct)
        if not lo < hi:
            raise PIDTuningError(
                f"ScheduledPID.triac_limits_pct: expected min < max [%]; got {triac_limits_pct!r}")
        if not lo <= initial_triac_pct <= hi:
            raise PIDTuningError(
                f"ScheduledPID.initial_triac_pct: expected a value in [{lo:g}, {hi:g}] %; "
                f"got {initial_triac_pct!r}")
        if max_move_pct_per_step is not None and not max_move_pct_per_step > 0:
            raise PIDTuningError(
                f"ScheduledPID.max_move_pct_per_step: expected a number > 0 [%]; "
                f"got {max_move_pct_per_step!r}")
        self.schedule = schedule
        self.ts_s = float(ts_s)
        self.initial_triac_pct = float(initial_triac_pct)
        self.triac_limits_pct = (lo, hi)
        self.max_move_pct_per_step = max_move_pct_per_step
        self.bumpless = bumpless
        self.voltage_characterizer = voltage_characterizer
        self.reset()

    def reset(self) -> None:
        """Forget all state: at rest at ``initial_triac_pct`` with zero error."""
        self._last = self.initial_triac_pct   # the law's last output, at nominal voltage [%]
        self._applied = self.initial_triac_pct  # the TRIAC input last returned [%]
        self._p_prev = 0.0            # b r - y of the previous step [kW]
        self._d_prev = 0.0            # filtered -Td dy/dt of the previous step [kW]
        self._y_prev = math.nan       # previous measurement [kW]; NaN before the first
        self._integral_move = 0.0     # (Kc Ts/Ti e) of the previous step [%]
        self._kc_prev: float | None = None
        self._voltage = VoltageDeadband()
        self._last_step: PIDStep | None = None

    @property
    def last_step(self) -> PIDStep | None:
        """Diagnostics of the latest `step`, None before the first."""
        return self._last_step

    def step(self, power_kw: float, setpoint_kw: float, *,
             setpoint_preview_kw: object = None,
             grid_voltage_factor: float | None = None) -> float:
        """Return the TRIAC input [%] for this sample; a missing sample holds the input.

        Parameters
        ----------
        power_kw :
            Measured power [kW]; NaN (or inf) marks a missing sample.
        setpoint_kw :
            Desired power [kW]; a non-finite value holds the input.
        setpoint_preview_kw :
            Setpoints of the coming samples: a PID has no use for them (ignored).
        grid_voltage_factor :
            Grid voltage relative to nominal [-] measured over the last sample, used
            through ``voltage_characterizer`` and `czmpc.voltage.VoltageDeadband`, as the
            MPC uses it; None, missing or implausible: 1.
        """
        tuning = self.schedule.tuning_at(self._last)
        kc = tuning.kc_pct_per_kw
        volt = (1.0 if self.voltage_characterizer is None
                else self._voltage.take(grid_voltage_factor)[0])
        if not (math.isfinite(power_kw) and math.isfinite(setpoint_kw)):
            self._last_step = PIDStep(measurement_used=False, error_kw=math.nan,
                                      gain_pct_per_kw=kc, integral_time_s=tuning.ti_s,
                                      unsaturated_pct=self._applied, triac_pct=self._applied,
                                      saturated=False)
            return self._applied
        error = setpoint_kw - power_kw
        p = tuning.setpoint_weight * setpoint_kw - power_kw
        d = 0.0
        if tuning.td_s > 0 and math.isfinite(self._y_prev):
            d = ((tuning.td_filter_s * self._d_prev - tuning.td_s * (power_kw - self._y_prev))
                 / (tuning.td_filter_s + self.ts_s))
        kc_prev = kc if self._kc_prev is None else self._kc_prev
        if self.bumpless:
            move = kc * (p - self._p_prev + d - self._d_prev) + self._integral_move
        else:
            move = kc * (p + d) - kc_prev * (self._p_prev + self._d_prev) + self._integral_move
        v = self._last + move
        characterizer = self.voltage_characterizer
        if characterizer is not None and volt != 1.0:
            v = characterizer.applied_pct(v, volt)
        lo, hi = self.triac_limits_pct
        if self.max_move_pct_per_step is not None:
            lo = max(lo, self._applied - self.max_move_pct_per_step)
            hi = min(hi, self._applied + self.max_move_pct_per_step)
        u = lo if v < lo else hi if v > hi else v
        self._integral_move = kc * self.ts_s / tuning.ti_s * error
        self._p_prev, self._d_prev, self._y_prev, self._kc_prev = p, d, power_kw, kc
        self._applied = u
        # The law goes on from what the limits allowed, at nominal voltage: no windup.
        self._last = (characterizer.nominal_pct(u, volt)
                      if characterizer is not None and volt != 1.0 else u)
        self._last_step = PIDStep(measurement_used=True, error_kw=error, gain_pct_per_kw=kc,
                                  integral_time_s=tuning.ti_s, unsaturated_pct=v, triac_pct=u,
                                  saturated=u != v)
        return u


__all__ = ["PIDStep", "ScheduledPID", "TableSchedule", "TuningSchedule"]
