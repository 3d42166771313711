"""OffsetFreeMPC: composes estimator, target, QP, inversion and supervision into one step.

Notation
--------
``s`` [%] TRIAC input, ``ds = s - s_nom``; ``P`` [kW] heater power, ``y = P - P_nom``;
``w = f(ds)`` [kW-equivalent] (paper eq. 28); ``z = [x; d]`` the augmented estimator
state (`czmpc.kalman.Estimator`); ``eps`` [kW] the innovation.

One step (``docs/theory.rst``, C3-C9), for measured ``P_k`` and setpoint ``P_ref``:

0. take the input actually applied over the last sample (``applied_triac_pct``) and the
   grid voltage measured over it (``grid_voltage_factor``, `czmpc.voltage`): the
   estimator's prediction is corrected to the effective input they give and the rate
   limit starts from the applied input; ramp the limits and shape the setpoint and its
   preview (`czmpc.supervision`);
1. validity checks (`czmpc.validation`), then the measurement update with a valid
   ``y_k`` only; otherwise the estimator runs on the model alone (soft sensor);
2. target ``(x_s, w_s)`` for the current ``d`` and the last setpoint in the horizon
   (`czmpc.target`);
3. QP over the horizon in the effective ``w`` (`czmpc.qp`), tracking the setpoint
   trajectory (the preview, held past its end; a setpoint the target cannot reach is
   tracked itself, not the reachable target), checked; on failure the shifted previous
   plan, then the target;
4. ``ds = f^-1(w_0)`` (`czmpc.inversion`, through the voltage), clipped to the limits and
   the rate limit;
5. time update with the effective ``w`` applied (in ``OFF``/``PREDICT`` the caller's input).

Modes and statuses: `czmpc.modes`. Run-time trouble never raises; what the controller
does for each fault, and what it reports, is ``docs/guides/controller_failures.rst``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace

import numpy as np

from czmpc._records import record_from_fields
from czmpc.diagnostics import Fallback, StepDiagnostics
from czmpc.errors import DesignError, SettingsError
from czmpc.inversion import InputMap, build_input_map, clamp, slope
from czmpc.kalman import Estimator, LevelChangeRule, SteadyStateKalman
from czmpc.mismatch import InnovationMonitor, monitored_noise_std_kw
from czmpc.modes import Mode, ModeTransition, Status, transition
from czmpc.ordered import OrderedProduct
from czmpc.qp import MPCQP, QPSolution
from czmpc.qp_daqp import DAQPMPCQP
from czmpc.realization import AugmentedModel, augment, innovations_form
from czmpc.settings import MPCSettings
from czmpc.supervision import LimitRamp, SetpointShaper, ShapedPreview, ShapedSetpoint
from czmpc.target import SteadyStateMap, Target, compute_target, steady_state_map
from czmpc.validation import MeasurementCheck, MeasurementChecker, Verdict
from czmpc.voltage import VoltageDeadband, absolute_drive_kw
from sysid._typing import FloatArray
from sysid.model import HammersteinModel

#: Tolerance [% or kW-equivalent] for "the input sits on a bound" (status CLAMPED).
CLAMP_TOL = 1e-6
#: Tolerance [%] for "the applied input differs from the command".
APPLIED_TOL_PCT = 1e-6


#: Stage 3's decision: solution, first move [kW-equivalent], fallback, the first move's
#: bounds [kW-equivalent], max_bad_solves reached. A plain tuple: a NamedTuple cost 0.3 us.
_Plan = tuple[QPSolution, float, Fallback, float, float, bool]


class OffsetFreeMPC:
    """Offset-free Hammerstein MPC of heater power (``docs/theory.rst``, C1-C7).

    Parameters
    ----------
    model :
        The identified Hammerstein (or linear) model; at least one sample of delay.
    settings :
        Tuning; None for `MPCSettings.default_for` ``(model)`` (rate limit on).
    initial_triac_pct :
        The input the plant holds now [%], for a bumpless start; overrides
        ``settings.initial_triac_pct`` (None keeps that).

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
        The allowed input range leaves the monotone branch of ``f``, the augmented pair
        is not detectable, the model has no delay or no static gain, a DARE has no
        stabilizing solution, or ``initial_triac_pct`` is outside the allowed range.

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
        rel = self._rel = settings.reliability
        im = self._input_map = build_input_map(
            model, triac_min_pct=settings.triac_min_pct, triac_max_pct=settings.triac_max_pct,
            validity_margin_pct=settings.validity_margin_pct,
        )
        base = innovations_form(model)
        self._aug: AugmentedModel = augment(base, settings.disturbance_model)
        # The trace reaches back over a frozen run of several times stuck_samples.
        self._est = Estimator(self._aug, settings.disturbance_noise,
                              noise_std_kw=monitored_noise_std_kw(model),
                              max_gap=rel.max_predicted_samples + 1,
                              history_samples=4 * max(rel.stuck_samples, 1) + 1)
        self._level_change = LevelChangeRule(rel.level_change_k_sigma)
        self._ssm: SteadyStateMap = steady_state_map(base, settings.disturbance_model)
        _check_static_gain(model, self._ssm.static_gain, im)
        n = self._n_x = base.n_states
        # h = A (x - x_s) + G_x eps (`czmpc.qp`) = [A, 0, -A, G_x] [z; x_s; eps]: the QP
        # folds the map into its own products and reads the terms from its h_input.
        h_map = np.hstack([base.A, np.zeros((n, 1)), -base.A, self._est.gains.G[:n].reshape(n, 1)])
        qp_class = DAQPMPCQP if settings.solver == "daqp" else MPCQP  # the same QP
        self._qp = qp_class(
            A=base.A, B=base.B, C=base.C, horizon_steps=settings.horizon_steps,
            output_weight=settings.output_weight,
            input_target_weight=settings.input_target_weight,
            move_weight=settings.move_weight, has_rate_limit=settings.has_rate_limit,
            has_soft_min=settings.soft_power_min_kw is not None,
            has_soft_max=settings.soft_power_max_kw is not None,
            soft_limit_weight=settings.soft_limit_weight,
            soft_limit_linear_weight=settings.soft_limit_linear_weight,
            options=settings.osqp, bound_tol_kw=rel.solver_bound_tol_kw, h_map=h_map,
        )
        s_init = self._s_nom if settings.initial_triac_pct is None else settings.initial_triac_pct
        self._ds_init = s_init - self._s_nom
        if not im.ds_min_pct <= self._ds_init <= im.ds_max_pct:
            raise DesignError(
                f"OffsetFreeMPC: initial_triac_pct must lie in the allowed range "
                f"[{im.ds_min_pct + self._s_nom:g}, {im.ds_max_pct + self._s_nom:g}] %; "
                f"got {s_init:g}"
            )
        self._h_in = self._qp.h_input
        self._h_in_z, self._h_in_xs = self._h_in[: n + 1], self._h_in[n + 1 : -1]  # views, once
        self._d_power_gain = self._aug.disturbance_power_gain
        self._soft_min_rel, self._soft_max_rel = (
            None if kw is None else kw - self._p_nom
            for kw in (settings.soft_power_min_kw, settings.soft_power_max_kw))
        self._max_move = settings.max_move_pct_per_step
        self._bounds = self._qp.move_bounds(self._max_move)
        self._checker = MeasurementChecker(
            power_min_kw=rel.power_min_kw, power_max_kw=rel.power_max_kw,
            max_change_kw=rel.max_change_kw_per_sample, stuck_samples=rel.stuck_samples,
            stuck_min_predicted_change_kw=rel.stuck_min_predicted_change_kw,
            gate_k_sigma=rel.spike_gate_k_sigma, gate_floor_kw=rel.spike_gate_floor_kw,
            reopen_after=rel.reopen_after_samples,
        )
        self._monitor = InnovationMonitor(window_samples=rel.mismatch_window_samples,
                                          sigma_kw=self._est.sigma_kw,
                                          disturbance_limit_kw=rel.mismatch_disturbance_limit_kw)
        self._shaper = SetpointShaper(ts_s=self.ts_s, ramp_kw_per_s=rel.setpoint_ramp_kw_per_s,
                                      filter_time_s=rel.setpoint_filter_time_s,
                                      power_min_kw=rel.power_min_kw, power_max_kw=rel.power_max_kw)
        self._limits = LimitRamp(im, ramp_pct_per_step=rel.limit_ramp_pct_per_s * self.ts_s)
        self._shed_ds = (None if rel.shed_triac_pct is None
                         else clamp(rel.shed_triac_pct - self._s_nom, im.ds_min_pct, im.ds_max_pct))
        self._nan_plan = np.full(settings.horizon_steps, math.nan)
        self._nan_plan.flags.writeable = False
        self._horizon = settings.horizon_steps
        self._w0_abs = absolute_drive_kw(self._p_nom, self._ssm.static_gain)
        self._voltage = VoltageDeadband()
        self._scaled: tuple[InputMap, float, InputMap] | None = None  # (map, v^2, v^2 f)
        self._ref_cost = self._qp.reference_cost
        self._ref = np.empty(2 * settings.horizon_steps)          # [rho; sigma_-1..N-1], reused
        self._traj = np.empty(settings.horizon_steps + 3)         # [r_{k..k+N}; c_y; c_w]
        self._traj_cost = self._ref_cost @ _trajectory_map(settings.horizon_steps,
                                                             self._ssm.static_gain)
        # The step's products in one fixed order (`czmpc.ordered`): the generated C's.
        self._traj_product = OrderedProduct(self._traj_cost)
        self._ref_product = OrderedProduct(self._ref_cost)
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
        """Steps whose QP ended "solved inaccurate" (used, but flagged in the diagnostics)."""
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
        """``(s_min, s_max)`` the output stays in [%] (settings, model; `set_triac_limits` narrows it)."""
        return (self._input_map.ds_min_pct + self._s_nom,
                self._input_map.ds_max_pct + self._s_nom)

    @property
    def triac_limits_pct(self) -> tuple[float, float]:
        """Effective ``(min, max)`` TRIAC limits now [%] (ramping after a tightening)."""
        return self._limits.triac_pct

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
        return self._est.gains

    @property
    def qp(self) -> MPCQP:
        """The QP wrapper (for tests and experts)."""
        return self._qp

    def reset(self) -> None:
        """Forget all state, as if newly constructed: the estimator at the steady state of
        the initial input with ``d = 0``; mode, limits, counters and transition log initial."""
        w0 = self._input_map.f(self._ds_init)
        self._v2, self._v_offset = 1.0, 0.0   # v^2 and (v^2 - 1) W0 in force (`czmpc.voltage`)
        self._voltage.reset()
        self._restart_estimator(w0)
        self._ds_prev = self._ds_init
        self._w_prev = w0
        self._shaper.reset(self._p_nom + self._ssm.static_gain * w0)
        self._k = 0
        self._plan: FloatArray | None = None
        self._plan_k = 0
        self._n_fallbacks = self._n_inaccurate = self._n_rejected = self._n_shed = 0
        self._bad_in_row = 0
        self._mode = Mode(self._rel.initial_mode)
        self._warm = self._rel.warmup_samples if self._mode is Mode.ON else 0
        self._transitions: deque[ModeTransition] = deque(maxlen=self._rel.transition_log_size)
        self._pending: ModeTransition | None = None
        self._limits.reset()
        self._last: StepDiagnostics | None = None
        self._qp.request_cold_start()

    def _restart_estimator(self, w: float) -> None:
        """Estimator at the steady state of input ``w`` with ``d = 0``; checks reset."""
        w_eff = self._effective(w)
        self._est.restart(np.append(self._ssm.xw * w_eff, 0.0))
        self._w_eff_assumed = w_eff   # the effective input the estimator's last predict took
        self._warm = 0
        self._level_change.reset()
        self._stuck_rolled = False
        self._checker.reset()
        self._monitor.reset()

    # --- mode and limits ----------------------------------------------------------
    def request_mode(self, mode: Mode | str) -> ModeTransition:
        """Ask for a mode change; it applies from the next `step` (`czmpc.modes.transition`).

        Leaving ``OFF`` restarts the estimator, so ``ON`` needs ``warmup_samples`` valid
        samples in ``PREDICT`` first. Every request is logged (`drain_transitions`).

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

        Intersected with `allowed_triac_range_pct`; a tightened limit moves in from the
        current input at ``limit_ramp_pct_per_s``, a widened one applies at once
        (`czmpc.supervision.LimitRamp`).

        Raises
        ------
        SettingsError
            Non-finite or inverted limits, or none of the allowed range left.
        """
        self._limits.set(triac_min_pct, triac_max_pct, ds_now_pct=self._ds_prev)

    # --- the step -------------------------------------------------------------------
    def step(self, power_kw: float | None, setpoint_kw: float | None, *,
             applied_triac_pct: float | None = None,
             setpoint_preview_kw: object = None,
             grid_voltage_factor: float | None = None) -> float:
        """Return the TRIAC input [%] to apply now.

        Parameters
        ----------
        power_kw :
            Measured heater power [kW]; None, NaN or inf mark a missing sample. A sample
            failing a validity check (`czmpc.validation`, `czmpc.kalman.MAX_INNOVATION_KW`)
            is not fed to the estimator.
        setpoint_kw :
            Power setpoint [kW]. None, non-finite or implausible (``power_min_kw`` ..
            ``power_max_kw``, `czmpc.supervision.MAX_SETPOINT_KW`): the previous valid one
            is held (`StepDiagnostics.setpoint_verdict` says why), and nothing of it
            reaches the ramp or filter.
        applied_triac_pct :
            The input actually applied over the previous sample [%] if it differs from
            the one returned (saturation, override); None or non-finite: as returned. In
            ``OFF``/``PREDICT`` it is the caller's own input.
        setpoint_preview_kw :
            The setpoints [kW] of the coming samples as far as they are known (a recipe):
            entry ``i`` is the setpoint of sample ``k + 1 + i``. None or empty: no
            preview. Checked, ramped and filtered as ``setpoint_kw`` is; the known part
            ends at the first rejected entry and its last value is held to the end of
            the horizon (`StepDiagnostics.preview_samples` says how many were used).
        grid_voltage_factor :
            Grid voltage relative to nominal [-] measured over the previous sample; it
            is held over the horizon (`czmpc.voltage`). None: not measured (1). Missing
            (NaN) or implausible values also give 1 and say so in
            `StepDiagnostics.voltage_verdict`.

        Returns
        -------
        float
            TRIAC input [%]. In ``ON``: finite, inside the effective limits and within
            ``max_move_pct_per_step`` of the previous input (module notes). In
            ``OFF``/``PREDICT``: the caller's input (the last one known).
        """
        power = math.nan if power_kw is None else float(power_kw)
        mode = self._mode
        transition_record, self._pending = self._pending, None
        applied_differs = (False if applied_triac_pct is None
                           else self._take_applied_input(applied_triac_pct))
        v_verdict = self._take_voltage(grid_voltage_factor)
        if mode is not Mode.OFF:
            w_eff = self._effective(self._w_prev)
            if w_eff != self._w_eff_assumed:
                self._est.correct_input(self._w_eff_assumed, w_eff)
                self._w_eff_assumed = w_eff
        self._limits.ramp()
        sp = self._shaper.shape(setpoint_kw)
        preview = (None if setpoint_preview_kw is None
                   else self._shaper.preview(setpoint_preview_kw, self._horizon))
        n_preview = 0 if preview is None else preview.values_kw.size
        if mode is Mode.OFF:
            return self._record_off(power, sp, transition_record, v_verdict, n_preview)

        check, used, std_kw, rolled_back = self._measurement_update(power)
        est = self._est
        z, eps = est.z, est.eps
        d = float(z[self._n_x])
        em = self._limits.map
        v_off = self._v_offset
        em_v = em if self._v2 == 1.0 else self._scaled_map(em)   # v^2 f: w_eff = em_v.f + v_off
        w_min, w_max = em_v.w_min + v_off, em_v.w_max + v_off
        q_offset: FloatArray | None
        if preview is not None and n_preview:
            tgt = compute_target(self._ssm, setpoint=float(preview.values_kw[-1]) - self._p_nom,
                                 disturbance=d, w_min=w_min, w_max=w_max)
            q_offset = self._reference_cost(sp.used_kw, preview, tgt, w_min, w_max)
        else:
            tgt = compute_target(self._ssm, setpoint=sp.used_kw - self._p_nom, disturbance=d,
                                 w_min=w_min, w_max=w_max)
            q_offset = (None if tgt.is_reachable else self._reference_cost(
                sp.used_kw, ShapedPreview(np.array([sp.used_kw]), sp.used_kw, sp.used_kw), tgt,
                w_min, w_max))
        ds_prev = self._ds_prev
        plan = self._solve_or_fall_back(z, eps, tgt, em, em_v, q_offset)
        sol, w0, fallback, _, _, solver_shed = plan
        measurement_shed = est.gap > self._rel.max_predicted_samples
        ds, ds_raw = self._guard_input(w0 - v_off, ds_prev, measurement_shed, tgt, em_v)

        if mode is Mode.ON:
            status = self._judge(used, plan, tgt, ds, ds_raw, applied_differs,
                                 shed=measurement_shed or solver_shed)
            self._ds_prev = ds
            self._w_prev = em.f(ds)
        else:  # PREDICT: the caller keeps its input
            status = Status.HELD
        self._w_eff_assumed = w_applied = self._effective(self._w_prev)
        est.predict(w_applied)

        triac = self._s_nom + self._ds_prev
        d_power = d * self._d_power_gain
        verdict = sp.verdict
        # Every field, in the class's order (`record_from_fields`).
        self._last = record_from_fields(StepDiagnostics, {
            "k": self._k, "power_kw": power, "setpoint_kw": sp.received_kw,
            "setpoint_used_kw": sp.used_kw, "setpoint_held": verdict != "valid",
            "triac_pct": triac, "measurement_used": used, "innovation_kw": eps,
            "state_estimate": z, "disturbance_estimate": d, "disturbance_power_kw": d_power,
            "target_w": tgt.w_s, "target_triac_pct": self._s_nom + em_v.inverse(tgt.w_s - v_off),
            "target_power_kw": self._p_nom + tgt.y_s, "setpoint_reachable": tgt.is_reachable,
            "planned_w": sol.w, "solver_status": sol.status, "solve_time_s": sol.solve_time_s,
            "n_iterations": sol.n_iterations, "fallback": fallback,
            "soft_limit_slack_kw": sol.slack_kw, "mode": mode, "status": status,
            "verdict": check.verdict, "level_change_accepted": check.reopened,
            "innovation_std_kw": std_kw, "samples_without_measurement": est.gap,
            "bad_solves_in_row": self._bad_in_row, "advised_triac_pct": self._s_nom + ds,
            "applied_triac_pct": self._s_nom + ds_prev,
            "triac_limits_pct": self._limits.triac_pct,
            "mismatch": self._monitor.update(eps if used else None, disturbance_kw=d_power),
            "transition": transition_record, "setpoint_verdict": verdict,
            "rolled_back_samples": rolled_back, "preview_samples": n_preview,
            "voltage_factor_used": math.sqrt(self._v2), "voltage_verdict": v_verdict,
        })
        self._k += 1
        return triac

    # --- the stages of a step, in order ---------------------------------------------
    def _take_applied_input(self, applied_triac_pct: float) -> bool:
        """Stage 0: take the input applied over the last sample (if finite): the rate limit
        starts from it and the estimator is corrected to it (`step`). Returns whether it
        differs from the command."""
        applied = float(applied_triac_pct)
        if not math.isfinite(applied):
            return False
        ds_a = clamp(applied, 0.0, 100.0) - self._s_nom
        differs = abs(ds_a - self._ds_prev) > APPLIED_TOL_PCT
        if ds_a != self._ds_prev:
            self._ds_prev = ds_a
            self._w_prev = self._input_map.f(ds_a)
        return differs

    def _take_voltage(self, grid_voltage_factor: float | None) -> str:
        """Stage 0: the voltage factor in force from now on (1 unless measured and
        plausible; `czmpc.voltage.VoltageDeadband`), as ``v^2`` and ``(v^2 - 1) W0``;
        returns the reading's verdict."""
        v, verdict = self._voltage.take(grid_voltage_factor)
        self._v2 = v * v
        self._v_offset = (self._v2 - 1.0) * self._w0_abs
        return verdict

    def _effective(self, w: float) -> float:
        """The effective input ``v^2 w + (v^2 - 1) W0`` of nonlinearity output ``w`` now."""
        return w if self._v2 == 1.0 else self._v2 * w + self._v_offset

    def _scaled_map(self, em: InputMap) -> InputMap:
        """``v^2 f`` on ``em``'s range (kept while neither changes: the deadband holds ``v``)."""
        v2 = self._v2
        cached = self._scaled
        if cached is None or cached[0] is not em or cached[1] != v2:
            scaled = replace(em, coefficients=tuple(v2 * c for c in em.coefficients),
                             w_min=v2 * em.w_min, w_max=v2 * em.w_max)
            cached = self._scaled = (em, v2, scaled)
        return cached[2]

    def _reference_cost(self, setpoint_kw: float, preview: ShapedPreview, tgt: Target,
                        w_min: float, w_max: float) -> FloatArray:
        """Stage 2: the QP's linear cost for the setpoint now and those of samples ``k+1,
        ...`` [kW], held past their end; ``tgt`` is the last one's target
        (`czmpc.qp.MPCQP.solve`'s ``q_offset``; ``docs/theory.rst``, C8).

        The output references are the setpoints themselves, so a setpoint the target
        cannot reach pulls the output towards it, not towards the reachable target. The
        input targets follow the setpoints through the static gain, clipped to the bounds,
        and the moves they make cost nothing. Where none is clipped, the cost is one
        product with the trajectory.
        """
        n, n_values = self._horizon, preview.values_kw.size
        traj = self._traj
        traj[0] = setpoint_kw
        traj[1 : n_values + 1] = preview.values_kw
        r_end = float(preview.values_kw[-1])
        if n_values < n:
            traj[n_values + 1 : n + 1] = r_end
        inv_g = 1.0 / self._ssm.static_gain
        low, high = min(preview.low_kw, setpoint_kw), max(preview.high_kw, setpoint_kw)
        if (w_min <= tgt.w_unclipped + (low - r_end) * inv_g
                and tgt.w_unclipped + (high - r_end) * inv_g <= w_max):
            traj[n + 1] = self._p_nom + tgt.y_s
            traj[n + 2] = tgt.w_unclipped - tgt.w_s
            return self._traj_product(traj)
        ref = self._ref
        np.subtract(traj[1:n], self._p_nom + tgt.y_s, out=ref[: n - 1])
        sigma = np.clip(tgt.w_unclipped + (traj[: n + 1] - r_end) * inv_g, w_min, w_max)
        np.subtract(sigma, tgt.w_s, out=ref[n - 1 :])
        return self._ref_product(ref)

    def _measurement_update(self, power: float) -> tuple[MeasurementCheck, bool, float, int]:
        """Stage 1: validity checks, then the measurement update with a valid sample only.

        Returns the check, whether the update ran, the innovation std the gate used [kW]
        and the frozen samples rolled back now."""
        est = self._est
        std_kw = est.innovation_std_kw
        check = self._checker.check(power, predicted_kw=self._p_nom + est.predicted_output,
                                    innovation_std_kw=std_kw,
                                    gate=self._warm >= self._rel.warmup_samples)
        rolled_back = 0
        if check.verdict is Verdict.STUCK:
            if not self._stuck_rolled:   # first detection of this frozen run
                # The first of the identical readings was the sensor's last live one;
                # those accepted after it taught the estimator a false disturbance.
                self._stuck_rolled = True
                rolled_back = est.roll_back(check.stuck_run_samples - 2)
                self._n_rejected += rolled_back
                std_kw = est.innovation_std_kw
        else:
            self._stuck_rolled = False
        used = check.verdict is Verdict.VALID and est.update(power - self._p_nom)
        self._level_change.observe(est, std_kw, used)
        if used:
            self._warm += 1
        else:
            if check.verdict is not Verdict.VALID:
                est.skip()
            self._n_rejected += 1
        return check, used, std_kw, rolled_back

    def _solve_or_fall_back(self, z: FloatArray, eps: float, tgt: Target, em: InputMap,
                            em_v: InputMap, q_offset: FloatArray | None) -> _Plan:
        """Stage 3: the QP, checked; on failure the shifted previous plan, then the target.

        ``em_v`` is ``v^2 f`` (``em`` itself at ``v = 1``): the plan is of ``w_eff =
        em_v.f + (v^2 - 1) W0`` (`czmpc.voltage`)."""
        ds_prev = self._ds_prev
        ds_base = clamp(ds_prev, em.ds_min_pct, em.ds_max_pct)
        v_off = self._v_offset
        w_base = (self._effective(self._w_prev) if ds_base == ds_prev
                  else em_v.f(ds_base) + v_off if v_off else em_v.f(ds_base))
        h_in = self._h_in
        self._h_in_z[...] = z
        self._h_in_xs[...] = tgt.x_s
        h_in[-1] = eps
        w_lo, w_hi, rate = self._bounds.compute(em_v, ds_base)
        if v_off:
            w_lo += v_off
            w_hi += v_off
        sol: QPSolution = self._qp.solve(
            h_terms=h_in, w_prev=w_base, w_target=tgt.w_s, y_target=tgt.y_s, w_lo=w_lo,
            w_hi=w_hi, rate=rate, soft_min_rel_kw=self._soft_min_rel,
            soft_max_rel_kw=self._soft_max_rel, q_offset=q_offset,
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
        return (sol, w0, fallback, float(w_lo[0]), float(w_hi[0]),
                self._bad_in_row >= self._rel.max_bad_solves)

    def _guard_input(self, w0: float, ds_prev: float, measurement_shed: bool, tgt: Target,
                     em: InputMap) -> tuple[float, float]:
        """Stage 4: invert ``w0`` (less the voltage's offset; ``em`` is ``v^2 f``), or take the
        safe input when shed, then guard rate and limits.

        The safe input is ``shed_triac_pct``, else the target (from the last trusted
        estimate). Returns the guarded input and the one asked for [%, deviation].
        """
        if self._max_move is not None:
            r_lo, r_hi = ds_prev - self._max_move, ds_prev + self._max_move
        else:
            r_lo, r_hi = -math.inf, math.inf
        if measurement_shed:
            ds_raw = (em.inverse(tgt.w_s - self._v_offset) if self._shed_ds is None
                      else self._shed_ds)
        else:
            ds_raw = em.inverse(w0)
            if not math.isfinite(ds_raw):
                ds_raw = ds_prev
        return clamp(clamp(ds_raw, r_lo, r_hi), em.ds_min_pct, em.ds_max_pct), ds_raw

    def _judge(self, used: bool, plan: _Plan, tgt: Target, ds: float, ds_raw: float,
               applied_differs: bool, *, shed: bool) -> Status:
        """Stage 5: the status of an ``ON`` step (`czmpc.modes.Status`)."""
        if shed:
            self._n_shed += 1
            return Status.SHED
        _, w0, fallback, w_lo0, w_hi0, _ = plan
        if fallback != "none":
            return Status.HELD
        if not used:
            return Status.PREDICTED
        if (applied_differs or not tgt.is_reachable or abs(ds - ds_raw) > CLAMP_TOL
                or abs(w0 - w_lo0) <= CLAMP_TOL or abs(w0 - w_hi0) <= CLAMP_TOL):
            return Status.CLAMPED
        return Status.GOOD

    def _record_off(self, power: float, sp: ShapedSetpoint,
                    transition_record: ModeTransition | None, v_verdict: str,
                    n_preview: int) -> float:
        """``OFF``: nothing runs; record the held input and return it."""
        triac = self._s_nom + self._ds_prev
        z = self._est.z
        d = float(z[self._n_x])
        d_power = d * self._d_power_gain
        self._last = record_from_fields(StepDiagnostics, {
            "k": self._k, "power_kw": power, "setpoint_kw": sp.received_kw,
            "setpoint_used_kw": sp.used_kw, "setpoint_held": sp.verdict != "valid",
            "triac_pct": triac, "measurement_used": False, "innovation_kw": 0.0,
            "state_estimate": z, "disturbance_estimate": d, "disturbance_power_kw": d_power,
            "target_w": math.nan, "target_triac_pct": math.nan, "target_power_kw": math.nan,
            "setpoint_reachable": True, "planned_w": self._nan_plan,
            "solver_status": "skipped (mode off)", "solve_time_s": 0.0, "n_iterations": 0,
            "fallback": "none", "soft_limit_slack_kw": 0.0, "mode": Mode.OFF,
            "status": Status.HELD,
            "verdict": Verdict.VALID if math.isfinite(power) else Verdict.MISSING,
            "level_change_accepted": False, "innovation_std_kw": math.nan,
            "samples_without_measurement": self._est.gap, "bad_solves_in_row": self._bad_in_row,
            "advised_triac_pct": triac, "applied_triac_pct": triac,
            "triac_limits_pct": self._limits.triac_pct, "mismatch": None,
            "transition": transition_record, "setpoint_verdict": sp.verdict,
            "rolled_back_samples": 0, "preview_samples": n_preview,
            "voltage_factor_used": math.sqrt(self._v2), "voltage_verdict": v_verdict,
        })
        self._k += 1
        return triac


def _trajectory_map(horizon_steps: int, static_gain: float) -> FloatArray:
    """(2N, N+3) ``T`` with ``[rho; sigma] = T [r_{k..k+N}; c_y; c_w]`` when no input
    target is clipped: ``rho_j = r_{k+j} - c_y`` (``j = 1..N-1``) and ``sigma_j =
    (r_{k+j+1} - r_{k+N}) / g + c_w`` (``j = -1..N-1``), ``c_y = P_nom + y_s``,
    ``c_w = w_unclipped - w_s`` (`OffsetFreeMPC._reference_cost`)."""
    n = horizon_steps
    t = np.zeros((2 * n, n + 3))
    t[: n - 1, 1:n] = np.eye(n - 1)
    t[: n - 1, n + 1] = -1.0
    t[n - 1 :, : n + 1] = np.eye(n + 1) / static_gain
    t[n - 1 :, n] -= 1.0 / static_gain
    t[n - 1 :, n + 2] = 1.0
    return t


def _check_static_gain(model: HammersteinModel, gain: float, input_map: InputMap) -> None:
    """Refuse a static gain ``B(1)/A(1) f'(ds)`` over the allowed range not positive and finite."""
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


__all__ = ["APPLIED_TOL_PCT", "CLAMP_TOL", "Fallback", "OffsetFreeMPC", "StepDiagnostics"]
