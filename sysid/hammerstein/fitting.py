"""Fitting routines of the Hammerstein model: joint PEM on V (OE block) and on W (ARMAX block).

Steps 3 and 4 of the paper's route (secs. 7.5-7.6), each a pure function of deviation
arrays returning a `HammersteinFit`. Residuals and exact Jacobians come from the
sensitivity filters of `sysid.hammerstein.filtering` (scipy ``lfilter``), the search is
`sysid.optimize.levenberg_marquardt` with the unstable roots of ``F`` (``A``, ``C``)
mirrored into the unit circle, and every fit returns its full parameter covariance.
A record may hold several segments (experiments), each with its own initial state.
Notation as in `sysid.hammerstein`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Literal

import numpy as np

from sysid._typing import FloatArray
from sysid.errors import IdentificationError, IdentificationWarning
from sysid.greybox import GreyBoxStructure
from sysid.hammerstein.filtering import (
    Drive,
    HammersteinOrders,
    InitialState,
    Segment,
    check_initial_state,
    estimate_transients,
    residual_function,
)
from sysid.hammerstein.model import (
    HammersteinFit,
    _check_arrays,
    _check_excitation,
    hammerstein_armax_structure,
    hammerstein_oe_structure,
)
from sysid.linear import segment_bounds
from sysid.optimize import (
    DEFAULT_FTOL,
    DEFAULT_XTOL,
    MAX_ITERATIONS,
    LMResult,
    levenberg_marquardt,
    parameter_std_errors,
    triangular_factor,
)
from sysid.voltage import (
    MAX_W0_ITERATIONS,
    W0_RTOL,
    GridVoltage,
    VoltageCompensation,
    nominal_drive_kw,
)

#: ``progress(iteration, cost)`` after every Levenberg-Marquardt iteration.
ProgressCallback = Callable[[int, float], None]


# =========================================================================== steps 3 and 4
def split_segments(
    y: FloatArray, ds: FloatArray, segment_starts: Sequence[int] | None, where: str
) -> list[Segment]:
    """Cut deviation arrays into segments at `segment_starts` (`sysid.linear.segment_bounds`)."""
    starts = None if segment_starts is None else list(segment_starts)
    return [(y[lo:hi], ds[lo:hi]) for lo, hi in segment_bounds(y.size, starts, where)]


def covariance_from_jacobian(jacobian: FloatArray, residuals: FloatArray, *,
                             factor: FloatArray | None = None) -> FloatArray:
    """``sigma^2 (J'J)^-1`` with ``sigma^2 = sum r^2 / (N - p)``, by the SVD of ``J``'s ``R``.

    Directions the data do not determine (singular values below ``N eps s_max``) are
    left out (pseudo-inverse); their standard errors come out as `inf` from
    `sysid.optimize.parameter_std_errors` instead. ``factor``: that ``R`` if the caller
    has it (`sysid.optimize.triangular_factor`), or None to factor here.
    """
    n, p = jacobian.shape
    sigma2 = float(residuals @ residuals) / max(n - p, 1)
    r_factor = triangular_factor(jacobian) if factor is None else factor
    _, sv, vt = np.linalg.svd(r_factor)  # J = QR: same sv and V
    keep = sv > max(n, p) * np.finfo(float).eps * (sv[0] if sv.size else 0.0)
    inv = np.where(keep, 1.0 / np.where(keep, sv, 1.0) ** 2, 0.0)
    out: FloatArray = sigma2 * (vt.T * inv) @ vt
    return out


def _pem(
    orders: HammersteinOrders,
    structure: GreyBoxStructure,
    segments: list[Segment],
    initial_state: InitialState,
    max_iterations: int,
    progress: ProgressCallback | None,
    *,
    tolerance: float | None = None,
    drives: Sequence[Drive] | None = None,
) -> tuple[LMResult, FloatArray, FloatArray, FloatArray]:
    """The search; returns the LM result, model covariance, std errors and transients.

    ``tolerance``: LM's ``ftol`` and ``xtol`` both (None: `levenberg_marquardt`'s tight
    defaults, for a final fit; looser for a fit that only ranks structures).
    ``drives``: each segment's grid-voltage drive, or None (no compensation).
    """
    p = orders.n_model
    theta0 = np.array(structure.initial_values, dtype=float)
    project = structure.project
    if initial_state == "estimate":
        theta0 = np.concatenate([theta0, estimate_transients(orders, theta0, segments,
                                                             drives=drives)])

    def project_full(theta: FloatArray) -> FloatArray:
        out = np.array(theta, dtype=float, copy=True)
        if project is not None:
            out[:p] = project(out[:p])
        return out

    lm = levenberg_marquardt(
        residual_function(orders, segments, initial_state, drives), theta0, project=project_full,
        max_iterations=max_iterations, callback=progress,
        ftol=DEFAULT_FTOL if tolerance is None else tolerance,
        xtol=DEFAULT_XTOL if tolerance is None else tolerance,
    )
    n_theta = lm.theta.size
    factor = lm.factor[:n_theta, :n_theta]  # R of the Jacobian: the factor of [J, r] without r
    cov = covariance_from_jacobian(lm.jacobian, lm.residuals, factor=factor)[:p, :p]
    std = parameter_std_errors(lm.jacobian, lm.residuals, factor=factor)[:p]
    return lm, cov, std, lm.theta[p:]


def _start_values(
    initial: HammersteinFit | Mapping[str, float] | None, names: tuple[str, ...]
) -> tuple[dict[str, float], str]:
    """Start values by name, and their label; a previous fit gives what it shares with ``names``.

    An OE fit's ``f_i`` start an ARMAX fit's ``a_i`` (so ``C = A``). A user's mapping is
    passed on whole, so an unknown name is an error, not dropped.
    """
    if initial is None:
        return {}, "zeros"
    if isinstance(initial, HammersteinFit):
        values = {(f"a{k[1:]}" if k[0] == "f" and k not in names else k): v
                  for k, v in initial.values().items()}
        return {k: v for k, v in values.items() if k in names}, "initial-values"
    return {k: float(v) for k, v in initial.items()}, "initial-values"


def fit_hammerstein_oe(
    y: FloatArray,
    ds: FloatArray,
    *,
    initial: HammersteinFit | Mapping[str, float] | None = None,
    degree: int = 2,
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    max_iterations: int = MAX_ITERATIONS,
    initial_state: InitialState = "estimate",
    segment_starts: Sequence[int] | None = None,
    progress: ProgressCallback | None = None,
    voltage: GridVoltage | None = None,
) -> HammersteinFit:
    """Estimate all parameters of the normalized Hammerstein-OE model by PEM on V (sec. 7.5).

    Parameters
    ----------
    y, ds :
        Output deviation ``dP`` [kW] and input deviation [%], shape ``(N,)``.
    initial :
        Start: a previous fit (for example the OE re-identification of step 2, whose
        ``F``, ``B`` and ``f`` give ``f1, b2, d1, d2``), a mapping by name, or None for
        all zeros (the paper's test: 3 iterations from good values, 17 from zeros).
    degree, nb, nf, nk :
        Degree of ``f``, number of ``B`` coefficients, order of ``F``, delay.
    max_iterations :
        Levenberg-Marquardt iteration limit.
    initial_state :
        ``"estimate"`` (default: each segment's initial state is fitted with the model,
        as MATLAB's ``'estimate'``), ``"held"`` (past held at the first sample, the rule
        of `sysid.simulate`) or ``"zero"`` (the record starts at rest).
    segment_starts :
        First sample of each segment (experiment) of the record, starting with 0;
        default one segment. Each segment has its own initial state.
    progress :
        ``progress(iteration, cost)`` after every iteration (sign of life on long logs).
    voltage :
        The record's grid voltage (`sysid.voltage.GridVoltage`), or None (default: no
        compensation, the fit as without the column). Given, the fit is run as without
        it, then refitted with the input ``w_eff = v^2 f(ds) + (v^2 - 1) W0``,
        ``W0 = P_nom / G1`` from the previous fit, until ``W0`` moves by less than
        `sysid.voltage.W0_RTOL` relative (at most `sysid.voltage.MAX_W0_ITERATIONS`
        refits); the fit's ``grid_voltage`` says how.

    Returns
    -------
    HammersteinFit
        ``linear_block = "oe"``, ``C = A = F``, ``B = q^-nk (1 + b2 q^-1 ..)``,
        criterion ``"ballistic"`` with ``cost`` = V under `initial_state` (with
        ``"held"`` equal to `sysid.criteria.ballistic_mse`), and the full `covariance`.

    Raises
    ------
    IdentificationError
        Bad options or arrays; fewer than ``degree + 1`` distinct input levels; fewer
        than 10 samples per parameter.

    Warns
    -----
    IdentificationWarning
        The search did not converge (the best iterate is returned, ``converged=False``).
    """
    return _fit(
        "oe", y, ds, initial=initial, degree=degree, na=nf, nb=nb, nc=0, nk=nk,
        max_iterations=max_iterations, initial_state=initial_state,
        segment_starts=segment_starts, progress=progress, where="fit_hammerstein_oe",
        voltage=voltage,
    )


def fit_hammerstein_armax(
    y: FloatArray,
    ds: FloatArray,
    *,
    initial: HammersteinFit | Mapping[str, float] | None = None,
    degree: int = 2,
    na: int = 1,
    nb: int = 2,
    nc: int = 1,
    nk: int = 1,
    max_iterations: int = MAX_ITERATIONS,
    initial_state: InitialState = "estimate",
    segment_starts: Sequence[int] | None = None,
    progress: ProgressCallback | None = None,
    voltage: GridVoltage | None = None,
) -> HammersteinFit:
    """Estimate the Hammerstein model with an ARMAX noise model by PEM on W (sec. 7.6).

    Parameters
    ----------
    y, ds, max_iterations, initial_state, segment_starts, progress, voltage :
        As in `fit_hammerstein_oe`.
    initial :
        Start: a previous fit (an OE fit gives ``a = f`` and ``k = 0``, i.e. ``C = A``;
        an ARMAX fit gives all), a mapping by name, or None for zeros.
    degree, na, nb, nc, nk :
        Degree of ``f`` and the orders of ``A``, ``B``, ``C`` and the delay.

    Returns
    -------
    HammersteinFit
        ``linear_block = "armax"`` with ``c_i = a_i + k_i`` (eq. 32), criterion
        ``"one_step"``, ``cost`` = W under `initial_state` (with ``"held"``: zero past
        innovations, equal to `sysid.criteria.one_step_mse`), and the full `covariance`.

    Raises
    ------
    IdentificationError
        As `fit_hammerstein_oe`.

    Warns
    -----
    IdentificationWarning
        As `fit_hammerstein_oe`.
    """
    return _fit(
        "armax", y, ds, initial=initial, degree=degree, na=na, nb=nb, nc=nc, nk=nk,
        max_iterations=max_iterations, initial_state=initial_state,
        segment_starts=segment_starts, progress=progress, where="fit_hammerstein_armax",
        voltage=voltage,
    )


def _fit(
    block: Literal["oe", "armax"],
    y: FloatArray,
    ds: FloatArray,
    *,
    initial: HammersteinFit | Mapping[str, float] | None,
    degree: int,
    na: int,
    nb: int,
    nc: int,
    nk: int,
    max_iterations: int,
    initial_state: InitialState,
    segment_starts: Sequence[int] | None,
    progress: ProgressCallback | None,
    where: str,
    voltage: GridVoltage | None = None,
) -> HammersteinFit:
    """The one PEM loop behind `fit_hammerstein_oe` (``na`` is ``nf``) and `fit_hammerstein_armax`.

    Checks the arrays and the excitation, builds the grey-box structure from the start
    values, runs the Levenberg-Marquardt search on the segments and packs the fit. With
    a `voltage`, this is also the one place that compensates it (`_compensated`).
    """
    y_arr, ds_arr = _check_arrays(y, ds, where)

    def structure_for(start: Mapping[str, float] | None) -> GreyBoxStructure:
        if block == "oe":
            return hammerstein_oe_structure(
                degree=degree, nb=nb, nf=na, nk=nk, initial_values=start)
        return hammerstein_armax_structure(
            degree=degree, na=na, nb=nb, nc=nc, nk=nk, initial_values=start)

    structure = structure_for(None)
    _check_excitation(ds_arr, degree, structure.n_parameters, where)
    start, label = _start_values(initial, structure.parameter_names)
    structure = structure_for(start)
    policy = check_initial_state(initial_state, where)
    orders = HammersteinOrders(block=block, degree=degree, nb=nb, na=na, nc=nc, nk=nk)
    segments = split_segments(y_arr, ds_arr, segment_starts, where)
    fit = _searched(orders, structure, segments, policy, max_iterations, progress, label, where)
    if voltage is None:
        return fit
    return _compensated(fit, voltage, orders, structure_for, segments, policy, max_iterations,
                        progress, where, segment_starts)


def _compensated(
    fit: HammersteinFit,
    voltage: GridVoltage,
    orders: HammersteinOrders,
    structure_for: Callable[[Mapping[str, float] | None], GreyBoxStructure],
    segments: list[Segment],
    policy: InitialState,
    max_iterations: int,
    progress: ProgressCallback | None,
    where: str,
    segment_starts: Sequence[int] | None,
) -> HammersteinFit:
    """Refit `fit` with the grid voltage compensated until ``W0 = P_nom / G1`` settles.

    Each refit starts from the previous one and regresses on ``v^2 ds^i`` with the known
    input ``(v^2 - 1) W0``, ``W0`` from the previous fit's ``G1``; stops when ``W0``
    moves by less than `W0_RTOL` relative, or after `MAX_W0_ITERATIONS` refits.
    """
    n = sum(y.size for y, _ in segments)
    if voltage.factor.size != n:
        raise IdentificationError(
            f"{where}: the grid voltage factor has {voltage.factor.size} samples; the record "
            f"has {n}")
    bounds = segment_bounds(n, None if segment_starts is None else list(segment_starts), where)
    method = f"{fit.method}-voltage-compensated"
    w0 = nominal_drive_kw(voltage.power_nom_kw, fit.a, fit.b)
    history = [w0]
    settled = False
    for _ in range(MAX_W0_ITERATIONS):
        used = w0
        start, _label = _start_values(fit, structure_for(None).parameter_names)
        fit = _searched(orders, structure_for(start), segments, policy, max_iterations, progress,
                        "voltage-refit", where, drives=voltage.drives(bounds, used))
        w0 = nominal_drive_kw(voltage.power_nom_kw, fit.a, fit.b)
        history.append(w0)
        if abs(w0 - used) < W0_RTOL * abs(used):
            settled = True
            break
    return replace(fit, method=method,
                   grid_voltage=VoltageCompensation(
                       nominal_drive_kw=used, history_kw=tuple(history),
                       n_refits=len(history) - 1, settled=settled))


def _searched(
    orders: HammersteinOrders,
    structure: GreyBoxStructure,
    segments: list[Segment],
    policy: InitialState,
    max_iterations: int,
    progress: ProgressCallback | None,
    label: str,
    where: str,
    *,
    drives: Sequence[Drive] | None = None,
) -> HammersteinFit:
    """One Levenberg-Marquardt search from `structure`'s start values, packed as a fit."""
    block = orders.block
    lm, cov, std, transients = _pem(orders, structure, segments, policy, max_iterations, progress,
                                    drives=drives)
    if not lm.converged:
        warnings.warn(
            f"{where}: the prediction-error search did not converge after "
            f"{lm.n_iterations} iterations ({lm.message}); the best iterate is kept",
            IdentificationWarning,
            stacklevel=4,
        )
    p = orders.n_model
    a, beta, c, poly = orders.polynomials(lm.theta[:p])
    criterion: Literal["ballistic", "one_step"] = "ballistic" if block == "oe" else "one_step"
    return HammersteinFit(
        linear_block=block,
        a=a,
        b=beta,
        c=c,
        input_poly=poly,
        parameter_names=orders.parameter_names(),
        parameters=lm.theta[:p],
        std_errors=std,
        residuals=lm.residuals,
        criterion=criterion,
        cost=lm.cost,
        n_iterations=lm.n_iterations,
        converged=lm.converged,
        message=lm.message,
        method=f"hammerstein-{block}-pem-{criterion}-from-{label}",
        covariance=cov,
        initial_state=policy,
        initial_transients=transients,
    )
