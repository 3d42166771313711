"""What a finished run is measured by: the metric columns of a row, one definition each.

`metric_row` gives the closed-loop metrics of `sim.metrics.compute_metrics` (errors of
the true power against the setpoint over the whole run); `reachable_row` gives the
robustness measures, taken against the *reachable setpoint*: the setpoint clipped to
``[P_ss(s_min), P_ss(s_max)]`` of that plant, where ``[s_min, s_max]`` is the
controller's allowed input range. A setpoint the plant cannot hold with that range (a
plant with 30 % less gain cannot reach the top of the staircase) is *unreachable*; the
best any controller can do there is the closest power the plant can hold, so an
unreachable step counts as tracked when the power settles at the plant's limit.

Over the setpoint changes of the scenario (the initial segment, which starts at rest,
is left out; a scenario without a change is measured over the whole run):

* ``offset_free``: every change ends with ``|steady-state error| <``
  `OFFSET_FREE_THRESHOLD_KW`, the error being the mean of the *measured* power minus
  the reachable setpoint over the last quarter of the segment
  (`sim.metrics.STEADY_STATE_FRACTION`); the measured power is what is regulated;
* ``iae_changes_reachable_kw_s``: IAE of the *true* power against the reachable setpoint;
* ``max_overshoot_reachable_kw`` / ``_pct``: the largest overshoot beyond the reachable
  setpoint, and in % of that change's (reachable) size;
* ``n_allowed_range_violations``: samples outside the allowed range plus moves beyond
  the rate limit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from sim.loop import ClosedLoopResult
from sim.metrics import (
    compute_metrics,
    count_limit_violations,
    count_rate_violations,
    integral_absolute_error_kw_s,
    overshoot_kw,
    steady_state_error_kw,
)
from sim.scenario import Scenario

#: Offset-free threshold on |steady-state error| [kW]: 1 % of the 5 kW setpoint steps of
#: the staircase scenario, about 4 noise standard deviations.
OFFSET_FREE_THRESHOLD_KW = 0.05
#: Columns of `metric_row`.
METRIC_COLUMNS: tuple[str, ...] = (
    "n_steps", "iae_kw_s", "ise_kw2_s", "max_overshoot_kw", "max_overshoot_pct",
    "max_settling_time_s", "n_not_settled", "max_abs_steady_state_error_kw",
    "input_total_variation_pct", "n_limit_violations", "n_rate_violations", "n_solver_failures")
#: Columns of `reachable_row`.
REACHABLE_COLUMNS: tuple[str, ...] = (
    "offset_free", "max_abs_steady_state_error_reachable_kw", "n_unreachable_changes",
    "iae_changes_reachable_kw_s", "max_overshoot_reachable_kw", "max_overshoot_reachable_pct",
    "n_allowed_range_violations")
#: Columns of machine-dependent timings.
TIMING_COLUMNS: tuple[str, ...] = (
    "wall_time_s", "step_time_median_ms", "step_time_p95_ms", "step_time_max_ms")
#: Whole-number columns (compared exactly by a regression check).
COUNT_COLUMNS: frozenset[str] = frozenset({
    "n_steps", "n_not_settled", "n_limit_violations", "n_rate_violations", "n_solver_failures",
    "n_unreachable_changes", "n_allowed_range_violations"})


def _max_or_nan(values: Sequence[float | None]) -> float:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return max(finite) if finite else math.nan


def _nan_if_none(value: float | None) -> float:
    return math.nan if value is None else float(value)


def metric_row(result: ClosedLoopResult) -> dict[str, Any]:
    """`METRIC_COLUMNS` and `TIMING_COLUMNS` (but ``wall_time_s``) of a run.

    Overshoot and settling time are the largest over the setpoint changes (NaN without
    a change); ``n_not_settled`` counts the changes that did not settle.
    """
    m = compute_metrics(result)
    settling = [c.settling_time_s for c in m.changes]
    return {
        "n_steps": int(result.n_steps), "iae_kw_s": m.iae_kw_s, "ise_kw2_s": m.ise_kw2_s,
        "max_overshoot_kw": _max_or_nan([c.overshoot_kw for c in m.changes]),
        "max_overshoot_pct": _max_or_nan([c.overshoot_pct for c in m.changes]),
        "max_settling_time_s": _max_or_nan(settling),
        "n_not_settled": sum(1 for s in settling if s is None),
        "max_abs_steady_state_error_kw": _nan_if_none(m.max_abs_steady_state_error_kw),
        "input_total_variation_pct": m.input_total_variation_pct,
        "n_limit_violations": int(m.n_limit_violations),
        "n_rate_violations": int(m.n_rate_violations),
        "n_solver_failures": int(m.n_solver_failures or 0),
        "step_time_median_ms": m.step_time_median_ms, "step_time_p95_ms": m.step_time_p95_ms,
        "step_time_max_ms": m.step_time_max_ms,
    }


def reachable_row(result: ClosedLoopResult, scenario: Scenario, power_at: Callable[[float], float],
                  allowed_triac_range_pct: tuple[float, float],
                  max_move_pct_per_step: float | None) -> dict[str, Any]:
    """`REACHABLE_COLUMNS` of a run (definitions: module docstring).

    Parameters
    ----------
    result :
        The run.
    scenario :
        Its scenario (the setpoint-change segments).
    power_at :
        The plant's steady-state power [kW] at an input [%].
    allowed_triac_range_pct :
        The controller's allowed input range [%]: its ends give the plant's power range.
    max_move_pct_per_step :
        Rate limit [%/sample] whose excess moves count as violations, or None.
    """
    lo, hi = allowed_triac_range_pct
    p_lo, p_hi = sorted((power_at(lo), power_at(hi)))
    target = np.clip(result.setpoint_kw, p_lo, p_hi)
    true_error = result.power_true_kw - target
    measured_error = result.power_measured_kw - target
    sse, n_unreachable, iae, worst_kw, worst_pct = [], 0, 0.0, 0.0, 0.0
    segments = [seg for seg in scenario.segments() if seg.kind != "initial"]
    for seg in segments or list(scenario.segments()):
        part = slice(seg.start_k, seg.stop_k)
        n_unreachable += not p_lo < seg.to_kw < p_hi
        sse.append(abs(steady_state_error_kw(measured_error[part])))
        iae += integral_absolute_error_kw_s(true_error[part], scenario.ts_s)
        from_kw, to_kw = (min(max(v, p_lo), p_hi) for v in (seg.from_kw, seg.to_kw))
        over = overshoot_kw(result.power_true_kw[part], from_kw=from_kw, to_kw=to_kw)
        if over > worst_kw:
            worst_kw = over
            worst_pct = 100.0 * over / abs(to_kw - from_kw) if to_kw != from_kw else math.nan
    n_violations = count_limit_violations(result.triac_pct, (lo, hi))
    if max_move_pct_per_step is not None:
        n_violations += count_rate_violations(result.triac_pct, max_move_pct_per_step)
    return {
        "offset_free": all(e < OFFSET_FREE_THRESHOLD_KW for e in sse),
        "max_abs_steady_state_error_reachable_kw": (
            math.nan if not sse or any(math.isnan(e) for e in sse) else max(sse)),
        "n_unreachable_changes": int(n_unreachable), "iae_changes_reachable_kw_s": iae,
        "max_overshoot_reachable_kw": worst_kw, "max_overshoot_reachable_pct": worst_pct,
        "n_allowed_range_violations": int(n_violations),
    }


__all__ = ["COUNT_COLUMNS", "METRIC_COLUMNS", "OFFSET_FREE_THRESHOLD_KW", "REACHABLE_COLUMNS",
           "TIMING_COLUMNS", "metric_row", "reachable_row"]
