"""The paper's route to a Hammerstein model: eq. 21 start, re-identification, joint PEM, noise model.

Steps 1-2 here (`initial_input_poly`, `reidentify_linear_block`), steps 3-4 in
`sysid.hammerstein.fitting`; `run_hammerstein_route` runs them all on deviation arrays and
`fit_hammerstein` on a `Dataset`. Notation as in `sysid.hammerstein`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from sysid._arrays import readonly_array as _readonly
from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.data import Dataset
from sysid.errors import IdentificationError, IdentificationWarning
from sysid.hammerstein.filtering import InitialState
from sysid.hammerstein.fitting import fit_hammerstein_armax, fit_hammerstein_oe
from sysid.hammerstein.model import (
    HammersteinFit,
    RowForm,
    _check_arrays,
    _check_orders,
    hammerstein_model,
)
from sysid.linear import ArxFit, PemFit, arx_least_squares, arx_oe_start, oe_pem, segment_bounds, sriv_oe
from sysid.model import OperatingPoint, _poly_eval
from sysid.optimize import MAX_ITERATIONS, PROGRESS_WINDOW, parameter_std_errors
from sysid.result import IdentificationResult
from sysid.steps import InputStep, detect_steps
from sysid.voltage import GridVoltage, grid_voltage


@dataclass(frozen=True, kw_only=True, eq=False)
class InputPolyInit:
    """Least-squares initial input polynomial from step responses (paper eq. 21).

    Parameters
    ----------
    input_poly :
        ``[d_1, ..., d_n]`` of ``f(ds) = sum d_i ds^i`` in the units of the ARX
        model's input, i.e. before normalization: the ARX ``b`` multiply ``f``.
    std_errors :
        Standard errors of `input_poly` from the least squares.
    regressor :
        The rows of eq. 21, one per step, shape ``(n_steps, n)``.
    target :
        Their left-hand sides, shape ``(n_steps,)`` [kW].
    residuals :
        ``target - regressor @ input_poly`` [kW].
    row_form :
        ``"eq21"`` or ``"jump"`` (see `initial_input_poly`).
    fit :
        The Hammerstein model of the paper's Fig. 12: the ARX polynomials with ``ds``
        replaced by ``f(ds)``, normalized (``B / b_first``, ``f * b_first``).
    """

    input_poly: FloatArray
    std_errors: FloatArray
    regressor: FloatArray = field(repr=False)
    target: FloatArray = field(repr=False)
    residuals: FloatArray
    row_form: RowForm
    fit: HammersteinFit


def initial_input_poly(
    steps: Sequence[InputStep],
    arx_a: npt.ArrayLike,
    arx_b: npt.ArrayLike,
    *,
    operating_point: OperatingPoint,
    degree: int = 2,
    row_form: RowForm = "eq21",
) -> InputPolyInit:
    """Estimate the input polynomial ``f`` from the input steps and an ARX model (eq. 21).

    Parameters
    ----------
    steps :
        Input steps with their instantaneous responses (`sysid.steps.detect_steps`,
        the rows of Table 3), in absolute units.
    arx_a :
        ARX ``A(q) = [1, a_1, ..]`` identified with ``ds`` as input (sec. 6).
    arx_b :
        ARX ``B(q) = [0]*nk + [b_nk, ..]`` (not normalized).
    operating_point :
        ``(s_nom, P_nom)`` the deviations are taken about.
    degree :
        Degree ``n`` of ``f`` (the paper: 2).
    row_form :
        ``"eq21"`` (default, the paper's literal rows) or ``"jump"`` (see Notes).

    Returns
    -------
    InputPolyInit
        The coefficients, their standard errors, the least-squares system and the
        Hammerstein model of Fig. 12.

    Raises
    ------
    IdentificationError
        Fewer steps than ``degree`` (or a rank-deficient system: the steps do not
        span enough input levels), bad polynomials or options.

    Notes
    -----
    Eq. 20 at the sample ``k = k_step + nk`` where a step from ``ds_before`` to
    ``ds_after`` first shows, with every earlier output at ``dP_before`` and the input at
    ``ds_after`` for lag ``nk`` and ``ds_before`` for longer lags, gives one row per step
    of Table 3 (``row_form = "eq21"``)::

        dP_after + (a_1 + .. + a_na) dP_before
            = sum_i d_i (b_nk ds_after^i + (b_{nk+1} + .. ) ds_before^i)       (eq. 21)

    Subtracting the rest equation of the ARX model leaves the jump of eq. 18,
    ``dP_after - dP_before = b_nk (f(ds_after) - f(ds_before))`` (``row_form = "jump"``,
    blind to how far from rest the output was); the two agree when the steps start from
    rest. Solved by ordinary least squares (the paper: four rows, two unknowns).
    """
    where = "initial_input_poly"
    degree = checked_int(degree, 1, f"{where}: degree")
    if row_form not in ("eq21", "jump"):
        raise IdentificationError(f"{where}: row_form must be 'eq21' or 'jump'; got {row_form!r}")
    a = np.asarray(arx_a, dtype=float)
    b = np.asarray(arx_b, dtype=float)
    if a.ndim != 1 or a.size < 1 or a[0] != 1.0 or not np.all(np.isfinite(a)):
        raise IdentificationError(f"{where}: arx_a must be [1, a1, ...] and finite; got {a.tolist()}")
    nonzero = np.flatnonzero(b)
    if b.ndim != 1 or nonzero.size == 0 or not np.all(np.isfinite(b)):
        raise IdentificationError(
            f"{where}: arx_b must be finite with a non-zero coefficient; got {b.tolist()}"
        )
    steps = tuple(steps)
    if len(steps) < degree:
        raise IdentificationError(
            f"{where}: a degree-{degree} polynomial needs at least {degree} steps; got "
            f"{len(steps)}"
        )
    nk = int(nonzero[0])
    b_first = float(b[nk])
    b_rest = float(np.sum(b[nk + 1 :]))
    a_rest = float(np.sum(a[1:]))
    powers = np.arange(1, degree + 1)
    rows = []
    target = []
    for step in steps:
        ds_before = step.triac_before_pct - operating_point.triac_pct
        ds_after = step.triac_after_pct - operating_point.triac_pct
        dp_before = step.power_before_kw - operating_point.power_kw
        dp_after = step.power_after_kw - operating_point.power_kw
        if row_form == "eq21":
            rows.append(b_first * ds_after**powers + b_rest * ds_before**powers)
            target.append(dp_after + a_rest * dp_before)
        else:
            rows.append(b_first * (ds_after**powers - ds_before**powers))
            target.append(dp_after - dp_before)
    phi = np.asarray(rows, dtype=float)
    rhs = np.asarray(target, dtype=float)
    scale = np.linalg.norm(phi, axis=0)
    if np.any(scale == 0.0):
        raise IdentificationError(f"{where}: the steps give an all-zero column; no information")
    sol, _, rank, _ = np.linalg.lstsq(phi / scale, rhs, rcond=None)
    if rank < degree:
        raise IdentificationError(
            f"{where}: the {len(steps)} steps determine only {rank} of {degree} coefficients "
            "(they do not span enough distinct input levels); lower the degree"
        )
    d = sol / scale
    residuals = rhs - phi @ d
    std = (
        parameter_std_errors(phi, residuals)
        if len(steps) > degree
        else np.full(degree, np.inf)
    )
    fit = _normalized_fit(
        "arx", a, b / b_first, d * b_first, tuple(f"d{i}" for i in powers), d * b_first,
        np.asarray(std) * abs(b_first), residuals,
        message="least squares on the step rows of eq. 21", method=f"hammerstein-eq21-{row_form}",
    )
    return InputPolyInit(
        input_poly=_readonly(d),
        std_errors=_readonly(std),
        regressor=_readonly(phi),
        target=_readonly(rhs),
        residuals=_readonly(residuals),
        row_form=row_form,
        fit=fit,
    )


def _normalized_fit(
    linear_block: Literal["arx", "oe"],
    a: FloatArray,
    b: FloatArray,
    input_poly: FloatArray,
    names: tuple[str, ...],
    theta: FloatArray,
    std: FloatArray,
    residuals: FloatArray,
    *,
    c: FloatArray | None = None,
    criterion: Literal["ballistic", "least_squares"] = "least_squares",
    n_iterations: int = 0,
    converged: bool = True,
    message: str,
    method: str,
) -> HammersteinFit:
    """A step's `HammersteinFit` (``C = [1]`` by default); ``cost`` is the mean square of `residuals`."""
    return HammersteinFit(
        linear_block=linear_block,
        a=a,
        b=b,
        c=np.array([1.0]) if c is None else c,
        input_poly=input_poly,
        parameter_names=names,
        parameters=theta,
        std_errors=std,
        residuals=residuals,
        criterion=criterion,
        cost=float(np.mean(np.asarray(residuals) ** 2)),
        n_iterations=n_iterations,
        converged=converged,
        message=message,
        method=method,
    )


# =========================================================================== step 2
def reidentify_linear_block(
    y: FloatArray,
    ds: FloatArray,
    input_poly: npt.ArrayLike,
    *,
    method: Literal["arx", "oe"] = "oe",
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    max_iterations: int = MAX_ITERATIONS,
    segment_starts: Sequence[int] | None = None,
) -> HammersteinFit:
    """Re-identify the linear block with ``f`` fixed: input ``w = f(ds)`` (sec. 7.4).

    Parameters
    ----------
    y, ds :
        Output deviation ``dP`` [kW] and input deviation [%], shape ``(N,)``.
    input_poly :
        ``[d_1, ..., d_n]`` of the fixed ``f`` (for example `InputPolyInit.input_poly`).
    method :
        ``"arx"`` (least squares, ``A`` of order ``nf``) or ``"oe"`` (PEM on V).
    nb, nf, nk :
        Orders of ``B`` and ``F`` (or ``A``) and the delay.
    max_iterations :
        Iteration limit of the OE search.
    segment_starts :
        First sample of each segment (experiment), starting with 0; default one
        segment. The ARX regressors never reach across a boundary; the OE simulation
        restarts in each segment (held past).

    Returns
    -------
    HammersteinFit
        Normalized: ``B / b_nk`` and ``f * b_nk`` (eqs. 22-24). The OE residuals are
        the simulation errors (V); the ARX ones are equation errors.

    Raises
    ------
    IdentificationError
        Bad options or arrays, a constant input, or an estimated ``b_nk`` of zero.

    Warns
    -----
    IdentificationWarning
        The OE search did not converge (from `sysid.linear.oe_pem`).
    """
    where = "reidentify_linear_block"
    y_arr, ds_arr = _check_arrays(y, ds, where)
    poly = np.asarray(input_poly, dtype=float)
    if poly.ndim != 1 or poly.size == 0 or not np.all(np.isfinite(poly)):
        raise IdentificationError(f"{where}: input_poly must be a non-empty finite 1-D list")
    if method not in ("arx", "oe"):
        raise IdentificationError(f"{where}: method must be 'arx' or 'oe'; got {method!r}")
    w = _poly_eval(poly, ds_arr)
    starts = None if segment_starts is None else tuple(int(v) for v in segment_starts)
    est: ArxFit | PemFit
    if method == "arx":
        est = arx_least_squares(y_arr, w, na=nf, nb=nb, nk=nk, segment_starts=starts)
        c, n_it, converged, message = np.array([1.0]), 0, True, "least squares: exact solution"
    else:
        est = oe_pem(y_arr, w, nb=nb, nf=nf, nk=nk, max_iterations=max_iterations,
                     segment_starts=starts)
        c, n_it, converged, message = est.c, est.n_iterations, est.converged, est.message
    b_first = float(est.b[np.flatnonzero(est.b)[0]]) if np.any(est.b) else 0.0
    if b_first == 0.0:
        raise IdentificationError(f"{where}: the estimated B(q) is zero; f(ds) has no effect")
    return _normalized_fit(
        method, est.a, est.b / b_first, poly * b_first, est.parameter_names, est.theta,
        est.std_errors, est.residuals, c=c,
        criterion="least_squares" if method == "arx" else "ballistic", n_iterations=n_it,
        converged=converged, message=message, method=f"hammerstein-reidentified-{method}",
    )


# =========================================================================== multistart
#: Fixed-pole starts of the final OE fit on request (``czmpc identify --orders auto``): time
#: constants geometric from 1 sample to a tenth of the record (ratio ~2 on 1000 samples).
N_POLE_STARTS = 8
#: A multistart fit replaces the route's own only if its V is lower by more than this share:
#: equal minima from two starts differ by the searches' tolerances (ftol 1e-12).
MULTISTART_V_RTOL = 1e-6
#: A multistart search is abandoned once its V could not fall below the incumbent's
#: (less `MULTISTART_V_RTOL`) within its iteration cap even at this many times its fall
#: over the last `PROGRESS_WINDOW` iterations: such a fit could not replace the incumbent.
#: On the exchanger log at 4 times its rate, four starts crawled 700 to 900 iterations at
#: about 1e-6 relative per iteration (V 0.26 to 0.52 against the incumbent's 0.19): 20 s
#: of its 41 s identification.
ABANDON_RATE_FACTOR = 10.0


class _CatchUpError(IdentificationError):
    """A multistart search abandoned by `_catch_up_watch`."""


def _catch_up_watch(target: float, max_iterations: int,
                    progress: Callable[[int, float], None] | None,
                    ) -> Callable[[int, float], None]:
    """A progress callback for one multistart search: passes each ``(iteration, V)`` on
    to ``progress`` and raises `_CatchUpError` when V is above ``target`` and could not
    reach it within ``max_iterations`` at `ABANDON_RATE_FACTOR` times its recent fall."""
    history: list[float] = []

    def watch(iteration: int, cost: float) -> None:
        if progress is not None:
            progress(iteration, cost)
        if iteration == 1:
            history.clear()
        history.append(cost)
        if len(history) <= PROGRESS_WINDOW or cost <= target:
            return
        fall = (history[-1 - PROGRESS_WINDOW] - cost) / PROGRESS_WINDOW
        if cost - ABANDON_RATE_FACTOR * fall * (max_iterations - iteration) > target:
            raise _CatchUpError(
                f"V {cost:.6g} at iteration {iteration} cannot reach {target:.6g} within "
                f"{max_iterations} iterations")
    return watch


def pole_start_time_constants(n_samples: int, n_starts: int = N_POLE_STARTS) -> FloatArray:
    """Time constants [samples] of the fixed-pole starts: geometric from 1 to ``n_samples / 10``.

    Parameters
    ----------
    n_samples :
        Samples in the record (it shows too little of a longer time constant's settling).
    n_starts :
        Number of time constants (>= 1; 1 gives one sample).

    Returns
    -------
    FloatArray
        Shape ``(n_starts,)`` [samples], increasing.

    Raises
    ------
    IdentificationError
        ``n_samples < 1`` or ``n_starts < 1``.
    """
    where = "pole_start_time_constants"
    n = checked_int(n_samples, 1, f"{where}: n_samples")
    m = checked_int(n_starts, 1, f"{where}: n_starts")
    out: FloatArray = np.geomspace(1.0, max(n / 10.0, 1.0), m)
    return out


def fixed_pole_starts(
    y: FloatArray,
    ds: FloatArray,
    *,
    nb: int,
    nf: int,
    nk: int,
    time_constants_samples: Sequence[float] | FloatArray,
    segment_starts: Sequence[int] | None = None,
) -> tuple[dict[str, float], ...]:
    """Starts of a Hammerstein-OE fit with ``F`` fixed at repeated poles and ``B`` by least squares.

    The OE search is not convex and its usual start, the ARX, is biased under coloured
    noise (cascaded tanks: the OE search ends at 1.08 from the ARX, at 0.48 from a
    fixed-pole start). For each time constant ``tau``, ``F = (1 - z q^-1)^nf`` with
    ``z = exp(-1 / tau)``, and ``B`` is the least-squares fit of ``y`` on the lagged
    ``ds / F`` (zero initial state); ``f(ds) = b_nk ds`` (higher ``d_i`` start at zero).

    Parameters
    ----------
    y, ds :
        Output and input deviations, shape ``(N,)``.
    nb, nf, nk :
        Orders of the OE block (``nb`` counts ``b_nk``) and the delay [samples].
    time_constants_samples :
        Time constants of the repeated pole [samples], each > 0 (for example
        `pole_start_time_constants`). With ``nf = 0`` one start is returned.
    segment_starts :
        First sample of each segment, starting with 0; default one segment. Each
        segment is filtered from a zero state and its lags never reach across a
        boundary; the least squares pools the rows of all segments.

    Returns
    -------
    tuple of dict
        Start values by name (``d1``, ``b_{nk+1}..`` normalized by ``b_nk``, ``f1..``),
        one per time constant; a time constant whose ``b_nk`` comes out zero or
        non-finite gives none.

    Raises
    ------
    IdentificationError
        Bad arrays or orders, or a time constant that is not finite and > 0.
    """
    where = "fixed_pole_starts"
    y_arr, ds_arr = _check_arrays(y, ds, where)
    _, nb, nf, nk = _check_orders(1, nb, nf, nk, where)
    taus = np.asarray(time_constants_samples, dtype=float).reshape(-1)
    if taus.size == 0 or not np.all(np.isfinite(taus) & (taus > 0)):
        raise IdentificationError(
            f"{where}: time_constants_samples must be finite numbers > 0; got {taus.tolist()}"
        )
    out: list[dict[str, float]] = []
    bounds = segment_bounds(ds_arr.size, None if segment_starts is None
                            else tuple(int(v) for v in segment_starts), where)
    for tau in taus if nf else taus[:1]:
        f = np.poly(np.full(nf, np.exp(-1.0 / tau))) if nf else np.array([1.0])
        phi = np.zeros((ds_arr.size, nb))
        for lo, hi in bounds:
            filtered = lfilter([1.0], f, ds_arr[lo:hi])
            for col, lag in enumerate(range(nk, nk + nb)):
                if lag < hi - lo:
                    phi[lo + lag : hi, col] = filtered[: hi - lo - lag]
        b, *_ = np.linalg.lstsq(phi, y_arr, rcond=None)
        if not np.all(np.isfinite(b)) or b[0] == 0.0:
            continue
        start = {"d1": float(b[0])}
        start.update({f"b{nk + j}": float(b[j] / b[0]) for j in range(1, nb)})
        start.update({f"f{i}": float(f[i]) for i in range(1, nf + 1)})
        out.append(start)
    return tuple(out)


def sriv_start(
    y: FloatArray, ds: FloatArray, input_poly: FloatArray, *, nb: int, nf: int, nk: int,
) -> dict[str, float] | None:
    """Start of a Hammerstein-OE fit from the SRIV estimate of its linear block.

    With ``f`` fixed at `input_poly`, ``y = B/F f(ds)`` is a linear OE problem that
    `sysid.linear.sriv_oe` solves without the ARX's noise bias (several segments are
    treated as one: this is a start only).

    Returns
    -------
    dict or None
        Start values by name (``d1..`` of ``f`` scaled by ``b_nk``, ``b_{nk+1}..``
        normalized by ``b_nk``, ``f1..``), or None where the estimate fails or ``b_nk``
        is zero.
    """
    w = _poly_eval(np.asarray(input_poly, dtype=float), ds)
    arx = arx_oe_start(y, w, nb=nb, nf=nf, nk=nk)
    theta = None if arx is None else sriv_oe(y, w, nb=nb, nf=nf, nk=nk, start=arx)
    if theta is None or theta[0] == 0.0:
        return None
    start = {f"d{i + 1}": float(d * theta[0]) for i, d in enumerate(input_poly)}
    start.update({f"b{nk + j}": float(theta[j] / theta[0]) for j in range(1, nb)})
    start.update({f"f{i}": float(theta[nb + i - 1]) for i in range(1, nf + 1)})
    return start


def _multistart(
    final: HammersteinFit,
    y: FloatArray,
    ds: FloatArray,
    *,
    degree: int,
    nb: int,
    nf: int,
    nk: int,
    n_starts: int,
    max_iterations: int,
    initial_state: InitialState,
    progress: Callable[[int, float], None] | None,
    segment_starts: Sequence[int] | None = None,
    voltage: GridVoltage | None = None,
) -> HammersteinFit:
    """The best of `final` and the OE fits from `sriv_start` and `fixed_pole_starts`.

    A start's fit replaces `final` only if its V is lower by more than `MULTISTART_V_RTOL`;
    only the winner's non-convergence warnings are issued. Without a grid voltage, a
    search that cannot catch up with the best so far is abandoned (`ABANDON_RATE_FACTOR`;
    with one, V changes between its refits).
    """
    best = final
    kept: list[warnings.WarningMessage] = []
    longest = max(hi - lo for lo, hi in segment_bounds(
        y.size, None if segment_starts is None else tuple(segment_starts), "_multistart"))
    iv = sriv_start(y, ds, final.input_poly, nb=nb, nf=nf, nk=nk)
    for start in ([] if iv is None else [iv]) + list(fixed_pole_starts(
        y, ds, nb=nb, nf=nf, nk=nk,
        time_constants_samples=pole_start_time_constants(longest, n_starts),
        segment_starts=segment_starts,
    )):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", IdentificationWarning)
            try:
                watch = progress if voltage is not None else _catch_up_watch(
                    (1.0 - MULTISTART_V_RTOL) * best.cost, max_iterations, progress)
                fit = fit_hammerstein_oe(
                    y, ds, initial=start, degree=degree, nb=nb, nf=nf, nk=nk,
                    max_iterations=max_iterations, initial_state=initial_state,
                    segment_starts=segment_starts, progress=watch, voltage=voltage,
                )
            except IdentificationError:     # a failed start, or one that cannot catch up
                continue
        if fit.cost < (1.0 - MULTISTART_V_RTOL) * best.cost:
            best, kept = fit, [w for w in caught if issubclass(w.category, IdentificationWarning)]
    for w in kept:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return best


# =========================================================================== public entry
@dataclass(frozen=True, kw_only=True, eq=False)
class HammersteinRoute:
    """Every step of the paper's Hammerstein route on one record (secs. 7.3-7.6).

    Parameters
    ----------
    arx :
        The linear ARX fit on ``ds`` that eq. 21 uses (as a `HammersteinFit` with
        ``f(ds) = b_nk ds``).
    steps :
        The input steps used in eq. 21.
    initial_poly :
        Step 1 (eq. 21, Fig. 12), or None when skipped (fewer steps than the degree).
    arx_reidentified, oe_reidentified :
        Step 2 (Fig. 13).
    final_oe :
        Step 3 from the good initial values (eq. 27).
    final_oe_from_zeros :
        Step 3 from zeros, or None if not run.
    noise_model :
        Step 4 (eq. 30), or None if not run.
    skipped :
        What was skipped and why, in words.
    """

    arx: HammersteinFit
    steps: tuple[InputStep, ...]
    initial_poly: InputPolyInit | None
    arx_reidentified: HammersteinFit
    oe_reidentified: HammersteinFit
    final_oe: HammersteinFit
    final_oe_from_zeros: HammersteinFit | None
    noise_model: HammersteinFit | None
    skipped: tuple[str, ...] = ()


def run_hammerstein_route(
    y: FloatArray,
    ds: FloatArray,
    *,
    steps: Sequence[InputStep],
    operating_point: OperatingPoint,
    degree: int = 2,
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    noise_model: bool = True,
    nc: int | None = None,
    from_zeros: bool = False,
    row_form: RowForm = "eq21",
    max_iterations: int = MAX_ITERATIONS,
    initial_state: InitialState = "estimate",
    progress: Callable[[str, int, float], None] | None = None,
    extra_start: Mapping[str, float] | None = None,
    pole_starts: int = 0,
    segment_starts: Sequence[int] | None = None,
    voltage: GridVoltage | None = None,
) -> HammersteinRoute:
    """Run steps 1-4 of the paper's route on deviation arrays.

    Parameters
    ----------
    y, ds :
        Output and input deviations, shape ``(N,)`` [kW], [%].
    steps :
        Input steps (absolute units) for eq. 21.
    operating_point :
        The operating point the deviations are about (converts the steps).
    degree, nb, nf, nk, nc, max_iterations, initial_state :
        As in `fit_hammerstein` (the ARX uses ``na = nf``).
    noise_model :
        Also fit the ARMAX-block model on W (step 4), with ``na = nf`` and ``nc``.
    from_zeros :
        Also run step 3 from all-zero initial values.
    row_form :
        Rows of eq. 21 (see `initial_input_poly`).
    progress :
        ``progress(step, iteration, cost)`` after every iteration of the joint PEM
        fits, with ``step`` naming the fit.
    extra_start :
        A second start of step 3 by parameter name (for example the structure
        search's fit); the better of the two final OE fits on V is kept.
    pole_starts :
        Also run step 3 from the SRIV start (`sriv_start`) and this many fixed-pole
        starts (`fixed_pole_starts` at `pole_start_time_constants`); one replaces the
        fit from the route's own start only if its V is lower by more than
        `MULTISTART_V_RTOL`. 0 (default): the paper's route alone.
    segment_starts :
        First sample of each segment (experiment) of the record, starting with 0;
        default one segment. Every step uses all segments, each with its own initial
        state: the ARX fits never reach across a boundary, the OE and joint PEM fits
        restart in each segment (the steps must not straddle a boundary either; see
        `sysid.steps.detect_steps`).
    voltage :
        The record's grid voltage, or None: given, the joint PEM fits of step 3 and 4
        compensate it (`fit_hammerstein_oe`); steps 1-2 (eq. 21 and the linear
        re-identification with ``f`` fixed) take ``f(ds)`` without it and only start
        them, which `skipped` says.

    Returns
    -------
    HammersteinRoute
        With fewer steps than ``degree`` (or steps that do not determine ``f``), step 1
        is skipped and ``f(ds) = ds`` starts step 2 (said in `skipped`).

    Raises
    ------
    IdentificationError
        As the individual steps.
    """
    where = "run_hammerstein_route"
    y_arr, ds_arr = _check_arrays(y, ds, where)
    degree, nb, nf, nk = _check_orders(degree, nb, nf, nk, where)
    nc_used = nf if nc is None else checked_int(nc, 0, f"{where}: nc")
    skipped: list[str] = []
    seg = None if segment_starts is None else tuple(int(v) for v in segment_starts)
    arx_fit = arx_least_squares(y_arr, ds_arr, na=nf, nb=nb, nk=nk, segment_starts=seg)
    b_first = float(arx_fit.b[nk])
    arx = _normalized_fit(
        "arx", arx_fit.a, arx_fit.b / b_first, np.array([b_first]), arx_fit.parameter_names,
        arx_fit.theta, arx_fit.std_errors, arx_fit.residuals,
        message="least squares: exact solution", method="arx-least-squares",
    )
    steps = tuple(steps)
    init: InputPolyInit | None = None
    try:
        init = initial_input_poly(
            steps, arx_fit.a, arx_fit.b, operating_point=operating_point, degree=degree,
            row_form=row_form,
        )
        poly = np.asarray(init.input_poly)
    except IdentificationError as exc:
        skipped.append(f"eq. 21 initial polynomial skipped ({exc}); f(ds) = ds used instead")
        poly = np.zeros(degree)
        poly[0] = 1.0
    arx_re = reidentify_linear_block(y_arr, ds_arr, poly, method="arx", nb=nb, nf=nf, nk=nk,
                                     segment_starts=seg)
    oe_re = reidentify_linear_block(
        y_arr, ds_arr, poly, method="oe", nb=nb, nf=nf, nk=nk, max_iterations=max_iterations,
        segment_starts=seg,
    )

    def report(step: str) -> Callable[[int, float], None] | None:
        if progress is None:
            return None
        return lambda iteration, cost: progress(step, iteration, cost)

    if voltage is not None:
        skipped.append(
            "grid voltage: eq. 21 and the ARX/OE re-identification with f fixed take f(ds) "
            "without it (they only start the joint PEM fits, which compensate it)")

    def joint_oe(initial: HammersteinFit | Mapping[str, float] | None, step: str) -> HammersteinFit:
        return fit_hammerstein_oe(
            y_arr, ds_arr, initial=initial, degree=degree, nb=nb, nf=nf, nk=nk,
            max_iterations=max_iterations, initial_state=initial_state, segment_starts=seg,
            progress=report(step), voltage=voltage,
        )

    final = joint_oe(oe_re, "joint PEM of the OE block (V)")
    if extra_start is not None:
        other = joint_oe(extra_start, "joint PEM of the OE block from the structure search (V)")
        if other.cost < final.cost:
            final = other
    if pole_starts:
        final = _multistart(
            final, y_arr, ds_arr, degree=degree, nb=nb, nf=nf, nk=nk,
            n_starts=checked_int(pole_starts, 0, f"{where}: pole_starts"),
            max_iterations=max_iterations, initial_state=initial_state, segment_starts=seg,
            progress=report("joint PEM of the OE block from fixed poles (V)"), voltage=voltage,
        )
    zeros = joint_oe(None, "joint PEM of the OE block from zeros (V)") if from_zeros else None
    noise = None
    if noise_model:
        noise = fit_hammerstein_armax(
            y_arr, ds_arr, initial=final, degree=degree, na=nf, nb=nb, nc=nc_used, nk=nk,
            max_iterations=max_iterations, initial_state=initial_state, segment_starts=seg,
            progress=report("joint PEM of the noise model (W)"), voltage=voltage,
        )
    return HammersteinRoute(
        arx=arx,
        steps=steps,
        initial_poly=init,
        arx_reidentified=arx_re,
        oe_reidentified=oe_re,
        final_oe=final,
        final_oe_from_zeros=zeros,
        noise_model=noise,
        skipped=tuple(skipped),
    )


def fit_hammerstein(
    data: Dataset,
    *,
    operating_point: OperatingPoint,
    degree: int = 2,
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    noise_model: bool = True,
    nc: int | None = None,
    steps: Sequence[InputStep] | None = None,
    max_iterations: int = MAX_ITERATIONS,
    initial_state: InitialState = "estimate",
) -> IdentificationResult:
    """Identify a Hammerstein model of a heater log by the paper's route (secs. 7.3-7.6).

    Parameters
    ----------
    data :
        The (preprocessed) identification record, absolute units. If it carries
        ``grid_voltage_factor``, the joint PEM fits compensate the voltage
        (`run_hammerstein_route`).
    operating_point :
        ``(s_nom, P_nom)`` for the deviation variables (sec. 5.1).
    degree :
        Degree ``n`` of ``f(ds) = sum_{i=1..n} p_i ds^i`` (no constant term).
    nb, nf, nk :
        Number of ``B`` coefficients (the first normalized to 1), order of ``F``
        (``A``), delay [samples]. The paper: 2, 1, 1.
    noise_model :
        True: the ARMAX-block model of eq. 30, optimized for W (the model for
        control). False: the OE-block model of eq. 27, optimized for V.
    nc :
        Order of ``C`` for the noise model; default ``nf``.
    steps :
        Input steps for eq. 21; default `sysid.steps.detect_steps` with delay ``nk``.
    max_iterations :
        Iteration limit of every search.
    initial_state :
        Initial-state policy of the joint PEM fits: ``"estimate"`` (default, as
        MATLAB's ``'estimate'``), ``"held"`` or ``"zero"``; recorded in the model's
        provenance (``extra["initial_state"]``).

    Returns
    -------
    IdentificationResult
        ``model.kind = "hammerstein"``, ``linear_block = "armax"`` (``C = [1, c1]``) or
        ``"oe"`` (``C = A``), ``B = [0, 1, b2]``, ``input_poly = [d1, d2]``, criteria V
        and W on `data`, ``noise_std_kw``, ``input_range_pct`` and provenance; the
        parameters and standard errors of the last search; ``raw`` is the
        `HammersteinRoute` with every intermediate step.

    Raises
    ------
    IdentificationError
        Bad options, a record too short or not exciting enough, or an unusable
        estimate.

    Warns
    -----
    IdentificationWarning
        A search did not converge (its best iterate is kept).

    Examples
    --------
    >>> import numpy as np
    >>> from sysid.data import Dataset
    >>> from sysid.model import OperatingPoint, _poly_eval
    >>> rng = np.random.default_rng(0)
    >>> s = 45.0 + np.repeat(rng.uniform(-10, 15, 20), 100)
    >>> ds = s - 45.0
    >>> w = 1.3 * ds - 0.007 * ds**2
    >>> p = np.zeros_like(ds)
    >>> for k in range(2, ds.size):
    ...     p[k] = 0.99 * p[k - 1] + w[k - 1] - 0.98 * w[k - 2]
    >>> data = Dataset(time_s=2.0 * np.arange(ds.size), triac_pct=s,
    ...                power_kw=45.0 + p + 0.01 * rng.standard_normal(ds.size), ts_s=2.0)
    >>> result = fit_hammerstein(data, operating_point=OperatingPoint(triac_pct=45.0,
    ...                          power_kw=45.0), noise_model=False)
    >>> np.round(result.model.input_poly, 2).tolist()
    [1.3, -0.01]
    """
    where = "fit_hammerstein"
    if not isinstance(data, Dataset):
        raise IdentificationError(f"{where}: data must be a sysid Dataset; got {type(data)}")
    if not isinstance(operating_point, OperatingPoint):
        raise IdentificationError(
            f"{where}: operating_point must be an OperatingPoint; got {operating_point!r}"
        )
    nk = checked_int(nk, 0, f"{where}: nk")
    used_steps = tuple(detect_steps(data, delay_steps=nk) if steps is None else steps)
    y = data.power_kw - operating_point.power_kw
    ds = data.triac_pct - operating_point.triac_pct
    route = run_hammerstein_route(
        y, ds, steps=used_steps, operating_point=operating_point, degree=degree, nb=nb,
        nf=nf, nk=nk, noise_model=noise_model, nc=nc, max_iterations=max_iterations,
        initial_state=initial_state, segment_starts=data.segment_starts,
        voltage=grid_voltage(data, operating_point),
    )
    fit = route.noise_model if route.noise_model is not None else route.final_oe
    model = hammerstein_model(
        fit, data, operating_point=operating_point,
        extra={"route_skipped": list(route.skipped), "n_steps_eq21": len(used_steps)},
    )
    return IdentificationResult(
        model=model,
        converged=fit.converged,
        message=fit.message,
        n_iterations=fit.n_iterations,
        criterion="one_step" if fit.criterion == "one_step" else "ballistic",
        parameter_names=fit.parameter_names,
        parameters=fit.parameters,
        std_errors=fit.std_errors,
        residuals_kw=fit.residuals,
        raw=route,
    )
