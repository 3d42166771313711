"""The Hammerstein model of the paper's route: its value type, grey-box structures and criteria.

`HammersteinFit` is one estimate on deviation arrays; `hammerstein_oe_structure` and
`hammerstein_armax_structure` are its simulators (eqs. 26, 29-32) as `sysid.greybox`
structures; `hammerstein_criteria` scores a fit (V, W) and `hammerstein_model` turns it
into a `HammersteinModel`. Notation as in `sysid.hammerstein`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

import casadi as ca
import numpy as np

from sysid._arrays import readonly_array as _readonly
from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.criteria import model_criteria
from sysid.data import Dataset
from sysid.errors import IdentificationError, UnstableModelError
from sysid.greybox import GreyBoxStructure
from sysid.hammerstein.filtering import HammersteinOrders, _powers, mean_square_criterion
from sysid.model import Criteria, HammersteinModel, OperatingPoint, Provenance, _poly_eval
from sysid.polynomials import reflect_unstable_roots
from sysid.voltage import PROVENANCE_KEY as VOLTAGE_KEY
from sysid.voltage import VoltageCompensation, not_compensated_record

HammersteinBlock = Literal["arx", "oe", "armax"]
RowForm = Literal["eq21", "jump"]


# =========================================================================== values

@dataclass(frozen=True, kw_only=True, eq=False)
class HammersteinFit:
    """A Hammerstein model estimated on deviation arrays (one step of the route).

    Parameters
    ----------
    linear_block :
        ``"arx"``, ``"oe"`` or ``"armax"``.
    a, b, c :
        ``A(q)`` (``F`` for OE), ``B(q)`` normalized (first non-zero is 1, leading
        zeros are the delay), ``C(q)`` (``[1]`` for ARX, ``A`` for OE); ascending powers
        of q^-1.
    input_poly :
        ``[p_1, ..., p_n]``: ``f(ds) = sum p_i ds^i`` [kW-equivalent per %^i].
    parameter_names :
        Names of the estimated parameters (empty if nothing was estimated).
    parameters, std_errors :
        Their values and standard errors (``inf`` where the data do not determine one).
    residuals :
        Residuals of the minimized criterion, shape ``(n_samples,)`` or shorter for
        ARX equation errors [kW].
    criterion :
        ``"ballistic"`` (V, eq. 9), ``"one_step"`` (W, eq. 10) or ``"least_squares"``.
    cost :
        Mean square of `residuals` [kW^2].
    n_iterations, converged, message :
        From the optimizer (0, True, "least squares" for closed-form steps).
    method :
        Short label of the step that produced it (for provenance).
    covariance :
        Full covariance of `parameters` (`sysid.hammerstein.fitting.covariance_from_jacobian`,
        estimated initial states marginalized out), shape ``(p, p)``; empty ``(0, 0)`` when
        not computed.
    initial_state :
        How each segment's initial state was treated: ``"estimate"`` (fitted),
        ``"held"`` (past held at the first sample), ``"zero"``, or ``"none"`` (ARX
        equation errors, no state).
    initial_transients :
        The estimated initial transients, ``n_state`` per segment (empty otherwise).
    grid_voltage :
        How the fit compensated the grid voltage (`sysid.voltage.VoltageCompensation`),
        or None: fitted on ``f(ds)`` without the voltage.
    """

    linear_block: HammersteinBlock
    a: FloatArray
    b: FloatArray
    c: FloatArray
    input_poly: FloatArray
    parameter_names: tuple[str, ...]
    parameters: FloatArray
    std_errors: FloatArray
    residuals: FloatArray = field(repr=False)
    criterion: Literal["ballistic", "one_step", "least_squares"]
    cost: float
    n_iterations: int
    converged: bool
    message: str
    method: str
    covariance: FloatArray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    initial_state: Literal["estimate", "held", "zero", "none"] = "held"
    initial_transients: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)
    grid_voltage: VoltageCompensation | None = None

    def __post_init__(self) -> None:
        for name in ("a", "b", "c", "input_poly", "parameters", "std_errors", "residuals",
                     "covariance", "initial_transients"):
            object.__setattr__(self, name, _readonly(getattr(self, name)))

    @property
    def delay_steps(self) -> int:
        """Input delay ``nk`` [samples]."""
        return int(np.flatnonzero(self.b)[0])

    def values(self) -> dict[str, float]:
        """All model coefficients by the names `sysid.hammerstein` uses (for starts)."""
        letter = "f" if self.linear_block == "oe" else "a"
        out = {f"b{j}": float(self.b[j]) for j in range(self.delay_steps + 1, self.b.size)}
        out |= {f"d{i}": float(p) for i, p in enumerate(self.input_poly, start=1)}
        out |= {f"{letter}{i}": float(self.a[i]) for i in range(1, self.a.size)}
        if self.linear_block == "armax":
            out |= {f"k{i}": float(self.c[i]) - (float(self.a[i]) if i < self.a.size else 0.0)
                    for i in range(1, self.c.size)}
        return out

    def input_nonlinearity(self, ds_pct: FloatArray | float) -> FloatArray:
        """``f(ds)`` (eq. 28) for TRIAC deviations ``ds`` [%]."""
        return _poly_eval(self.input_poly, np.asarray(ds_pct, dtype=float))


def _check_arrays(y: Any, ds: Any, where: str) -> tuple[FloatArray, FloatArray]:
    y_arr = np.asarray(y, dtype=float)
    ds_arr = np.asarray(ds, dtype=float)
    if y_arr.ndim != 1 or ds_arr.ndim != 1 or y_arr.size != ds_arr.size:
        raise IdentificationError(
            f"{where}: y and ds must be 1-D arrays of equal length; got shapes "
            f"{y_arr.shape} and {ds_arr.shape}"
        )
    if not (np.all(np.isfinite(y_arr)) and np.all(np.isfinite(ds_arr))):
        raise IdentificationError(f"{where}: y and ds must be finite (repair missing samples)")
    return y_arr, ds_arr


def _check_excitation(ds: FloatArray, degree: int, n_parameters: int, where: str) -> None:
    """Refuse an input that cannot determine ``f`` or data too short for the parameters.

    ``f`` has no constant term, so its ``n`` coefficients need its values at ``n`` distinct
    non-zero deviations: a quadratic needs 2 input levels besides the operating point.
    """
    levels = np.unique(ds[ds != 0.0])
    if levels.size < degree:
        raise IdentificationError(
            f"{where}: a degree-{degree} input polynomial without constant term needs the "
            f"input at >= {degree} distinct levels other than the operating point (ds != 0); "
            f"got {levels.size} (the record does not excite the nonlinearity; lower the "
            "degree or log more input levels)"
        )
    if ds.size < 10 * n_parameters:
        raise IdentificationError(
            f"{where}: {n_parameters} parameters need at least {10 * n_parameters} samples; "
            f"got {ds.size}"
        )


# =========================================================================== structures
def _observer_form(
    a: Sequence[Any], beta: Sequence[Any], kgain: Sequence[Any], n: int
) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX]:
    """Observer canonical form of ``A y = B w + C e``; ``beta[j]`` multiplies ``q^-j``.

    Returns ``(A, b_col, D, K)`` with ``x+ = A x + b_col w + K e``, ``y = x_1 + D w + e``;
    ``kgain[i-1] = c_i - a_i``.
    """
    a_full = [a[i] if i < len(a) else 0 for i in range(n + 1)]
    beta_full = [beta[j] if j < len(beta) else 0 for j in range(n + 1)]
    A = ca.SX.zeros(n, n)
    b_col = ca.SX.zeros(n, 1)
    K = ca.SX.zeros(n, 1)
    for i in range(1, n + 1):
        A[i - 1, 0] = -a_full[i]
        if i < n:
            A[i - 1, i] = 1
        b_col[i - 1] = beta_full[i] - a_full[i] * beta_full[0]
        K[i - 1] = kgain[i - 1] if i - 1 < len(kgain) else 0
    return A, b_col, ca.SX(beta_full[0]), K


def _check_orders(degree: int, nb: int, nf: int, nk: int, where: str) -> tuple[int, int, int, int]:
    return (
        checked_int(degree, 1, f"{where}: degree"),
        checked_int(nb, 1, f"{where}: nb"),
        checked_int(nf, 0, f"{where}: nf"),
        checked_int(nk, 0, f"{where}: nk"),
    )


def hammerstein_oe_structure(
    *,
    degree: int = 2,
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    initial_values: Mapping[str, float] | None = None,
) -> GreyBoxStructure:
    """The grey-box structure of eq. 26, generalized: Hammerstein with an OE block.

    ``y_k = B(q)/F(q) f(ds_k) + eps_k`` with ``B = q^-nk (1 + b_{nk+1} q^-1 + ..)``
    (normalized, eq. 25), ``f(ds) = sum_{i=1..n} d_i ds^i`` (no constant term: the
    thing MATLAB's ``nlhw`` could not express, sec. 7.5). The state-space form is the
    observer canonical form of ``B/F`` with input vector ``[ds, ds^2, .., ds^n]`` and
    ``B_ss = b_col [d_1 .. d_n]``; it has the same input-output map as eq. 26.

    Parameters
    ----------
    degree :
        ``n``, degree of ``f``.
    nb, nf, nk :
        Number of ``B`` coefficients (including the normalized 1), order of ``F``,
        delay [samples].
    initial_values :
        Starting values by name (``b2``, ``d1``, ``d2``, ``f1`` for the paper's
        orders); missing names start at 0. An unstable ``F`` is mirrored into the
        unit circle.

    Returns
    -------
    GreyBoxStructure
        Parameters ``b_{nk+1}..b_{nk+nb-1}, d1..dn, f1..f_nf``, all free; ``F`` kept
        stable by mirroring roots (`sysid.polynomials.reflect_unstable_roots`).

    Raises
    ------
    IdentificationError
        Bad orders or unknown names in `initial_values`.
    """
    where = "hammerstein_oe_structure"
    degree, nb, nf, nk = _check_orders(degree, nb, nf, nk, where)
    orders = HammersteinOrders(block="oe", degree=degree, nb=nb, na=nf, nc=0, nk=nk)
    i_f = slice(nb - 1 + degree, orders.n_model)

    def project(theta: FloatArray) -> FloatArray:
        out = np.array(theta, dtype=float, copy=True)
        if nf:
            out[i_f] = reflect_unstable_roots(np.concatenate([[1.0], out[i_f]]))[1:]
        return out

    return _structure(
        orders, initial_values, None, project, f"hammerstein-oe(nb={nb},nf={nf},"
        f"nk={nk},degree={degree})"
    )


def hammerstein_armax_structure(
    *,
    degree: int = 2,
    na: int = 1,
    nb: int = 2,
    nc: int = 1,
    nk: int = 1,
    initial_values: Mapping[str, float] | None = None,
) -> GreyBoxStructure:
    """The grey-box structure of eq. 29, generalized: Hammerstein with an ARMAX block.

    ``A(q) y_k = B(q) f(ds_k) + C(q) e_k`` (eq. 30) in innovations form
    ``x+ = A x + B_ss u + K e``, ``y = x_1 + e`` (observer canonical form), with
    ``K_i = c_i - a_i``: the parameters ``k_1..k_nc`` are the paper's Kalman gain and
    ``c_i = a_i + k_i`` (eq. 32).

    Parameters
    ----------
    degree :
        ``n``, degree of ``f``.
    na, nb, nc, nk :
        Orders of ``A``, ``B`` (including the normalized 1), ``C`` and the delay.
    initial_values :
        Starting values by name (``b2``, ``d1``, ``d2``, ``a1``, ``k1``); missing
        names start at 0. Unstable ``A`` or ``C`` are mirrored into the unit circle.

    Returns
    -------
    GreyBoxStructure
        Parameters ``b.., d1..dn, a1..a_na, k1..k_nc``; ``A`` and ``C`` kept stable by
        mirroring roots.

    Raises
    ------
    IdentificationError
        Bad orders or unknown names in `initial_values`.
    """
    where = "hammerstein_armax_structure"
    degree, nb, _, nk = _check_orders(degree, nb, 0, nk, where)
    na = checked_int(na, 0, f"{where}: na")
    nc = checked_int(nc, 0, f"{where}: nc")
    orders = HammersteinOrders(block="armax", degree=degree, nb=nb, na=na, nc=nc, nk=nk)

    def kgain(p: Mapping[str, Any], n: int) -> list[Any]:
        # K_i = c_i - a_i; c_i = a_i + k_i for i <= nc, c_i = 0 beyond
        return [
            p[f"k{i}"] if i <= nc else (-p[f"a{i}"] if i <= na else 0)
            for i in range(1, n + 1)
        ]

    i_a = slice(nb - 1 + degree, nb - 1 + degree + na)
    i_k = slice(nb - 1 + degree + na, orders.n_model)

    def project(theta: FloatArray) -> FloatArray:
        out = np.array(theta, dtype=float, copy=True)
        a_old = np.zeros(max(na, nc) + 1)
        a_old[: na + 1] = np.concatenate([[1.0], out[i_a]])
        c = a_old[: nc + 1].copy()
        c[1:] += out[i_k]
        if na:
            out[i_a] = reflect_unstable_roots(np.concatenate([[1.0], out[i_a]]))[1:]
        if nc:
            a_new = np.zeros(max(na, nc) + 1)
            a_new[: na + 1] = np.concatenate([[1.0], out[i_a]])
            out[i_k] = reflect_unstable_roots(c)[1:] - a_new[1 : nc + 1]
        return out

    return _structure(
        orders, initial_values, kgain, project,
        f"hammerstein-armax(na={na},nb={nb},nc={nc},nk={nk},degree={degree})",
    )


def _structure(
    orders: HammersteinOrders,
    initial_values: Mapping[str, float] | None,
    kgain: Callable[[Mapping[str, Any], int], list[Any]] | None,
    project: Callable[[FloatArray], FloatArray],
    label: str,
) -> GreyBoxStructure:
    """The observer canonical form of `orders` with input ``[ds, .., ds^n]`` (``K`` from `kgain`)."""
    names = orders.parameter_names()
    nk, nb1, degree, n = orders.nk, orders.nb - 1, orders.degree, max(orders.n_state, 1)
    names_b, names_d = names[:nb1], names[nb1 : nb1 + degree]
    names_a = names[nb1 + degree : nb1 + degree + orders.na]

    def matrices(p: Mapping[str, Any]) -> tuple[Any, Any, Any, Any, Any]:
        beta = [0] * nk + [1] + [p[name] for name in names_b]
        a = [1] + [p[name] for name in names_a]
        A, b_col, D, K = _observer_form(a, beta, [] if kgain is None else kgain(p, n), n)
        d_row = ca.horzcat(*[p[name] for name in names_d])
        C = ca.horzcat(ca.SX(1), ca.SX.zeros(1, n - 1))
        return A, b_col @ d_row, C, D @ d_row, None if kgain is None else K

    given = dict(initial_values or {})
    unknown = set(given) - set(names)
    if unknown:
        raise IdentificationError(
            f"{label}: unknown parameter name(s) {sorted(unknown)}; expected some of "
            f"{list(names)}"
        )
    start = np.array([float(given.get(n, 0.0)) for n in names])
    start = project(start)
    return GreyBoxStructure(
        parameter_names=names,
        initial_values=tuple(float(v) for v in start),
        matrices=matrices,
        input_map=lambda ds: _powers(np.asarray(ds, dtype=float), degree),
        project=project,
        name=label,
    )


# =========================================================================== comparing and scoring fits


def relative_parameter_difference(first: HammersteinFit, second: HammersteinFit) -> float:
    """Largest ``|p1 - p2| / max(|p1|, |p2|)`` over the shared parameters of two fits.

    Used for the paper's check that the final PEM from zeros reaches the same
    parameters as from good initial values (sec. 7.5).
    """
    v1, v2 = first.values(), second.values()
    shared = sorted(set(v1) & set(v2))
    if not shared:
        raise IdentificationError("relative_parameter_difference: the fits share no parameter")
    worst = 0.0
    for name in shared:
        scale = max(abs(v1[name]), abs(v2[name]))
        if scale > 0:
            worst = max(worst, abs(v1[name] - v2[name]) / scale)
    return worst


def hammerstein_criteria(fit: HammersteinFit, y: FloatArray, ds: FloatArray) -> Criteria:
    """V (eq. 9) and W (eq. 10) of a fit on deviation arrays, under the fit's initial-state policy.

    The fit's policy (``estimate``: re-fitted by least squares; ``held``; ``zero``; ARX
    fits: ``held``) is applied by the filters of `sysid.hammerstein.filtering`; with
    ``held`` the numbers match `sysid.criteria` on the corresponding `HammersteinModel`.
    """
    y_arr, ds_arr = _check_arrays(y, ds, "hammerstein_criteria")
    policy = fit.initial_state if fit.initial_state != "none" else "held"
    nk = fit.delay_steps
    na = fit.a.size - 1
    nb = fit.b.size - nk
    degree = fit.input_poly.size
    oe = HammersteinOrders(block="oe", degree=degree, nb=nb, na=na, nc=0, nk=nk)
    theta_oe = np.concatenate([fit.b[nk + 1 :], fit.input_poly, fit.a[1:]])
    v = mean_square_criterion(oe, theta_oe, [(y_arr, ds_arr)], policy)
    if fit.linear_block == "oe":
        return Criteria(ballistic_mse_kw2=v, one_step_mse_kw2=v)
    nc = max(fit.c.size - 1, na)
    c = np.zeros(nc + 1)
    c[: fit.c.size] = fit.c
    a_pad = np.zeros(nc + 1)
    a_pad[: na + 1] = fit.a
    armax = HammersteinOrders(block="armax", degree=degree, nb=nb, na=na, nc=nc, nk=nk)
    theta_armax = np.concatenate([theta_oe, c[1:] - a_pad[1:]])
    w = mean_square_criterion(armax, theta_armax, [(y_arr, ds_arr)], policy)
    return Criteria(ballistic_mse_kw2=v, one_step_mse_kw2=w)


# =========================================================================== models
def _covariance_field(covariance: FloatArray, n_par: int) -> tuple[tuple[float, ...], ...] | None:
    """The fit's covariance as the model-file field (symmetrized), or None if not usable."""
    cov = np.asarray(covariance, dtype=float)
    if cov.shape != (n_par, n_par) or not np.isfinite(cov).all():
        return None
    cov = 0.5 * (cov + cov.T)
    return tuple(tuple(float(v) for v in row) for row in cov)


def hammerstein_model(
    fit: HammersteinFit,
    data: Dataset,
    *,
    operating_point: OperatingPoint,
    extra: Mapping[str, Any] | None = None,
) -> HammersteinModel:
    """Turn a fit into a `HammersteinModel` with V, W, noise level and provenance.

    Parameters
    ----------
    fit :
        Any step of the route.
    data :
        The identification record (absolute units); gives ``ts_s``, the input range,
        the provenance and the criteria.
    operating_point :
        ``(s_nom, P_nom)`` the fit's deviations were taken about.
    extra :
        Extra provenance entries (JSON-able).

    Returns
    -------
    HammersteinModel
        ``kind = "hammerstein"``; ``noise_std_kw = sqrt(sum r^2 / (N - p))`` of the
        fit's residuals; criteria from `sysid.criteria`.

    Raises
    ------
    IdentificationError
        The fit's ``A`` or ``C`` is unstable (not a usable model).
    """
    n_par = len(fit.parameter_names)
    dof = max(fit.residuals.size - n_par, 1)
    noise_std = float(np.sqrt(float(fit.residuals @ fit.residuals) / dof))
    info: dict[str, Any] = {
        "parameter_names": list(fit.parameter_names),
        "parameters": [float(v) for v in fit.parameters],
        "std_errors": [float(v) if math.isfinite(v) else None for v in fit.std_errors],
        "n_iterations": fit.n_iterations,
        "converged": fit.converged,
        "initial_state": fit.initial_state,
    }
    if fit.grid_voltage is not None:
        info[VOLTAGE_KEY] = fit.grid_voltage.record()
    elif data.grid_voltage_factor is not None:
        info[VOLTAGE_KEY] = not_compensated_record(
            f"{fit.method}: this fit takes the input f(ds) at nominal voltage (only the joint "
            "PEM fits of the OE and noise-model blocks compensate the voltage)")
    info.update(extra or {})
    try:
        model = HammersteinModel(
            kind="hammerstein",
            linear_block=fit.linear_block,
            ts_s=data.ts_s,
            operating_point=operating_point,
            a=fit.a,
            b=fit.b,
            c=fit.c,
            input_poly=fit.input_poly,
            noise_std_kw=noise_std,
            input_range_pct=(float(np.min(data.triac_pct)), float(np.max(data.triac_pct))),
            covariance=_covariance_field(fit.covariance, len(fit.parameter_names)),
            provenance=Provenance(
                data_file=None if data.source is None else Path(data.source).name,
                data_sha256=data.sha256,
                preprocessing=data.preprocessing,
                method=fit.method,
                created_utc=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
                extra=info,
            ),
        )
    except UnstableModelError as exc:
        raise IdentificationError(
            f"hammerstein_model: the {fit.method} estimate is not a usable model ({exc})"
        ) from None
    return model.with_updates(criteria=model_criteria(model, data))


