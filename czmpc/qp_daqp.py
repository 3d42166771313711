"""DAQPMPCQP: the MPC's QP of `czmpc.qp`, solved by DAQP (dual active set) instead of OSQP.

The problem is `czmpc.qp.MPCQP`'s, built by it: the same condensed Hessian, the same
``q``, ``l``, ``u`` written each step by the same code paths (`MPCQP.move_bounds` writes
the bounds into them), over the same constraint rows. Only the solver differs
(`czmpc.settings.MPCSettings.solver`); the result is the same typed `czmpc.qp.QPSolution`.

DAQP (Arnstrom, Bemporad, Axehill, IEEE TAC 67(8), 2022; the ``daqp`` package, MIT
licence, the optional extra ``czmpc[daqp]``) solves::

    min 0.5 x^T H x + f^T x   s.t.  blower <= [x_0..x_{ms-1}; A_g x] <= bupper

The first ``N`` rows of `MPCQP`'s constraint matrix are the identity on ``w``: they are
DAQP's ``ms = N`` simple bounds, and ``l``, ``u`` go over unchanged, in the same order;
the other rows (moves, soft power limits, ``v >= 0``) are its general rows ``A_g``,
dense. ``H`` is ``2 H_w`` (and ``2 rho_2`` for the slack), ``f`` is ``q``.

Factorizations are reused across steps. ``H``'s Cholesky factor is formed once, at set-up;
each step `daqp.Model.update` is given ``f``, ``bupper`` and ``blower`` only, which
recomputes the linear terms of DAQP's least-distance problem (``O(n m)``) and keeps the
working set and its LDL factors: the solve starts from the previous step's active set
(a hot start; measured on the shipped staircase's 3,900 QPs, N = 39: 1.0 iteration on
average, at most 5). A cold start (`MPCQP.request_cold_start`, and after every unusable
solve, as with OSQP) clears the working set (all ``sense`` flags 0).

Exactness. DAQP stops at the optimal active set: the plan is the QP's solution to
rounding, every constraint held to ``primal_tol`` (1e-6, in the constraint's own units,
kW-equivalent) and the multipliers' signs to ``dual_tol``; OSQP stops at ``eps`` 1e-5
(`czmpc.settings.OSQPOptions`), its plans a few 1e-4 kW from DAQP's (BENCHMARKS.md,
"Controller step time and 24 h simulation"). Against OSQP at ``eps`` 1e-10 with
polishing the plans agree to 1e-8 kW (tests/czmpc/test_qp_daqp.py). A plan within
``primal_tol`` of its bounds needs no bound check of its own unless the controller's
``solver_bound_tol_kw`` is tighter.

Exit flags (DAQP's ``exitflag``) and statuses: 1 (optimal) is ``"solved"``, usable and
accurate if the plan is finite; every other flag, and a negative flag from ``update``
(bounds with ``l > u`` beyond ``primal_tol``), is not usable: the controller falls back
(docs/theory.rst, C7) and the next solve cold-starts. OSQP's words are used where the
condition is the same (``"primal infeasible"``, ``"maximum iterations reached"``).
"""

from __future__ import annotations

import math
from types import ModuleType
from typing import Any

import numpy as np

from czmpc._records import record_from_fields
from czmpc.errors import DesignError, SettingsError
from czmpc.qp import MPCQP, QPSolution
from czmpc.settings import OSQPOptions
from sysid._typing import FloatArray

#: DAQP's iteration cap per solve (active-set changes): a solve that reaches it is not
#: usable and the controller falls back. Measured: at most 5 iterations warm-started on
#: the shipped staircase (N = 39) and 40 on issue 42's 10,500 closed-loop QPs.
DAQP_ITER_LIMIT = 1000
#: DAQP's primal feasibility tolerance (its default) [kW-equivalent]: an optimal plan
#: violates no constraint by more.
DAQP_PRIMAL_TOL_KW = 1e-6
#: DAQP's exit flag for an optimal solution.
DAQP_EXIT_OPTIMAL = 1
#: Statuses by DAQP exit flag (daqp's documentation, "Parameters"): OSQP's wording where
#: the condition is the same.
DAQP_STATUS: dict[int, str] = {
    1: "solved",
    2: "soft optimal",
    -1: "primal infeasible",
    -2: "cycling",
    -3: "unbounded",
    -4: "maximum iterations reached",
    -5: "nonconvex",
    -6: "overdetermined initial active set",
    -7: "time limit reached",
    -8: "unsupported problem",
}


def daqp_module() -> ModuleType:
    """Return the ``daqp`` package.

    Raises
    ------
    SettingsError
        If it is not installed: the message names the extra that installs it.
    """
    try:
        import daqp
    except ImportError as exc:
        raise SettingsError(
            "MPCSettings.solver = 'daqp' needs the package daqp, which is not installed: "
            "pip install 'czmpc[daqp]'"
        ) from exc
    module: ModuleType = daqp
    return module


def daqp_status(exitflag: int) -> str:
    """The status string of DAQP exit flag ``exitflag`` (`DAQP_STATUS`), with the flag for a failure."""
    name = DAQP_STATUS.get(exitflag, "unknown exit flag")
    return name if exitflag == DAQP_EXIT_OPTIMAL else f"{name} (daqp exit {exitflag})"


def general_rows(A: FloatArray, B: FloatArray, C: FloatArray, *, horizon_steps: int,
                 has_rate_limit: bool, has_soft_min: bool, has_soft_max: bool) -> FloatArray:
    """The rows of `MPCQP`'s constraint matrix after its ``N`` box rows, dense.

    In `MPCQP`'s order: the ``N - 1`` moves ``w_j - w_{j-1}``; the soft upper rows
    ``C dx_j (w) - v`` and lower rows ``C dx_j (w) + v`` (only the ``w`` part of
    ``C dx_j``: ``sum_i C A^(j-i) B w_i``); the slack row ``v``.

    Parameters
    ----------
    A, B, C :
        The linear block (``n`` states).
    horizon_steps :
        ``N``.
    has_rate_limit, has_soft_min, has_soft_max :
        The rows the QP was built with.

    Returns
    -------
    ndarray
        ``(m - N, n_var)``, ``n_var = N + 1`` with soft limits (the slack last), else ``N``.
    """
    N = horizon_steps
    has_soft = has_soft_min or has_soft_max
    n_var = N + (1 if has_soft else 0)
    rows: list[FloatArray] = []
    if has_rate_limit:
        moves = np.zeros((N - 1, n_var))
        moves[:, 1:N] += np.eye(N - 1)
        moves[:, : N - 1] -= np.eye(N - 1)
        rows.append(moves)
    if has_soft:
        markov = np.empty(N)                  # C A^k B, k = 0..N-1
        x = np.asarray(B, dtype=float)
        for k in range(N):
            markov[k] = C @ x
            x = A @ x
        outputs = np.zeros((N, n_var))
        for j in range(N):
            outputs[j, : j + 1] = markov[j::-1]
        for present, sign in ((has_soft_max, -1.0), (has_soft_min, 1.0)):
            if present:
                soft = outputs.copy()
                soft[:, N] = sign
                rows.append(soft)
        slack = np.zeros((1, n_var))
        slack[0, N] = 1.0
        rows.append(slack)
    return np.ascontiguousarray(np.vstack(rows) if rows else np.zeros((0, n_var)))


class DAQPMPCQP(MPCQP):
    """`czmpc.qp.MPCQP`'s problem solved by DAQP (module notes): same constructor, same `solve`.

    Parameters
    ----------
    A, B, C, horizon_steps, output_weight, input_target_weight, move_weight, \
has_rate_limit, has_soft_min, has_soft_max, soft_limit_weight, soft_limit_linear_weight, \
bound_tol_kw, h_map :
        As `MPCQP`.
    options :
        OSQP options of the base class's OSQP workspace, which this class sets up (as
        `MPCQP` does) and never solves; DAQP runs with `DAQP_ITER_LIMIT` and its own
        default tolerances.

    Raises
    ------
    SettingsError
        If ``daqp`` is not installed (``pip install 'czmpc[daqp]'``).
    DesignError
        As `MPCQP`, or if DAQP refuses the problem at set-up.
    """

    def __init__(
        self, *, A: FloatArray, B: FloatArray, C: FloatArray, horizon_steps: int,
        output_weight: float, input_target_weight: float, move_weight: float,
        has_rate_limit: bool = False, has_soft_min: bool = False, has_soft_max: bool = False,
        soft_limit_weight: float = 1e3, soft_limit_linear_weight: float = 1e2,
        options: OSQPOptions | None = None, bound_tol_kw: float = 1e-2,
        h_map: FloatArray | None = None,
    ) -> None:
        daqp = daqp_module()
        super().__init__(
            A=A, B=B, C=C, horizon_steps=horizon_steps, output_weight=output_weight,
            input_target_weight=input_target_weight, move_weight=move_weight,
            has_rate_limit=has_rate_limit, has_soft_min=has_soft_min,
            has_soft_max=has_soft_max, soft_limit_weight=soft_limit_weight,
            soft_limit_linear_weight=soft_limit_linear_weight, options=options,
            bound_tol_kw=bound_tol_kw, h_map=h_map,
        )
        N = horizon_steps
        n_var = self.n_variables
        hessian = np.zeros((n_var, n_var))
        hessian[:N, :N] = 2.0 * self.cost_hessian
        if self.has_soft:
            hessian[N, N] = 2.0 * soft_limit_weight
        rows = general_rows(A, B, C, horizon_steps=N, has_rate_limit=has_rate_limit,
                            has_soft_min=has_soft_min, has_soft_max=has_soft_max)
        if rows.shape[0] != self.n_constraints - N:  # pragma: no cover - a changed MPCQP
            raise DesignError(f"DAQP QP: expected {self.n_constraints - N} general rows after "
                              f"the {N} box rows of MPCQP; built {rows.shape[0]}")
        model = daqp.Model()
        model.settings = {"iter_limit": DAQP_ITER_LIMIT, "primal_tol": DAQP_PRIMAL_TOL_KW}
        # q, l and u are MPCQP's own arrays (views of one buffer), written in place each step.
        flag, _ = model.setup(hessian, self._q, rows, self._u, self._l)
        if flag < 0:
            raise DesignError(f"DAQP QP: DAQP must accept the problem at set-up; got exit "
                              f"flag {flag} ({daqp_status(int(flag))})")
        self._model: Any = model
        self._daqp_hessian = hessian
        self._daqp_rows = rows
        self._zero_sense = np.zeros(self.n_constraints, dtype=np.intc)
        self._x_zeros = np.zeros(n_var)
        # An optimal plan holds every row to DAQP_PRIMAL_TOL_KW: a bound check of its own
        # only when the caller asks for less violation than that.
        self._check_bounds = self.bound_tol_kw < DAQP_PRIMAL_TOL_KW

    @property
    def daqp_model(self) -> Any:
        """The ``daqp.Model`` (for the benchmark's bare replay; nothing else calls it)."""
        return self._model

    def solve(
        self, *, h_terms: FloatArray, w_prev: float, w_target: float, y_target: float,
        w_lo: FloatArray, w_hi: FloatArray, rate: FloatArray | None = None,
        soft_min_rel_kw: float | None = None, soft_max_rel_kw: float | None = None,
        q_offset: FloatArray | None = None,
    ) -> QPSolution:
        """Update ``q``, ``l``, ``u`` as `MPCQP.solve` does, solve with DAQP, return the plan.

        Parameters
        ----------
        h_terms, w_prev, w_target, y_target, w_lo, w_hi, rate, soft_min_rel_kw, \
soft_max_rel_kw, q_offset :
            As `MPCQP.solve`.

        Notes
        -----
        ``n_iterations`` counts DAQP's active-set changes and ``solve_time_s`` is DAQP's
        own time; a solve that is not usable makes the next one cold-start.
        """
        N = self.horizon_steps
        if not self._write_problem(h_terms, w_prev, w_target, y_target, w_lo, w_hi, rate,
                                   soft_min_rel_kw, soft_max_rel_kw, q_offset):
            return self._failed("non-finite problem data")
        # --- DAQP ----------------------------------------------------------------------
        model = self._model
        if self._needs_cold_start:
            flag = model.update(f=self._q, bupper=self._u, blower=self._l, sense=self._zero_sense)
            self._needs_cold_start = False
        else:
            flag = model.update(f=self._q, bupper=self._u, blower=self._l)
        if flag < 0:
            return self._failed(daqp_status(int(flag)))
        x, fval, exitflag, info = model.solve()
        usable = exitflag == DAQP_EXIT_OPTIMAL and self._x_zeros.dot(x) == 0.0  # 0 * NaN is NaN
        status = daqp_status(int(exitflag))
        if usable and self._check_bounds:
            violation = self._bound_violation(x[:N], w_lo, w_hi, rate)
            if violation > self.bound_tol_kw:
                usable = False
                status = f"{status}; outside bounds by {violation:.3g} kW"
        if usable:
            plan = x[:N] if self.has_soft else x  # a fresh array from daqp, ours alone
            plan.setflags(write=False)
            slack = max(0.0, float(x[N])) if self.has_soft else 0.0
        else:
            plan = self._nan_plan
            slack = math.nan if self.has_soft else 0.0
            self._needs_cold_start = True
        return record_from_fields(QPSolution, {
            "status": status,
            "is_usable": usable,
            "is_accurate": usable,
            "w": plan,
            "slack_kw": slack,
            "objective": float(fval) if usable else math.nan,
            "n_iterations": int(info["iterations"]),
            "solve_time_s": float(info["solve_time"]),
        })


__all__ = ["DAQPMPCQP", "DAQP_ITER_LIMIT", "DAQP_PRIMAL_TOL_KW", "DAQP_STATUS", "daqp_module",
           "daqp_status", "general_rows"]
