"""Tuning one local plant: a rule with its knob, or the knob found for an Ms bound.

`DesignSpec` says how (rule, PI or PID, ``tau_c``/``lambda`` or an Ms bound);
`tune_local` applies it to one `LocalPlant`. With an Ms bound, SIMC and lambda search
their knob (bisection: Ms falls as the knob grows) for the smallest knob whose sampled
loop has ``Ms <= bound``; the ``ms`` rule minimises the IAE of a unit load step at the
plant input over ``Ti`` (and ``Td/Ti``) with ``Kc`` the largest the bound allows
(`_optimise_for_ms`). Every Ms here is of the sampled loop.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.polynomial import polynomial as npoly
from scipy.optimize import minimize_scalar
from scipy.signal import lfilter

from czmpc.pid.errors import PIDTuningError
from czmpc.pid.margins import SAMPLED_LOW_FRACTION, sampled_loop, sampled_margins
from czmpc.pid.plant import LocalPlant, reduce_to_rule_plant
from czmpc.pid.rules import DERIVATIVE_FILTER_RATIO, ControllerType, PIDTuning, amigo, lambda_imc, simc
from sysid._typing import FloatArray

RuleName = Literal["simc", "lambda", "amigo", "ms"]
RULES: tuple[str, ...] = ("simc", "lambda", "amigo", "ms")
#: Ms bound of the ``ms`` rule when none is given [-] (a common robust choice).
DEFAULT_MS = 1.4
#: Knob search range of SIMC and lambda under an Ms bound, in multiples of the dead time.
KNOB_RANGE_DEAD_TIMES = (0.05, 100.0)
#: Bisection steps of the knob search (the range shrinks by 2^-40).
_BISECTION_STEPS = 40
#: Length of the load-step simulation of the ``ms`` rule [samples].
LOAD_STEP_SAMPLES = 300
#: Grid of the Ms evaluations inside the searches [points].
_SEARCH_GRID_POINTS = 1500
#: Step of the knob (up) or of Kc (down) while the refined Ms still exceeds the bound
#: after a grid-based search: the grid can miss the top of a sharp peak [-].
_BOUND_STEP = 1e-3


@dataclass(frozen=True, slots=True, kw_only=True)
class DesignSpec:
    """How each row is tuned.

    Parameters
    ----------
    rule :
        ``"simc"``, ``"lambda"``, ``"amigo"`` or ``"ms"``.
    controller :
        ``"pi"`` or ``"pid"``.
    tau_c_s :
        SIMC's ``tau_c`` or lambda's ``lambda`` [s]; None: the effective dead time
        (SIMC's "tight" choice) unless ``ms`` is given.
    ms :
        Ms bound [-] (> 1): the knob is chosen to meet it (SIMC, lambda) or the ``ms``
        rule optimises under it; None: no bound (the ``ms`` rule uses `DEFAULT_MS`).

    Raises
    ------
    PIDTuningError
        An unknown rule or type, both ``tau_c_s`` and ``ms``, a knob for AMIGO or the
        ``ms`` rule, a non-positive ``tau_c_s`` or ``ms <= 1``.
    """

    rule: RuleName = "simc"
    controller: ControllerType = "pi"
    tau_c_s: float | None = None
    ms: float | None = None

    def __post_init__(self) -> None:
        if self.rule not in RULES:
            raise PIDTuningError(f"rule: expected one of {', '.join(RULES)}; got {self.rule!r}")
        if self.controller not in ("pi", "pid"):
            raise PIDTuningError(f"controller type: expected 'pi' or 'pid'; got {self.controller!r}")
        if self.tau_c_s is not None and self.ms is not None:
            raise PIDTuningError("give either tau_c_s (the rule's knob) or ms (a bound the "
                                 "knob is chosen for), not both")
        if self.tau_c_s is not None and (self.rule in ("amigo", "ms")
                                         or not (math.isfinite(self.tau_c_s) and self.tau_c_s > 0)):
            raise PIDTuningError(
                f"tau_c_s: expected a time > 0 [s] for rule simc or lambda (amigo and ms have "
                f"no such knob); got {self.tau_c_s!r} with rule {self.rule!r}")
        if self.ms is not None and (self.rule == "amigo"
                                    or not (math.isfinite(self.ms) and self.ms > 1)):
            raise PIDTuningError(
                f"ms: expected a bound > 1 for rule simc, lambda or ms (AMIGO has no knob; it "
                f"aims at about 1.4 by itself); got {self.ms!r} with rule {self.rule!r}")

    @property
    def ms_bound(self) -> float | None:
        """The Ms bound the rows are tuned for, if any."""
        return DEFAULT_MS if self.rule == "ms" and self.ms is None else self.ms

    def describe(self) -> str:
        """One line for reports: rule, type and knob or bound."""
        knob = (f", tau_c = {self.tau_c_s:g} s" if self.tau_c_s is not None else
                f", Ms <= {self.ms_bound:g}" if self.ms_bound is not None else
                ", tau_c = effective dead time" if self.rule in ("simc", "lambda") else "")
        return f"{self.rule} {self.controller.upper()}{knob}"


def _grid_ms(tuning: PIDTuning, plant: LocalPlant) -> float:
    wn = math.pi / plant.ts_s
    w = np.geomspace(SAMPLED_LOW_FRACTION * wn, wn, _SEARCH_GRID_POINTS)
    return float(np.max(np.abs(1.0 / (1.0 + sampled_loop(tuning, plant)(w)))))


def _controller_polynomials(tuning: PIDTuning, ts_s: float) -> tuple[FloatArray, FloatArray]:
    """``C(z) = num/den`` of the running law, ascending powers of ``z^-1``.

    ``num = Kc [(1 - z^-1 + (Ts/Ti) z^-1) F + Td (1 - z^-1)^2]``, ``den = (1 - z^-1) F``
    with ``F = Tf + Ts - Tf z^-1`` (`czmpc.pid.controller`).
    """
    filt = np.array([tuning.td_filter_s + ts_s, -tuning.td_filter_s])
    diff = np.array([1.0, -1.0])
    proportional_integral = np.array([1.0, ts_s / tuning.ti_s - 1.0])
    num = npoly.polyadd(npoly.polymul(proportional_integral, filt),
                    tuning.td_s * npoly.polymul(diff, diff))
    return tuning.kc_pct_per_kw * num, npoly.polymul(diff, filt)


def _loop_polynomials(tuning: PIDTuning, plant: LocalPlant) -> tuple[FloatArray, FloatArray]:
    """``(g B Cd, A Cd + g B Cn)``: load-to-power numerator and characteristic polynomial."""
    num, den = _controller_polynomials(tuning, plant.ts_s)
    gb = plant.gain_kw_per_pct * np.asarray(plant.b)
    char = npoly.polyadd(npoly.polymul(np.asarray(plant.a), den), npoly.polymul(gb, num))
    return np.asarray(npoly.polymul(gb, den), dtype=float), np.asarray(char, dtype=float)


def closed_loop_stable(tuning: PIDTuning, plant: LocalPlant) -> bool:
    """Whether every closed-loop pole of ``tuning`` on ``plant`` lies inside the unit circle.

    The roots ``x`` of the characteristic polynomial in ``x = z^-1`` are the inverses of
    the poles, so all must lie outside the unit circle.
    """
    char = np.trim_zeros(_loop_polynomials(tuning, plant)[1], "b")
    return bool(np.all(np.abs(npoly.polyroots(char)) > 1.0)) if char.size > 1 else True


def load_step_iae(tuning: PIDTuning, plant: LocalPlant) -> float:
    """IAE of the power after a unit step [%] of load at the plant input [kW s].

    Simulates ``y = g B Cd / (A Cd + g B Cn) d`` for ``LOAD_STEP_SAMPLES`` samples
    (`scipy.signal.lfilter`); inf for an unstable loop.
    """
    if not closed_loop_stable(tuning, plant):
        return math.inf
    forward, char = _loop_polynomials(tuning, plant)
    y = lfilter(forward, char, np.ones(LOAD_STEP_SAMPLES))
    return float(plant.ts_s * np.sum(np.abs(y)))


def _knob_for_ms(make: Callable[[float], PIDTuning], plant: LocalPlant, dead_time_s: float,
                 bound: float) -> PIDTuning:
    lo, hi = (f * dead_time_s for f in KNOB_RANGE_DEAD_TIMES)
    if _grid_ms(make(lo), plant) <= bound:
        return make(lo)
    if _grid_ms(make(hi), plant) > bound:
        raise PIDTuningError(
            f"Ms bound {bound:g}: not met at s = {plant.triac_pct:g} % even with the knob at "
            f"{hi:g} s ({KNOB_RANGE_DEAD_TIMES[1]:g} dead times); use a larger bound")
    for _ in range(_BISECTION_STEPS):
        mid = math.sqrt(lo * hi)
        if _grid_ms(make(mid), plant) <= bound:
            hi = mid
        else:
            lo = mid
    while sampled_margins(make(hi), plant).ms > bound:
        hi *= 1.0 + _BOUND_STEP
    return make(hi)


def _within_bound(tuning: PIDTuning, plant: LocalPlant, bound: float) -> PIDTuning:
    """``tuning`` with ``Kc`` lowered in small steps until the refined Ms meets ``bound``."""
    while sampled_margins(tuning, plant).ms > bound:
        tuning = tuning.scaled(1.0 - _BOUND_STEP)
    return tuning


def _largest_gain(shape: PIDTuning, plant: LocalPlant, bound: float) -> PIDTuning:
    """``shape`` with the largest ``Kc`` whose sampled loop keeps ``Ms <= bound``.

    Bisection on ``log Kc`` (Ms grows with ``Kc`` at fixed ``Ti, Td``) between a gain so
    small that ``Ms`` is about 1 and one 10^6 times larger.
    """
    lo = 1e-3 / (plant.gain_kw_per_pct * 1e3)
    hi = lo * 1e6
    if _grid_ms(shape.scaled(hi / shape.kc_pct_per_kw), plant) <= bound:
        return _within_bound(shape.scaled(hi / shape.kc_pct_per_kw), plant, bound)
    for _ in range(_BISECTION_STEPS):
        mid = math.sqrt(lo * hi)
        if _grid_ms(shape.scaled(mid / shape.kc_pct_per_kw), plant) <= bound:
            lo = mid
        else:
            hi = mid
    return _within_bound(shape.scaled(lo / shape.kc_pct_per_kw), plant, bound)


#: Integral times the ``ms`` rule tries, in multiples of the sampling time [-].
_TI_GRID_SAMPLES = np.geomspace(0.1, 500.0, 25)
#: Derivative-to-integral time ratios the ``ms`` rule tries for a PID [-].
_TD_RATIOS = (0.0, 0.05, 0.1, 0.2, 0.35, 0.5)


def _optimise_for_ms(plant: LocalPlant, bound: float, controller: ControllerType) -> PIDTuning:
    """The tuning with the least load-step IAE among those on the bound ``Ms = bound``.

    For each integral time of a grid (and each ``Td/Ti`` of `_TD_RATIOS` for a PID) the
    gain is the largest the bound allows (`_largest_gain`); the best integral time is then
    refined between its grid neighbours by a bounded scalar search.
    """
    def on_bound(ti_s: float, ratio: float) -> PIDTuning:
        td = ratio * ti_s
        shape = PIDTuning(kc_pct_per_kw=1.0, ti_s=ti_s, td_s=td,
                          td_filter_s=td / DERIVATIVE_FILTER_RATIO)
        return _largest_gain(shape, plant, bound)

    ratios = _TD_RATIOS if controller == "pid" else (0.0,)
    grid = plant.ts_s * _TI_GRID_SAMPLES
    best: tuple[float, float, float] = (math.inf, float(grid[0]), 0.0)
    for ratio in ratios:
        for ti in grid:
            iae = load_step_iae(on_bound(float(ti), ratio), plant)
            if iae < best[0]:
                best = (iae, float(ti), ratio)
    iae, ti, ratio = best
    if not math.isfinite(iae):
        raise PIDTuningError(
            f"ms rule at s = {plant.triac_pct:g} %: no stable loop meets Ms <= {bound:g}")
    step = float(_TI_GRID_SAMPLES[1] / _TI_GRID_SAMPLES[0])
    refined = minimize_scalar(lambda x: load_step_iae(on_bound(math.exp(x), ratio), plant),
                              bounds=(math.log(ti / step), math.log(ti * step)),
                              method="bounded", options={"xatol": 1e-3})
    if refined.fun < iae:
        ti = math.exp(float(refined.x))
    return on_bound(ti, ratio)


def tune_local(plant: LocalPlant, spec: DesignSpec) -> PIDTuning:
    """Tune ``plant`` as ``spec`` says (module notes).

    Parameters
    ----------
    plant :
        The local plant at one breakpoint.
    spec :
        Rule, type and knob or bound.

    Raises
    ------
    PIDTuningError
        A plant the rule cannot reduce (`reduce_to_rule_plant`; the ``ms`` rule needs no
        reduction), or an Ms bound no knob meets.
    """
    bound = spec.ms_bound
    if spec.rule == "ms":
        return _optimise_for_ms(plant, DEFAULT_MS if bound is None else bound, spec.controller)
    rp = reduce_to_rule_plant(plant)
    if spec.rule == "amigo":
        return amigo(rp, controller=spec.controller)

    def make(knob: float) -> PIDTuning:
        if spec.rule == "lambda":
            return lambda_imc(rp, lambda_s=knob, controller=spec.controller)
        return simc(rp, tau_c_s=knob, controller=spec.controller, delay_dominant=True)

    if bound is not None:
        return _knob_for_ms(make, plant, rp.dead_time_s, bound)
    return make(rp.dead_time_s if spec.tau_c_s is None else spec.tau_c_s)


__all__ = ["DEFAULT_MS", "RULES", "DesignSpec", "RuleName", "closed_loop_stable", "load_step_iae",
           "tune_local"]
