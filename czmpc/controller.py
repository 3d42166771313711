"""OffsetFreeMPC and StepDiagnostics: composes the modules above.

Notation
--------
``s`` [%] TRIAC input, ``ds = s - s_nom``; ``P`` [kW] heater power, ``y = P - P_nom``;
``w = f(ds)`` [kW-equivalent] (paper eq. 28); ``z = [x; d]`` the augmented estimator
state (`czmpc.realization`); ``eps`` [kW] the innovation.

One step (DESIGN.md item 3), for measured ``P_k`` and setpoint ``P_ref``:

1. measurement update with ``y_k`` (skipped if ``P_k`` is NaN or infinite);
2. target ``(x_s, w_s)`` for the current ``d`` (`czmpc.target`);
3. QP over the horizon in ``w`` (`czmpc.qp`);
4. apply: ``ds = f^-1(w_0)`` on the monotone branch, clipped to the allowed range and
   the rate limit (`czmpc.inversion`);
5. time update with the ``w = f(ds)`` actually applied (`czmpc.kalman`).

Run-time trouble never raises (STYLE.md B.8): a failed solve falls back to the
previous plan shifted by the samples since it was made, and when that is used up, to
the target ``w_s``; each fallback is recorded in `StepDiagnostics` and counted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from czmpc.errors import DesignError
from czmpc.inversion import InputMap, build_input_map
from czmpc.kalman import SteadyStateKalman, design_estimator
from czmpc.qp import MPCQP, QPSolution, move_bounds
from czmpc.realization import AugmentedModel, augment, innovations_form
from czmpc.settings import MPCSettings
from czmpc.target import SteadyStateMap, compute_target, steady_state_map
from sysid._typing import FloatArray
from sysid.model import HammersteinModel

Fallback = Literal["none", "shifted_plan", "target"]

#: A measurement whose innovation exceeds this [kW] is no heater power (CZ heaters run at
#: tens to a few hundred kW); it is treated as missing, so absurd values such as 1e300
#: cannot overflow the estimator. Recorded as ``measurement_used = False``.
MAX_INNOVATION_KW = 1e6


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
        Setpoint the step worked with [kW]: the received one, or the previous one
        held when the received one was not finite.
    setpoint_held :
        True if the received setpoint was not finite and the previous one was held.
    triac_pct :
        What `OffsetFreeMPC.step` returned [%].
    measurement_used :
        False if the measurement update was skipped: a missing (NaN) or infinite
        sample, or one whose innovation exceeds `MAX_INNOVATION_KW`.
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


class OffsetFreeMPC:
    """Offset-free Hammerstein MPC of heater power (DESIGN.md, "The controller").

    Parameters
    ----------
    model :
        The identified Hammerstein (or linear) model; at least one sample of delay.
    settings :
        Tuning; None for `MPCSettings.default_for` ``(model)``.

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
    >>> mpc = OffsetFreeMPC(m)
    >>> s = mpc.step(power_kw=45.0, setpoint_kw=46.0)
    >>> 45.0 < s < 50.0
    True
    """

    def __init__(self, model: HammersteinModel, settings: MPCSettings | None = None) -> None:
        settings = MPCSettings.default_for(model) if settings is None else settings
        if not isinstance(settings, MPCSettings):
            raise TypeError(f"OffsetFreeMPC: settings must be MPCSettings; got {settings!r}")
        self.model = model
        self.settings = settings
        self.ts_s = model.ts_s
        self._p_nom = model.operating_point.power_kw
        self._s_nom = model.operating_point.triac_pct

        self._input_map: InputMap = build_input_map(
            model, triac_min_pct=settings.triac_min_pct, triac_max_pct=settings.triac_max_pct,
            validity_margin_pct=settings.validity_margin_pct,
        )
        base = innovations_form(model)
        self._aug: AugmentedModel = augment(base, settings.disturbance_model)
        self._kf: SteadyStateKalman = design_estimator(self._aug, settings.disturbance_noise)
        self._ssm: SteadyStateMap = steady_state_map(base, settings.disturbance_model)
        self._qp = MPCQP(
            A=base.A, B=base.B, C=base.C, horizon_steps=settings.horizon_steps,
            output_weight=settings.output_weight,
            input_target_weight=settings.input_target_weight,
            move_weight=settings.move_weight, has_rate_limit=settings.has_rate_limit,
            has_soft_min=settings.soft_power_min_kw is not None,
            has_soft_max=settings.soft_power_max_kw is not None,
            soft_limit_weight=settings.soft_limit_weight,
            soft_limit_linear_weight=settings.soft_limit_linear_weight,
            options=settings.osqp,
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
        if self._max_move is None:
            w_lo, w_hi, _ = move_bounds(im, 0.0, None, settings.horizon_steps)
            self._fixed_w_lo: FloatArray | None = w_lo
            self._fixed_w_hi: FloatArray | None = w_hi
        else:
            self._fixed_w_lo = None
            self._fixed_w_hi = None
        self.reset()

    # --- public state -----------------------------------------------------------
    @property
    def last_step(self) -> StepDiagnostics | None:
        """Diagnostics of the latest `step`, or None before the first."""
        return self._last

    @property
    def n_fallbacks(self) -> int:
        """Steps since construction/reset whose QP result was not used."""
        return self._n_fallbacks

    @property
    def n_inaccurate(self) -> int:
        """Steps whose QP ended "solved inaccurate" (used, but flagged; STYLE.md B.14)."""
        return self._n_inaccurate

    @property
    def allowed_triac_range_pct(self) -> tuple[float, float]:
        """``(s_min, s_max)`` the controller keeps its output in [%]."""
        return (self._input_map.ds_min_pct + self._s_nom,
                self._input_map.ds_max_pct + self._s_nom)

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
        (``initial_triac_pct`` or the operating point) with ``d = 0``.
        """
        im = self._input_map
        w0 = im.f(self._ds_init)
        z = np.zeros(self._n_x + 1)
        z[: self._n_x] = self._ssm.xw * w0
        z.flags.writeable = False
        self._z = z
        self._ds_prev = self._ds_init
        self._w_prev = w0
        self._setpoint_kw = self._p_nom + self._ssm.static_gain * w0
        self._k = 0
        self._plan: FloatArray | None = None
        self._plan_k = 0
        self._n_fallbacks = 0
        self._n_inaccurate = 0
        self._last: StepDiagnostics | None = None
        self._qp.request_cold_start()

    # --- the step -------------------------------------------------------------------
    def step(self, power_kw: float, setpoint_kw: float) -> float:
        """Return the TRIAC input [%] to apply now.

        Parameters
        ----------
        power_kw :
            Measured heater power [kW] at this sample. NaN (or inf) marks a missing
            sample; the measurement update is then skipped (also for an absurd value,
            see `MAX_INNOVATION_KW`).
        setpoint_kw :
            Power setpoint [kW]. A non-finite value holds the previous setpoint
            (recorded in `last_step`).

        Returns
        -------
        float
            TRIAC input [%]: finite, inside the allowed range (so inside the TRIAC
            limits), and within ``max_move_pct_per_step`` of the previous input.
        """
        power = float(power_kw)
        setpoint_in = float(setpoint_kw)
        if math.isfinite(setpoint_in):
            setpoint = setpoint_in
            held = False
        else:
            setpoint = self._setpoint_kw
            held = True
        self._setpoint_kw = setpoint
        im = self._input_map

        # 1. measurement update
        z_pred = self._z
        used = False
        eps = 0.0
        z = z_pred
        if math.isfinite(power):
            innovation = (power - self._p_nom) - float(self._Caug @ z_pred)
            if abs(innovation) <= MAX_INNOVATION_KW:  # also False for NaN
                z = z_pred + self._M * innovation
                eps = innovation
                used = True
        if z is not z_pred:
            z.flags.writeable = False  # handed out in the diagnostics
        n = self._n_x
        x = z[:n]
        d = float(z[n])

        # 2. target
        tgt = compute_target(self._ssm, setpoint=setpoint - self._p_nom, disturbance=d,
                             w_min=im.w_min, w_max=im.w_max)

        # 3. QP
        h = self._A @ (x - tgt.x_s) + self._Gx * eps
        if self._fixed_w_lo is not None and self._fixed_w_hi is not None:
            w_lo, w_hi, rate = self._fixed_w_lo, self._fixed_w_hi, None
        else:
            w_lo, w_hi, rate = move_bounds(im, self._ds_prev, self._max_move,
                                           self.settings.horizon_steps)
        sol: QPSolution = self._qp.solve(
            h=h, w_prev=self._w_prev, w_target=tgt.w_s, y_target=tgt.y_s, w_lo=w_lo,
            w_hi=w_hi, rate=rate, soft_min_rel_kw=self._soft_min_rel,
            soft_max_rel_kw=self._soft_max_rel,
        )
        fallback: Fallback
        if sol.is_usable:
            w0 = float(sol.w[0])
            fallback = "none"
            self._plan = sol.w
            self._plan_k = self._k
            if not sol.is_accurate:
                self._n_inaccurate += 1
        else:
            self._n_fallbacks += 1
            age = self._k - self._plan_k
            if self._plan is not None and age < self._plan.size:
                w0 = float(self._plan[age])
                fallback = "shifted_plan"
            else:
                w0 = tgt.w_s
                fallback = "target"
                self._plan = None

        # 4. apply: invert and clip to the allowed range and the rate limit
        ds_prev = self._ds_prev
        lo, hi = im.ds_min_pct, im.ds_max_pct
        if self._max_move is not None:
            lo = max(lo, ds_prev - self._max_move)
            hi = min(hi, ds_prev + self._max_move)
        ds = im.inverse(w0)
        if not math.isfinite(ds):
            ds = ds_prev
        ds = min(hi, max(lo, ds))
        w_applied = im.f(ds)

        # 5. time update with the w actually applied
        z_next = self._Aaug @ z + self._Baug * w_applied + self._G * eps
        if not np.isfinite(z_next).all():
            z_next = z.copy()
        z_next.flags.writeable = False
        self._z = z_next
        self._ds_prev = ds
        self._w_prev = w_applied
        triac = self._s_nom + ds

        self._last = StepDiagnostics(
            k=self._k, power_kw=power, setpoint_kw=setpoint_in, setpoint_used_kw=setpoint,
            setpoint_held=held, triac_pct=triac, measurement_used=used, innovation_kw=eps,
            state_estimate=z, disturbance_estimate=d,
            disturbance_power_kw=d * self._d_power_gain, target_w=tgt.w_s,
            target_triac_pct=self._s_nom + im.inverse(tgt.w_s),
            target_power_kw=self._p_nom + tgt.y_s, setpoint_reachable=tgt.is_reachable,
            planned_w=sol.w, solver_status=sol.status, solve_time_s=sol.solve_time_s,
            n_iterations=sol.n_iterations, fallback=fallback,
            soft_limit_slack_kw=sol.slack_kw,
        )
        self._k += 1
        return triac


__all__ = ["MAX_INNOVATION_KW", "Fallback", "OffsetFreeMPC", "StepDiagnostics"]
