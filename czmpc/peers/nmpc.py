"""NonlinearMPC: the Hammerstein MPC solved by CasADi + IPOPT without inverting f.

The reference for "does the inversion lose anything": the same model, estimator
(`czmpc.kalman.Estimator`), disturbance model, target, cost and constraints as
`czmpc.controller.OffsetFreeMPC`, but the decision variables are the TRIAC deviations ``ds_j`` themselves and
``w_j = f(ds_j)`` sits inside the predicted dynamics (a nonlinear program).

Notation as in `czmpc.qp`: ``dx_j = x_j - x_s``, ``h = A (x_{k|k} - x_s) + G_x eps_k``,
``w_{-1} = f(ds_prev)``. The NLP (``docs/theory.rst``, C5, with ``w_j = f(ds_j)``)::

    min_ds  sum_{j=1}^{N-1} q_y (C dx_j - rho)^2
          + sum_{j=0}^{N-1} [ q_u (f(ds_j) - w_s)^2 + q_dw (f(ds_j) - f(ds_{j-1}))^2 ]
          + [dx_N; f(ds_{N-1}) - w_s]^T P_f [dx_N; f(ds_{N-1}) - w_s]
          + rho_2 v^2 + rho_1 v                                    (soft limits only)
    s.t.  dx_1 = h + B (f(ds_0) - w_s),  dx_{j+1} = A dx_j + B (f(ds_j) - w_s)
          ds_min <= ds_j <= ds_max
          |ds_0 - ds_prev| <= delta,  |ds_j - ds_{j-1}| <= delta    (rate, exact)
          P_min - v <= P_nom + y_s + C dx_j <= P_max + v, j = 1..N, v >= 0   (soft)

``rho = r - y_s`` is the gap to a setpoint the target cannot reach (0 when it can): the
output tracks the setpoint itself, as the MPC's (C8). The rate limit is exact on every
move here; the QP bounds later moves conservatively
(`czmpc.qp.MoveBounds`). Otherwise it is the same problem in another variable: without a
rate limit the two controllers agree to the solvers' tolerances.

The NLP is built once (``nlpsol`` with parameters ``[h, w_s, w_prev, y_s, rho]``); each step
warm-starts from the previous plan shifted by one sample. A failed solve falls back like
the MPC (shifted previous plan, then the target), counted in `n_fallbacks`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Literal

import casadi as ca
import numpy as np

from czmpc.errors import DesignError, SettingsError
from czmpc.inversion import InputMap, build_input_map
from czmpc.kalman import Estimator, LevelChangeRule
from czmpc.qp import terminal_cost
from czmpc.realization import augment, innovations_form
from czmpc.settings import MPCSettings
from czmpc.target import SteadyStateMap, compute_target, steady_state_map
from sysid._typing import FloatArray
from sysid.model import HammersteinModel

NMPCFallback = Literal["none", "shifted_plan", "target"]

#: IPOPT's convergence tolerance: tight enough that the plan matches the QP's (OSQP at
#: about 1e-5) to well below the noise, loose enough to converge in a few iterations.
IPOPT_TOL = 1e-8
#: IPOPT iteration cap per step; a solve that hits it counts as failed.
IPOPT_MAX_ITER = 200


@dataclass(frozen=True, eq=False, kw_only=True)
class NMPCStep:
    """What one call of `NonlinearMPC.step` saw, decided and did.

    Parameters
    ----------
    k :
        Sample index since construction or `NonlinearMPC.reset`.
    power_kw :
        Measured power as received [kW].
    setpoint_used_kw :
        Setpoint the step worked with [kW] (the previous one held if not finite).
    triac_pct :
        What `NonlinearMPC.step` returned [%].
    measurement_used :
        False if the measurement update was skipped (missing, infinite or absurd).
    innovation_kw :
        ``eps_k`` [kW] (0 when the measurement was not used).
    disturbance_estimate :
        ``d`` of the augmented state (as in `czmpc.controller.StepDiagnostics`).
    target_triac_pct :
        TRIAC input holding the steady-state target [%].
    setpoint_reachable :
        False if the target had to be clipped.
    planned_triac_pct :
        (N,) planned TRIAC inputs [%]; NaN if the solve failed.
    solver_status :
        IPOPT's return status.
    solve_time_s :
        Wall-clock time of the ``nlpsol`` call [s].
    n_iterations :
        IPOPT iterations.
    fallback :
        ``"none"`` (NLP plan used), ``"shifted_plan"`` or ``"target"``.
    """

    k: int
    power_kw: float
    setpoint_used_kw: float
    triac_pct: float
    measurement_used: bool
    innovation_kw: float
    disturbance_estimate: float
    target_triac_pct: float
    setpoint_reachable: bool
    planned_triac_pct: FloatArray = field(repr=False)
    solver_status: str
    solve_time_s: float
    n_iterations: int
    fallback: NMPCFallback


def _poly(coefficients: tuple[float, ...], ds: Any) -> Any:
    """``f(ds)`` by Horner's rule on a CasADi expression."""
    out = 0.0
    for coef in reversed(coefficients):
        out = (out + coef) * ds
    return out


class NonlinearMPC:
    """Offset-free Hammerstein NMPC in ``ds`` (module notes), CasADi + IPOPT.

    Parameters
    ----------
    model :
        The identified Hammerstein (or linear) model; at least one sample of delay.
    settings :
        The same `MPCSettings` as `OffsetFreeMPC` (horizon, weights, disturbance model
        and noise, limits, soft limits, initial input); None: `MPCSettings.default_for`.
        The OSQP options are not used.
    ipopt_tol :
        IPOPT's convergence tolerance (`IPOPT_TOL`), > 0.

    Attributes
    ----------
    ts_s :
        Sampling time [s].
    settings, model :
        What the controller was built from.

    Raises
    ------
    DesignError
        As `OffsetFreeMPC`: allowed range off the monotone branch, undetectable
        augmentation, no delay, no static gain, a failed DARE, or an initial input
        outside the allowed range.
    """

    def __init__(self, model: HammersteinModel, settings: MPCSettings | None = None, *,
                 ipopt_tol: float = IPOPT_TOL) -> None:
        settings = MPCSettings.default_for(model) if settings is None else settings
        if not isinstance(settings, MPCSettings):
            raise TypeError(f"NonlinearMPC: settings must be MPCSettings; got {settings!r}")
        if not (math.isfinite(ipopt_tol) and ipopt_tol > 0):
            raise SettingsError(f"NonlinearMPC.ipopt_tol: expected a number > 0; got {ipopt_tol!r}")
        self.ipopt_tol = float(ipopt_tol)
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
        self._est = Estimator(augment(base, settings.disturbance_model),
                              settings.disturbance_noise, noise_std_kw=model.noise_std_kw)
        self._level_change = LevelChangeRule(settings.reliability.level_change_k_sigma)
        self._ssm: SteadyStateMap = steady_state_map(base, settings.disturbance_model)
        s_init = self._s_nom if settings.initial_triac_pct is None else settings.initial_triac_pct
        im = self._input_map
        if not im.ds_min_pct <= s_init - self._s_nom <= im.ds_max_pct:
            raise DesignError(
                f"NonlinearMPC: initial_triac_pct must lie in the allowed range "
                f"[{im.ds_min_pct + self._s_nom:g}, {im.ds_max_pct + self._s_nom:g}] %; "
                f"got {s_init:g}"
            )
        self._ds_init = s_init - self._s_nom
        self._n_x = base.n_states
        self._A = np.array(base.A)
        self._Gx = np.array(self._est.gains.G[: self._n_x])
        self._soft_min_rel = (None if settings.soft_power_min_kw is None
                              else settings.soft_power_min_kw - self._p_nom)
        self._soft_max_rel = (None if settings.soft_power_max_kw is None
                              else settings.soft_power_max_kw - self._p_nom)
        self._build_nlp(base.A, base.B, base.C)
        self.reset()

    # --- set-up ---------------------------------------------------------------------------
    def _build_nlp(self, A: FloatArray, B: FloatArray, C: FloatArray) -> None:
        st = self.settings
        N = st.horizon_steps
        n = self._n_x
        coefficients = self._input_map.coefficients
        P_f = terminal_cost(A, B, C, output_weight=st.output_weight,
                            input_target_weight=st.input_target_weight,
                            move_weight=st.move_weight)
        has_soft = st.has_soft_power_limits
        ds = ca.SX.sym("ds", N)
        v = ca.SX.sym("v", 1 if has_soft else 0)
        p = ca.SX.sym("p", n + 4)
        h, w_s, w_prev, y_s, rho = p[:n], p[n], p[n + 1], p[n + 2], p[n + 3]
        Am, Bm, Cm = ca.DM(A), ca.DM(B), ca.DM(C).T
        w = [_poly(coefficients, ds[j]) for j in range(N)]
        cost = 0
        constraints: list[Any] = []
        self._g_kinds: list[str] = []
        dxs = [h + Bm * (w[0] - w_s)]   # dx_1 .. dx_N
        for j in range(N):
            if j >= 1:
                cost += st.output_weight * (Cm @ dxs[-1] - rho) ** 2
                dxs.append(Am @ dxs[-1] + Bm * (w[j] - w_s))
            cost += st.input_target_weight * (w[j] - w_s) ** 2
            cost += st.move_weight * (w[j] - (w[j - 1] if j else w_prev)) ** 2
        xi = ca.vertcat(dxs[-1], w[N - 1] - w_s)
        cost += ca.mtimes([xi.T, ca.DM(P_f), xi])
        if st.has_rate_limit:
            for j in range(1, N):
                constraints.append(ds[j] - ds[j - 1])
                self._g_kinds.append("rate")
        if has_soft:
            cost += st.soft_limit_weight * v[0] ** 2 + st.soft_limit_linear_weight * v[0]
            for dx in dxs:
                y = y_s + Cm @ dx
                if self._soft_max_rel is not None:
                    constraints.append(y - v[0])
                    self._g_kinds.append("soft_max")
                if self._soft_min_rel is not None:
                    constraints.append(y + v[0])
                    self._g_kinds.append("soft_min")
        nlp = {"x": ca.vertcat(ds, v), "p": p, "f": cost, "g": ca.vertcat(*constraints)}
        opts: dict[str, Any] = {
            "print_time": False,
            "ipopt": {"print_level": 0, "sb": "yes", "tol": self.ipopt_tol,
                      "max_iter": IPOPT_MAX_ITER},
        }
        self._solver = ca.nlpsol("czmpc_nmpc", "ipopt", nlp, opts)
        self._n_var = N + (1 if has_soft else 0)
        kinds = np.array(self._g_kinds)
        delta = st.max_move_pct_per_step if st.max_move_pct_per_step is not None else math.inf
        self._lbg_fixed = np.where(kinds == "rate", -delta, -math.inf)
        self._ubg_fixed = np.where(kinds == "rate", delta, math.inf)
        self._soft_max_rows = kinds == "soft_max"
        self._soft_min_rows = kinds == "soft_min"

    # --- public state -----------------------------------------------------------------------
    @property
    def last_step(self) -> NMPCStep | None:
        """Diagnostics of the latest `step`, or None before the first."""
        return self._last

    @property
    def n_fallbacks(self) -> int:
        """Steps since construction/reset whose NLP result was not used."""
        return self._n_fallbacks

    @property
    def allowed_triac_range_pct(self) -> tuple[float, float]:
        """``(s_min, s_max)`` the controller keeps its output in [%]."""
        return (self._input_map.ds_min_pct + self._s_nom,
                self._input_map.ds_max_pct + self._s_nom)

    def reset(self) -> None:
        """Forget all state, as if newly constructed (as `OffsetFreeMPC.reset`)."""
        im = self._input_map
        w0 = im.f(self._ds_init)
        z = np.zeros(self._n_x + 1)
        z[: self._n_x] = self._ssm.xw * w0
        self._est.restart(z)
        self._level_change.reset()
        self._ds_prev = self._ds_init
        self._setpoint_kw = self._p_nom + self._ssm.static_gain * w0
        self._k = 0
        self._plan: FloatArray | None = None
        self._plan_k = 0
        self._x0 = self._start_guess(self._ds_init)
        self._n_fallbacks = 0
        self._last: NMPCStep | None = None

    def _start_guess(self, ds: float) -> FloatArray:
        """Every planned input at ``ds``, the soft-limit slack (if any) at 0."""
        x0 = np.full(self._n_var, ds)
        if self._n_var > self.settings.horizon_steps:
            x0[-1] = 0.0
        return x0

    def _move_range(self, ds_prev: float) -> tuple[float, float]:
        """The allowed range of ``ds`` one move from ``ds_prev`` (rate limit included) [%]."""
        im, delta = self._input_map, self.settings.max_move_pct_per_step
        if delta is None:
            return im.ds_min_pct, im.ds_max_pct
        return max(im.ds_min_pct, ds_prev - delta), min(im.ds_max_pct, ds_prev + delta)

    # --- the step ------------------------------------------------------------------------
    def step(self, power_kw: float, setpoint_kw: float) -> float:
        """Return the TRIAC input [%] to apply now (same contract as `OffsetFreeMPC.step`).

        Parameters
        ----------
        power_kw :
            Measured power [kW]; NaN or inf marks a missing sample.
        setpoint_kw :
            Power setpoint [kW]; a non-finite value holds the previous one.
        """
        power = float(power_kw)
        if math.isfinite(float(setpoint_kw)):
            self._setpoint_kw = float(setpoint_kw)
        setpoint = self._setpoint_kw
        im = self._input_map
        st = self.settings
        N = st.horizon_steps

        # 1. measurement update (skipped for a missing or absurd sample)
        est = self._est
        std_kw = est.innovation_std_kw
        used = math.isfinite(power) and est.update(power - self._p_nom)
        self._level_change.observe(est, std_kw, used)   # as OffsetFreeMPC does
        if not math.isfinite(power):
            est.skip()
        z, eps = est.z, est.eps
        n = self._n_x
        x = z[:n]
        d = float(z[n])

        # 2. target
        tgt = compute_target(self._ssm, setpoint=setpoint - self._p_nom, disturbance=d,
                             w_min=im.w_min, w_max=im.w_max)

        # 3. NLP
        h = self._A @ (x - tgt.x_s) + self._Gx * eps
        ds_prev = self._ds_prev
        lbx = np.full(self._n_var, im.ds_min_pct)
        ubx = np.full(self._n_var, im.ds_max_pct)
        lbx[0], ubx[0] = self._move_range(ds_prev)
        if self._n_var > N:
            lbx[N], ubx[N] = 0.0, math.inf
        lbg = self._lbg_fixed.copy()
        ubg = self._ubg_fixed.copy()
        if self._soft_max_rel is not None:
            ubg[self._soft_max_rows] = self._soft_max_rel
        if self._soft_min_rel is not None:
            lbg[self._soft_min_rows] = self._soft_min_rel
        rho = 0.0 if tgt.is_reachable else setpoint - self._p_nom - tgt.y_s
        params = np.concatenate([h, [tgt.w_s, im.f(ds_prev), tgt.y_s, rho]])
        x0 = np.clip(self._x0, lbx, ubx)
        t0 = time.perf_counter()
        sol = self._solver(x0=x0, p=params, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        solve_time = time.perf_counter() - t0
        stats = self._solver.stats()
        status = str(stats.get("return_status", "unknown"))
        iterations = int(stats.get("iter_count", 0))
        plan = np.array(sol["x"], dtype=float).ravel()
        fallback: NMPCFallback
        planned = plan[:N].copy()
        if bool(stats.get("success", False)) and np.isfinite(plan).all():
            ds = float(plan[0])
            fallback = "none"
            self._plan = planned
            self._plan_k = self._k
            self._x0 = np.concatenate([plan[1:N], plan[N - 1:N], plan[N:]])
        else:
            planned = np.full(N, math.nan)
            self._n_fallbacks += 1
            age = self._k - self._plan_k
            if self._plan is not None and age < self._plan.size:
                ds = float(self._plan[age])
                fallback = "shifted_plan"
            else:
                ds = im.inverse(tgt.w_s)
                fallback = "target"
                self._plan = None
            self._x0 = self._start_guess(ds)

        # 4. apply within the allowed range and the rate limit
        lo, hi = self._move_range(ds_prev)
        if not math.isfinite(ds):
            ds = ds_prev
        ds = min(hi, max(lo, ds))
        w_applied = im.f(ds)

        # 5. time update with the w actually applied
        est.predict(w_applied)
        self._ds_prev = ds
        triac = self._s_nom + ds
        planned_pct = planned + self._s_nom
        planned_pct.setflags(write=False)
        self._last = NMPCStep(
            k=self._k, power_kw=power, setpoint_used_kw=setpoint, triac_pct=triac,
            measurement_used=used, innovation_kw=eps, disturbance_estimate=d,
            target_triac_pct=self._s_nom + im.inverse(tgt.w_s),
            setpoint_reachable=tgt.is_reachable, planned_triac_pct=planned_pct,
            solver_status=status, solve_time_s=solve_time, n_iterations=iterations,
            fallback=fallback,
        )
        self._k += 1
        return triac


__all__ = ["IPOPT_MAX_ITER", "IPOPT_TOL", "NMPCFallback", "NMPCStep", "NonlinearMPC"]
