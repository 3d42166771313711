"""The gain schedule: breakpoints over the TRIAC range, one tuned row each, checked between.

`tune_schedule` linearises the model over each row's interval, from its breakpoint to the
next (`czmpc.pid.plant.local_plant`; the row holds there,
`czmpc.pid.controller.TableSchedule`), tunes the row (`czmpc.pid.design.design_local`) on
the plant of the interval with the largest gain ``f'`` (only the gain moves, so that plant
has the smallest margins: a bound met there holds over the whole interval), computes the
margins at the breakpoint on the sampled loop and ``worst_ms_to_next``: the largest Ms of
the row's controller on the local plants of its interval. Both are computed for each of
the three sampled forms of the law (`czmpc.pid.discretization`); a row's own numbers are
the worst over the forms its design holds for (``DesignSpec.discretization``), and
`ScheduleRow.margins_for` gives them for any other discretization.

The schedule *holds* between two breakpoints when, for the row's controller in every form
of the design on every plant between them,

* ``Ms <= bound``: the Ms bound asked for, or without one the row's own Ms times
  ``1 + MS_SLACK`` (robustness as tuned), and
* the instantaneous gain ``f'`` stays within ``MAX_GAIN_CHANGE`` of the row's (speed
  as tuned).

Default breakpoints are the ends of the allowed range and the operating point; where the
schedule does not hold, a breakpoint is added halfway, until it holds or the interval is
narrower than ``MIN_INTERVAL_PCT`` (then a warning says where it does not hold).

Where a row's rule asked for an integral time below the sampling time
(`czmpc.pid.design.LocalDesign.integral_dominant`), every row also gets the
integral-only law (`czmpc.pid.design.SampledIntegral`) tuned for the same bound on the
same plant, with its own margins: the schedule a block that integrates the current error
can run instead.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from czmpc.pid.controller import TableSchedule
from czmpc.pid.design import (
    MIN_TI_SAMPLES,
    DesignSpec,
    LocalDesign,
    SampledIntegral,
    design_local,
    tune_sampled_integral,
)
from czmpc.pid.discretization import INTEGRAL_FORMS, Discretization, IntegralForm, forms_of
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.margins import LoopMargins, sampled_margins, sampled_ms, worst_margins
from czmpc.pid.plant import LocalPlant, RulePlant, local_plant, reduce_to_rule_plant
from czmpc.pid.rules import PIDTuning
from sysid.model import HammersteinModel

#: Largest relative change of the instantaneous gain ``f'`` over one row's interval [-].
MAX_GAIN_CHANGE = 0.10
#: Without an Ms bound, a row's worst Ms up to the next breakpoint may exceed its own by
#: this fraction [-].
MS_SLACK = 0.05
#: Narrowest interval bisection creates [%].
MIN_INTERVAL_PCT = 0.5
#: Plants checked between two breakpoints (both ends included) [-].
CHECK_POINTS = 9
#: Ms above which a row is flagged whatever was asked (a common upper limit) [-].
MS_WARNING = 2.0


@dataclass(frozen=True, slots=True, kw_only=True)
class SampledIntegralRow:
    """A row's integral-only law (`czmpc.pid.design.SampledIntegral`) with its margins.

    Parameters
    ----------
    law :
        The law, tuned on the row's plant of largest ``f'``.
    margins :
        Its margins on the row's plant at the breakpoint (one law: no discretization).
    worst_ms_to_next :
        Its largest Ms on the plants from this breakpoint to the next [-].
    """

    law: SampledIntegral
    margins: LoopMargins
    worst_ms_to_next: float


@dataclass(frozen=True, slots=True, kw_only=True)
class ScheduleRow:
    """One breakpoint of the schedule: the local plant, its tuning and margins.

    Parameters
    ----------
    plant :
        The local plant at the breakpoint.
    tuned_at_pct :
        The TRIAC input of the plant the row was tuned on: that of the largest ``f'`` from
        the breakpoint to the next [%].
    rule_plant :
        The first-order-plus-dead-time reduction of that plant (None when the model has
        no such reduction and the ``ms`` rule tuned on the sampled model alone).
    tuning :
        The tuned PID (ideal ISA form).
    margins :
        Margins of ``tuning`` on ``plant`` (sampled loop): the worst over the forms of the
        schedule's discretization.
    worst_ms_to_next :
        Largest Ms of ``tuning`` on the plants from this breakpoint to the next, over the
        same forms [-].
    worst_gain_change :
        Largest relative change of ``f'`` from this breakpoint to the next [-].
    margins_by_form :
        ``margins`` of each of `czmpc.pid.discretization.INTEGRAL_FORMS` alone.
    worst_ms_to_next_by_form :
        ``worst_ms_to_next`` of each form alone [-].
    rule_ti_s :
        The integral time the rule asked for on the row's plant [s]
        (`czmpc.pid.design.LocalDesign.rule_ti_s`).
    sampled_integral :
        The integral-only law of the row, when any row of the schedule is integral-dominant;
        else None.
    """

    plant: LocalPlant
    tuned_at_pct: float
    rule_plant: RulePlant | None
    tuning: PIDTuning
    margins: LoopMargins
    worst_ms_to_next: float
    worst_gain_change: float
    margins_by_form: Mapping[IntegralForm, LoopMargins]
    worst_ms_to_next_by_form: Mapping[IntegralForm, float]
    rule_ti_s: float
    sampled_integral: SampledIntegralRow | None = None

    @property
    def triac_pct(self) -> float:
        """The breakpoint [%]."""
        return self.plant.triac_pct

    @property
    def integral_dominant(self) -> bool:
        """True when the rule asked for ``Ti`` below ``MIN_TI_SAMPLES`` sampling times."""
        return self.rule_ti_s < MIN_TI_SAMPLES * self.plant.ts_s

    def margins_for(self, discretization: Discretization) -> tuple[LoopMargins, float]:
        """``(margins, worst_ms_to_next)`` of the row in ``discretization``: worst over its forms."""
        forms = forms_of(discretization)
        return (worst_margins(self.margins_by_form[f] for f in forms),
                max(self.worst_ms_to_next_by_form[f] for f in forms))


@dataclass(frozen=True, kw_only=True)
class PIDSchedule:
    """A tuned schedule with what it was tuned for.

    Parameters
    ----------
    rows :
        One row per breakpoint, by increasing TRIAC input.
    spec :
        How the rows were tuned (``spec.discretization``: the forms the rows' margins
        and any bound hold for).
    ts_s :
        Sampling time of the model and the controller [s].
    triac_range_pct :
        ``(min, max)`` TRIAC range the schedule covers [%].
    added_breakpoints_pct :
        Breakpoints added because the schedule did not hold [%].
    warnings :
        Where the schedule does not hold, in words.
    """

    rows: tuple[ScheduleRow, ...]
    spec: DesignSpec
    ts_s: float
    triac_range_pct: tuple[float, float]
    added_breakpoints_pct: tuple[float, ...]
    warnings: tuple[str, ...]

    @property
    def breakpoints_pct(self) -> tuple[float, ...]:
        """The breakpoints [%]."""
        return tuple(r.triac_pct for r in self.rows)

    @property
    def integral_dominant_pct(self) -> tuple[float, ...]:
        """Breakpoints whose rule asked for ``Ti`` below the floor [%]."""
        return tuple(r.triac_pct for r in self.rows if r.integral_dominant)

    def table_schedule(self) -> TableSchedule:
        """The schedule the controller runs (`czmpc.pid.controller.TableSchedule`)."""
        return TableSchedule(breakpoints_pct=self.breakpoints_pct,
                             tunings=tuple(r.tuning for r in self.rows))

    def sampled_integral_schedule(self) -> TableSchedule | None:
        """The integral-only laws as the forward-Euler PIs `ScheduledPID` runs them exactly.

        None when the rows have no integral-only law (no row is integral-dominant).
        """
        laws = [r.sampled_integral for r in self.rows]
        if any(law is None for law in laws):
            return None
        tunings = tuple(law.law.as_tuning("forward") for law in laws if law is not None)
        return TableSchedule(breakpoints_pct=self.breakpoints_pct,
                             tunings=tuple(t for t in tunings if t is not None))


def _reduced(plant: LocalPlant) -> RulePlant | None:
    try:
        return reduce_to_rule_plant(plant)
    except PIDTuningError:
        return None


def _interval_check(model: HammersteinModel, tuning: PIDTuning, lo_pct: float, hi_pct: float,
                    forms: Sequence[IntegralForm] = INTEGRAL_FORMS,
                    ) -> tuple[dict[IntegralForm, float], float]:
    """``({form: worst Ms}, worst relative change of f')`` of ``tuning`` on plants in [lo, hi]."""
    base = local_plant(model, lo_pct)
    worst_ms = dict.fromkeys(forms, 0.0)
    worst_change = 0.0
    for s in np.linspace(lo_pct, hi_pct, CHECK_POINTS if hi_pct > lo_pct else 1):
        plant = local_plant(model, float(s))
        for form in forms:
            worst_ms[form] = max(worst_ms[form], sampled_ms(tuning, plant, form))
        worst_change = max(worst_change,
                           abs(plant.gain_kw_per_pct / base.gain_kw_per_pct - 1.0))
    return worst_ms, worst_change


def _sampled_integral_row(model: HammersteinModel, row: ScheduleRow, nxt: float,
                          bound: float) -> SampledIntegralRow:
    law = tune_sampled_integral(local_plant(model, row.tuned_at_pct), bound)
    tuning = law.as_tuning("forward")
    if tuning is None:  # forward Euler holds every integral-only law
        raise PIDTuningError("sampled integral: no forward-Euler PI holds the law")
    worst, _ = _interval_check(model, tuning, row.triac_pct, nxt, ("forward",))
    return SampledIntegralRow(law=law, margins=sampled_margins(tuning, row.plant, "forward"),
                              worst_ms_to_next=worst["forward"])


def tune_schedule(
    model: HammersteinModel, spec: DesignSpec, *, triac_range_pct: tuple[float, float],
    breakpoints_pct: tuple[float, ...] | None = None, add_breakpoints: bool = True,
) -> PIDSchedule:
    """Tune a gain schedule of ``model`` over ``triac_range_pct`` (module notes).

    Parameters
    ----------
    model :
        The identified model.
    spec :
        Rule, type and knob or Ms bound of every row.
    triac_range_pct :
        ``(min, max)`` TRIAC input the schedule covers [%] (the controller's allowed
        range).
    breakpoints_pct :
        Breakpoints to start from [%], inside the range; None: the range's ends and the
        operating point.
    add_breakpoints :
        Add breakpoints where the schedule does not hold (default); False keeps the
        given ones and only warns.

    Raises
    ------
    PIDTuningError
        An empty range, breakpoints outside it or repeated, or a row that cannot be
        tuned.
    """
    lo, hi = (float(v) for v in triac_range_pct)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise PIDTuningError(f"TRIAC range: expected min < max [%]; got {triac_range_pct!r}")
    if breakpoints_pct is None:
        s_nom = model.operating_point.triac_pct
        points = sorted({lo, hi} | ({s_nom} if lo < s_nom < hi else set()))
    else:
        points = sorted(float(v) for v in breakpoints_pct)
        bad = [v for v in points if not (math.isfinite(v) and lo <= v <= hi)]
        if bad or len(set(points)) != len(points) or not points:
            raise PIDTuningError(
                f"breakpoints: expected distinct TRIAC inputs inside the range [{lo:g}, {hi:g}] "
                f"%; got {list(breakpoints_pct)}")
    given = set(points)
    designs: dict[float, LocalDesign] = {}
    forms = spec.forms

    def highest_gain_input(s: float, nxt: float) -> float:
        grid = np.linspace(s, nxt, CHECK_POINTS if nxt > s else 1)
        return float(grid[int(np.argmax([local_plant(model, float(v)).gain_kw_per_pct
                                         for v in grid]))])

    warnings: list[str] = []
    fragile: list[str] = []   # said after every "does not hold"
    rows: list[ScheduleRow] = []
    ends: list[float] = []
    i = 0
    while i < len(points):
        s = points[i]
        nxt = points[i + 1] if i + 1 < len(points) else (hi if s < hi else s)
        tuned_at = highest_gain_input(s, nxt)
        if tuned_at not in designs:
            designs[tuned_at] = design_local(local_plant(model, tuned_at), spec)
        design = designs[tuned_at]
        tuning = design.tuning
        own = max(sampled_ms(tuning, local_plant(model, tuned_at), f) for f in forms)
        bound = spec.ms_bound if spec.ms_bound is not None else own * (1.0 + MS_SLACK)
        worst_by_form, change = _interval_check(model, tuning, s, nxt)
        worst_ms = max(worst_by_form[f] for f in forms)
        holds = worst_ms <= bound and change <= MAX_GAIN_CHANGE
        if not holds and add_breakpoints and nxt - s >= 2 * MIN_INTERVAL_PCT:
            points.insert(i + 1, s + (nxt - s) / 2.0)
            continue
        if not holds:
            warnings.append(
                f"between {s:g} % and {nxt:g} % the schedule does not hold: worst Ms "
                f"{worst_ms:.3f} (bound {bound:.3f}), gain change {100 * change:.1f} % "
                f"(limit {100 * MAX_GAIN_CHANGE:g} %)")
        # point i is final: later breakpoints are inserted after it
        plant = local_plant(model, s)
        by_form = {f: sampled_margins(tuning, plant, f) for f in INTEGRAL_FORMS}
        margins = worst_margins(by_form[f] for f in forms)
        if margins.ms > MS_WARNING:
            fragile.append(f"row at {s:g} %: Ms {margins.ms:.3f} exceeds {MS_WARNING:g}; the "
                           "loop is fragile")
        rows.append(ScheduleRow(plant=plant, tuned_at_pct=tuned_at,
                                rule_plant=_reduced(local_plant(model, tuned_at)), tuning=tuning,
                                margins=margins, worst_ms_to_next=worst_ms,
                                worst_gain_change=change, margins_by_form=by_form,
                                worst_ms_to_next_by_form=worst_by_form,
                                rule_ti_s=design.rule_ti_s))
        ends.append(nxt)
        i += 1
    if any(r.integral_dominant for r in rows):
        rows = [replace(r, sampled_integral=_sampled_integral_row(
            model, r, nxt, spec.ms_bound if spec.ms_bound is not None else r.worst_ms_to_next))
            for r, nxt in zip(rows, ends, strict=True)]
    return PIDSchedule(rows=tuple(rows), spec=spec, ts_s=model.ts_s, triac_range_pct=(lo, hi),
                        added_breakpoints_pct=tuple(p for p in points if p not in given),
                        warnings=tuple(warnings + fragile))


@dataclass(frozen=True, slots=True, kw_only=True)
class Region:
    """A range of TRIAC inputs that shares one tuning (a DCS block's scheduling region).

    Parameters
    ----------
    lo_pct, hi_pct :
        The region's inputs [%].
    row :
        The row whose tuning the region uses.
    worst_ms :
        Largest Ms of that tuning over the region's local plants, in the forms of the
        discretization the regions were merged for [-].
    """

    lo_pct: float
    hi_pct: float
    row: ScheduleRow
    worst_ms: float


def merge_regions(schedule: PIDSchedule, model: HammersteinModel, n_regions: int = 3,
                  discretization: Discretization | None = None) -> tuple[Region, ...]:
    """Merge the rows into ``n_regions`` contiguous regions of about equal width.

    Region boundaries are the breakpoints nearest to the equal divisions of the range;
    each region uses, of its own rows, the one whose tuning has the smallest worst Ms over
    the whole region (the most robust there), and reports that Ms.

    Parameters
    ----------
    schedule :
        The tuned schedule.
    model :
        The model it was tuned on.
    n_regions :
        Number of regions (DeltaV's template has three), at most the number of rows.
    discretization :
        The forms the worst Ms is taken over; None: the schedule's own.

    Raises
    ------
    PIDTuningError
        ``n_regions`` below 1.
    """
    if n_regions < 1:
        raise PIDTuningError(f"regions: expected at least 1; got {n_regions}")
    lo, hi = schedule.triac_range_pct
    forms = forms_of(discretization or schedule.spec.discretization)
    points = list(schedule.breakpoints_pct)
    n = min(n_regions, len(points))
    starts = sorted({min(range(len(points)), key=lambda i: abs(points[i] - target))
                     for target in np.linspace(lo, hi, n + 1)[:-1]} | {0})
    regions = []
    for j, first in enumerate(starts):
        last = starts[j + 1] if j + 1 < len(starts) else len(points)
        r_lo = lo if j == 0 else points[first]
        r_hi = points[last] if last < len(points) else hi
        scored = [(max(_interval_check(model, row.tuning, r_lo, r_hi, forms)[0].values()), row)
                  for row in schedule.rows[first:last]]
        worst, row = min(scored, key=lambda t: t[0])
        regions.append(Region(lo_pct=r_lo, hi_pct=r_hi, row=row, worst_ms=worst))
    return tuple(regions)


__all__ = ["CHECK_POINTS", "MAX_GAIN_CHANGE", "MIN_INTERVAL_PCT", "MS_SLACK", "MS_WARNING",
           "PIDSchedule", "Region", "SampledIntegralRow", "ScheduleRow", "merge_regions",
           "tune_schedule"]
