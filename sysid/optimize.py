"""Levenberg-Marquardt least squares with bounds, projection and standard errors.

Notation
--------
``theta`` (p,) is the parameter vector (paper eq. 8), ``r(theta)`` (N,) the residual
vector (simulation errors for V, eq. 9, or one-step prediction errors for W, eq. 10)
and ``J = dr/dtheta`` (N, p) its Jacobian. The search minimizes ``sum_k r_k^2``, i.e.
N times V or W.

The step solves the damped Gauss-Newton system with Marquardt's diagonal scaling
``D`` (MINPACK's non-decreasing column norms of ``J``)::

    (J'J + mu D'D) s = -J'r

through a QR factorization of ``[J, r]`` (never forming ``J'J``; its ``R`` also gives
the gradient ``J'r`` and the column norms) and one SVD of the small scaled ``R`` per
iteration, which solves the system for every damping that iteration tries; the damping
``mu`` is updated by Nielsen's rule (Madsen, Nielsen and Tingleff, 2004, sec. 3.2).

Gauss-Newton's ``J'J`` leaves out ``S = sum_k r_k d^2 r_k/dtheta^2``, which is not small
for an output-error fit whose residuals are mostly model error, not noise: there
Gauss-Newton converges only linearly (the cost falling by a constant factor per
iteration). As NL2SOL does (Dennis, Gay and Welsch, ACM TOMS 7, 1981), a secant
approximation of ``S`` is kept, and each iteration uses the model, ``J'J`` or
``J'J + S``, that predicted the last reduction better; an augmented step that fails
falls back to Gauss-Newton's at the same damping.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.errors import IdentificationError

#: Initial damping, relative to the scaled Gauss-Newton matrix.
_MU_INITIAL = 1e-6
#: Rejected trial steps tolerated in one iteration before giving up.
_MAX_REJECTIONS = 60
_EPS = float(np.finfo(float).eps)
_TINY = float(np.finfo(float).tiny)


@dataclass(frozen=True, kw_only=True, eq=False)
class LMResult:
    """Outcome of `levenberg_marquardt`.

    Parameters
    ----------
    theta :
        Best parameter vector found, shape ``(p,)``.
    residuals :
        Residuals at `theta`, shape ``(N,)``.
    jacobian :
        Jacobian ``dr/dtheta`` at `theta`, shape ``(N, p)``.
    factor :
        `triangular_factor` of ``[jacobian, residuals]``, shape ``(p + 1, p + 1)``; its
        leading ``(p, p)`` block is the Jacobian's ``R``.
    cost :
        Mean of the squared residuals at `theta` (V or W).
    n_iterations :
        Iterations used (one Jacobian and a damping search each).
    converged :
        True if a convergence test (ftol, xtol, gtol or zero cost) was met.
    message :
        Why the search stopped, in words.
    """

    theta: FloatArray
    residuals: FloatArray
    jacobian: FloatArray
    factor: FloatArray
    cost: float
    n_iterations: int
    converged: bool
    message: str


def sum_of_squares(x: FloatArray) -> float:
    """``sum x^2`` of a 1-D array, without BLAS (whose threads stall on a loaded machine)."""
    return float(np.einsum("i,i->", x, x))


def triangular_factor(jac: FloatArray, free: FloatArray | None = None,
                      last: FloatArray | None = None, *, overwrite: bool = False) -> FloatArray:
    """``R`` of the QR factorization of ``[J[:, free], last]`` (Householder, LAPACK geqrf).

    Factored in place in one column-major copy (measured on 12,000 x 9: 0.3 ms against
    ``numpy.linalg.qr``'s 1.2 ms). ``overwrite``: a column-major ``jac`` (no ``free``, no
    ``last``) is factored in its own memory, which it then loses.
    """
    cols = range(jac.shape[1]) if free is None else np.flatnonzero(free).tolist()
    if overwrite and free is None and last is None and jac.flags.f_contiguous:
        block = jac
    else:
        block = np.empty((jac.shape[0], len(cols) + (last is not None)), order="F")
        if len(cols) == jac.shape[1]:
            block[:, : len(cols)] = jac
        else:
            for i, j in enumerate(cols):
                block[:, i] = jac[:, j]
        if last is not None:
            block[:, -1] = last
    qr, _, _, info = lapack.dgeqrf(block, overwrite_a=True)
    if info != 0:  # pragma: no cover - geqrf fails only on an illegal argument
        raise IdentificationError(f"triangular_factor: LAPACK dgeqrf returned info = {info}")
    k = min(block.shape)
    out: FloatArray = np.ascontiguousarray(qr[:k])  # zero the reflectors below the diagonal
    for i in range(1, k):
        out[i, :i] = 0.0
    return out


#: What ``fun`` may return as its Jacobian: the array, or a callable that makes it, called
#: only at accepted trial points (a rejected trial costs the residuals alone).
Jacobian = FloatArray | Callable[[], FloatArray]


def _evaluate(
    fun: Callable[[FloatArray], tuple[FloatArray, Jacobian]], theta: FloatArray
) -> tuple[FloatArray, Jacobian, float] | None:
    """``fun(theta)``'s residuals (checked 1-D), Jacobian and ``sum r^2``; None if not finite."""
    r_raw, jac = fun(theta)
    r = np.asarray(r_raw, dtype=float)
    if r.ndim != 1:
        raise IdentificationError(
            f"levenberg_marquardt: fun must return residuals of shape (N,); got {r.shape}")
    ssr = sum_of_squares(r)
    if not math.isfinite(ssr):
        return None
    return r, jac, ssr


def _factored(jac: Jacobian, r: FloatArray, p: int) -> tuple[FloatArray, FloatArray] | None:
    """The Jacobian (made if lazy, shape checked) and the `triangular_factor` of ``[J, r]``;
    None if that factor is not finite (a nan or inf in ``J`` reaches it)."""
    out = np.asarray(jac() if callable(jac) else jac, dtype=float)
    if out.shape != (r.size, p):
        raise IdentificationError(
            "levenberg_marquardt: fun must return (r of shape (N,), J of shape (N, p)) with "
            f"p = {p}; got shapes ({r.size},) and {out.shape}"
        )
    factor = triangular_factor(out, None, r)
    return (out, factor) if np.isfinite(np.einsum("ij->", factor)) else None


def _damped_solver(r_mat: FloatArray, qtr: FloatArray,
                   d: FloatArray) -> Callable[[float], FloatArray]:
    """``s(mu) = argmin |R s + Q'r|^2 + mu |D s|^2`` for any damping ``mu``, one SVD.

    With ``t = D s`` and ``R D^-1 = U S V'``: ``t = -V S / (S^2 + mu) U'Q'r``, so one SVD
    serves every trial of an iteration's damping search.
    """
    u, sing, vt = np.linalg.svd(r_mat / d, full_matrices=False)
    coef = u.T @ qtr
    sing2 = sing * sing
    rel_cut = (_EPS * 2 * d.size) ** 2
    top2 = float(sing2[0]) if sing.size else 0.0

    def solve(mu: float) -> FloatArray:
        denom = sing2 + mu
        cut = rel_cut * (top2 + mu) if sing.size else 0.0
        weights = np.divide(sing, denom, out=np.zeros_like(sing), where=denom > cut)
        out: FloatArray = -(vt.T @ (weights * coef)) / d
        return out

    return solve


def _augmented_solver(jtj: FloatArray, second: FloatArray, grad: FloatArray,
                      d: FloatArray) -> Callable[[float], FloatArray] | None:
    """``s(mu) = -(J'J + S + mu D'D)^-1 J'r`` from one eigendecomposition, or None.

    None where ``J'J + S`` (scaled by ``D``) is not positive definite: the augmented
    model then has no minimum and Gauss-Newton's is used instead.
    """
    scaled = (jtj + second) / np.outer(d, d)
    lam, vec = np.linalg.eigh((scaled + scaled.T) / 2.0)
    if lam.size == 0 or not lam[0] > 0:
        return None
    coef = vec.T @ (grad / d)

    def solve(mu: float) -> FloatArray:
        out: FloatArray = -(vec @ (coef / (lam + mu))) / d
        return out

    return solve


def _secant_update(second: FloatArray, step: FloatArray, y_sharp: FloatArray,
                   y_full: FloatArray) -> FloatArray:
    """NL2SOL's sized structured secant update of ``S`` (Dennis, Gay and Welsch 1981).

    Sized by ``min(1, |s'y#| / |s'Ss|)``, then the symmetric rank-two update with
    ``S+ s = y#``, ``y# = (J+ - J)' r+`` and ``y = J+'r+ - J'r``; only sized where
    ``y's <= 0``.
    """
    s_s = float(step @ second @ step)
    if s_s > 0:
        second = second * min(1.0, abs(float(step @ y_sharp)) / s_s)
    ys = float(y_full @ step)
    if not ys > 0:
        return second
    z = y_sharp - second @ step
    zy = np.outer(z, y_full)
    out: FloatArray = second + (zy + zy.T) / ys - float(z @ step) * np.outer(y_full, y_full) / ys**2
    return out


def _as_bound(bound: FloatArray | None, p: int, fill: float, name: str) -> FloatArray:
    if bound is None:
        return np.full(p, fill)
    arr = np.array(bound, dtype=float, copy=True).reshape(-1)
    if arr.size != p:
        raise IdentificationError(
            f"levenberg_marquardt: {name} must have one entry per parameter ({p}); "
            f"got {arr.size}"
        )
    return arr


#: `levenberg_marquardt`'s step and cost tolerances: tight, for a final fit.
DEFAULT_XTOL = 1e-10
DEFAULT_FTOL = 1e-12
#: Progress test: the search stops (converged) when the cost fell by less than this,
#: relative, over the last `PROGRESS_WINDOW` iterations, so a crawl along a flat valley
#: ends instead of hitting the cap (MATLAB's pem stops at 1e-4 expected improvement).
DEFAULT_PROGRESS_RTOL = 1e-6
#: Iterations over which the progress test compares the cost.
PROGRESS_WINDOW = 10
#: Cap on the iterations of every prediction-error search (a safety net behind the
#: progress test). Stated in the report.
MAX_ITERATIONS = 1000


def levenberg_marquardt(
    fun: Callable[[FloatArray], tuple[FloatArray, Jacobian]],
    theta0: FloatArray,
    *,
    lower: FloatArray | None = None,
    upper: FloatArray | None = None,
    project: Callable[[FloatArray], FloatArray] | None = None,
    max_iterations: int = MAX_ITERATIONS,
    xtol: float = DEFAULT_XTOL,
    ftol: float = DEFAULT_FTOL,
    gtol: float = 1e-10,
    progress_rtol: float = DEFAULT_PROGRESS_RTOL,
    callback: Callable[[int, float], None] | None = None,
) -> LMResult:
    """Minimize ``sum r(theta)^2`` by Levenberg-Marquardt with exact Jacobians.

    Each iteration takes the Gauss-Newton or the NL2SOL-augmented model (see the module
    docstring), whichever predicted the last accepted step's reduction better.

    Parameters
    ----------
    fun :
        ``fun(theta) -> (r, J)``: residuals, shape ``(N,)``, and their Jacobian
        ``dr/dtheta``, shape ``(N, p)``, or a `Jacobian` callable. Non-finite values at a
        trial point (an unstable filter) reject it and raise the damping.
    theta0 :
        Starting point, shape ``(p,)``, clipped to the bounds and projected.
    lower, upper :
        Bounds on ``theta`` (``-inf``/``+inf`` allowed), or None. Trial points are
        clipped into them; parameters at a bound whose gradient pushes outward are held
        for that step (a simple active set).
    project :
        Maps a trial point into the feasible set after clipping, or None (to keep F(q)
        and C(q) stable: `sysid.polynomials.reflect_unstable_roots`).
    max_iterations :
        Cap on the iterations; the progress test normally ends the search first.
    xtol :
        Converged when a step satisfies ``||s|| <= xtol (xtol + ||theta||)``.
    ftol :
        Converged when an accepted step reduces the sum of squares by at most
        ``ftol`` relative, both actually and as predicted by the linear model.
    gtol :
        Converged when ``max_i |J_i' r| / (||J_i|| ||r||) <= gtol`` over the free
        parameters (MINPACK's scale-free gradient test: the largest cosine between
        the residual and a Jacobian column).
    progress_rtol :
        Converged when the cost fell by at most ``progress_rtol`` relative over the
        last `PROGRESS_WINDOW` iterations; 0 turns the test off.
    callback :
        Called after every iteration as ``callback(iteration, cost)`` with the best
        iterate's cost (mean squared residual).

    Returns
    -------
    LMResult
        The best (last accepted) iterate; ``converged=False`` and a message if no test
        was met within `max_iterations`.

    Raises
    ------
    IdentificationError
        Bad option values, shapes that do not match, or non-finite residuals or Jacobian
        at the starting point.

    Examples
    --------
    >>> def line(theta):
    ...     x = np.arange(5.0)
    ...     r = theta[0] + theta[1] * x - (1.0 + 2.0 * x)
    ...     return r, np.column_stack([np.ones(5), x])
    >>> np.round(levenberg_marquardt(line, np.zeros(2)).theta, 12).tolist()
    [1.0, 2.0]
    """
    max_iterations = checked_int(max_iterations, 1, "levenberg_marquardt: max_iterations")
    for name, tol in (("xtol", xtol), ("ftol", ftol), ("gtol", gtol),
                      ("progress_rtol", progress_rtol)):
        if not (np.isfinite(tol) and tol >= 0):
            raise IdentificationError(
                f"levenberg_marquardt: {name} must be a finite number >= 0; got {tol!r}"
            )
    theta = np.array(theta0, dtype=float, copy=True).reshape(-1)
    p = theta.size
    if p == 0 or not np.all(np.isfinite(theta)):
        raise IdentificationError(
            f"levenberg_marquardt: theta0 must be a non-empty finite vector; got {theta0!r}"
        )
    lo = _as_bound(lower, p, -np.inf, "lower")
    hi = _as_bound(upper, p, np.inf, "upper")
    if np.any(lo > hi):
        raise IdentificationError(
            f"levenberg_marquardt: lower must not exceed upper; got {lo} > {hi}"
        )

    bounded = bool(np.any(np.isfinite(lo)) or np.any(np.isfinite(hi)))

    def feasible(x: FloatArray) -> FloatArray:
        x = np.clip(x, lo, hi) if bounded else x
        return np.asarray(project(x), dtype=float) if project is not None else x

    theta = feasible(theta)
    first = _evaluate(fun, theta)
    made = None if first is None else _factored(first[1], first[0], p)
    if first is None or made is None:
        raise IdentificationError(
            "levenberg_marquardt: the residuals or Jacobian at the starting point theta0 "
            f"= {theta.tolist()} are not finite; start from a point where the model is "
            "stable and defined"
        )
    r, _, ssr = first
    jac, r_aug = made
    n = r.size
    scale = np.zeros(p)
    mu = _MU_INITIAL
    nu = 2.0
    converged = False
    message = ""
    iteration = 0
    history = [ssr]
    second = np.zeros((p, p))  # NL2SOL's S: the second-order part of the Hessian
    use_augmented = False
    pending: tuple[FloatArray, FloatArray, FloatArray] | None = None
    while iteration < max_iterations:
        iteration += 1
        if ssr <= _TINY:
            converged, message = True, "the sum of squared residuals is zero"
            break
        # r_aug = R of [J, r]: J = Q R_J, r = Q R_r + (orthogonal to J), so J'r = R_J' R_r
        # and J's column norms are R_J's
        grad = r_aug[:, :p].T @ r_aug[:, p]
        col_norms = np.sqrt(np.einsum("ij,ij->j", r_aug[:, :p], r_aug[:, :p]))
        if pending is not None:  # y# = (J - J_old)'r and y = J'r - J_old'r_old
            step_old, old_jac_r, old_grad = pending
            second = _secant_update(second, step_old, grad - old_jac_r, grad - old_grad)
            pending = None
        free = col_norms > 0
        if bounded:
            free &= ~(((theta <= lo) & (grad > 0)) | ((theta >= hi) & (grad < 0)))
        n_free = int(np.count_nonzero(free))
        if n_free == 0:
            converged, message = True, "every parameter is held at a bound or has no effect"
            break
        all_free = n_free == p
        root_ssr = math.sqrt(ssr)
        cosines = (np.abs(grad) / (col_norms * root_ssr) if all_free
                   else np.abs(grad[free]) / (col_norms[free] * root_ssr))
        if float(np.max(cosines)) <= gtol:
            converged, message = True, f"gradient test met (max cosine <= gtol = {gtol:g})"
            break
        scale = np.maximum(scale, col_norms)
        d = scale.copy() if all_free else np.where(scale[free] > 0, scale[free], 1.0)
        r_free = r_aug if all_free else triangular_factor(jac, free, r)  # R of [J_free, r]
        r_mat = r_free[:n_free, :n_free]
        qtr = r_free[:n_free, -1]
        gauss_newton = _damped_solver(r_mat, qtr, d)
        second_free = second if all_free else second[np.ix_(free, free)]
        augmented = (_augmented_solver(r_mat.T @ r_mat, second_free, grad[free], d)
                     if use_augmented else None)
        theta_norm = math.sqrt(float(theta @ theta))
        qtr_qtr = float(qtr @ qtr)
        accepted = False
        for _ in range(_MAX_REJECTIONS):
            if all_free:
                trial = feasible(theta + (augmented or gauss_newton)(mu))
            else:
                step = np.zeros(p)
                step[free] = (augmented or gauss_newton)(mu)
                trial = feasible(theta + step)
            step = trial - theta
            step_free = step if all_free else step[free]
            step_small = math.sqrt(float(step @ step)) <= xtol * (xtol + theta_norm)
            lin = qtr + r_mat @ step_free
            predicted_gn = qtr_qtr - float(lin @ lin)
            predicted_aug = predicted_gn - float(step_free @ second_free @ step_free)
            predicted = predicted_gn if augmented is None else predicted_aug
            evaluated = _evaluate(fun, trial)
            ssr_new = evaluated[2] if evaluated is not None else math.inf
            made = (_factored(evaluated[1], evaluated[0], p)
                    if evaluated is not None and ssr_new < ssr else None)
            if evaluated is not None and made is not None:
                actual = ssr - ssr_new
                if predicted > 0:
                    rho = actual / predicted
                    mu *= max(0.1, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                small_reduction = actual <= ftol * ssr and 0 <= predicted <= ftol * ssr
                r_new = evaluated[0]
                # the secant update waits for the next iteration's J'r (from its R)
                pending = (step, r_new @ jac, grad)
                # the next iteration uses the model that predicted this reduction better
                use_augmented = abs(predicted_aug - actual) < abs(predicted_gn - actual)
                theta, r, ssr = trial, r_new, ssr_new
                jac, r_aug = made
                accepted = True
                if small_reduction:
                    converged, message = True, f"relative reduction of the cost below ftol = {ftol:g}"
                elif step_small:
                    converged, message = True, f"step size below xtol = {xtol:g} (relative to |theta|)"
                break
            if augmented is not None:  # the augmented model failed: Gauss-Newton's, same mu
                augmented = None
                use_augmented = False
                continue
            if step_small:
                converged = True
                message = (
                    f"no cost reduction possible with a step above xtol = {xtol:g} "
                    "(relative to |theta|)"
                )
                break
            mu *= nu
            nu *= 2.0
        if callback is not None:
            callback(iteration, ssr / n)
        history.append(ssr)
        if not converged and len(history) > PROGRESS_WINDOW and (
                history[-1 - PROGRESS_WINDOW] - ssr <= progress_rtol * ssr):
            converged = True
            message = (f"V fell by less than {progress_rtol:g} relative over the last "
                       f"{PROGRESS_WINDOW} iterations (the progress test)")
        if converged:
            break
        if not accepted:
            message = (
                f"no trial step reduced the cost after {_MAX_REJECTIONS} increases of the "
                "damping; the best iterate is kept"
            )
            break
    if not converged and not message:
        message = (
            f"maximum number of iterations ({max_iterations}) reached before the ftol, xtol "
            "or gtol test was met; the best iterate is kept"
        )
    return LMResult(
        theta=theta,
        residuals=r,
        jacobian=jac,
        factor=r_aug,
        cost=ssr / n,
        n_iterations=iteration,
        converged=converged,
        message=message,
    )


def parameter_std_errors(jacobian: FloatArray, residuals: FloatArray, *,
                         factor: FloatArray | None = None) -> FloatArray:
    """Standard errors ``sqrt(diag(s^2 (J'J)^-1))`` of least-squares parameters.

    Parameters
    ----------
    jacobian :
        ``dr/dtheta`` at the optimum, shape ``(N, p)``.
    residuals :
        Residuals at the optimum, shape ``(N,)``.
    factor :
        `triangular_factor` of `jacobian` if the caller has it (the first ``p`` columns
        of the factor of ``[J, r]`` are it), or None to factor here.

    Returns
    -------
    FloatArray
        Shape ``(p,)``. ``s^2 = sum r^2 / (N - p)``.

    Notes
    -----
    ``(J'J)^-1 = V S^-2 V'`` from the SVD ``J = U S V'`` (of the triangular factor of
    ``J``). Singular values below ``max(N, p) * eps * S_max`` mark unidentifiable
    directions: a parameter with a component above ``sqrt(eps)`` along one gets an
    infinite standard error, the others keep theirs. With ``N <= p`` every entry is
    infinite (no residual degrees of freedom).
    """
    jac = np.asarray(jacobian, dtype=float)
    n, p = jac.shape
    if n <= p:
        return np.full(p, np.inf)
    s2 = sum_of_squares(np.asarray(residuals, dtype=float)) / (n - p)
    # J = Q R, so J and the small R share singular values and right singular vectors.
    _, sing, vt = np.linalg.svd(triangular_factor(jac) if factor is None else factor)
    tol = max(n, p) * np.finfo(float).eps * (float(sing[0]) if sing.size else 0.0)
    good = sing > tol
    if not np.any(good):
        return np.full(p, np.inf)
    out = np.sqrt(s2 * np.sum((vt[good].T / sing[good]) ** 2, axis=1))
    if not np.all(good):
        out[np.max(np.abs(vt[~good].T), axis=1) > np.sqrt(np.finfo(float).eps)] = np.inf
    return np.asarray(out, dtype=float)


__all__ = [
    "DEFAULT_PROGRESS_RTOL",
    "Jacobian",
    "MAX_ITERATIONS",
    "PROGRESS_WINDOW",
    "LMResult",
    "levenberg_marquardt",
    "parameter_std_errors",
    "sum_of_squares",
    "triangular_factor",
]
