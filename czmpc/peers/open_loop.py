"""Open-loop inversion: the static map inverted, no feedback (the floor every controller must beat).

Same protocol as `czmpc.OffsetFreeMPC`: ``ts_s``, ``step(power_kw, setpoint_kw) ->
triac_pct``, ``reset()`` and ``last_step``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from czmpc.errors import SettingsError
from czmpc.inversion import build_input_map
from czmpc.realization import innovations_form
from czmpc.target import steady_state_map
from sysid.model import HammersteinModel


@dataclass(frozen=True, slots=True, kw_only=True)
class OpenLoopStep:
    """Diagnostics of one open-loop step.

    Parameters
    ----------
    setpoint_kw :
        Setpoint used [kW] (the previous one held when the received one was not finite).
    target_w :
        ``w_s = (r - P_nom) / g`` clipped to the allowed range [kW-equivalent].
    setpoint_reachable :
        False if no allowed input holds the setpoint in steady state.
    triac_pct :
        What `OpenLoopInversion.step` returned [%].
    fallback :
        Always ``"none"``.
    """

    setpoint_kw: float
    target_w: float
    setpoint_reachable: bool
    triac_pct: float
    fallback: str = "none"


class OpenLoopInversion:
    """Feed-forward through the model's steady state, no feedback: the floor.

    The input is the one whose steady-state power on the model equals the setpoint,
    ``s = s_nom + f^-1((r - P_nom) / g)`` with ``g = B(1)/A(1)`` (paper eqs. 27/30 at
    rest), clipped to the model's allowed range and the rate limit. The measured power
    is ignored.

    Parameters
    ----------
    model :
        The identified model (Hammerstein or linear).
    initial_triac_pct :
        Input before the first step [%] (for the rate limit); None: the operating point.
    triac_limits_pct :
        Hard TRIAC limits [%].
    validity_margin_pct :
        Allowed range: the identified input range widened by this margin [%].
    max_move_pct_per_step :
        Largest input change per sample [%], or None.

    Raises
    ------
    DesignError
        No allowed range on the monotone branch of ``f``, or a zero static gain.
    SettingsError
        A non-positive rate limit or a start outside the limits.
    """

    def __init__(
        self,
        model: HammersteinModel,
        *,
        initial_triac_pct: float | None = None,
        triac_limits_pct: tuple[float, float] = (0.0, 100.0),
        validity_margin_pct: float = 5.0,
        max_move_pct_per_step: float | None = None,
    ) -> None:
        self.model = model
        self.ts_s = model.ts_s
        self._s_nom = model.operating_point.triac_pct
        self._p_nom = model.operating_point.power_kw
        self._map = build_input_map(model, triac_min_pct=triac_limits_pct[0],
                                    triac_max_pct=triac_limits_pct[1],
                                    validity_margin_pct=validity_margin_pct)
        self._gain = steady_state_map(innovations_form(model), "output").static_gain
        s0 = self._s_nom if initial_triac_pct is None else float(initial_triac_pct)
        if not triac_limits_pct[0] <= s0 <= triac_limits_pct[1]:
            raise SettingsError(
                f"OpenLoopInversion.initial_triac_pct: expected a value in "
                f"[{triac_limits_pct[0]:g}, {triac_limits_pct[1]:g}] %; got {initial_triac_pct!r}"
            )
        if max_move_pct_per_step is not None and not max_move_pct_per_step > 0:
            raise SettingsError(
                f"OpenLoopInversion.max_move_pct_per_step: expected a number > 0; "
                f"got {max_move_pct_per_step!r}"
            )
        self.initial_triac_pct = s0
        self.max_move_pct_per_step = max_move_pct_per_step
        self.reset()

    @property
    def allowed_triac_range_pct(self) -> tuple[float, float]:
        """``(s_min, s_max)`` the controller keeps its output in [%]."""
        return (self._map.ds_min_pct + self._s_nom, self._map.ds_max_pct + self._s_nom)

    def reset(self) -> None:
        """Forget all state."""
        self._last = self.initial_triac_pct
        self._setpoint_kw = self._p_nom + self._gain * self._map.f(
            min(self._map.ds_max_pct, max(self._map.ds_min_pct, self._last - self._s_nom)))
        self._last_step: OpenLoopStep | None = None

    @property
    def last_step(self) -> OpenLoopStep | None:
        """Diagnostics of the latest `step`, None before the first."""
        return self._last_step

    def step(self, power_kw: float, setpoint_kw: float) -> float:
        """Return the steady-state input for ``setpoint_kw`` [%]; ``power_kw`` is ignored.

        Parameters
        ----------
        power_kw :
            Measured power [kW] (unused: no feedback).
        setpoint_kw :
            Desired power [kW]; a non-finite value holds the previous setpoint.
        """
        if math.isfinite(setpoint_kw):
            self._setpoint_kw = float(setpoint_kw)
        im = self._map
        w_free = (self._setpoint_kw - self._p_nom) / self._gain
        w_s = min(im.w_max, max(im.w_min, w_free))
        s = self._s_nom + im.inverse(w_s)
        if self.max_move_pct_per_step is not None:
            s = min(self._last + self.max_move_pct_per_step,
                    max(self._last - self.max_move_pct_per_step, s))
        lo, hi = self.allowed_triac_range_pct
        s = min(hi, max(lo, s))
        self._last = s
        self._last_step = OpenLoopStep(setpoint_kw=self._setpoint_kw, target_w=w_s,
                                       setpoint_reachable=w_s == w_free, triac_pct=s)
        return s


__all__ = ["OpenLoopInversion", "OpenLoopStep"]
