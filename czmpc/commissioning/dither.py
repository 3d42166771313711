"""A designed dither on the MPC's input for closed-loop identification (`czmpc run --dither-pct`).

Where: on the INPUT, added to the MPC's command, not on the setpoint: a setpoint dither
reaches the TRIAC only filtered by the MPC's move penalty and terminal dynamics, with an
amplitude unknown in advance; an input dither is the excitation itself, of amplitude
``A`` [%] in the unit of the test band and independent of the plant noise, which makes
closed-loop data informative for the direct prediction-error method (Ljung, System
Identification, 2nd ed., sec. 13.4). The MPC is told the input actually applied every
step (``applied_triac_pct``), so its estimator treats the dither as a known input.

The dither is generalized binary noise of levels ``+A`` and ``-A`` (zero mean) whose
mean switching time is the model's dominant time constant (the same rule as
`sysid.design`: Tulleken 1990), seeded. The dithered input stays inside the MPC's
input limits and within its rate limit of the previous applied input. In OFF and
PREDICT nothing is added (the operator drives the TRIAC).
"""

from __future__ import annotations

import math

import numpy as np

from czmpc.controller import OffsetFreeMPC
from czmpc.errors import SettingsError
from czmpc.modes import Mode
from czmpc.runtime.loop import MPCDriver
from sysid.model import HammersteinModel
from sysid.polynomials import slowest_time_constant_samples

#: Largest dither amplitude [%] accepted: a dither is small by design; larger
#: excitation is an open-loop test (`czmpc run --test`).
MAX_DITHER_PCT = 10.0


def dominant_time_constant_s(model: HammersteinModel) -> float:
    """Time constant [s] of the model's slowest stable real-magnitude pole: ``-ts / ln|z|``.

    Raises
    ------
    SettingsError
        If the model has no stable pole with ``0 < |z| < 1`` (no time constant to use).
    """
    tau_s = model.ts_s * slowest_time_constant_samples(model.a)   # a model's A is stable
    if tau_s == 0.0:
        raise SettingsError("the model has no stable pole that gives a time constant for the dither")
    return tau_s


class DitheredMPC(MPCDriver):
    """The MPC with a GBN dither of ``±amplitude_pct`` on its input (module docstring).

    Parameters
    ----------
    mpc :
        The controller.
    amplitude_pct :
        Dither amplitude ``A`` [%], ``0 < A <= MAX_DITHER_PCT``.
    switch_time_s :
        Mean switching time of the GBN [s] (default rule: `dominant_time_constant_s`).
    rng :
        Seed or generator of the switching.
    """

    def __init__(self, mpc: OffsetFreeMPC, *, amplitude_pct: float, switch_time_s: float,
                 rng: np.random.Generator | int | None = None) -> None:
        if not (math.isfinite(amplitude_pct) and 0.0 < amplitude_pct <= MAX_DITHER_PCT):
            raise SettingsError(f"dither amplitude: expected 0 < A <= {MAX_DITHER_PCT:g} %; "
                                f"got {amplitude_pct!r}")
        if not (math.isfinite(switch_time_s) and switch_time_s > 0.0):
            raise SettingsError(f"dither switching time: expected > 0 s; got {switch_time_s!r}")
        super().__init__(mpc)
        self.amplitude_pct = float(amplitude_pct)
        self.switch_time_s = float(switch_time_s)
        self.switch_probability = min(0.5, mpc.model.ts_s / self.switch_time_s)
        self._rng = np.random.default_rng(rng)
        self._sign = 1.0
        self._last = math.nan
        #: Dither actually added at the last step [%] (after the limits).
        self.last_dither_pct = 0.0

    def step(self, power_kw: float, setpoint_kw: float, *,
             applied_triac_pct: float | None = None, setpoint_preview_kw: object = None,
             grid_voltage_factor: float | None = None) -> float:
        """One MPC step plus the dither (ON only); the MPC learns the applied input, and
        is given the setpoint preview and the grid voltage (`OffsetFreeMPC.step`)."""
        applied = applied_triac_pct
        if (applied is None or not math.isfinite(applied)) and self.mpc.mode is Mode.ON \
                and math.isfinite(self._last):
            applied = self._last
        u = self.mpc.step(power_kw, setpoint_kw, applied_triac_pct=applied,
                          setpoint_preview_kw=setpoint_preview_kw,
                          grid_voltage_factor=grid_voltage_factor)
        if self.mpc.mode is not Mode.ON:
            self._last = math.nan
            self.last_dither_pct = 0.0
            return u
        if self._rng.random() < self.switch_probability:
            self._sign = -self._sign
        v = u + self._sign * self.amplitude_pct
        rate = self.rate_limit_pct_per_step
        ref = applied if applied is not None and math.isfinite(applied) else u
        if rate is not None:
            v = min(ref + rate, max(ref - rate, v))
        lo, hi = self.mpc.triac_limits_pct
        v = min(hi, max(lo, v))
        self.last_dither_pct = v - u
        self._last = v
        return v

    def provenance(self, seed: int | None) -> dict[str, object]:
        """What the run log's ``<log>.meta.json`` records about the dither."""
        return {"kind": "closed-loop run with input dither", "closed_loop": True,
                "dither": {"where": "input", "amplitude_pct": self.amplitude_pct,
                           "signal": "GBN", "switch_time_s": self.switch_time_s,
                           "switch_probability": self.switch_probability, "seed": seed}}


__all__ = ["MAX_DITHER_PCT", "DitheredMPC", "dominant_time_constant_s"]
