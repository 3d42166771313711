"""Closed-loop metrics: IAE, ISE, overshoot, settling time, offsets, limit hits, step times.

Notation
--------
``e_k = P_k - r_k`` [kW], the power error at sample ``k`` (``P`` the true power by
default, see `compute_metrics`). Integrals use the rectangle rule over samples,
``IAE = sum |e_k| ts_s`` [kW s] and ``ISE = sum e_k^2 ts_s`` [kW^2 s], over the samples
from a setpoint change up to the next change (or the end of the run).

Per setpoint change of size ``D = r_new - r_old``:

* overshoot ``max(0, max_k sign(D) (P_k - r_new))`` [kW], also in % of ``|D|``;
* 2 % settling time: ``(k_last + 1 - k_0) ts_s`` [s], with ``k_0`` the first sample of
  the change and ``k_last`` the last sample of the segment with ``|e_k| > 0.02 |D|``
  (0 if there is none; None if the segment ends outside the band);
* steady-state error: mean of ``e`` over the last `STEADY_STATE_FRACTION` of the
  segment [kW].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Literal

import numpy as np

from sim.errors import ScenarioError
from sim.loop import ClosedLoopResult
from sysid._typing import FloatArray

#: Part of each segment (its end) over which the steady-state error is averaged.
STEADY_STATE_FRACTION = 0.25
#: Settling band, as a fraction of the step size.
SETTLING_BAND = 0.02
#: Slack on input and rate limits [%]: QP solutions meet bounds to about 1e-5 of the scale.
LIMIT_ATOL_PCT = 1e-6


# --- the metric functions (pure, on arrays) -----------------------------------------------
def integral_absolute_error_kw_s(error_kw: FloatArray, ts_s: float) -> float:
    """IAE ``sum |e_k| ts_s`` [kW s] (rectangle rule; NaN samples are skipped)."""
    return float(np.nansum(np.abs(error_kw)) * ts_s)


def integral_squared_error_kw2_s(error_kw: FloatArray, ts_s: float) -> float:
    """ISE ``sum e_k^2 ts_s`` [kW^2 s] (rectangle rule; NaN samples are skipped)."""
    return float(np.nansum(np.square(error_kw)) * ts_s)


def overshoot_kw(power_kw: FloatArray, *, from_kw: float, to_kw: float) -> float:
    """Largest excursion of ``power_kw`` beyond ``to_kw`` in the direction of the change [kW].

    0 when the response never passes ``to_kw`` (or the change is zero).
    """
    direction = math.copysign(1.0, to_kw - from_kw)
    if to_kw == from_kw or np.all(np.isnan(power_kw)):
        return 0.0
    return max(0.0, float(np.nanmax(direction * (np.asarray(power_kw) - to_kw))))


def settling_time_s(
    error_kw: FloatArray, *, step_kw: float, ts_s: float, band: float = SETTLING_BAND
) -> float | None:
    """Time after the change until ``|e|`` stays within ``band |step_kw|`` [s].

    Parameters
    ----------
    error_kw :
        ``e_k`` from the first sample of the change to the end of its segment [kW].
    step_kw :
        Size of the change [kW]; non-zero.
    ts_s :
        Sampling time [s].
    band :
        Band as a fraction of ``|step_kw|``.

    Returns
    -------
    float or None
        ``(k_last + 1) ts_s`` for the last sample ``k_last`` outside the band, 0 if none
        is; None if the last sample is outside (not settled). NaN samples are skipped.
    """
    e = np.asarray(error_kw, dtype=float)
    outside = np.abs(e) > band * abs(step_kw)        # NaN compares False: skipped
    idx = np.flatnonzero(outside)
    if idx.size == 0:
        return 0.0
    valid = np.flatnonzero(~np.isnan(e))
    if valid.size and idx[-1] == valid[-1]:
        return None
    return float((idx[-1] + 1) * ts_s)


def steady_state_error_kw(error_kw: FloatArray, *, fraction: float = STEADY_STATE_FRACTION) -> float:
    """Mean error over the last ``fraction`` of a segment (at least one sample) [kW]."""
    e = np.asarray(error_kw, dtype=float)
    n_tail = max(1, math.ceil(fraction * e.size))
    tail = e[-n_tail:]
    return math.nan if np.all(np.isnan(tail)) else float(np.nanmean(tail))


def total_variation_pct(triac_pct: FloatArray) -> float:
    """Input total variation ``sum |s_k - s_{k-1}|`` [%]."""
    return float(np.sum(np.abs(np.diff(triac_pct))))


def count_limit_violations(
    triac_pct: FloatArray, triac_limits_pct: tuple[float, float], *, atol_pct: float = LIMIT_ATOL_PCT
) -> int:
    """Number of samples with the input outside ``triac_limits_pct`` by more than ``atol_pct``."""
    lo, hi = triac_limits_pct
    s = np.asarray(triac_pct, dtype=float)
    return int(np.count_nonzero((s < lo - atol_pct) | (s > hi + atol_pct)))


def count_rate_violations(
    triac_pct: FloatArray, max_move_pct_per_step: float, *, atol_pct: float = LIMIT_ATOL_PCT
) -> int:
    """Number of moves ``|s_k - s_{k-1}|`` larger than ``max_move_pct_per_step + atol_pct``."""
    return int(np.count_nonzero(np.abs(np.diff(triac_pct)) > max_move_pct_per_step + atol_pct))


# --- results -------------------------------------------------------------------------------
def _jsonable(value: Any) -> Any:
    """``value`` for JSON: non-finite floats become None, tuples lists."""
    if isinstance(value, tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, float):
        return float(value) if math.isfinite(value) else None
    return value


@dataclass(frozen=True, slots=True, kw_only=True)
class ChangeMetrics:
    """Metrics of one setpoint change (its segment runs to the next change).

    Parameters
    ----------
    kind :
        ``"step"`` or ``"ramp"``.
    time_s :
        When the change begins [s].
    from_kw, to_kw :
        Setpoint before and after [kW].
    iae_kw_s :
        Integral absolute error over the segment [kW s].
    ise_kw2_s :
        Integral squared error over the segment [kW^2 s].
    overshoot_kw :
        Overshoot beyond ``to_kw`` [kW].
    overshoot_pct :
        Overshoot in % of ``|to_kw - from_kw|`` (NaN for a zero change).
    settling_time_s :
        2 % settling time after ``time_s`` [s]; None if not settled by the segment's end.
    steady_state_error_kw :
        Mean error over the segment's last part [kW].
    """

    kind: Literal["step", "ramp"]
    time_s: float
    from_kw: float
    to_kw: float
    iae_kw_s: float
    ise_kw2_s: float
    overshoot_kw: float
    overshoot_pct: float
    settling_time_s: float | None
    steady_state_error_kw: float

    @property
    def step_kw(self) -> float:
        """``to_kw - from_kw`` [kW]."""
        return self.to_kw - self.from_kw

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready mapping, the fields in order (non-finite numbers become None)."""
        return {f.name: _jsonable(getattr(self, f.name)) for f in fields(self)}


@dataclass(frozen=True, slots=True, kw_only=True)
class ClosedLoopMetrics:
    """Metrics of one closed-loop run.

    Parameters
    ----------
    scenario :
        Name of the scenario.
    power_signal :
        Which power the errors use: ``"true"`` or ``"measured"``.
    changes :
        One `ChangeMetrics` per setpoint change.
    steady_state_errors_kw :
        Steady-state error of every segment, the initial one first [kW].
    max_abs_steady_state_error_kw :
        Largest ``|steady-state error|`` over the segments [kW].
    iae_kw_s :
        IAE over the whole run [kW s].
    ise_kw2_s :
        ISE over the whole run [kW^2 s].
    input_total_variation_pct :
        ``sum |s_k - s_{k-1}|`` [%].
    max_move_pct :
        Largest ``|s_k - s_{k-1}|`` [%].
    step_time_median_ms, step_time_p95_ms, step_time_max_ms :
        Statistics of the controller's step time [ms].
    n_limit_violations :
        Samples with the input outside the TRIAC limits.
    n_rate_violations :
        Moves beyond the rate limit (0 when there is none).
    n_solver_failures :
        Steps whose diagnostics report ``fallback != "none"``; None without diagnostics.
    """

    scenario: str
    power_signal: Literal["true", "measured"]
    changes: tuple[ChangeMetrics, ...]
    steady_state_errors_kw: tuple[float, ...]
    max_abs_steady_state_error_kw: float
    iae_kw_s: float
    ise_kw2_s: float
    input_total_variation_pct: float
    max_move_pct: float
    step_time_median_ms: float
    step_time_p95_ms: float
    step_time_max_ms: float
    n_limit_violations: int
    n_rate_violations: int
    n_solver_failures: int | None

    @property
    def n_constraint_violations(self) -> int:
        """Limit plus rate violations."""
        return self.n_limit_violations + self.n_rate_violations

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready mapping, the fields in order with ``n_constraint_violations`` before
        ``n_solver_failures`` (non-finite numbers become None)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            if f.name == "n_solver_failures":
                out["n_constraint_violations"] = self.n_constraint_violations
            value = getattr(self, f.name)
            out[f.name] = [c.to_dict() for c in value] if f.name == "changes" else _jsonable(value)
        return out


def compute_metrics(
    result: ClosedLoopResult,
    *,
    triac_limits_pct: tuple[float, float] | None = None,
    max_move_pct_per_step: float | None = None,
    power_signal: Literal["true", "measured"] = "true",
) -> ClosedLoopMetrics:
    """Compute the metrics of a closed-loop run (see the module docstring for definitions).

    Parameters
    ----------
    result :
        The run; its scenario gives the setpoint changes.
    triac_limits_pct :
        ``(min, max)`` input [%] to check; None: the scenario's ``triac_limits_pct``.
    max_move_pct_per_step :
        Rate limit to check [%]; None: the scenario's (which may be None: no check).
    power_signal :
        ``"true"``: errors of the plant's noise-free power (sensor noise and faults are
        no control error); ``"measured"``: of the power the controller got (NaN skipped).

    Raises
    ------
    ScenarioError
        Inverted limits, a non-positive rate limit, or an unknown ``power_signal``.
    """
    scenario = result.scenario
    lo, hi = scenario.triac_limits_pct if triac_limits_pct is None else triac_limits_pct
    if not lo < hi:
        raise ScenarioError(f"compute_metrics: expected triac_limits_pct min < max; got ({lo}, {hi})")
    move = scenario.max_move_pct_per_step if max_move_pct_per_step is None else max_move_pct_per_step
    if move is not None and not move > 0:
        raise ScenarioError(f"compute_metrics: expected max_move_pct_per_step > 0; got {move!r}")
    power = {"true": result.power_true_kw, "measured": result.power_measured_kw}.get(power_signal)
    if power is None:
        raise ScenarioError(
            f"compute_metrics: expected power_signal 'true' or 'measured'; got {power_signal!r}")
    ts_s = result.ts_s
    error = power - result.setpoint_kw

    changes: list[ChangeMetrics] = []
    offsets: list[float] = []
    for seg in scenario.segments():
        e_seg = error[seg.start_k:seg.stop_k]
        offsets.append(steady_state_error_kw(e_seg))
        if seg.kind == "initial":
            continue
        step = seg.step_kw
        over = overshoot_kw(power[seg.start_k:seg.stop_k], from_kw=seg.from_kw, to_kw=seg.to_kw)
        changes.append(ChangeMetrics(
            kind=seg.kind,
            time_s=seg.start_k * ts_s,
            from_kw=seg.from_kw,
            to_kw=seg.to_kw,
            iae_kw_s=integral_absolute_error_kw_s(e_seg, ts_s),
            ise_kw2_s=integral_squared_error_kw2_s(e_seg, ts_s),
            overshoot_kw=over,
            overshoot_pct=100.0 * over / abs(step) if step != 0 else math.nan,
            settling_time_s=(settling_time_s(e_seg, step_kw=step, ts_s=ts_s)
                             if step != 0 else 0.0),
            steady_state_error_kw=offsets[-1],
        ))

    triac = result.triac_pct
    moves = np.abs(np.diff(triac))
    diags = result.diagnostics
    n_failures = (
        None if diags is None
        else sum(1 for d in diags if getattr(d, "fallback", "none") != "none")
    )
    step_ms = result.step_time_s * 1e3
    finite_offsets = [abs(v) for v in offsets if math.isfinite(v)]
    return ClosedLoopMetrics(
        scenario=scenario.name, power_signal=power_signal, changes=tuple(changes),
        steady_state_errors_kw=tuple(offsets),
        max_abs_steady_state_error_kw=max(finite_offsets) if finite_offsets else math.nan,
        iae_kw_s=integral_absolute_error_kw_s(error, ts_s),
        ise_kw2_s=integral_squared_error_kw2_s(error, ts_s),
        input_total_variation_pct=total_variation_pct(triac),
        max_move_pct=float(moves.max()) if moves.size else 0.0,
        n_limit_violations=count_limit_violations(triac, (lo, hi)),
        n_rate_violations=0 if move is None else count_rate_violations(triac, move),
        n_solver_failures=n_failures, step_time_median_ms=float(np.median(step_ms)),
        step_time_p95_ms=float(np.percentile(step_ms, 95)), step_time_max_ms=float(step_ms.max()))


__all__ = ["LIMIT_ATOL_PCT", "SETTLING_BAND", "STEADY_STATE_FRACTION", "ChangeMetrics", "ClosedLoopMetrics",
           "compute_metrics", "count_limit_violations", "count_rate_violations",
           "integral_absolute_error_kw_s", "integral_squared_error_kw2_s", "overshoot_kw", "settling_time_s",
           "steady_state_error_kw", "total_variation_pct"]
