"""MPCQP: OSQP problem built once, vectors updated, typed QPSolution.

Notation
--------
``w_j`` [kW-equivalent]
    Planned nonlinearity outputs ``f(ds_j)``, ``j = 0..N-1``: the decision variables.
``x_j``
    Predicted state of the linear block; ``x_j - x_s = dx_j``.
``(x_s, w_s, y_s)``
    The steady-state target (`czmpc.target`).
``h``
    ``dx_1`` with ``w_0 = w_s``: ``h = A (x_{k|k} - x_s) + G_x eps_k``. It carries the
    filtered state and this sample's innovation (`czmpc.kalman`), so that
    ``dx_1 = h + B (w_0 - w_s)`` and ``dx_{j+1} = A dx_j + B (w_j - w_s)``.
``delta`` [%/step]
    The TRIAC rate limit.

The QP (``docs/theory.rst``, C5), condensed in ``w`` (the states are eliminated)::

    min   sum_{j=1}^{N-1} q_y (C dx_j)^2
        + sum_{j=0}^{N-1} [ q_u (w_j - w_s)^2 + q_dw (w_j - w_{j-1})^2 ]
        + [dx_N; w_{N-1} - w_s]^T P_f [dx_N; w_{N-1} - w_s]
        + rho_2 v^2 + rho_1 v                                  (soft limits only)
    s.t.  w_lo_j <= w_j <= w_hi_j                              (box, reachable set)
          |w_j - w_{j-1}| <= m_j delta,  j >= 1                 (rate, conservative)
          P_min - v <= P_nom + y_s + C dx_j <= P_max + v,  v >= 0   (soft, optional)

``P_f`` solves the DARE of the same stage cost written as an LQ problem on
``xi = [dx; w_{j-1} - w_s]`` (the move penalty is a cross term), so without active
constraints the first move equals the infinite-horizon LQR law for any ``N``.

Bounds are exact where possible: ``w_lo_0 = f(max(ds_min, ds_prev - delta))`` and
``w_hi_0 = f(min(ds_max, ds_prev + delta))`` (f increases on the allowed range); later
``w_j`` are boxed by the image of the inputs reachable in ``j + 1`` moves, and their
moves limited by ``m_j delta``, ``m_j`` the smallest slope of ``f`` over those inputs,
so ``|ds_j - ds_{j-1}| <= delta`` holds by the mean value theorem.

Condensed, by measurement (``n = 2``, ``N = 50``, the 1500 QPs of a staircase run):
22 us and 8.7 iterations per solve, against 79 us and 28 iterations for the sparse form
(150 variables, 100 equality rows), with the same first moves to 4e-5.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import osqp
import scipy.linalg
import scipy.sparse as sp

from czmpc._records import record_from_fields
from czmpc.errors import DesignError
from czmpc.inversion import InputMap
from czmpc.inversion import slope as slope_at
from czmpc.ordered import OrderedProduct
from czmpc.settings import OSQPOptions
from sysid._typing import FloatArray

#: OSQP's status values for a usable solution.
_SOLVED = 1
_SOLVED_INACCURATE = 2
#: OSQP treats magnitudes at or above this as infinite.
OSQP_INFINITY = 1e30


@dataclass(frozen=True, eq=False, kw_only=True)
class QPSolution:
    """One solve of the MPC QP, in our own types (no OSQP object leaks out).

    Parameters
    ----------
    status :
        OSQP's status string (``"solved"``, ``"solved inaccurate"``, ...).
    is_usable :
        True if the status is solved or solved-inaccurate and the plan is finite.
    is_accurate :
        True if the status is solved (to the set tolerances).
    w :
        (N,) planned nonlinearity outputs [kW-equivalent], read-only; NaN if not usable.
    slack_kw :
        Soft-limit violation ``v`` [kW] (0 without soft limits).
    objective :
        QP objective value (without constant terms).
    n_iterations :
        ADMM iterations.
    solve_time_s :
        OSQP's solve time [s] (reported, never used in decisions).
    """

    status: str
    is_usable: bool
    is_accurate: bool
    w: FloatArray
    slack_kw: float
    objective: float
    n_iterations: int
    solve_time_s: float


def terminal_cost(
    A: FloatArray, B: FloatArray, C: FloatArray, *, output_weight: float,
    input_target_weight: float, move_weight: float,
) -> FloatArray:
    """DARE terminal weight ``P_f`` on ``xi = [dx; w_prev - w_s]`` (module notes).

    The LQ problem: ``xi+ = [[A, 0], [0, 0]] xi + [B; 1] u``, stage cost
    ``q_y (C dx)^2 + q_dw prev^2 + (q_u + q_dw) u^2 - 2 q_dw prev u``.

    Parameters
    ----------
    A, B, C :
        The linear block (``n`` states).
    output_weight, input_target_weight, move_weight :
        ``q_y``, ``q_u``, ``q_dw`` [1/kW^2].

    Raises
    ------
    DesignError
        If the DARE has no stabilizing solution.
    """
    Axi, Bxi, Qxi, Rxi, Sxi = lq_problem(
        A, B, C, output_weight=output_weight, input_target_weight=input_target_weight,
        move_weight=move_weight,
    )
    try:
        P = scipy.linalg.solve_discrete_are(Axi, Bxi, Qxi, Rxi, s=Sxi)
    except (ValueError, np.linalg.LinAlgError) as exc:
        # scipy's QZ ordering can fail on a slow pole near z = 1 next to the delay states'
        # poles at z = 0; doubling needs no ordering (its answer is checked).
        P = dare_by_doubling(Axi, Bxi, Qxi, Rxi, Sxi)
        if P is None:
            raise DesignError(
                f"MPC terminal cost: the control DARE must have a stabilizing solution; got: "
                f"{exc} (and the doubling algorithm found none)"
            ) from exc
    return np.asarray(0.5 * (P + P.T), dtype=float)


#: Relative residual below which `dare_by_doubling` accepts its solution.
DARE_RESIDUAL_RTOL = 1e-9


def dare_by_doubling(A: FloatArray, B: FloatArray, Q: FloatArray, R: FloatArray,
                     S: FloatArray, *, max_iterations: int = 100) -> FloatArray | None:
    """Stabilizing solution of the DARE with cross term by the doubling algorithm.

    Solves ``P = A^T P A - (A^T P B + S)(R + B^T P B)^{-1}(B^T P A + S^T) + Q`` (scipy's
    convention) by structure-preserving doubling (Chu, Fan, Lin, Linear Algebra Appl.
    396, 2005, discrete-time form): with the cross term removed (``A - B R^-1 S^T``,
    ``Q - S R^-1 S^T``), ``A_k, G_k, H_k`` double the horizon each step and ``H_k``
    converges quadratically to ``P``.

    Returns
    -------
    ndarray or None
        ``P``, or None when the iteration does not converge, the DARE residual is
        above `DARE_RESIDUAL_RTOL` relative to ``|P|``, or ``A - B K`` is not stable.
    """
    r_inv = np.linalg.inv(R)
    a_k = A - B @ r_inv @ S.T
    g_k = B @ r_inv @ B.T
    h_k = Q - S @ r_inv @ S.T
    eye = np.eye(A.shape[0])
    for _ in range(max_iterations):
        try:
            w_inv = np.linalg.inv(eye + g_k @ h_k)
        except np.linalg.LinAlgError:
            return None
        a_next = a_k @ w_inv @ a_k
        g_next = g_k + a_k @ w_inv @ g_k @ a_k.T
        h_next = h_k + a_k.T @ h_k @ w_inv @ a_k
        done = float(np.linalg.norm(h_next - h_k)) <= 1e-14 * max(1.0, float(np.linalg.norm(h_next)))
        a_k, g_k, h_k = a_next, g_next, h_next
        if not np.all(np.isfinite(h_k)):
            return None
        if done:
            break
    else:
        return None
    P = 0.5 * (h_k + h_k.T)
    gain = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A + S.T)
    residual = A.T @ P @ A - (A.T @ P @ B + S) @ gain + Q - P
    if float(np.linalg.norm(residual)) > DARE_RESIDUAL_RTOL * max(1.0, float(np.linalg.norm(P))):
        return None
    if np.max(np.abs(np.linalg.eigvals(A - B @ gain))) >= 1.0:
        return None
    return np.asarray(P, dtype=float)


def lq_problem(
    A: FloatArray, B: FloatArray, C: FloatArray, *, output_weight: float,
    input_target_weight: float, move_weight: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """``(A_xi, B_xi, Q_xi, R_xi, S_xi)`` of the LQ problem behind the MPC cost.

    In scipy's convention: cost ``xi^T Q xi + u^T R u + 2 xi^T S u``.

    Parameters
    ----------
    A, B, C :
        The linear block.
    output_weight, input_target_weight, move_weight :
        ``q_y``, ``q_u``, ``q_dw`` [1/kW^2].
    """
    n = B.size
    Axi = np.zeros((n + 1, n + 1))
    Axi[:n, :n] = A
    Bxi = np.zeros((n + 1, 1))
    Bxi[:n, 0] = B
    Bxi[n, 0] = 1.0
    Qxi = np.zeros((n + 1, n + 1))
    Qxi[:n, :n] = output_weight * np.outer(C, C)
    Qxi[n, n] = move_weight
    Rxi = np.array([[input_target_weight + move_weight]])
    Sxi = np.zeros((n + 1, 1))
    Sxi[n, 0] = -move_weight
    return Axi, Bxi, Qxi, Rxi, Sxi


class MoveBounds:
    """Box and rate bounds on the planned ``w`` (module notes), into arrays kept for reuse.

    Parameters
    ----------
    max_move_pct_per_step :
        ``delta`` [%/step], or None for no rate limit.
    horizon_steps :
        ``N``.
    box_rows :
        ``(w_lo, w_hi)`` (N,) arrays to write the box bounds into (a QP's rows,
        `MPCQP.move_bounds`); None for arrays of its own.
    rate_rows :
        ``(lower, upper)`` (N-1,) arrays to write ``-rate`` and ``rate`` into; None for
        an array of its own (``rate`` only).

    Notes
    -----
    The scalars enter numpy as 0-d arrays, made once per input map: a Python float costs
    a conversion per call (0.2 us of 0.55 us). The arithmetic is the same.
    """

    def __init__(self, max_move_pct_per_step: float | None, horizon_steps: int, *,
                 box_rows: tuple[FloatArray, FloatArray] | None = None,
                 rate_rows: tuple[FloatArray, FloatArray] | None = None) -> None:
        n = horizon_steps
        self.max_move_pct_per_step = max_move_pct_per_step
        self.horizon_steps = n
        self._rate_rows = rate_rows
        delta = 0.0 if max_move_pct_per_step is None else max_move_pct_per_step
        reach = delta * np.arange(1, n + 1)
        self._reach = np.concatenate([-reach, reach])   # [lower; upper] reach after j + 1 moves
        self._delta, self._minus_delta = np.array(delta), np.array(-delta)
        self._ds_prev = np.array(0.0)
        self._ds = np.empty(2 * n)
        self._w = np.empty(2 * n)
        self._slope = np.empty(2 * n)
        self._min_slope = np.empty(n - 1)
        # Views, taken once: [lower; upper] halves, and their moves j >= 1.
        self._w_half = self._w[:n], self._w[n:]
        self._ds_half = self._ds[:n], self._ds[n:]
        self._w_lo, self._w_hi = (np.empty(n), np.empty(n)) if box_rows is None else box_rows
        self._ds_lo1, self._ds_hi1 = self._ds[1:n], self._ds[n + 1 :]
        self._slope_lo1, self._slope_hi1 = self._slope[1:n], self._slope[n + 1 :]
        self._map: InputMap | None = None
        self._ds_min = self._ds_max = self._c0 = self._2c1 = np.array(0.0)
        self._horner: tuple[FloatArray, ...] = ()

    def _take_map(self, input_map: InputMap) -> None:
        """Its scalars as 0-d arrays (class notes): the range, and ``c_n, ..., c_1`` for Horner."""
        self._map = input_map
        c = input_map.coefficients
        self._ds_min, self._ds_max = np.array(input_map.ds_min_pct), np.array(input_map.ds_max_pct)
        self._horner = tuple(np.array(v) for v in reversed(c))
        self._c0 = np.array(c[0])
        self._2c1 = np.array(2 * c[1] if len(c) > 1 else 0.0)

    def compute(self, input_map: InputMap, ds_prev_pct: float
                ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        """Return ``(w_lo, w_hi, rate)`` for the input applied at the previous sample.

        Parameters
        ----------
        input_map :
            ``f`` on the allowed range.
        ds_prev_pct :
            TRIAC deviation applied at the previous sample [%], inside the allowed range.

        Returns
        -------
        w_lo, w_hi :
            (N,) bounds on ``w_j`` [kW-equivalent]; element 0 is the exact first-move
            interval.
        rate :
            (N-1,) limits ``m_j delta`` on ``|w_j - w_{j-1}|``, ``j = 1..N-1``
            [kW-equivalent], or None without a rate limit.

        The arrays are overwritten by the next call; copy them to keep them.
        """
        w = self._w
        if self.max_move_pct_per_step is None:
            self._w_lo.fill(input_map.w_min)
            self._w_hi.fill(input_map.w_max)
            return self._w_lo, self._w_hi, None
        if input_map is not self._map:
            self._take_map(input_map)
        ds = self._ds
        ds_prev = self._ds_prev
        ds_prev[()] = ds_prev_pct
        np.add(self._reach, ds_prev, out=ds)
        np.maximum(ds, self._ds_min, out=ds)
        np.minimum(ds, self._ds_max, out=ds)
        # f(ds) by Horner's rule, (..(c_n ds + c_n-1) ds + .. + c_1) ds; the last product
        # of each half goes straight into w_lo and w_hi (a QP's rows: no copy).
        ds_lo, ds_hi = self._ds_half
        horner = self._horner
        if len(horner) == 1:                           # f(ds) = c_1 ds
            np.multiply(ds_lo, horner[0], out=self._w_lo)
            np.multiply(ds_hi, horner[0], out=self._w_hi)
        else:
            np.multiply(ds, horner[0], out=w)
            for coef in horner[1:-1]:
                np.add(w, coef, out=w)
                np.multiply(w, ds, out=w)
            np.add(w, horner[-1], out=w)
            inner_lo, inner_hi = self._w_half
            np.multiply(inner_lo, ds_lo, out=self._w_lo)
            np.multiply(inner_hi, ds_hi, out=self._w_hi)
        c = input_map.coefficients
        rate = self._min_slope                         # min of f' over [ds_lo_j, ds_hi_j]
        if len(c) == 1:
            rate.fill(c[0])
        elif len(c) == 2:
            # f' = c_0 + 2 c_1 ds is monotone, in floating point too: its minimum is at
            # the lower end for c_1 >= 0, at the upper end otherwise.
            np.multiply(self._ds_lo1 if c[1] >= 0.0 else self._ds_hi1, self._2c1, out=rate)
            np.add(rate, self._c0, out=rate)
        else:
            slope = self._slope                        # f'(ds) by Horner's rule
            deg = len(c)
            np.multiply(ds, deg * c[-1], out=slope)
            slope += (deg - 1) * c[-2]
            for i in range(deg - 2, 0, -1):
                slope *= ds
                slope += i * c[i - 1]
            np.minimum(self._slope_lo1, self._slope_hi1, out=rate)
            for r in input_map.slope_critical_points_pct:  # an interior minimum of f'
                inside = (self._ds_lo1 < r) & (r < self._ds_hi1)
                rate[inside] = np.minimum(rate[inside], slope_at(c, r))
        if self._rate_rows is None:
            np.multiply(rate, self._delta, out=rate)
            return self._w_lo, self._w_hi, rate
        lower, upper = self._rate_rows
        np.multiply(rate, self._minus_delta, out=lower)  # = -(rate * delta): the sign is exact
        np.multiply(rate, self._delta, out=upper)
        return self._w_lo, self._w_hi, upper


class MPCQP:
    """The MPC's OSQP problem: built once, then only ``q``, ``l``, ``u`` change.

    Parameters
    ----------
    A, B, C :
        The linear block (``n`` states; `czmpc.realization.InnovationsForm`).
    horizon_steps :
        ``N``.
    output_weight, input_target_weight, move_weight :
        ``q_y``, ``q_u``, ``q_dw`` [1/kW^2].
    has_rate_limit :
        Build the ``N - 1`` move rows.
    has_soft_min, has_soft_max :
        Build the ``N`` soft lower / upper power rows (and the slack).
    soft_limit_weight, soft_limit_linear_weight :
        ``rho_2`` [1/kW^2] and ``rho_1`` [1/kW].
    options :
        OSQP options.
    bound_tol_kw :
        How far [kW-equivalent] a returned plan may violate its box and rate bounds and
        still count as usable (OSQP may stop outside them).
    h_map :
        (n, k) ``M`` with ``h = M t`` for the k terms ``t`` `solve` is given (the
        controller's ``[z; x_s; eps]``); None for ``t = h``. Folded into the products,
        so ``h`` is never formed (``q`` differs by about an ulp).

    Raises
    ------
    DesignError
        If the terminal-cost DARE fails, ``h_map`` has not ``n`` rows, or OSQP rejects
        the problem at set-up.
    """

    def __init__(
        self, *, A: FloatArray, B: FloatArray, C: FloatArray, horizon_steps: int,
        output_weight: float, input_target_weight: float, move_weight: float,
        has_rate_limit: bool = False, has_soft_min: bool = False, has_soft_max: bool = False,
        soft_limit_weight: float = 1e3, soft_limit_linear_weight: float = 1e2,
        options: OSQPOptions | None = None, bound_tol_kw: float = 1e-2,
        h_map: FloatArray | None = None,
    ) -> None:
        options = OSQPOptions() if options is None else options
        h_map = np.eye(B.size) if h_map is None else np.asarray(h_map, dtype=float)
        if h_map.ndim != 2 or h_map.shape[0] != B.size:
            raise DesignError(f"MPC QP: h_map must have {B.size} rows (one per state); "
                              f"got shape {h_map.shape}")
        self.bound_tol_kw = float(bound_tol_kw)
        n_x = B.size
        N = horizon_steps
        self.horizon_steps = N
        self.has_rate_limit = has_rate_limit
        self.has_soft = has_soft_min or has_soft_max
        self.has_soft_min = has_soft_min
        self.has_soft_max = has_soft_max
        self.options = options

        # Prediction: dx_j = Phi_j h + sum_{i<j} Gamma_{j,i} (w_i - w_s), j = 1..N.
        Phi = np.zeros((N, n_x, n_x))
        Apow = np.eye(n_x)
        for j in range(N):
            Phi[j] = Apow
            Apow = A @ Apow
        Gam = np.zeros((N, n_x, N))
        for j in range(N):
            for i in range(j + 1):
                Gam[j, :, i] = Phi[j - i] @ B
        Cphi = np.einsum("i,jik->jk", C, Phi)  # (N, n_x): C Phi_j
        Cgam = np.einsum("i,jik->jk", C, Gam)  # (N, N):   C Gamma_j
        P_f = terminal_cost(
            A, B, C, output_weight=output_weight, input_target_weight=input_target_weight,
            move_weight=move_weight,
        )
        # Terminal rows: xi_N = [dx_N; w_{N-1} - w_s] = T_h h + T_w (w - w_s 1).
        T_h = np.zeros((n_x + 1, n_x))
        T_h[:n_x] = Phi[N - 1]
        T_w = np.zeros((n_x + 1, N))
        T_w[:n_x] = Gam[N - 1]
        T_w[n_x, N - 1] = 1.0
        # Moves: D (w - w_s 1) - e_0 (w_prev - w_s) = differences of w.
        D = np.eye(N) - np.eye(N, k=-1)
        Ey = Cgam[: N - 1]  # outputs j = 1..N-1
        Eh = Cphi[: N - 1]
        H = (
            output_weight * Ey.T @ Ey
            + input_target_weight * np.eye(N)
            + move_weight * D.T @ D
            + T_w.T @ P_f @ T_w
        )
        H = 0.5 * (H + H.T)
        # J = dW^T H dW + 2 f^T dW, f = F_h h + f_p (w_prev - w_s), dW = w - w_s 1.
        F_h = output_weight * Ey.T @ Eh + T_w.T @ P_f @ T_h
        f_p = np.zeros(N)
        f_p[0] = -move_weight
        # In absolute w: q/2 = F_h M t + f_p w_prev - (f_p + H 1) w_s (h = M t).
        # q[:N] = Q_p [t; w_prev; w_s]: one product per step.
        self._q_params = np.column_stack([2.0 * F_h @ h_map, 2.0 * f_p,
                                          -2.0 * (f_p + H.sum(axis=1))])
        self._params = np.empty(h_map.shape[1] + 2)
        #: (k,) where `solve` reads ``h_terms`` from when given this very array (no copy).
        self.h_input: FloatArray = self._params[:-2]
        self._terminal_P: FloatArray = P_f
        # (N, 2N) q per [rho; sigma_-1; sigma] (`solve`'s q_offset): the linear terms of
        # q_y (C dx_j - rho_j)^2, q_u (dW_j - sigma_j)^2 and q_dw (w_j - w_{j-1} - m_j)^2,
        # m_j = sigma_j - sigma_{j-1}, beyond those of rho = sigma = 0.
        D_ext = np.eye(N, N + 1, k=1) - np.eye(N, N + 1)
        #: (N, 2N) ``q`` per ``[rho; sigma_-1; sigma]`` (`solve`'s ``q_offset``).
        self.reference_cost: FloatArray = np.hstack([
            -2.0 * output_weight * Ey.T,
            -2.0 * input_target_weight * np.eye(N, N + 1, k=1) - 2.0 * move_weight * D.T @ D_ext])
        self._Cgam_rowsum = Cgam.sum(axis=1)
        self._Cphi_map = Cphi @ h_map  # C Phi_j h = (C Phi_j M) t
        # The step's products in one fixed order (`czmpc.ordered`): the generated C's.
        self._q_product = OrderedProduct(self._q_params)
        self._cphi_product = OrderedProduct(self._Cphi_map)
        self._cost_hessian: FloatArray = np.asarray(H, dtype=float)

        n_var = N + (1 if self.has_soft else 0)
        blocks: list[sp.spmatrix] = [sp.eye(N, n_var, format="csc")]
        if has_rate_limit:
            blocks.append(sp.csc_matrix(D[1:]) @ sp.eye(N, n_var, format="csc"))
        if self.has_soft:
            soft_dense = np.zeros((N, n_var))
            soft_dense[:, :N] = Cgam
            if has_soft_max:
                upper = soft_dense.copy()
                upper[:, N] = -1.0
                blocks.append(sp.csc_matrix(upper))
            if has_soft_min:
                lower = soft_dense.copy()
                lower[:, N] = 1.0
                blocks.append(sp.csc_matrix(lower))
            slack_row = np.zeros((1, n_var))
            slack_row[0, N] = 1.0
            blocks.append(sp.csc_matrix(slack_row))
        A_con = sp.vstack(blocks, format="csc")
        self.n_constraints = A_con.shape[0]
        self.n_variables = n_var

        P_full = np.zeros((n_var, n_var))
        P_full[:N, :N] = 2.0 * H
        if self.has_soft:
            P_full[N, N] = 2.0 * soft_limit_weight
        P_upper = sp.csc_matrix(np.triu(P_full))

        # q, l and u are views of one array: one finiteness check per step.
        m = self.n_constraints
        self._data = np.concatenate([np.zeros(n_var), np.full(m, -OSQP_INFINITY),
                                     np.full(m, OSQP_INFINITY)])
        self._q = self._data[:n_var]
        self._l = self._data[n_var : n_var + m]
        self._u = self._data[n_var + m :]
        # Views of the rows each step writes, taken once.
        self._q_w = self._q[:N]
        self._l_box, self._u_box = self._l[:N], self._u[:N]
        self._l_rate, self._u_rate = self._l[N : 2 * N - 1], self._u[N : 2 * N - 1]
        if self.has_soft:
            self._q[N] = soft_limit_linear_weight
        self._row_soft = N + (N - 1 if has_rate_limit else 0)
        if self.has_soft:
            self._l[-1] = 0.0
        self._solver = osqp.OSQP()
        settings: dict[str, Any] = {
            "verbose": False,
            "eps_abs": options.eps_abs,
            "eps_rel": options.eps_rel,
            "max_iter": options.max_iter,
            "polishing": options.polishing,
            "check_termination": options.check_termination,
            "adaptive_rho_interval": options.adaptive_rho_interval,
            "warm_starting": True,
        }
        if options.time_limit_s is not None:
            settings["time_limit"] = options.time_limit_s
        try:
            self._solver.setup(P_upper, self._q.copy(), A_con, self._l.copy(), self._u.copy(),
                               **settings)
        except (osqp.OSQPException, ValueError) as exc:
            raise DesignError(f"MPC QP: OSQP set-up must succeed; got: {exc}") from exc
        # The solver object behind osqp.OSQP (osqp 1.x) skips the wrapper's per-call work,
        # a third of a bare solve (BENCHMARKS.md, "MPC step against a bare OSQP solve").
        self._ext = self._solver._solver
        # Its info and solution: the same objects on every access, read after each solve.
        self._info = self._ext.info
        self._solution = self._ext.solution
        self._status_names: dict[int, str] = {}  # OSQP's status string by value, as seen
        # Without polishing, the returned x and z are the ADMM iterates, z inside [l, u],
        # so a primal residual |A x - z| below the tolerance bounds the violation.
        self._residual_bounds_violation = not options.polishing
        self._needs_cold_start = False
        self._zero_x = np.zeros(n_var)
        self._zero_y = np.zeros(self.n_constraints)
        self._data_zeros = np.zeros(self._data.size)
        self._nan_plan = np.full(N, math.nan)
        self._nan_plan.setflags(write=False)

    def _failed(self, status: str) -> QPSolution:
        self._needs_cold_start = True
        return QPSolution(
            status=status, is_usable=False, is_accurate=False, w=self._nan_plan,
            slack_kw=math.nan if self.has_soft else 0.0, objective=math.nan, n_iterations=0,
            solve_time_s=0.0,
        )

    def _bound_violation(self, w: FloatArray, w_lo: FloatArray, w_hi: FloatArray,
                         rate: FloatArray | None) -> float:
        """Largest violation [kW-equivalent] of the box and rate bounds by plan ``w``."""
        worst = float(max(np.max(w_lo - w), np.max(w - w_hi), 0.0))
        if self.has_rate_limit and rate is not None and w.size > 1:
            worst = max(worst, float(np.max(np.abs(np.diff(w)) - rate)))
        return worst

    @property
    def cost_hessian(self) -> FloatArray:
        """(N, N) ``H`` of ``J = dW^T H dW + 2 f^T dW`` (for tests and experts)."""
        return self._cost_hessian

    @property
    def terminal_weight(self) -> FloatArray:
        """(n+1, n+1) DARE terminal weight ``P_f`` on ``[dx_N; w_{N-1} - w_s]``."""
        return self._terminal_P

    def move_bounds(self, max_move_pct_per_step: float | None) -> MoveBounds:
        """A `MoveBounds` that writes the bounds straight into this problem's ``l`` and ``u``.

        Parameters
        ----------
        max_move_pct_per_step :
            ``delta`` [%/step], or None for no rate limit.
        """
        rows = (self._l_rate, self._u_rate) if self.has_rate_limit else None
        return MoveBounds(max_move_pct_per_step, self.horizon_steps,
                          box_rows=(self._l_box, self._u_box), rate_rows=rows)

    def request_cold_start(self) -> None:
        """Start the next solve from zero instead of the previous solution."""
        self._needs_cold_start = True

    def _write_problem(self, h_terms: FloatArray, w_prev: float, w_target: float,
                       y_target: float, w_lo: FloatArray, w_hi: FloatArray,
                       rate: FloatArray | None, soft_min_rel_kw: float | None,
                       soft_max_rel_kw: float | None, q_offset: FloatArray | None) -> bool:
        """Write ``q``, ``l``, ``u`` of one step (`solve`'s parameters) into the kept arrays;
        return whether they are all finite. Every solver's `solve` starts here."""
        N = self.horizon_steps
        params = self._params
        if h_terms is not self.h_input:
            self.h_input[...] = h_terms
        params[-2] = w_prev
        params[-1] = w_target
        self._q_product(params, out=self._q_w)  # in the generated C's order (`czmpc.ordered`)
        if q_offset is not None:
            self._q_w += q_offset
        if w_lo is not self._l_box:
            self._l_box[...] = w_lo  # [...]: no slice object made
        if w_hi is not self._u_box:
            self._u_box[...] = w_hi
        if self.has_rate_limit and rate is not None and rate is not self._u_rate:
            np.negative(rate, out=self._l_rate)
            self._u_rate[...] = rate
        if self.has_soft:
            # C dx_j = Cphi_j h + Cgam_j w - (Cgam_j 1) w_s ; y_j = y_s + C dx_j.
            base = self._cphi_product(h_terms) - self._Cgam_rowsum * w_target + y_target
            r0 = self._row_soft
            if self.has_soft_max and soft_max_rel_kw is not None:
                self._u[r0 : r0 + N] = soft_max_rel_kw - base
                r0 += N
            if self.has_soft_min and soft_min_rel_kw is not None:
                self._l[r0 : r0 + N] = soft_min_rel_kw - base
        # 0 * v is 0 for every finite v and NaN for inf or NaN: one product checks them all.
        return bool(self._data_zeros.dot(self._data) == 0.0)

    def solve(
        self, *, h_terms: FloatArray, w_prev: float, w_target: float, y_target: float,
        w_lo: FloatArray, w_hi: FloatArray, rate: FloatArray | None = None,
        soft_min_rel_kw: float | None = None, soft_max_rel_kw: float | None = None,
        q_offset: FloatArray | None = None,
    ) -> QPSolution:
        """Update ``q``, ``l``, ``u``, solve, and return the plan.

        Parameters
        ----------
        h_terms :
            (k,) the terms ``t`` of the free first-step state error ``h = M t`` (module
            notes, ``h_map``): ``h`` itself without an ``h_map``; `h_input` itself is
            taken without a copy.
        w_prev :
            Nonlinearity output applied at the previous sample [kW-equivalent].
        w_target :
            ``w_s`` [kW-equivalent].
        y_target :
            ``y_s`` [kW deviation] (used by the soft limits only).
        w_lo, w_hi :
            (N,) box bounds on ``w_j`` (see `MoveBounds`).
        rate :
            (N-1,) move limits, required if built with ``has_rate_limit``; those of a
            `move_bounds` are in place already (``-rate`` too).
        soft_min_rel_kw, soft_max_rel_kw :
            Soft power limits as deviations from ``P_nom`` [kW], required for the rows
            the problem was built with.
        q_offset :
            (N,) added to the plan's linear cost: ``reference_cost @ [rho; sigma]`` for
            output references ``y_s + rho_j`` (``j = 1..N-1``) and input targets ``w_s +
            sigma_j`` (``j = -1..N-1``; ``sigma_-1`` that of the input applied now), i.e.
            stage costs ``q_y (C dx_j - rho_j)^2``, ``q_u (dW_j - sigma_j)^2`` and
            ``q_dw (w_j - w_{j-1} - (sigma_j - sigma_{j-1}))^2``: a move the targets make
            costs nothing (a setpoint trajectory, or a setpoint the target cannot reach);
            None for zeros.

        Notes
        -----
        A solve without a finite plan inside its bounds (to ``bound_tol_kw``), solved or
        solved-inaccurate, is not usable and makes the next solve cold-start.
        """
        N = self.horizon_steps
        if not self._write_problem(h_terms, w_prev, w_target, y_target, w_lo, w_hi, rate,
                                   soft_min_rel_kw, soft_max_rel_kw, q_offset):
            return self._failed("non-finite problem data")
        lo = self._l
        up = self._u
        ext = self._ext
        try:
            ext.update_data_vec(self._q, lo, up)  # (q, l, u): keywords cost more
            if self._needs_cold_start:
                ext.warm_start(self._zero_x, self._zero_y)
                self._needs_cold_start = False
            ext.solve()
        except osqp.OSQPException as exc:
            return self._failed(f"osqp error: {exc}")
        info = self._info
        status_val = info.status_val
        x = self._solution.x
        status = self._status_names.get(status_val)
        if status is None:
            status = self._status_names[status_val] = info.status
        usable = status_val == _SOLVED or status_val == _SOLVED_INACCURATE
        # Every variable enters A x, so a residual below the tolerance also means x is finite.
        if usable and not (self._residual_bounds_violation and info.prim_res <= self.bound_tol_kw):
            if not np.isfinite(x).all():
                usable = False
            else:
                violation = self._bound_violation(x[:N], w_lo, w_hi, rate)
                if violation > self.bound_tol_kw:
                    usable = False
                    status = f"{status}; outside bounds by {violation:.3g} kW"
        if usable:
            plan = x[:N] if self.has_soft else x  # x is the solver's copy, ours alone
            plan.setflags(write=False)
            slack = max(0.0, float(x[N])) if self.has_soft else 0.0  # >= 0 up to eps
        else:
            plan = self._nan_plan
            slack = math.nan if self.has_soft else 0.0
            self._needs_cold_start = True
        return record_from_fields(QPSolution, {
            "status": status,
            "is_usable": usable,
            "is_accurate": usable and status_val == _SOLVED,
            "w": plan,
            "slack_kw": slack,
            "objective": info.obj_val,  # float, int, float already
            "n_iterations": info.iter,
            "solve_time_s": info.solve_time,
        })


__all__ = [
    "DARE_RESIDUAL_RTOL",
    "MPCQP",
    "OSQP_INFINITY",
    "QPSolution",
    "MoveBounds",
    "dare_by_doubling",
    "lq_problem",
    "terminal_cost",
]
