"""Robustness margins of a loop from its frequency response: Ms, gain and phase margins.

The loop transfer ``L`` is given as a function of the angular frequency, so the same code
serves a continuous loop ``L(j w)`` and a sampled loop ``L(e^{j w Ts})`` (then up to the
Nyquist frequency ``pi/Ts``). `sampled_margins` builds the sampled loop of a tuning on a
`LocalPlant`: ``C(z)`` of one sampled form of the law (`czmpc.pid.discretization`;
``forward`` is the law `czmpc.pid.controller.ScheduledPID` runs) times ``g B/A`` with its
delay, so the hold and the sample of delay are inside the numbers. `worst_margins` is
the worst over several forms: the largest Ms, the smallest gain and phase margins.

Definitions
-----------
* ``Ms = max_w |1/(1 + L)|`` (the inverse of the shortest distance of the Nyquist curve
  to -1);
* gain crossover ``w_c``: ``|L| = 1``; phase margin ``180 + arg L(j w_c)`` [deg], the
  smallest over all gain crossovers;
* phase crossover ``w_180``: ``arg L = -180 deg`` (``Im L = 0`` with ``Re L < 0``); gain
  margin ``1/|L(j w_180)|``, the smallest over all phase crossovers (inf without one).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from czmpc.pid.discretization import IntegralForm, controller_frequency_response
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.plant import LocalPlant
from czmpc.pid.rules import PIDTuning
from sysid._typing import FloatArray

LoopResponse = Callable[[FloatArray], FloatArray]

#: Points of the logarithmic frequency grid the crossings and the peak are bracketed on.
GRID_POINTS = 3000
#: Relative tolerance of the refined crossing frequencies and of the Ms peak.
FREQUENCY_RTOL = 1e-10
#: Lowest frequency of the sampled grid, as a fraction of the Nyquist frequency.
SAMPLED_LOW_FRACTION = 1e-5


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopMargins:
    """Margins of one loop (module definitions).

    Parameters
    ----------
    ms :
        Peak sensitivity ``Ms`` [-].
    ms_rad_per_s :
        Frequency of that peak [rad/s].
    gain_margin :
        Gain margin [-] (a factor, not dB); inf when the phase never reaches -180 deg.
    phase_margin_deg :
        Phase margin [deg]; NaN when ``|L|`` never crosses 1.
    crossover_rad_per_s :
        Gain crossover frequency of that phase margin [rad/s]; NaN without one.
    phase_crossover_rad_per_s :
        Frequency of that gain margin [rad/s]; NaN without one.
    """

    ms: float
    ms_rad_per_s: float
    gain_margin: float
    phase_margin_deg: float
    crossover_rad_per_s: float
    phase_crossover_rad_per_s: float


def loop_margins(loop: LoopResponse, *, w_min_rad_per_s: float,
                 w_max_rad_per_s: float) -> LoopMargins:
    """Margins of the loop ``loop(w)`` on ``[w_min, w_max]`` (module definitions).

    The crossings are bracketed on a logarithmic grid of `GRID_POINTS` points and refined
    by `scipy.optimize.brentq`; the peak of ``|S|`` is refined around the grid maximum by
    a bounded scalar minimisation. At ``w_max`` (the Nyquist frequency of a sampled loop,
    where ``L`` is real) a negative real ``L`` counts as a phase crossover.

    Parameters
    ----------
    loop :
        ``L`` at an array of angular frequencies [rad/s] (complex, same shape).
    w_min_rad_per_s, w_max_rad_per_s :
        Frequency range [rad/s], ``0 < w_min < w_max``.

    Raises
    ------
    PIDTuningError
        A bad range or a loop that is not finite on it.
    """
    if not 0 < w_min_rad_per_s < w_max_rad_per_s:
        raise PIDTuningError(
            f"loop_margins: expected 0 < w_min < w_max [rad/s]; got "
            f"{w_min_rad_per_s!r}, {w_max_rad_per_s!r}")
    w = np.geomspace(w_min_rad_per_s, w_max_rad_per_s, GRID_POINTS)
    values = loop(w)
    if not np.all(np.isfinite(values)):
        raise PIDTuningError("loop_margins: the loop's frequency response is not finite "
                             "on the frequency range")

    def at(x: float) -> complex:
        return complex(loop(np.array([x]))[0])

    def refine(fun: Callable[[float], float], i: int) -> float:
        return float(brentq(fun, w[i], w[i + 1], xtol=1e-300, rtol=FREQUENCY_RTOL))

    pm, wc = math.nan, math.nan
    mag = np.log(np.abs(values))
    for i in np.flatnonzero(np.sign(mag[:-1]) * np.sign(mag[1:]) < 0):
        x = refine(lambda v: math.log(abs(at(v))), int(i))
        margin = math.degrees(math.atan2(at(x).imag, at(x).real)) + 180.0
        margin = (margin + 180.0) % 360.0 - 180.0
        if math.isnan(pm) or abs(margin) < abs(pm):
            pm, wc = margin, x
    gm, w180 = math.inf, math.nan
    crossings = [(refine(lambda v: at(v).imag, int(i))) for i in
                 np.flatnonzero(np.sign(values.imag[:-1]) * np.sign(values.imag[1:]) < 0)]
    if values[-1].real < 0 and abs(values[-1].imag) <= 1e-9 * abs(values[-1]):
        crossings.append(float(w[-1]))
    for x in crossings:
        value = at(x)
        if value.real < 0 and 1.0 / abs(value) < gm:
            gm, w180 = 1.0 / abs(value), x
    ms, ws = _refined_peak(loop, w, values)
    return LoopMargins(ms=ms, ms_rad_per_s=ws, gain_margin=gm, phase_margin_deg=pm,
                       crossover_rad_per_s=wc, phase_crossover_rad_per_s=w180)


def _refined_peak(loop: LoopResponse, w: FloatArray, values: FloatArray) -> tuple[float, float]:
    """``(Ms, its frequency)``: the grid's peak of ``|1/(1 + L)|`` refined between its neighbours."""
    sensitivity = np.abs(1.0 / (1.0 + values))
    j = int(np.argmax(sensitivity))
    lo, hi = w[max(j - 1, 0)], w[min(j + 1, w.size - 1)]
    best = minimize_scalar(lambda v: -abs(1.0 / (1.0 + complex(loop(np.array([v]))[0]))),
                           bounds=(lo, hi), method="bounded",
                           options={"xatol": FREQUENCY_RTOL * hi})
    if -best.fun > sensitivity[j]:
        return float(-best.fun), float(best.x)
    return float(sensitivity[j]), float(w[j])


def sampled_loop(tuning: PIDTuning, plant: LocalPlant,
                 form: IntegralForm = "forward") -> LoopResponse:
    """``L(e^{j w Ts}) = C(z) g B(z)/A(z)`` of ``tuning`` in ``form`` on ``plant``, a function of ``w``."""
    def loop(w: FloatArray) -> FloatArray:
        return np.asarray(controller_frequency_response(tuning, plant.ts_s, w, form)
                          * plant.frequency_response(w))
    return loop


def sampled_margins(tuning: PIDTuning, plant: LocalPlant,
                    form: IntegralForm = "forward") -> LoopMargins:
    """Margins of ``tuning`` on ``plant`` as sampled (hold and delay included).

    Parameters
    ----------
    tuning :
        The tuning.
    plant :
        The local plant.
    form :
        How the block samples the law (`czmpc.pid.discretization`); ``forward`` is the law
        of `czmpc.pid.controller.ScheduledPID`.
    """
    wn = math.pi / plant.ts_s
    return loop_margins(sampled_loop(tuning, plant, form),
                        w_min_rad_per_s=SAMPLED_LOW_FRACTION * wn, w_max_rad_per_s=wn)


def sampled_ms(tuning: PIDTuning, plant: LocalPlant, form: IntegralForm = "forward") -> float:
    """``Ms`` of `sampled_margins` alone, without the crossings (the same grid and refinement)."""
    wn = math.pi / plant.ts_s
    w = np.geomspace(SAMPLED_LOW_FRACTION * wn, wn, GRID_POINTS)
    loop = sampled_loop(tuning, plant, form)
    values = loop(w)
    if not np.all(np.isfinite(values)):
        raise PIDTuningError("sampled_ms: the loop's frequency response is not finite "
                             "on the frequency range")
    return _refined_peak(loop, w, values)[0]


def worst_margins(margins: Iterable[LoopMargins]) -> LoopMargins:
    """The worst of several loops' margins, each with its own frequency.

    The largest Ms, the smallest gain margin, and the phase margin of smallest magnitude
    (NaN only when no loop has a gain crossover).

    Raises
    ------
    PIDTuningError
        No margins given.
    """
    items = list(margins)
    if not items:
        raise PIDTuningError("worst_margins: expected the margins of at least one loop; got none")
    ms = max(items, key=lambda m: m.ms)
    gm = min(items, key=lambda m: m.gain_margin)
    crossing = [m for m in items if not math.isnan(m.phase_margin_deg)]
    pm = min(crossing, key=lambda m: abs(m.phase_margin_deg)) if crossing else items[0]
    return LoopMargins(ms=ms.ms, ms_rad_per_s=ms.ms_rad_per_s, gain_margin=gm.gain_margin,
                       phase_margin_deg=pm.phase_margin_deg,
                       crossover_rad_per_s=pm.crossover_rad_per_s,
                       phase_crossover_rad_per_s=gm.phase_crossover_rad_per_s)


__all__ = ["LoopMargins", "LoopResponse", "loop_margins", "sampled_loop", "sampled_margins",
           "sampled_ms", "worst_margins"]
