"""Tuning one local plant: a rule with its knob, or the knob found for an Ms bound.

`DesignSpec` says how (rule, PI or PID, ``tau_c``/``lambda`` or an Ms bound, and the
discretization the bound must hold for); `design_local` applies it to one `LocalPlant`.
With an Ms bound, SIMC and lambda search their knob (bisection: Ms falls as the knob
grows) for the smallest knob whose sampled loop has ``Ms <= bound``; the ``ms`` rule
minimises the IAE of a unit load step at the plant input over ``Ti`` (and ``Td/Ti``) with
``Kc`` the largest the bound allows (`_optimise_for_ms`). Every Ms here is of the sampled
loop, and with several forms (`czmpc.pid.discretization`, ``worst``: forward, backward
and trapezoidal integration) the largest of them: a bound holds for every form.

No row holds ``Ti`` below ``MIN_TI_SAMPLES`` sampling times. There the forms are different
controllers (forward Euler's proportional action at the Nyquist frequency,
``Kc (1 - Ts/(2 Ti))``, vanishes at ``Ti = Ts/2``; backward Euler's grows), and a rule
that asks for such a ``Ti`` (SIMC and the ``ms`` rule do on a plant that is nearly a gain
and a dead time) says that the loop wants integral action only. The design then raises
``Ti`` to the floor and chooses ``Kc`` for the bound in every form, and says so
(`LocalDesign.integral_dominant`); `SampledIntegral` is the integral-only law itself,
one difference equation whatever the block's discretization.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.polynomial import polynomial as npoly
from scipy.optimize import minimize_scalar
from scipy.signal import lfilter

from czmpc.pid.discretization import (
    DEFAULT_DISCRETIZATION,
    Discretization,
    IntegralForm,
    checked_discretization,
    controller_frequency_response,
    controller_polynomials,
    forms_of,
)
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.margins import SAMPLED_LOW_FRACTION, sampled_ms
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
#: Smallest integral time of a tuning, in sampling times (module notes) [-].
MIN_TI_SAMPLES = 1.0


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
    discretization :
        The sampled form(s) of the law the bound holds for and the ``ms`` rule's IAE is
        the worst of (`czmpc.pid.discretization`): ``forward``, ``backward``, ``tustin``
        or ``worst`` (all three, the default).

    Raises
    ------
    PIDTuningError
        An unknown rule, type or discretization, both ``tau_c_s`` and ``ms``, a knob for
        AMIGO or the ``ms`` rule, a non-positive ``tau_c_s`` or ``ms <= 1``.
    """

    rule: RuleName = "simc"
    controller: ControllerType = "pi"
    tau_c_s: float | None = None
    ms: float | None = None
    discretization: Discretization = DEFAULT_DISCRETIZATION

    def __post_init__(self) -> None:
        checked_discretization(self.discretization)
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

    @property
    def forms(self) -> tuple[IntegralForm, ...]:
        """The sampled forms the design holds for (`czmpc.pid.discretization.forms_of`)."""
        return forms_of(self.discretization)

    def describe(self) -> str:
        """One line for reports: rule, type, knob or bound, and discretization."""
        knob = (f", tau_c = {self.tau_c_s:g} s" if self.tau_c_s is not None else
                f", Ms <= {self.ms_bound:g}" if self.ms_bound is not None else
                ", tau_c = effective dead time" if self.rule in ("simc", "lambda") else "")
        form = ("worst of forward, backward and trapezoidal integration"
                if self.discretization == "worst" else f"{self.discretization} integration")
        return f"{self.rule} {self.controller.upper()}{knob}, {form}"


@functools.lru_cache(maxsize=256)
def _search_grid(plant: LocalPlant) -> tuple[FloatArray, FloatArray]:
    """``(w, G(e^{j w Ts}))`` on the grid of the searches (computed once per plant)."""
    wn = math.pi / plant.ts_s
    w = np.geomspace(SAMPLED_LOW_FRACTION * wn, wn, _SEARCH_GRID_POINTS)
    return w, plant.frequency_response(w)


@functools.lru_cache(maxsize=4096)
def _unit_gain_loop(plant: LocalPlant, form: IntegralForm, ti_s: float, td_s: float,
                    td_filter_s: float) -> FloatArray:
    """``L/Kc`` on the search grid: the loop of a tuning with ``Kc = 1`` (the searches vary ``Kc``)."""
    w, g = _search_grid(plant)
    shape = PIDTuning(kc_pct_per_kw=1.0, ti_s=ti_s, td_s=td_s, td_filter_s=td_filter_s)
    return np.asarray(g * controller_frequency_response(shape, plant.ts_s, w, form))


def _grid_ms(tuning: PIDTuning, plant: LocalPlant, forms: Sequence[IntegralForm]) -> float:
    """The largest Ms over ``forms`` on the search grid (no refinement)."""
    kc = tuning.kc_pct_per_kw
    return max(float(np.max(np.abs(1.0 / (1.0 + kc * _unit_gain_loop(
        plant, form, tuning.ti_s, tuning.td_s, tuning.td_filter_s))))) for form in forms)


def worst_ms(tuning: PIDTuning, plant: LocalPlant, forms: Sequence[IntegralForm]) -> float:
    """The largest refined Ms of ``tuning`` on ``plant`` over the sampled ``forms`` [-]."""
    return max(sampled_ms(tuning, plant, form) for form in forms)


def _loop_polynomials(tuning: PIDTuning, plant: LocalPlant,
                      form: IntegralForm) -> tuple[FloatArray, FloatArray]:
    """``(g B Cd, A Cd + g B Cn)``: load-to-power numerator and characteristic polynomial."""
    num, den = controller_polynomials(tuning, plant.ts_s, form)
    gb = plant.gain_kw_per_pct * np.asarray(plant.b)
    char = npoly.polyadd(npoly.polymul(np.asarray(plant.a), den), npoly.polymul(gb, num))
    return np.asarray(npoly.polymul(gb, den), dtype=float), np.asarray(char, dtype=float)


def closed_loop_stable(tuning: PIDTuning, plant: LocalPlant,
                       form: IntegralForm = "forward") -> bool:
    """Whether every closed-loop pole of ``tuning`` in ``form`` on ``plant`` lies inside the unit circle.

    The roots ``x`` of the characteristic polynomial in ``x = z^-1`` are the inverses of
    the poles, so all must lie outside the unit circle.
    """
    char = np.trim_zeros(_loop_polynomials(tuning, plant, form)[1], "b")
    return bool(np.all(np.abs(npoly.polyroots(char)) > 1.0)) if char.size > 1 else True


def load_step_iae(tuning: PIDTuning, plant: LocalPlant, form: IntegralForm = "forward") -> float:
    """IAE of the power after a unit step [%] of load at the plant input [kW s].

    Simulates ``y = g B Cd / (A Cd + g B Cn) d`` of ``form`` for ``LOAD_STEP_SAMPLES``
    samples (`scipy.signal.lfilter`); inf for an unstable loop.
    """
    if not closed_loop_stable(tuning, plant, form):
        return math.inf
    forward, char = _loop_polynomials(tuning, plant, form)
    y = lfilter(forward, char, np.ones(LOAD_STEP_SAMPLES))
    return float(plant.ts_s * np.sum(np.abs(y)))


def _worst_iae(tuning: PIDTuning, plant: LocalPlant, forms: Sequence[IntegralForm]) -> float:
    return max(load_step_iae(tuning, plant, form) for form in forms)


def _knob_for_ms(make: Callable[[float], PIDTuning], plant: LocalPlant, dead_time_s: float,
                 bound: float, forms: Sequence[IntegralForm]) -> float:
    """The smallest knob whose tuning keeps ``Ms <= bound`` in every form (bisection)."""
    lo, hi = (f * dead_time_s for f in KNOB_RANGE_DEAD_TIMES)
    if _grid_ms(make(lo), plant, forms) <= bound:
        hi = lo
    elif _grid_ms(make(hi), plant, forms) > bound:
        raise PIDTuningError(
            f"Ms bound {bound:g}: not met at s = {plant.triac_pct:g} % even with the knob at "
            f"{hi:g} s ({KNOB_RANGE_DEAD_TIMES[1]:g} dead times); use a larger bound")
    else:
        for _ in range(_BISECTION_STEPS):
            mid = math.sqrt(lo * hi)
            if _grid_ms(make(mid), plant, forms) <= bound:
                hi = mid
            else:
                lo = mid
    while worst_ms(make(hi), plant, forms) > bound:
        hi *= 1.0 + _BOUND_STEP
    return hi


def _within_bound(tuning: PIDTuning, plant: LocalPlant, bound: float,
                  forms: Sequence[IntegralForm]) -> PIDTuning:
    """``tuning`` with ``Kc`` lowered in small steps until the refined Ms meets ``bound``."""
    while worst_ms(tuning, plant, forms) > bound:
        tuning = tuning.scaled(1.0 - _BOUND_STEP)
    return tuning


def _largest_gain(shape: PIDTuning, plant: LocalPlant, bound: float,
                  forms: Sequence[IntegralForm]) -> PIDTuning:
    """``shape`` with the largest ``Kc`` whose sampled loops keep ``Ms <= bound`` in ``forms``.

    Bisection on ``log Kc`` (Ms grows with ``Kc`` at fixed ``Ti, Td``) between a gain so
    small that ``Ms`` is about 1 and one 10^6 times larger.
    """
    lo = 1e-3 / (plant.gain_kw_per_pct * 1e3)
    hi = lo * 1e6
    if _grid_ms(shape.scaled(hi / shape.kc_pct_per_kw), plant, forms) <= bound:
        return _within_bound(shape.scaled(hi / shape.kc_pct_per_kw), plant, bound, forms)
    for _ in range(_BISECTION_STEPS):
        mid = math.sqrt(lo * hi)
        if _grid_ms(shape.scaled(mid / shape.kc_pct_per_kw), plant, forms) <= bound:
            lo = mid
        else:
            hi = mid
    return _within_bound(shape.scaled(lo / shape.kc_pct_per_kw), plant, bound, forms)


#: Integral times the ``ms`` rule tries, in multiples of the sampling time [-].
_TI_GRID_SAMPLES = np.geomspace(0.1, 500.0, 25)
#: Derivative-to-integral time ratios the ``ms`` rule tries for a PID [-].
_TD_RATIOS = (0.0, 0.05, 0.1, 0.2, 0.35, 0.5)


def _optimise_for_ms(plant: LocalPlant, bound: float, controller: ControllerType,
                     forms: Sequence[IntegralForm]) -> tuple[PIDTuning, float]:
    """The tuning with the least load-step IAE among those on the bound ``Ms = bound``.

    For each integral time of a grid (and each ``Td/Ti`` of `_TD_RATIOS` for a PID) the
    gain is the largest the bound allows in every form (`_largest_gain`), and the IAE is
    the worst over the forms. The best integral time from ``MIN_TI_SAMPLES Ts`` up is
    refined between its grid neighbours by a bounded scalar search. Returns that tuning
    and the integral time the rule asks for: the best of the whole grid, which may lie
    below the floor.
    """
    def on_bound(ti_s: float, ratio: float) -> PIDTuning:
        td = ratio * ti_s
        shape = PIDTuning(kc_pct_per_kw=1.0, ti_s=ti_s, td_s=td,
                          td_filter_s=td / DERIVATIVE_FILTER_RATIO)
        return _largest_gain(shape, plant, bound, forms)

    floor = MIN_TI_SAMPLES * plant.ts_s
    ratios = _TD_RATIOS if controller == "pid" else (0.0,)
    grid = sorted({float(v) for v in plant.ts_s * _TI_GRID_SAMPLES} | {floor})
    scored = [(_worst_iae(on_bound(ti, ratio), plant, forms), ti, ratio)
              for ratio in ratios for ti in grid]
    asked = min(scored)
    iae, ti, ratio = min(s for s in scored if s[1] >= floor)
    if not math.isfinite(iae):
        raise PIDTuningError(
            f"ms rule at s = {plant.triac_pct:g} %: no stable loop meets Ms <= {bound:g}")
    step = float(_TI_GRID_SAMPLES[1] / _TI_GRID_SAMPLES[0])
    refined = minimize_scalar(
        lambda x: _worst_iae(on_bound(math.exp(x), ratio), plant, forms),
        bounds=(math.log(max(ti / step, floor)), math.log(ti * step)), method="bounded",
        options={"xatol": 1e-3})
    if refined.fun < iae:
        ti = math.exp(float(refined.x))
    return on_bound(ti, ratio), asked[1] if asked[1] < floor else ti


@dataclass(frozen=True, slots=True, kw_only=True)
class LocalDesign:
    """One local plant's tuning, and the integral time its rule asked for.

    Parameters
    ----------
    tuning :
        The tuning the table holds (``Ti >= MIN_TI_SAMPLES Ts``).
    rule_ti_s :
        The integral time the rule asked for [s] (before the floor); for the ``ms`` rule
        the best of its whole grid.
    ts_s :
        Sampling time [s].
    """

    tuning: PIDTuning
    rule_ti_s: float
    ts_s: float

    @property
    def integral_dominant(self) -> bool:
        """True when the rule asked for ``Ti`` below the floor: the loop wants integral action only."""
        return self.rule_ti_s < MIN_TI_SAMPLES * self.ts_s


def floored(tuning: PIDTuning, ts_s: float) -> PIDTuning:
    """``tuning`` with ``Ti`` raised to ``MIN_TI_SAMPLES ts_s`` where it is below (rest unchanged)."""
    floor = MIN_TI_SAMPLES * ts_s
    return tuning if tuning.ti_s >= floor else replace(tuning, ti_s=floor)


def design_local(plant: LocalPlant, spec: DesignSpec) -> LocalDesign:
    """Tune ``plant`` as ``spec`` says (module notes), with what the rule asked for.

    Parameters
    ----------
    plant :
        The local plant at one breakpoint.
    spec :
        Rule, type, knob or bound, and the discretization the bound holds for.

    Raises
    ------
    PIDTuningError
        A plant the rule cannot reduce (`reduce_to_rule_plant`; the ``ms`` rule needs no
        reduction), or an Ms bound no knob meets.
    """
    bound = spec.ms_bound
    forms = spec.forms
    if spec.rule == "ms":
        tuning, asked = _optimise_for_ms(plant, DEFAULT_MS if bound is None else bound,
                                         spec.controller, forms)
        return LocalDesign(tuning=tuning, rule_ti_s=asked, ts_s=plant.ts_s)
    rp = reduce_to_rule_plant(plant)
    if spec.rule == "amigo":
        raw = amigo(rp, controller=spec.controller)
        return LocalDesign(tuning=floored(raw, plant.ts_s), rule_ti_s=raw.ti_s, ts_s=plant.ts_s)

    def make(knob: float) -> PIDTuning:
        if spec.rule == "lambda":
            return lambda_imc(rp, lambda_s=knob, controller=spec.controller)
        return simc(rp, tau_c_s=knob, controller=spec.controller, delay_dominant=True)

    if bound is not None:
        knob = _knob_for_ms(lambda k: floored(make(k), plant.ts_s), plant, rp.dead_time_s,
                            bound, forms)
    else:
        knob = rp.dead_time_s if spec.tau_c_s is None else spec.tau_c_s
    raw = make(knob)
    return LocalDesign(tuning=floored(raw, plant.ts_s), rule_ti_s=raw.ti_s, ts_s=plant.ts_s)


def tune_local(plant: LocalPlant, spec: DesignSpec) -> PIDTuning:
    """Tune ``plant`` as ``spec`` says (module notes): the tuning of `design_local`.

    Parameters
    ----------
    plant :
        The local plant at one breakpoint.
    spec :
        Rule, type, knob or bound, and discretization.

    Raises
    ------
    PIDTuningError
        As `design_local`.
    """
    return design_local(plant, spec).tuning


@dataclass(frozen=True, slots=True, kw_only=True)
class SampledIntegral:
    """Integral-only control on the current error: ``u_k = u_{k-1} + Ki Ts e_k``.

    One law whatever the block's discretization, for a loop that wants integral action
    only (`LocalDesign.integral_dominant`). A block takes it as an I-only controller that
    integrates the current error, or as an ISA PI in the forms that can hold it
    (`as_tuning`).

    Parameters
    ----------
    ki_pct_per_kw_s :
        Integral gain ``Ki`` [% TRIAC per kW and second], > 0.
    ts_s :
        Sampling time [s].
    """

    ki_pct_per_kw_s: float
    ts_s: float

    @property
    def move_gain_pct_per_kw(self) -> float:
        """``Ki Ts``: the input move per kW of error each sample [%/kW]."""
        return self.ki_pct_per_kw_s * self.ts_s

    def as_tuning(self, form: IntegralForm) -> PIDTuning | None:
        """The ISA PI that runs exactly this law in ``form``; None where none can.

        Forward Euler: ``Kc = Ki Ts``, ``Ti = Ts`` (``du = Kc (e_k - e_{k-1}) + Kc e_{k-1}``).
        Trapezoidal: ``Kc = Ki Ts/2``, ``Ti = Ts/2``. Backward Euler would need ``Kc = 0``.
        """
        if form == "forward":
            return PIDTuning(kc_pct_per_kw=self.move_gain_pct_per_kw, ti_s=self.ts_s)
        if form == "tustin":
            return PIDTuning(kc_pct_per_kw=self.move_gain_pct_per_kw / 2.0, ti_s=self.ts_s / 2.0)
        return None


def tune_sampled_integral(plant: LocalPlant, bound: float) -> SampledIntegral:
    """The largest ``Ki`` of a `SampledIntegral` whose loop on ``plant`` keeps ``Ms <= bound``.

    Raises
    ------
    PIDTuningError
        ``bound`` not > 1.
    """
    if not (math.isfinite(bound) and bound > 1.0):
        raise PIDTuningError(f"sampled integral: expected an Ms bound > 1; got {bound!r}")
    shape = PIDTuning(kc_pct_per_kw=1.0, ti_s=plant.ts_s)
    tuning = _largest_gain(shape, plant, bound, ("forward",))
    return SampledIntegral(ki_pct_per_kw_s=tuning.kc_pct_per_kw / plant.ts_s, ts_s=plant.ts_s)


__all__ = ["DEFAULT_MS", "MIN_TI_SAMPLES", "RULES", "DesignSpec", "LocalDesign", "RuleName",
           "SampledIntegral", "closed_loop_stable", "design_local", "floored", "load_step_iae",
           "tune_local", "tune_sampled_integral", "worst_ms"]
