"""Measurement validity: limit, rate, stuck and spike checks of the measured power.

A measured power ``P_k`` [kW] is fed to the estimator only if it passes, in this order:

1. **missing**: finite (NaN or inf marks a missing sample);
2. **limits**: ``power_min_kw <= P_k <= power_max_kw`` (negative power, or more than
   the heater's rating, is a sensor fault);
3. **rate**: ``|P_k - P_last| <= max_change_kw`` with ``P_last`` the last accepted value;
4. **stuck**: not the exact same value for ``stuck_samples`` samples while the model's
   prediction moved by at least ``stuck_min_predicted_change_kw`` (the sensor quantizes
   to 1 W with 13 W noise: a repeated value while the input moves is frozen; at a
   constant input the prediction does not move, so a quiet signal never trips);
5. **spike**: ``|eps_k| <= max(k_sigma * std(eps_k), gate_floor_kw)``, ``std(eps_k)`` the
   predicted innovation std, which widens while samples are missed.

Checks 3 and 5 re-open after ``reopen_after`` consecutive rejections: the next value is
accepted as a level change (the spike gate stays open until the innovation is back
inside), so the estimator stays offset-free. Limit and stuck rejections never re-open.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass


class Verdict(enum.Enum):
    """Outcome of the validity checks for one sample."""

    VALID = "valid"
    MISSING = "missing"
    BELOW_LIMIT = "below_limit"
    ABOVE_LIMIT = "above_limit"
    TOO_FAST = "too_fast"
    STUCK = "stuck"
    SPIKE = "spike"


@dataclass(frozen=True, slots=True, kw_only=True)
class MeasurementCheck:
    """Result of `MeasurementChecker.check`.

    Parameters
    ----------
    verdict :
        `Verdict.VALID` or why the sample was rejected.
    reopened :
        True if the sample was accepted only because the rate or spike check re-opened
        after repeated rejections (a level change).
    stuck_run_samples :
        For `Verdict.STUCK`: identical readings in a row, this one included (the first
        was the sensor's last live one).
    """

    verdict: Verdict
    reopened: bool = False
    stuck_run_samples: int = 0

    @property
    def is_valid(self) -> bool:
        """True if the sample may be fed to the estimator."""
        return self.verdict is Verdict.VALID


# The records of an accepted sample, frozen, shared by every step (building one: 0.5 us).
_VALID = MeasurementCheck(verdict=Verdict.VALID)
_VALID_REOPENED = MeasurementCheck(verdict=Verdict.VALID, reopened=True)


def check_limits(power_kw: float, *, power_min_kw: float | None,
                 power_max_kw: float | None) -> Verdict:
    """`Verdict.MISSING` for a non-finite value, else the limit verdict; pure.

    Parameters
    ----------
    power_kw :
        Measured power [kW].
    power_min_kw, power_max_kw :
        Plausible range [kW]; None for no bound.
    """
    if not math.isfinite(power_kw):
        return Verdict.MISSING
    if power_min_kw is not None and power_kw < power_min_kw:
        return Verdict.BELOW_LIMIT
    if power_max_kw is not None and power_kw > power_max_kw:
        return Verdict.ABOVE_LIMIT
    return Verdict.VALID


def within_rate(power_kw: float, last_kw: float | None, *, max_change_kw: float | None) -> bool:
    """True if ``|power_kw - last_kw| <= max_change_kw`` (or no reference or no bound)."""
    if max_change_kw is None or last_kw is None:
        return True
    return abs(power_kw - last_kw) <= max_change_kw


def within_gate(innovation_kw: float, *, innovation_std_kw: float, k_sigma: float,
                floor_kw: float) -> bool:
    """True if ``|eps| <= max(k_sigma * std, floor_kw)``; pure.

    Parameters
    ----------
    innovation_kw :
        ``eps_k = y_k - C z_{k|k-1}`` [kW].
    innovation_std_kw :
        Its predicted standard deviation [kW].
    k_sigma :
        Gate width in standard deviations.
    floor_kw :
        Smallest gate half-width [kW] (covers model mismatch the noise model ignores).
    """
    return abs(innovation_kw) <= max(k_sigma * innovation_std_kw, floor_kw)


class MeasurementChecker:
    """The stateful part of the checks: last accepted value, stuck run, re-opening.

    Parameters
    ----------
    power_min_kw, power_max_kw :
        Plausible measured power range [kW]; None for no bound.
    max_change_kw :
        Largest change per sample from the last accepted value [kW]; None for none.
    stuck_samples :
        Identical readings in a row that count as stuck (with the prediction moving);
        0 disables the check.
    stuck_min_predicted_change_kw :
        How far [kW] the model's prediction must have moved over the identical run.
    gate_k_sigma :
        Spike gate width in predicted innovation standard deviations; None disables.
    gate_floor_kw :
        Smallest spike gate half-width [kW].
    reopen_after :
        Consecutive rate/spike rejections after which the next value is accepted.
    """

    def __init__(
        self, *, power_min_kw: float | None, power_max_kw: float | None,
        max_change_kw: float | None, stuck_samples: int, stuck_min_predicted_change_kw: float,
        gate_k_sigma: float | None, gate_floor_kw: float, reopen_after: int,
    ) -> None:
        self.power_min_kw = power_min_kw
        self.power_max_kw = power_max_kw
        self.max_change_kw = max_change_kw
        self.stuck_samples = stuck_samples
        self.stuck_min_predicted_change_kw = stuck_min_predicted_change_kw
        self.gate_k_sigma = gate_k_sigma
        self.gate_floor_kw = gate_floor_kw
        self.reopen_after = reopen_after
        # Strictly between these a sample is finite and within the limits (check's fast path).
        self._inside_min = -math.inf if power_min_kw is None else power_min_kw
        self._inside_max = math.inf if power_max_kw is None else power_max_kw
        self.reset()

    def reset(self) -> None:
        """Forget the history."""
        self._last_accepted: float | None = None
        self._run_value = math.nan
        self._run_length = 0
        self._run_pred_min = math.inf
        self._run_pred_max = -math.inf
        self._n_rejected = 0
        self._gate_open = False

    @property
    def consecutive_rejections(self) -> int:
        """Rate/spike rejections in a row (0 after an accepted sample)."""
        return self._n_rejected

    def _stuck(self, power_kw: float, predicted_kw: float) -> bool:
        if power_kw == self._run_value:
            self._run_length += 1
        else:
            self._run_value = power_kw
            self._run_length = 1
            self._run_pred_min = math.inf
            self._run_pred_max = -math.inf
        if math.isfinite(predicted_kw):  # min() and max() by comparison: no calls
            if predicted_kw < self._run_pred_min:
                self._run_pred_min = predicted_kw
            if predicted_kw > self._run_pred_max:
                self._run_pred_max = predicted_kw
        return (
            self.stuck_samples > 0
            and self._run_length >= self.stuck_samples
            and self._run_pred_max - self._run_pred_min >= self.stuck_min_predicted_change_kw
        )

    def check(self, power_kw: float, *, predicted_kw: float, innovation_std_kw: float,
              gate: bool = True) -> MeasurementCheck:
        """Check one sample and update the history.

        Parameters
        ----------
        power_kw :
            Measured power [kW] (any float).
        predicted_kw :
            The estimator's prediction ``P_nom + C z_{k|k-1}`` [kW].
        innovation_std_kw :
            Predicted innovation std [kW] for the spike gate.
        gate :
            False skips the spike gate (estimator warm-up after a restart).
        """
        if not self._inside_min < power_kw < self._inside_max:  # on a limit, beyond, or not finite
            verdict = check_limits(power_kw, power_min_kw=self.power_min_kw,
                                   power_max_kw=self.power_max_kw)
            if verdict is not Verdict.VALID:
                if verdict is Verdict.MISSING:
                    self._run_length = 0
                    self._run_value = math.nan
                return MeasurementCheck(verdict=verdict)
        if self._stuck(power_kw, predicted_kw):
            return MeasurementCheck(verdict=Verdict.STUCK, stuck_run_samples=self._run_length)
        suspect: Verdict | None = None
        if not within_rate(power_kw, self._last_accepted, max_change_kw=self.max_change_kw):
            suspect = Verdict.TOO_FAST
        elif (gate or self._gate_open) and self.gate_k_sigma is not None:
            inside = within_gate(power_kw - predicted_kw, innovation_std_kw=innovation_std_kw,
                                 k_sigma=self.gate_k_sigma, floor_kw=self.gate_floor_kw)
            if self._gate_open:
                self._gate_open = not inside
            elif not inside:
                suspect = Verdict.SPIKE
        reopened = False
        if suspect is not None:
            if self._n_rejected < self.reopen_after:
                self._n_rejected += 1
                return MeasurementCheck(verdict=suspect)
            reopened = True
            self._gate_open = suspect is Verdict.SPIKE
        self._n_rejected = 0
        self._last_accepted = power_kw
        return _VALID_REOPENED if reopened else _VALID


__all__ = ["MeasurementCheck", "MeasurementChecker", "Verdict", "check_limits", "within_gate", "within_rate"]
