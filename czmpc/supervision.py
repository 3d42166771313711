"""Setpoint shaping and limit ramps: what surrounds the MPC, not the MPC.

`SetpointShaper` checks each received setpoint (a rejected one holds the last valid
one), then moves at most ``ramp * Ts`` per sample and filters with a first-order lag
``alpha = 1 - exp(-Ts / T_f)``. A preview of the coming setpoints goes through the same
check, ramp and filter (`SetpointShaper.preview`); it ends at its first rejected entry.

`LimitRamp` keeps the effective TRIAC limits ``ds = s - s_nom`` [%] inside the
`InputMap`'s range: a tightened limit moves in from the current input at ``ramp * Ts``
per sample (it bites at once, the input never jumps); a widened one applies at once.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from czmpc.errors import SettingsError
from czmpc.inversion import InputMap, clamp
from sysid._typing import FloatArray

#: Largest setpoint magnitude taken [kW]; beyond it a setpoint is rejected like a
#: non-finite one, so 1e308 cannot overflow the ramp and filter.
MAX_SETPOINT_KW = 1e6


class ShapedSetpoint(NamedTuple):
    """What `SetpointShaper.shape` made of one received setpoint."""

    received_kw: float   # as received [kW] (NaN for None)
    used_kw: float       # after hold, ramp and filter [kW]
    verdict: str         # "valid" or why it was rejected (then the last valid one is held)


class ShapedPreview(NamedTuple):
    """What `SetpointShaper.preview` made of the coming setpoints."""

    values_kw: FloatArray  # (L,) shaped setpoints of samples k+1..k+L [kW]
    low_kw: float          # their smallest [kW] (NaN for L = 0)
    high_kw: float         # their largest [kW] (NaN for L = 0)


_NO_PREVIEW = ShapedPreview(np.empty(0), math.nan, math.nan)


class SetpointShaper:
    """Setpoint check, hold, ramp and filter (module notes).

    Parameters
    ----------
    ts_s :
        Sampling time [s].
    ramp_kw_per_s :
        Largest setpoint rate [kW/s]; None for no ramp.
    filter_time_s :
        First-order filter time constant [s]; None for no filter.
    power_min_kw, power_max_kw :
        Plausible setpoint range [kW]; None for no bound.
    """

    def __init__(self, *, ts_s: float, ramp_kw_per_s: float | None, filter_time_s: float | None,
                 power_min_kw: float | None, power_max_kw: float | None) -> None:
        self._alpha = 1.0 if filter_time_s is None else 1.0 - math.exp(-ts_s / filter_time_s)
        self._max_step = None if ramp_kw_per_s is None else ramp_kw_per_s * ts_s
        self._min_kw = power_min_kw
        self._max_kw = power_max_kw
        self.reset(0.0)

    def reset(self, setpoint_kw: float) -> None:
        """Hold ``setpoint_kw`` [kW], with the ramp and filter settled on it."""
        self._held = self._ramped = self._filtered = setpoint_kw

    def verdict(self, setpoint_kw: float | None) -> str:
        """``"valid"`` or why ``setpoint_kw`` is rejected: ``"missing"`` (None), ``"not
        finite"``, ``"below power_min_kw"``, ``"beyond MAX_SETPOINT_KW"``, ``"above
        power_max_kw"``."""
        if setpoint_kw is None:
            return "missing"
        if not math.isfinite(setpoint_kw):
            return "not finite"
        if self._min_kw is not None and setpoint_kw < self._min_kw:
            return "below power_min_kw"
        if abs(setpoint_kw) > MAX_SETPOINT_KW:
            return "beyond MAX_SETPOINT_KW"
        if self._max_kw is not None and setpoint_kw > self._max_kw:
            return "above power_max_kw"
        return "valid"

    def shape(self, setpoint_kw: float | None) -> ShapedSetpoint:
        """Take one received setpoint [kW]; return it, the setpoint to use, and the verdict."""
        received = math.nan if setpoint_kw is None else float(setpoint_kw)
        verdict = self.verdict(None if setpoint_kw is None else received)
        if verdict == "valid":
            self._held = received
        ramped = self._held
        if self._max_step is not None:
            delta = ramped - self._ramped
            ramped = self._ramped + clamp(delta, -self._max_step, self._max_step)
        self._ramped = ramped
        self._filtered += self._alpha * (ramped - self._filtered)
        # tuple.__new__ skips the NamedTuple's Python-level __new__ (once per step, issue 30).
        return tuple.__new__(ShapedSetpoint, (received, self._filtered, verdict))

    def preview(self, setpoints_kw: object, max_samples: int) -> ShapedPreview:
        """The setpoints to use over the coming samples, shaped as `shape` would shape them.

        Parameters
        ----------
        setpoints_kw :
            Setpoints [kW] of the samples after the one `shape` took last, in order (any
            1-d sequence). The known part ends at the first entry `verdict` rejects (or
            one that is not a number at all).
        max_samples :
            How many are wanted at most (the horizon).

        Returns
        -------
        ShapedPreview
            ``L`` shaped setpoints [kW], ``0 <= L <= max_samples``, from the state `shape`
            left (its own state is not changed), and their extremes.
        """
        try:
            raw = np.asarray(setpoints_kw, dtype=float)
        except (TypeError, ValueError):
            return _NO_PREVIEW
        if raw.ndim != 1:
            raw = raw.ravel()
        raw = raw[:max_samples]
        if not raw.size:
            return _NO_PREVIEW
        low, high = raw.min(), raw.max()   # NaN if any is
        lo_ok = -MAX_SETPOINT_KW if self._min_kw is None else max(self._min_kw, -MAX_SETPOINT_KW)
        hi_ok = MAX_SETPOINT_KW if self._max_kw is None else min(self._max_kw, MAX_SETPOINT_KW)
        if not (lo_ok <= low and high <= hi_ok):   # cut at the first rejected entry
            ok = (raw >= lo_ok) & (raw <= hi_ok)   # False for NaN
            raw = raw[: int(np.argmin(ok))]
            if not raw.size:
                return _NO_PREVIEW
            low, high = raw.min(), raw.max()
        if self._max_step is not None or self._alpha != 1.0:
            out = np.empty(raw.size)
            ramped, filtered = self._ramped, self._filtered
            for i, target in enumerate(raw.tolist()):
                if self._max_step is not None:
                    ramped += clamp(target - ramped, -self._max_step, self._max_step)
                else:
                    ramped = target
                filtered += self._alpha * (ramped - filtered)
                out[i] = filtered
            raw, low, high = out, out.min(), out.max()
        return tuple.__new__(ShapedPreview, (raw, float(low), float(high)))


class LimitRamp:
    """Effective TRIAC limits that move in at a ramp (module notes).

    Parameters
    ----------
    input_map :
        ``f`` on the allowed range: the widest limits.
    ramp_pct_per_step :
        How far a tightened limit moves per sample [%].

    Attributes
    ----------
    lo, hi :
        Effective limits now [%, deviation].
    triac_pct :
        Effective ``(min, max)`` TRIAC limits now [%].
    map :
        ``input_map`` restricted to ``[lo, hi]`` (the same object when not restricted).
    """

    def __init__(self, input_map: InputMap, *, ramp_pct_per_step: float) -> None:
        self._full = input_map
        self._step = ramp_pct_per_step
        self.reset()

    def reset(self) -> None:
        """Back to the allowed range."""
        im = self._full
        self._lo_goal = im.ds_min_pct
        self._hi_goal = im.ds_max_pct
        self._move(im.ds_min_pct, im.ds_max_pct)

    def set(self, triac_min_pct: float, triac_max_pct: float, *, ds_now_pct: float) -> None:
        """New limits [%], intersected with the allowed range; ``ds_now_pct`` the input now.

        Raises
        ------
        SettingsError
            Non-finite or inverted limits, or none of the allowed range left.
        """
        lo_pct, hi_pct = float(triac_min_pct), float(triac_max_pct)
        if not (math.isfinite(lo_pct) and math.isfinite(hi_pct) and lo_pct < hi_pct):
            raise SettingsError(
                f"OffsetFreeMPC.set_triac_limits: expected finite min < max [%]; got "
                f"({triac_min_pct!r}, {triac_max_pct!r})"
            )
        im = self._full
        s_nom = im.operating_triac_pct
        lo = max(im.ds_min_pct, lo_pct - s_nom)
        hi = min(im.ds_max_pct, hi_pct - s_nom)
        if not lo < hi:
            raise SettingsError(
                f"OffsetFreeMPC.set_triac_limits: expected limits overlapping the allowed "
                f"range [{im.ds_min_pct + s_nom:g}, {im.ds_max_pct + s_nom:g}] %; got "
                f"({lo_pct:g}, {hi_pct:g})"
            )
        self._lo_goal, self._hi_goal = lo, hi
        self._move(lo if lo <= self.lo else clamp(ds_now_pct, self.lo, lo),
                   hi if hi >= self.hi else max(hi, min(self.hi, ds_now_pct)))

    def ramp(self) -> None:
        """One sample: move tightened limits towards their goals."""
        if self.lo != self._lo_goal or self.hi != self._hi_goal:
            lo = min(self._lo_goal, self.lo + self._step) if self.lo < self._lo_goal else self._lo_goal
            hi = max(self._hi_goal, self.hi - self._step) if self.hi > self._hi_goal else self._hi_goal
            self._move(lo, hi)

    def _move(self, lo: float, hi: float) -> None:
        im = self._full
        self.lo, self.hi = lo, hi
        self.triac_pct = (lo + im.operating_triac_pct, hi + im.operating_triac_pct)
        if lo == im.ds_min_pct and hi == im.ds_max_pct:
            self.map = im
        else:
            self.map = replace(im, ds_min_pct=lo, ds_max_pct=hi, w_min=im.f(lo), w_max=im.f(hi))


__all__ = ["MAX_SETPOINT_KW", "LimitRamp", "SetpointShaper", "ShapedPreview", "ShapedSetpoint"]
