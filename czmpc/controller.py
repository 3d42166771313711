"""OffsetFreeMPC and StepDiagnostics: composes the modules above.

Notation
--------
``s`` [%] TRIAC input, ``ds = s - s_nom``; ``P`` [kW] heater power, ``y = P - P_nom``;
``w = f(ds)`` [kW-equivalent] (paper eq. 28); ``z = [x; d]`` the augmented estimator
state (`czmpc.realization`); ``eps`` [kW] the innovation.

One step (DESIGN.md item 3), for measured ``P_k`` and setpoint ``P_ref``:

0. if the caller reports the input actually applied over the last sample
   (``applied_triac_pct``), the estimator's prediction is corrected to it (the time
   update is linear in ``w``), and the rate limit starts from it: no windup, and
   manual-to-auto is bumpless;
1. validity checks (`czmpc.validation`), then the measurement update with ``y_k`` only
   for a valid sample; otherwise the estimator runs on the model alone (soft sensor);
2. target ``(x_s, w_s)`` for the current ``d`` (`czmpc.target`) inside the effective
   TRIAC limits, for the (optionally ramped and filtered) setpoint;
3. QP over the horizon in ``w`` (`czmpc.qp`); every result is checked (status, finite,
   inside its bounds); on failure the shifted previous plan, then the target;
4. apply (``ON`` only): ``ds = f^-1(w_0)`` on the monotone branch, clipped to the
   effective limits and the rate limit (`czmpc.inversion`);
5. time update with the ``w`` applied (in ``OFF``/``PREDICT`` the caller's input).

Modes and statuses: `czmpc.modes`. Run-time trouble never raises (STYLE.md B.8).

Failure behaviour
-----------------
Defaults in brackets (`czmpc.settings.ReliabilitySettings`); ``Ts`` = 2 s. For each
fault: what the controller does -> what it reports (`StepDiagnostics`, counters).

Missing sample (NaN/inf), short (<= ``max_predicted_samples`` [60 = 120 s])
    Soft sensor: the estimator runs on the model alone and control continues on its
    predictions; the spike gate widens with the grown prediction error covariance ->
    ``status PREDICTED``, ``verdict MISSING``, ``samples_without_measurement``,
    ``n_rejected_measurements``.
Missing samples, long (> ``max_predicted_samples``)
    Sheds: moves at the rate limit to a safe input and holds it until a valid sample
    returns: ``shed_triac_pct`` when set, else the steady input that holds the setpoint
    by the last trusted estimate (the target); then tracking resumes from it within the
    rate limit -> ``status SHED``, ``n_shed_steps``; ``GOOD`` again at the first valid
    sample.
Stuck sensor (the same value for ``stuck_samples`` [10] while the prediction moves by
>= ``stuck_min_predicted_change_kw`` [0.1 kW])
    Frozen readings are rejected (soft sensor, then shed as above); the frozen readings
    accepted before detection are undone: the estimator is rolled back to the last live
    reading and predicts from there with the inputs applied since, so nothing learned
    from them drives the input; a quiet signal at a constant input never trips ->
    ``verdict STUCK``, ``PREDICTED``/``SHED``, ``rolled_back_samples`` at detection.
Bad setpoint (None, not finite, below ``power_min_kw``, above ``power_max_kw`` or
`MAX_SETPOINT_KW`)
    Rejected per call: the last valid setpoint is held and nothing of the bad one
    reaches the ramp or filter -> ``setpoint_held``, ``setpoint_verdict``.
Missing power (None)
    As NaN: a missing sample.
Spike (``|eps| > max(k sigma, floor)`` [off; e.g. 8 sigma, 0.5 kW], sigma the predicted
innovation std)
    The sample is rejected (soft sensor for it); after ``reopen_after_samples`` [3]
    rejections in a row the value is accepted as a level change and the gate stays
    open until the innovation is back inside -> ``verdict SPIKE``,
    ``status PREDICTED``; ``level_change_accepted`` when re-opened. Off by default (a
    genuine step disturbance looks like a level change for a few samples).
Negative power / beyond the rating (``power_min_kw`` [0], ``power_max_kw`` [off])
    The sample is rejected (soft sensor, then shed) -> ``verdict BELOW_LIMIT`` /
    ``ABOVE_LIMIT``.
Too fast a change (``max_change_kw_per_sample`` [off])
    As a spike (re-opens the same way) -> ``verdict TOO_FAST``.
Solver failure (status not solved, non-finite, outside its bounds by more than
``solver_bound_tol_kw`` [0.01 kW], OSQP time limit ``osqp.time_limit_s`` [off])
    Shifted previous plan, then the target; the next solve cold-starts; after
    ``max_bad_solves`` [5] in a row it sheds to the offset-free target and keeps trying
    -> ``fallback``, ``solver_status``, ``status HELD``, ``n_fallbacks``,
    ``bad_solves_in_row``; ``SHED`` from ``max_bad_solves`` on; ``GOOD`` at the first
    good solve.
Manual operation (``OFF``/``PREDICT``, `request_mode`)
    The caller's input is returned and fed to the estimator (``PREDICT``); ``ON`` starts
    from the applied input within the rate limit (bumpless) and needs
    ``warmup_samples`` [5] valid samples first -> ``mode``, ``status HELD``,
    ``advised_triac_pct``; every request in ``transition`` and `drain_transitions`.
Manual override, stuck TRIAC, downstream saturation (``applied_triac_pct`` differs from
the command)
    The estimator uses the applied input, so ``d`` does not wind up; the next move
    starts from it; tracking resumes when the actuator frees -> ``status CLAMPED``,
    ``applied_triac_pct``.
Tightened limit (`set_triac_limits`)
    The limit moves in at ``limit_ramp_pct_per_s`` [0.5 %/s] from the current input;
    widening applies at once -> ``triac_limits_pct`` (effective), ``CLAMPED`` while the
    input sits on it.
Unreachable setpoint
    The target is clipped to the limits, not chased -> ``setpoint_reachable False``,
    ``CLAMPED``.
Biased sensor, plant drifted from the model
    Control unchanged (the integrating disturbance absorbs it) -> ``mismatch``
    (`czmpc.mismatch.MismatchStats`: ``biased`` / ``drifted``).

The returned input is always finite and inside the effective TRIAC limits in ``ON``;
it respects the rate limit except where a limit forces it (an input applied outside
the limits by the caller, or a limit ramp faster than the rate limit).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Literal, NamedTuple

import numpy as np

from czmpc.errors import DesignError, SettingsError
from czmpc.inversion import InputMap, build_input_map, slope
from czmpc.kalman import SteadyStateKalman, design_estimator, innovation_variance_after_gap
from czmpc.mismatch import InnovationMonitor, MismatchStats, monitored_noise_std_kw
from czmpc.modes import Mode, ModeTransition, Status, transition
from czmpc.qp import MPCQP, QPSolution, move_bounds
from czmpc.realization import AugmentedModel, augment, innovations_form
from czmpc.settings import MPCSettings
from czmpc.target import SteadyStateMap, Target, compute_target, steady_state_map
from czmpc.validation import MeasurementCheck, MeasurementChecker, Verdict
from sysid._typing import FloatArray
from sysid.model import HammersteinModel

Fallback = Literal["none", "shifted_plan", "target"]

#: A measurement whose innovation exceeds this [kW] is no heater power (CZ heaters run at
#: tens to a few hundred kW); it is treated as missing, so absurd values such as 1e300
#: cannot overflow the estimator. Recorded as ``measurement_used = False``.
MAX_INNOVATION_KW = 1e6
#: Largest setpoint magnitude taken [kW]: beyond it a setpoint is no heater power and is
#: rejected like a non-finite one (the previous setpoint is held), so that values such as
#: 1e308 cannot overflow the setpoint ramp and filter into inf or NaN.
MAX_SETPOINT_KW = 1e6
#: Tolerance [% or kW-equivalent] for "the input sits on a bound" (status CLAMPED).
CLAMP_TOL = 1e-6
#: Tolerance [%] for "the applied input differs from the command".
APPLIED_TOL_PCT = 1e-6


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
        Setpoint the step worked with [kW]: the received one (or the previous one
        held when the received one was not finite) after the optional ramp and filter.
    setpoint_held :
        True if the received setpoint was rejected and the previous one was held.
    setpoint_verdict :
        Why a setpoint was rejected, or ``"valid"``: ``"missing"`` (None),
        ``"not finite"``, ``"below power_min_kw"``, ``"beyond MAX_SETPOINT_KW"`` or
        ``"above power_max_kw"``.
    triac_pct :
        What `OffsetFreeMPC.step` returned [%].
    measurement_used :
        False if the measurement update was skipped: a sample that failed a validity
        check (`verdict`), one whose innovation exceeds `MAX_INNOVATION_KW`, or any
        sample in ``OFF``.
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
        What the step did (`czmpc.modes.Status`; module notes).
    verdict :
        Measurement validity (`czmpc.validation.Verdict`).
    level_change_accepted :
        True if the measurement was accepted only because the rate/spike check
        re-opened after repeated rejections.
    innovation_std_kw :
        Predicted innovation std the spike gate used [kW].
    samples_without_measurement :
        Consecutive samples (this one included) without a valid measurement.
    bad_solves_in_row :
        Consecutive QP solves (this one included) whose result was not used.
    advised_triac_pct :
        The input the controller would apply in ``ON`` [%] (equals ``triac_pct`` in
        ``ON``; the shadow advice in ``PREDICT``; the held input in ``OFF``).
    applied_triac_pct :
        The input applied over the previous sample as the estimator used it [%].
    triac_limits_pct :
        Effective ``(min, max)`` TRIAC limits this step [%] (ramping after a change).
    mismatch :
        Model-mismatch statistics (`czmpc.mismatch.MismatchStats`).
    transition :
        The mode request handled since the previous step, or None.
    rolled_back_samples :
        Past samples whose measurement updates this step undid: a frozen sensor was
        detected, so the readings it gave before detection are judged invalid too and
        the estimator was rolled back to the last live sample (0 otherwise).
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


class _Update(NamedTuple):
    """What the measurement update (stage 1b) produced."""

    z: FloatArray            # z_{k|k}: filtered augmented state (the prediction if not used)
    eps: float               # innovation used [kW] (0 when not used)
    used: bool               # the measurement update ran
    check: MeasurementCheck  # the validity verdict
    std_kw: float            # predicted innovation std the gate used [kW]
    rolled_back: int         # frozen samples undone at this step (`_roll_back`)


class _Trace(NamedTuple):
    """One past step as the estimator saw it, kept to roll back a frozen sensor."""

    z_post: FloatArray       # z_{j|j}
    eps: float               # innovation used at j [kW]
    w_applied: float         # w applied over sample j [kW-equivalent]


class _Plan(NamedTuple):
    """What the QP stage (stage 3) decided."""

    solution: QPSolution
    w0: float                # first move to apply [kW-equivalent] (plan or fallback)
    fallback: Fallback
    w_lo0: float             # bounds of the first move [kW-equivalent]
    w_hi0: float
    solver_shed: bool        # max_bad_solves reached


class OffsetFreeMPC:
    """Offset-free Hammerstein MPC of heater power (DESIGN.md, "The controller").

    Parameters
    ----------
    model :
        The identified Hammerstein (or linear) model; at least one sample of delay.
    settings :
        Tuning; None for `MPCSettings.default_for` ``(model)`` (rate limit on).
    initial_triac_pct :
        The TRIAC input the plant holds now [%] (read it from the plant), for a
        bumpless start: the estimator starts at its steady state and the first move is
        within the rate limit of it. Overrides ``settings.initial_triac_pct``; None
        keeps that (None there too: the model's operating point).

    Attributes
    ----------
    ts_s :
        Sampling time [s] (the model's).
    settings :
        The settings in use.
    model :
        The model in use.

    Raises
    ------
    SettingsError
        If ``settings.ts_s`` is given and differs from the model's sampling time.
    DesignError
        If the allowed input range leaves the monotone branch of ``f``, the augmented
        pair is not detectable, the model has no delay or no static gain, a DARE has
        no stabilizing solution, or ``initial_triac_pct`` lies outside the allowed range.

    Examples
    --------
    >>> from sysid.model import HammersteinModel, OperatingPoint
    >>> m = HammersteinModel(kind="hammerstein", linear_block="armax", ts_s=2.0,
    ...     operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
    ...     a=[1.0, -0.99], b=[0.0, 1.0, -0.991], c=[1.0, -0.9],
    ...     input_poly=[1.35, -0.0065], noise_std_kw=0.0134, input_range_pct=(20.0, 70.0))
    >>> mpc = OffsetFreeMPC(m, initial_triac_pct=45.0)
    >>> s = mpc.step(power_kw=45.0, setpoint_kw=46.0)
    >>> 45.0 < s <= 45.0 + mpc.settings.max_move_pct_per_step
    True
    >>> mpc.last_step.status.name
    'GOOD'
    """

    def __init__(self, model: HammersteinModel, settings: MPCSettings | None = None, *,
                 initial_triac_pct: float | None = None) -> None:
        settings = MPCSettings.default_for(model) if settings is None else settings
        if not isinstance(settings, MPCSettings):
            raise TypeError(f"OffsetFreeMPC: settings must be MPCSettings; got {settings!r}")
        if initial_triac_pct is not None:
            settings = settings.with_updates(initial_triac_pct=initial_triac_pct)
        if settings.ts_s is not None and not math.isclose(settings.ts_s, model.ts_s,
                                                          rel_tol=1e-9, abs_tol=0.0):
            raise SettingsError(
                f"MPCSettings.ts_s: expected the model's sampling time {model.ts_s:g} s; "
                f"got {settings.ts_s:g} s"
            )
        self.model = model
        self.settings = settings
        self.ts_s = model.ts_s
        self._p_nom = model.operating_point.power_kw
        self._s_nom = model.operating_point.triac_pct
        rel = settings.reliability
        self._rel = rel

        self._input_map: InputMap = build_input_map(
            model, triac_min_pct=settings.triac_min_pct, triac_max_pct=settings.triac_max_pct,
            validity_margin_pct=settings.validity_margin_pct,
        )
        base = innovations_form(model)
        self._aug: AugmentedModel = augment(base, settings.disturbance_model)
        self._kf: SteadyStateKalman = design_estimator(self._aug, settings.disturbance_noise)
        self._ssm: SteadyStateMap = steady_state_map(base, settings.disturbance_model)
        _check_static_gain(model, self._ssm.static_gain, self._input_map)
        # Long enough to reach back over a frozen run of several times stuck_samples.
        self._history: deque[_Trace] = deque(maxlen=4 * max(settings.reliability.stuck_samples, 1) + 1)
        self._stuck_rolled = False
        self._n_rolled_back = 0
        self._qp = MPCQP(
            A=base.A, B=base.B, C=base.C, horizon_steps=settings.horizon_steps,
            output_weight=settings.output_weight,
            input_target_weight=settings.input_target_weight,
            move_weight=settings.move_weight, has_rate_limit=settings.has_rate_limit,
            has_soft_min=settings.soft_power_min_kw is not None,
            has_soft_max=settings.soft_power_max_kw is not None,
            soft_limit_weight=settings.soft_limit_weight,
            soft_limit_linear_weight=settings.soft_limit_linear_weight,
            options=settings.osqp, bound_tol_kw=rel.solver_bound_tol_kw,
        )
        s_init = self._s_nom if settings.initial_triac_pct is None else settings.initial_triac_pct
        ds_init = s_init - self._s_nom
        im = self._input_map
        if not im.ds_min_pct <= ds_init <= im.ds_max_pct:
            raise DesignError(
                f"OffsetFreeMPC: initial_triac_pct must lie in the allowed range "
                f"[{im.ds_min_pct + self._s_nom:g}, {im.ds_max_pct + self._s_nom:g}] %; "
                f"got {s_init:g}"
            )
        self._ds_init = ds_init
        # Precomputed pieces for the hot loop.
        n = base.n_states
        self._n_x = n
        self._A = np.array(base.A)
        self._Aaug = np.array(self._aug.A)
        self._Baug = np.array(self._aug.B)
        self._Caug = np.array(self._aug.C)
        self._M = np.array(self._kf.M)
        self._G = np.array(self._kf.G)
        self._Gx = np.array(self._kf.G[:n])
        self._d_power_gain = self._aug.disturbance_power_gain
        self._soft_min_rel = (
            None if settings.soft_power_min_kw is None else settings.soft_power_min_kw - self._p_nom
        )
        self._soft_max_rel = (
            None if settings.soft_power_max_kw is None else settings.soft_power_max_kw - self._p_nom
        )
        self._max_move = settings.max_move_pct_per_step
        sigma = monitored_noise_std_kw(model)
        gap_var = innovation_variance_after_gap(
            self._aug, self._kf, settings.disturbance_noise, rel.max_predicted_samples + 1)
        self._innovation_std_kw = [sigma * math.sqrt(v) for v in gap_var.tolist()]
        self._checker = MeasurementChecker(
            power_min_kw=rel.power_min_kw, power_max_kw=rel.power_max_kw,
            max_change_kw=rel.max_change_kw_per_sample, stuck_samples=rel.stuck_samples,
            stuck_min_predicted_change_kw=rel.stuck_min_predicted_change_kw,
            gate_k_sigma=rel.spike_gate_k_sigma, gate_floor_kw=rel.spike_gate_floor_kw,
            reopen_after=rel.reopen_after_samples,
        )
        self._monitor = InnovationMonitor(
            window_samples=rel.mismatch_window_samples,
            sigma_kw=self._innovation_std_kw[0],
            disturbance_limit_kw=rel.mismatch_disturbance_limit_kw,
        )
        if rel.setpoint_filter_time_s is None:
            self._sp_alpha = 1.0
        else:
            self._sp_alpha = 1.0 - math.exp(-self.ts_s / rel.setpoint_filter_time_s)
        self._sp_max_step = (None if rel.setpoint_ramp_kw_per_s is None
                             else rel.setpoint_ramp_kw_per_s * self.ts_s)
        self._limit_step_pct = rel.limit_ramp_pct_per_s * self.ts_s
        self._shed_ds = (None if rel.shed_triac_pct is None
                         else min(im.ds_max_pct, max(im.ds_min_pct,
                                                     rel.shed_triac_pct - self._s_nom)))
        self.reset()

    # --- public state -----------------------------------------------------------
    @property
    def last_step(self) -> StepDiagnostics | None:
        """Diagnostics of the latest `step`, or None before the first."""
        return self._last

    @property
    def mode(self) -> Mode:
        """The current mode (`czmpc.modes.Mode`)."""
        return self._mode

    @property
    def n_fallbacks(self) -> int:
        """Steps since construction/reset whose QP result was not used."""
        return self._n_fallbacks

    @property
    def n_inaccurate(self) -> int:
        """Steps whose QP ended "solved inaccurate" (used, but flagged; STYLE.md B.14)."""
        return self._n_inaccurate

    @property
    def n_rejected_measurements(self) -> int:
        """Samples (in ``PREDICT``/``ON``) not fed to the estimator since reset."""
        return self._n_rejected

    @property
    def n_shed_steps(self) -> int:
        """Steps reported ``SHED`` since reset."""
        return self._n_shed

    @property
    def allowed_triac_range_pct(self) -> tuple[float, float]:
        """``(s_min, s_max)`` the controller keeps its output in [%] (settings and model).

        `set_triac_limits` narrows this further at run time (`triac_limits_pct`).
        """
        return (self._input_map.ds_min_pct + self._s_nom,
                self._input_map.ds_max_pct + self._s_nom)

    @property
    def triac_limits_pct(self) -> tuple[float, float]:
        """Effective ``(min, max)`` TRIAC limits now [%] (ramping after a tightening)."""
        return (self._lo + self._s_nom, self._hi + self._s_nom)

    @property
    def input_map(self) -> InputMap:
        """``f`` on the allowed range (for tests and experts)."""
        return self._input_map

    @property
    def augmented_model(self) -> AugmentedModel:
        """The augmented innovations form the estimator uses."""
        return self._aug

    @property
    def estimator(self) -> SteadyStateKalman:
        """The steady-state Kalman gains."""
        return self._kf

    @property
    def qp(self) -> MPCQP:
        """The QP wrapper (for tests and experts)."""
        return self._qp

    def reset(self) -> None:
        """Forget all state, as if newly constructed.

        The estimator restarts at the steady state of the initial input
        (``initial_triac_pct`` or the operating point) with ``d = 0``; mode, limits and
        counters return to their initial values and the transition log is emptied.
        """
        im = self._input_map
        w0 = im.f(self._ds_init)
        self._restart_estimator(w0)
        self._ds_prev = self._ds_init
        self._w_prev = w0
        self._setpoint_kw = self._p_nom + self._ssm.static_gain * w0
        self._sp_ramped = self._setpoint_kw
        self._sp_filtered = self._setpoint_kw
        self._k = 0
        self._plan: FloatArray | None = None
        self._plan_k = 0
        self._n_fallbacks = 0
        self._n_inaccurate = 0
        self._n_rejected = 0
        self._n_shed = 0
        self._n_rolled_back = 0
        self._bad_in_row = 0
        self._mode = Mode(self._rel.initial_mode)
        self._warm = self._rel.warmup_samples if self._mode is Mode.ON else 0
        self._transitions: deque[ModeTransition] = deque(maxlen=self._rel.transition_log_size)
        self._pending: ModeTransition | None = None
        self._lo = im.ds_min_pct
        self._hi = im.ds_max_pct
        self._lo_goal = im.ds_min_pct
        self._hi_goal = im.ds_max_pct
        self._eff_map = im
        self._last: StepDiagnostics | None = None
        self._qp.request_cold_start()

    def _restart_estimator(self, w: float) -> None:
        """Estimator at the steady state of input ``w`` with ``d = 0``; checks reset."""
        z = np.zeros(self._n_x + 1)
        z[: self._n_x] = self._ssm.xw * w
        z.flags.writeable = False
        self._z = z
        self._warm = 0
        self._gap = 0
        self._history.clear()
        self._stuck_rolled = False
        self._checker.reset()
        self._monitor.reset()

    # --- mode and limits ----------------------------------------------------------
    def request_mode(self, mode: Mode | str) -> ModeTransition:
        """Ask for a mode change; it applies from the next `step` (`czmpc.modes.transition`).

        Entering ``OFF`` stops the estimator; leaving ``OFF`` restarts it at the steady
        state of the applied input, so ``ON`` needs ``warmup_samples`` valid samples in
        ``PREDICT`` first. Every request is logged (`drain_transitions`).

        Parameters
        ----------
        mode :
            A `Mode` or its value (``"off"``, ``"predict"``, ``"on"``).

        Returns
        -------
        ModeTransition
            The request and its outcome (refused requests leave the mode unchanged).
        """
        requested: Mode | str = mode
        if isinstance(mode, str):
            try:
                requested = Mode(mode)
            except ValueError:
                requested = mode
        ready = self._warm >= self._rel.warmup_samples
        new, reason = transition(self._mode, requested,  # type: ignore[arg-type]
                                 estimator_ready=ready)
        record = ModeTransition(
            k=self._k, from_mode=self._mode, to_mode=new,
            requested=requested if isinstance(requested, Mode) else self._mode,
            accepted=new is not self._mode, reason=reason,
        )
        if new is not self._mode:
            if new is Mode.OFF:
                self._warm = 0
            elif self._mode is Mode.OFF:
                self._restart_estimator(self._w_prev)
            if new is Mode.ON:
                self._qp.request_cold_start()
                self._plan = None
            self._mode = new
        self._transitions.append(record)
        self._pending = record
        return record

    def drain_transitions(self) -> tuple[ModeTransition, ...]:
        """Mode requests logged since the last call (oldest first; the log is bounded)."""
        out = tuple(self._transitions)
        self._transitions.clear()
        return out

    def set_triac_limits(self, triac_min_pct: float, triac_max_pct: float) -> None:
        """Change the TRIAC limits at run time [%].

        The limits are intersected with `allowed_triac_range_pct` (the settings' limits
        and the model's validity range). A tightened limit moves in at
        ``limit_ramp_pct_per_s`` starting from the current input (so it bites at once
        but never makes the input jump); a widened limit applies at once.

        Raises
        ------
        SettingsError
            Non-finite or inverted limits, or limits that leave nothing of the allowed
            range.
        """
        lo_pct, hi_pct = float(triac_min_pct), float(triac_max_pct)
        if not (math.isfinite(lo_pct) and math.isfinite(hi_pct) and lo_pct < hi_pct):
            raise SettingsError(
                f"OffsetFreeMPC.set_triac_limits: expected finite min < max [%]; got "
                f"({triac_min_pct!r}, {triac_max_pct!r})"
            )
        im = self._input_map
        lo = max(im.ds_min_pct, lo_pct - self._s_nom)
        hi = min(im.ds_max_pct, hi_pct - self._s_nom)
        if not lo < hi:
            a_lo, a_hi = self.allowed_triac_range_pct
            raise SettingsError(
                f"OffsetFreeMPC.set_triac_limits: expected limits overlapping the allowed "
                f"range [{a_lo:g}, {a_hi:g}] %; got ({lo_pct:g}, {hi_pct:g})"
            )
        cur = self._ds_prev
        self._lo_goal, self._hi_goal = lo, hi
        self._lo = lo if lo <= self._lo else min(lo, max(self._lo, cur))
        self._hi = hi if hi >= self._hi else max(hi, min(self._hi, cur))
        self._update_eff_map()

    def _update_eff_map(self) -> None:
        im = self._input_map
        if self._lo == im.ds_min_pct and self._hi == im.ds_max_pct:
            self._eff_map = im
        else:
            self._eff_map = replace(im, ds_min_pct=self._lo, ds_max_pct=self._hi,
                                    w_min=im.f(self._lo), w_max=im.f(self._hi))

    def _ramp_limits(self) -> None:
        step = self._limit_step_pct
        lo = min(self._lo_goal, self._lo + step) if self._lo < self._lo_goal else self._lo_goal
        hi = max(self._hi_goal, self._hi - step) if self._hi > self._hi_goal else self._hi_goal
        if lo != self._lo or hi != self._hi:
            self._lo, self._hi = lo, hi
            self._update_eff_map()

    def _shape_setpoint(self, setpoint: float) -> float:
        ramped = setpoint
        if self._sp_max_step is not None:
            delta = setpoint - self._sp_ramped
            ramped = self._sp_ramped + min(self._sp_max_step, max(-self._sp_max_step, delta))
        self._sp_ramped = ramped
        filtered = self._sp_filtered + self._sp_alpha * (ramped - self._sp_filtered)
        self._sp_filtered = filtered
        return filtered

    # --- the step -------------------------------------------------------------------
    def step(self, power_kw: float | None, setpoint_kw: float | None, *,
             applied_triac_pct: float | None = None) -> float:
        """Return the TRIAC input [%] to apply now.

        Parameters
        ----------
        power_kw :
            Measured heater power [kW] at this sample. None, NaN (or inf) mark a missing
            sample; it and any sample failing a validity check (`czmpc.validation`) is
            not fed to the estimator (also an absurd value, see `MAX_INNOVATION_KW`).
        setpoint_kw :
            Power setpoint [kW]. None, a non-finite value or one outside the plausible
            range (``power_min_kw`` .. ``power_max_kw`` or `MAX_SETPOINT_KW`) is rejected:
            the previous valid setpoint is held and `StepDiagnostics.setpoint_verdict`
            says why. Nothing of a rejected setpoint reaches the ramp or filter.
        applied_triac_pct :
            The TRIAC input actually applied over the previous sample [%], when the
            caller knows it differs from what was returned (saturation downstream,
            manual override, stuck TRIAC); None (or non-finite): as returned. In
            ``OFF``/``PREDICT`` it is the caller's own input.

        Returns
        -------
        float
            TRIAC input [%]. In ``ON``: finite, inside the effective limits and within
            ``max_move_pct_per_step`` of the previous input (module notes). In
            ``OFF``/``PREDICT``: the caller's input (the last one known).

        Notes
        -----
        The stages, in the order of the module notes: `_take_applied_input`,
        `_take_setpoint`, `_measurement_update`, the target (`compute_target`),
        `_solve_or_fall_back`, `_guard_input`, `_judge`, `_time_update`, and the
        record (`StepDiagnostics`).
        """
        power = math.nan if power_kw is None else float(power_kw)
        setpoint_in = math.nan if setpoint_kw is None else float(setpoint_kw)
        setpoint_verdict = "missing" if setpoint_kw is None else self._setpoint_verdict(setpoint_in)
        mode = self._mode
        transition_record = self._pending
        self._pending = None

        applied_differs = self._take_applied_input(applied_triac_pct, mode)
        self._ramp_limits()
        setpoint_used, held = self._take_setpoint(setpoint_in, setpoint_verdict)
        if mode is Mode.OFF:
            return self._record_off(power, setpoint_in, setpoint_used, held, transition_record,
                                    setpoint_verdict)

        upd = self._measurement_update(power)
        n = self._n_x
        d = float(upd.z[n])
        em = self._eff_map
        tgt = compute_target(self._ssm, setpoint=setpoint_used - self._p_nom, disturbance=d,
                             w_min=em.w_min, w_max=em.w_max)
        ds_prev = self._ds_prev
        plan = self._solve_or_fall_back(upd.z[:n], upd.eps, tgt)
        measurement_shed = self._gap > self._rel.max_predicted_samples
        ds, ds_raw = self._guard_input(plan.w0, ds_prev, measurement_shed, tgt)

        if mode is Mode.ON:
            status = self._judge(upd.used, plan, tgt, ds, ds_raw, applied_differs,
                                 shed=measurement_shed or plan.solver_shed)
            w_applied = self._input_map.f(ds)
            self._ds_prev = ds
            self._w_prev = w_applied
        else:  # PREDICT: the caller keeps its input
            status = Status.HELD
            w_applied = self._w_prev
        self._time_update(upd.z, upd.eps, w_applied)

        triac = self._s_nom + self._ds_prev
        d_power = d * self._d_power_gain
        stats = self._monitor.update(upd.eps if upd.used else None, disturbance_kw=d_power)
        sol = plan.solution
        self._last = StepDiagnostics(
            k=self._k, power_kw=power, setpoint_kw=setpoint_in, setpoint_used_kw=setpoint_used,
            setpoint_held=held, triac_pct=triac, measurement_used=upd.used, innovation_kw=upd.eps,
            state_estimate=upd.z, disturbance_estimate=d, disturbance_power_kw=d_power,
            target_w=tgt.w_s, target_triac_pct=self._s_nom + em.inverse(tgt.w_s),
            target_power_kw=self._p_nom + tgt.y_s, setpoint_reachable=tgt.is_reachable,
            planned_w=sol.w, solver_status=sol.status, solve_time_s=sol.solve_time_s,
            n_iterations=sol.n_iterations, fallback=plan.fallback,
            soft_limit_slack_kw=sol.slack_kw, mode=mode, status=status,
            verdict=upd.check.verdict, level_change_accepted=upd.check.reopened,
            innovation_std_kw=upd.std_kw, samples_without_measurement=self._gap,
            bad_solves_in_row=self._bad_in_row, advised_triac_pct=self._s_nom + ds,
            applied_triac_pct=self._s_nom + ds_prev,
            triac_limits_pct=(self._lo + self._s_nom, self._hi + self._s_nom),
            mismatch=stats, transition=transition_record, setpoint_verdict=setpoint_verdict,
            rolled_back_samples=upd.rolled_back,
        )
        self._k += 1
        return triac

    # --- the stages of a step, in order ---------------------------------------------
    def _take_applied_input(self, applied_triac_pct: float | None, mode: Mode) -> bool:
        """Stage 0: take the input actually applied over the last sample, if reported.

        The estimator's prediction is corrected to it (the time update is linear in
        ``w``) and the rate limit starts from it. Returns whether it differs from the
        command.
        """
        if applied_triac_pct is None:
            return False
        applied = float(applied_triac_pct)
        if not math.isfinite(applied):
            return False
        ds_a = min(100.0, max(0.0, applied)) - self._s_nom
        differs = abs(ds_a - self._ds_prev) > APPLIED_TOL_PCT
        if ds_a != self._ds_prev:
            w_a = self._input_map.f(ds_a)
            if mode is not Mode.OFF:
                z_corr = self._z + self._Baug * (w_a - self._w_prev)
                if np.isfinite(z_corr).all():
                    z_corr.flags.writeable = False
                    self._z = z_corr
                    if self._history:
                        self._history[-1] = self._history[-1]._replace(w_applied=w_a)
            self._ds_prev = ds_a
            self._w_prev = w_a
        return differs

    def _setpoint_verdict(self, setpoint: float) -> str:
        """``"valid"`` or why the setpoint is rejected (see `step`)."""
        if not math.isfinite(setpoint):
            return "not finite"
        rel = self._rel
        if rel.power_min_kw is not None and setpoint < rel.power_min_kw:
            return "below power_min_kw"
        if abs(setpoint) > MAX_SETPOINT_KW:
            return "beyond MAX_SETPOINT_KW"
        if rel.power_max_kw is not None and setpoint > rel.power_max_kw:
            return "above power_max_kw"
        return "valid"

    def _take_setpoint(self, setpoint_in: float, verdict: str) -> tuple[float, bool]:
        """Stage 1a: the setpoint to work with (held if rejected), ramped and filtered."""
        held = verdict != "valid"
        setpoint = self._setpoint_kw if held else setpoint_in
        self._setpoint_kw = setpoint
        return self._shape_setpoint(setpoint), held

    def _measurement_update(self, power: float) -> _Update:
        """Stage 1b: validity checks, then the measurement update with a valid sample only."""
        y_pred = float(self._Caug @ self._z)
        std_kw = self._innovation_std_kw[min(self._gap, len(self._innovation_std_kw) - 1)]
        check = self._checker.check(power, predicted_kw=self._p_nom + y_pred, innovation_std_kw=std_kw,
                                    gate=self._warm >= self._rel.warmup_samples)
        rolled_back = 0
        if check.verdict is Verdict.STUCK:
            if not self._stuck_rolled:   # first detection of this frozen run
                self._stuck_rolled = True
                rolled_back = self._roll_back(check.stuck_run_samples)
                y_pred = float(self._Caug @ self._z)
                std_kw = self._innovation_std_kw[min(self._gap, len(self._innovation_std_kw) - 1)]
        else:
            self._stuck_rolled = False
        z_pred = self._z
        used = False
        eps = 0.0
        z = z_pred
        if check.is_valid:
            innovation = (power - self._p_nom) - y_pred
            if abs(innovation) <= MAX_INNOVATION_KW:
                z = z_pred + self._M * innovation
                eps = innovation
                used = True
        if used:
            z.flags.writeable = False  # handed out in the diagnostics
            self._gap = 0
            self._warm += 1
        else:
            self._gap += 1
            self._n_rejected += 1
        return _Update(z=z, eps=eps, used=used, check=check, std_kw=std_kw, rolled_back=rolled_back)

    def _roll_back(self, run_samples: int) -> int:
        """Undo the updates with frozen readings: predict from the last live sample.

        ``run_samples`` identical readings end with this one; the first of them was the
        sensor's last live reading, the others were frozen, and those accepted before
        the run was long enough to judge taught the estimator a false disturbance
        (issue: a frozen sensor during a setpoint change leaves a lasting error). The
        estimator restarts from ``z`` after the live sample's update and predicts with
        the inputs actually applied since, as the soft sensor would have. Returns the
        number of frozen samples undone.
        """
        steps_back = min(run_samples - 1, len(self._history))
        if steps_back < 1:
            return 0
        traces = list(self._history)[-steps_back:]
        live = traces[0]
        z = self._Aaug @ live.z_post + self._Baug * live.w_applied + self._G * live.eps
        for trace in traces[1:]:
            z = self._Aaug @ z + self._Baug * trace.w_applied
        if not np.isfinite(z).all():
            return 0
        z.flags.writeable = False
        self._z = z
        frozen = steps_back - 1           # readings after the live one, before this one
        self._gap = max(self._gap, frozen)
        self._n_rejected += frozen
        self._n_rolled_back += frozen
        return frozen

    def _solve_or_fall_back(self, x: FloatArray, eps: float, tgt: Target) -> _Plan:
        """Stage 3: the QP, checked; on failure the shifted previous plan, then the target."""
        em = self._eff_map
        ds_prev = self._ds_prev
        ds_base = min(em.ds_max_pct, max(em.ds_min_pct, ds_prev))
        w_base = self._w_prev if ds_base == ds_prev else em.f(ds_base)
        h = self._A @ (x - tgt.x_s) + self._Gx * eps
        w_lo, w_hi, rate = move_bounds(em, ds_base, self._max_move, self.settings.horizon_steps)
        sol: QPSolution = self._qp.solve(
            h=h, w_prev=w_base, w_target=tgt.w_s, y_target=tgt.y_s, w_lo=w_lo,
            w_hi=w_hi, rate=rate, soft_min_rel_kw=self._soft_min_rel,
            soft_max_rel_kw=self._soft_max_rel,
        )
        fallback: Fallback
        if sol.is_usable:
            w0 = float(sol.w[0])
            fallback = "none"
            self._plan = sol.w
            self._plan_k = self._k
            self._bad_in_row = 0
            if not sol.is_accurate:
                self._n_inaccurate += 1
        else:
            self._n_fallbacks += 1
            self._bad_in_row += 1
            age = self._k - self._plan_k
            if (self._bad_in_row < self._rel.max_bad_solves and self._plan is not None
                    and age < self._plan.size):
                w0 = float(self._plan[age])
                fallback = "shifted_plan"
            else:
                w0 = tgt.w_s
                fallback = "target"
                self._plan = None
        return _Plan(solution=sol, w0=w0, fallback=fallback, w_lo0=float(w_lo[0]),
                     w_hi0=float(w_hi[0]), solver_shed=self._bad_in_row >= self._rel.max_bad_solves)

    def _guard_input(self, w0: float, ds_prev: float, measurement_shed: bool,
                     tgt: Target) -> tuple[float, float]:
        """Stage 4: invert ``w0`` (or take the safe input when shed), then the rate and limit guard.

        Shed for want of measurements, the safe input is ``shed_triac_pct`` when set, else
        the steady input that holds the setpoint by the last trusted estimate (the
        target: the model's steady state with the disturbance last estimated from valid
        data). Holding whatever input the last steps produced would keep the
        transients of the soft-sensor period, or what bad readings taught the estimator.

        Returns ``(ds, ds_raw)``: the guarded input and the one asked for [%, deviation].
        """
        em = self._eff_map
        if self._max_move is not None:
            r_lo, r_hi = ds_prev - self._max_move, ds_prev + self._max_move
        else:
            r_lo, r_hi = -math.inf, math.inf
        if measurement_shed:
            ds_raw = em.inverse(tgt.w_s) if self._shed_ds is None else self._shed_ds
        else:
            ds_raw = em.inverse(w0)
            if not math.isfinite(ds_raw):
                ds_raw = ds_prev
        ds_rate = min(r_hi, max(r_lo, ds_raw))
        return min(em.ds_max_pct, max(em.ds_min_pct, ds_rate)), ds_raw

    def _judge(self, used: bool, plan: _Plan, tgt: Target, ds: float, ds_raw: float,
               applied_differs: bool, *, shed: bool) -> Status:
        """Stage 5a: the status of an ``ON`` step (`czmpc.modes.Status`)."""
        if shed:
            self._n_shed += 1
            return Status.SHED
        if plan.fallback != "none":
            return Status.HELD
        if not used:
            return Status.PREDICTED
        if (applied_differs or not tgt.is_reachable or abs(ds - ds_raw) > CLAMP_TOL
                or abs(plan.w0 - plan.w_lo0) <= CLAMP_TOL or abs(plan.w0 - plan.w_hi0) <= CLAMP_TOL):
            return Status.CLAMPED
        return Status.GOOD

    def _time_update(self, z: FloatArray, eps: float, w_applied: float) -> None:
        """Stage 5b: predict the next state with the ``w`` actually applied (and keep the trace)."""
        self._history.append(_Trace(z_post=z, eps=eps, w_applied=w_applied))
        z_next = self._Aaug @ z + self._Baug * w_applied + self._G * eps
        if not np.isfinite(z_next).all():
            z_next = z.copy()
        z_next.flags.writeable = False
        self._z = z_next

    def _record_off(self, power: float, setpoint_in: float, setpoint_used: float, held: bool,
                    transition_record: ModeTransition | None, setpoint_verdict: str) -> float:
        """``OFF``: nothing runs; record the held input and return it."""
        triac = self._s_nom + self._ds_prev
        z = self._z
        d = float(z[self._n_x])
        nan_plan = np.full(self.settings.horizon_steps, math.nan)
        nan_plan.flags.writeable = False
        self._last = StepDiagnostics(
            k=self._k, power_kw=power, setpoint_kw=setpoint_in, setpoint_used_kw=setpoint_used,
            setpoint_held=held, triac_pct=triac, measurement_used=False, innovation_kw=0.0,
            state_estimate=z, disturbance_estimate=d,
            disturbance_power_kw=d * self._d_power_gain, target_w=math.nan,
            target_triac_pct=math.nan, target_power_kw=math.nan, setpoint_reachable=True,
            planned_w=nan_plan, solver_status="skipped (mode off)", solve_time_s=0.0,
            n_iterations=0, fallback="none", soft_limit_slack_kw=0.0, mode=Mode.OFF,
            status=Status.HELD, verdict=_verdict_off(power), innovation_std_kw=math.nan,
            samples_without_measurement=self._gap, bad_solves_in_row=self._bad_in_row,
            advised_triac_pct=triac, applied_triac_pct=triac,
            triac_limits_pct=(self._lo + self._s_nom, self._hi + self._s_nom),
            mismatch=None, transition=transition_record, setpoint_verdict=setpoint_verdict,
        )
        self._k += 1
        return triac


def _check_static_gain(model: HammersteinModel, gain: float, input_map: InputMap) -> None:
    """Refuse a model whose static gain over the allowed input range is not positive and finite.

    The steady gain from the TRIAC input to the power is ``B(1)/A(1) f'(ds)``; ``f'`` is
    positive on the allowed range (`build_input_map`), so the sign and finiteness of
    ``B(1)/A(1)`` decide. A model fitted to uninformative or sign-wrong data can have
    either wrong; an MPC on it would drive the heater the wrong way (DESIGN.md, "Facts
    that bite": identification may model a negative gain, the controller refuses it).
    """
    lo, hi = input_map.ds_min_pct, input_map.ds_max_pct
    g_lo = gain * slope(input_map.coefficients, lo)
    g_hi = gain * slope(input_map.coefficients, hi)
    if not (math.isfinite(gain) and gain > 0.0 and math.isfinite(g_lo) and math.isfinite(g_hi)):
        s_nom = model.operating_point.triac_pct
        raise DesignError(
            f"OffsetFreeMPC: the model's static gain over the allowed input range "
            f"[{lo + s_nom:g}, {hi + s_nom:g}] % must be positive and finite (power rising with "
            f"the TRIAC input); got B(1)/A(1) = {gain:.4g}, i.e. {g_lo:.4g} .. {g_hi:.4g} kW/%"
        )


def _verdict_off(power_kw: float) -> Verdict:
    """Verdict recorded in ``OFF`` (no checks run): missing or not."""
    return Verdict.VALID if math.isfinite(power_kw) else Verdict.MISSING


__all__ = ["APPLIED_TOL_PCT", "CLAMP_TOL", "MAX_INNOVATION_KW", "MAX_SETPOINT_KW", "Fallback",
           "OffsetFreeMPC", "StepDiagnostics"]
