"""StepDiagnostics: the record of what one controller step saw, decided and did."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from czmpc.mismatch import MismatchStats
from czmpc.modes import Mode, ModeTransition, Status
from czmpc.validation import Verdict
from sysid._typing import FloatArray

Fallback = Literal["none", "shifted_plan", "target"]


@dataclass(frozen=True, eq=False, kw_only=True)
class StepDiagnostics:
    """What one call of `OffsetFreeMPC.step` saw, decided and did.

    Parameters
    ----------
    k :
        Sample index since construction or `OffsetFreeMPC.reset` (0-based).
    power_kw :
        Measured power as received [kW] (may be NaN or infinite).
    setpoint_kw :
        Setpoint as received [kW] (may be non-finite).
    setpoint_used_kw :
        Setpoint the step worked with [kW]: the received or held one after the optional
        ramp and filter.
    setpoint_held :
        True if the received setpoint was rejected and the previous one was held.
    setpoint_verdict :
        ``"valid"`` or why the setpoint was rejected (`czmpc.supervision.SetpointShaper.verdict`).
    triac_pct :
        What `OffsetFreeMPC.step` returned [%].
    measurement_used :
        False if the measurement update was skipped (`verdict`,
        `czmpc.kalman.MAX_INNOVATION_KW`, or ``OFF``).
    innovation_kw :
        ``eps_k = y_k - C z_{k|k-1}`` [kW] (0 when the measurement was not used).
    state_estimate :
        (n+1,) filtered augmented state ``z_{k|k} = [x; d]``.
    disturbance_estimate :
        ``d`` [kW-equivalent for an input, kW for an output disturbance].
    disturbance_power_kw :
        Steady power change the estimated ``d`` causes [kW].
    target_w :
        Steady-state target input ``w_s`` [kW-equivalent].
    target_triac_pct :
        TRIAC input holding the target [%].
    target_power_kw :
        Steady power the target reaches [kW]; equals the setpoint when reachable.
    setpoint_reachable :
        False if no allowed input holds the setpoint (the target was clipped).
    planned_w :
        (N,) planned ``w`` [kW-equivalent] from this step's QP; NaN if it failed.
    solver_status :
        OSQP's status string, or a reason the QP was not solved.
    solve_time_s :
        OSQP solve time [s].
    n_iterations :
        OSQP iterations.
    fallback :
        ``"none"`` (QP plan used), ``"shifted_plan"`` or ``"target"``.
    soft_limit_slack_kw :
        Soft power limit violation planned by the QP [kW] (0 without soft limits).
    mode :
        The mode this step ran in (`czmpc.modes.Mode`).
    status :
        What the step did (`czmpc.modes.Status`; ``docs/guides/controller_failures.rst``).
    verdict :
        Measurement validity (`czmpc.validation.Verdict`).
    level_change_accepted :
        True if the measurement was accepted only because the rate/spike check re-opened.
    innovation_std_kw :
        Predicted innovation std the spike gate used [kW].
    samples_without_measurement :
        Consecutive samples (this one included) without a valid measurement.
    bad_solves_in_row :
        Consecutive QP solves (this one included) whose result was not used.
    advised_triac_pct :
        The input the controller would apply in ``ON`` [%] (the shadow advice in
        ``PREDICT``, the held input in ``OFF``).
    applied_triac_pct :
        The input applied over the previous sample as the estimator used it [%].
    triac_limits_pct :
        Effective ``(min, max)`` TRIAC limits this step [%] (ramping after a change).
    mismatch :
        Model-mismatch statistics (`czmpc.mismatch.MismatchStats`).
    transition :
        The mode request handled since the previous step, or None.
    rolled_back_samples :
        Past samples whose measurement updates this step undid on detecting a frozen
        sensor (the estimator rolled back to its last live sample); 0 otherwise.
    preview_samples :
        How many setpoints of the coming samples the step planned with (0: no preview;
        the preview ends at its first rejected entry).
    voltage_factor_used :
        Grid voltage factor [-] the step planned and inverted with (1 unless a measured
        one was valid).
    voltage_verdict :
        ``"not measured"``, ``"valid"``, ``"missing"`` or ``"implausible"``
        (`czmpc.voltage.voltage_verdict`); the last two fall back to 1.
    """

    k: int
    power_kw: float
    setpoint_kw: float
    setpoint_used_kw: float
    setpoint_held: bool
    triac_pct: float
    measurement_used: bool
    innovation_kw: float
    state_estimate: FloatArray = field(repr=False)
    disturbance_estimate: float
    disturbance_power_kw: float
    target_w: float
    target_triac_pct: float
    target_power_kw: float
    setpoint_reachable: bool
    planned_w: FloatArray = field(repr=False)
    solver_status: str
    solve_time_s: float
    n_iterations: int
    fallback: Fallback
    soft_limit_slack_kw: float
    mode: Mode = Mode.ON
    status: Status = Status.GOOD
    verdict: Verdict = Verdict.VALID
    level_change_accepted: bool = False
    innovation_std_kw: float = math.nan
    samples_without_measurement: int = 0
    bad_solves_in_row: int = 0
    advised_triac_pct: float = math.nan
    applied_triac_pct: float = math.nan
    triac_limits_pct: tuple[float, float] = (math.nan, math.nan)
    mismatch: MismatchStats | None = None
    transition: ModeTransition | None = None
    setpoint_verdict: str = "valid"
    rolled_back_samples: int = 0
    preview_samples: int = 0
    voltage_factor_used: float = 1.0
    voltage_verdict: str = "not measured"


__all__ = ["Fallback", "StepDiagnostics"]
