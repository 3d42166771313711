"""Fitting routines of the Hammerstein model: joint PEM on V (OE block) and on W (ARMAX block).

Steps 3 and 4 of the paper's route (secs. 7.5-7.6), each a pure function of deviation
arrays returning a `HammersteinFit`. Notation as in `sysid.hammerstein`.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Literal

import numpy as np

from sysid._typing import FloatArray
from sysid.errors import IdentificationWarning
from sysid.greybox import GreyBoxResult, fit_greybox
from sysid.hammerstein.model import (
    HammersteinFit,
    _check_arrays,
    _check_excitation,
    hammerstein_armax_structure,
    hammerstein_oe_structure,
)


# =========================================================================== steps 3 and 4
def _fit_from_greybox(
    result: GreyBoxResult,
    *,
    linear_block: Literal["oe", "armax"],
    degree: int,
    nb: int,
    na: int,
    nc: int,
    nk: int,
    start: str,
) -> HammersteinFit:
    values = result.as_dict()
    b = np.concatenate(
        [np.zeros(nk), [1.0], [values[f"b{j}"] for j in range(nk + 1, nk + nb)]]
    )
    poly = np.array([values[f"d{i}"] for i in range(1, degree + 1)])
    letter = "f" if linear_block == "oe" else "a"
    a = np.concatenate([[1.0], [values[f"{letter}{i}"] for i in range(1, na + 1)]])
    if linear_block == "oe":
        c = a
    else:
        a_pad = np.zeros(max(na, nc) + 1)
        a_pad[: na + 1] = a
        c = np.concatenate([[1.0], [a_pad[i] + values[f"k{i}"] for i in range(1, nc + 1)]])
    return HammersteinFit(
        linear_block=linear_block,
        a=a,
        b=b,
        c=c,
        input_poly=poly,
        parameter_names=result.parameter_names,
        parameters=result.parameters,
        std_errors=result.std_errors,
        residuals=result.residuals,
        criterion=result.criterion,
        cost=result.criterion_value,
        n_iterations=result.n_iterations,
        converged=result.converged,
        message=result.message,
        method=f"hammerstein-{linear_block}-pem-{result.criterion}-from-{start}",
        greybox=result,
    )


def _start_values(
    initial: HammersteinFit | Mapping[str, float] | None, names: tuple[str, ...]
) -> tuple[dict[str, float], str]:
    """Start values by name; a previous fit gives what it shares with ``names``.

    A user's mapping is passed on whole, so an unknown name is an error, not dropped.
    """
    if initial is None:
        return {}, "zeros"
    if isinstance(initial, HammersteinFit):
        values = {k: v for k, v in initial.values().items() if k in names}
    else:
        values = dict(initial)
    return {k: float(v) for k, v in values.items()}, "initial-values"


def fit_hammerstein_oe(
    y: FloatArray,
    ds: FloatArray,
    *,
    initial: HammersteinFit | Mapping[str, float] | None = None,
    degree: int = 2,
    nb: int = 2,
    nf: int = 1,
    nk: int = 1,
    max_iterations: int = 100,
) -> HammersteinFit:
    """Estimate all parameters of the normalized Hammerstein-OE model by PEM on V (sec. 7.5).

    Parameters
    ----------
    y :
        Output deviation ``dP`` [kW], shape ``(N,)``.
    ds :
        Input deviation [%], shape ``(N,)``.
    initial :
        Start: a previous fit (for example the OE re-identification of step 2, whose
        ``F``, ``B`` and ``f`` give ``f1, b2, d1, d2``), a mapping by name, or None for
        all zeros (the paper's test: 3 iterations from good values, 17 from zeros).
    degree, nb, nf, nk :
        Degree of ``f``, number of ``B`` coefficients, order of ``F``, delay.
    max_iterations :
        Levenberg-Marquardt iteration limit.

    Returns
    -------
    HammersteinFit
        ``linear_block = "oe"``, ``C = A = F``, ``B = q^-nk (1 + b2 q^-1 ..)``,
        criterion ``"ballistic"`` with ``cost`` = V (held-past initial conditions, as
        `sysid.criteria.ballistic_mse`).

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
    where = "fit_hammerstein_oe"
    y_arr, ds_arr = _check_arrays(y, ds, where)
    structure = hammerstein_oe_structure(degree=degree, nb=nb, nf=nf, nk=nk)
    _check_excitation(ds_arr, degree, structure.n_parameters, where)
    start, label = _start_values(initial, structure.parameter_names)
    structure = hammerstein_oe_structure(
        degree=degree, nb=nb, nf=nf, nk=nk, initial_values=start
    )
    result = fit_greybox(
        structure, y_arr, ds_arr, criterion="ballistic", max_iterations=max_iterations,
        warn=False,
    )
    _warn_unconverged(result, where)
    return _fit_from_greybox(
        result, linear_block="oe", degree=degree, nb=nb, na=nf, nc=nf, nk=nk, start=label
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
    max_iterations: int = 100,
) -> HammersteinFit:
    """Estimate the Hammerstein model with an ARMAX noise model by PEM on W (sec. 7.6).

    Parameters
    ----------
    y :
        Output deviation ``dP`` [kW], shape ``(N,)``.
    ds :
        Input deviation [%], shape ``(N,)``.
    initial :
        Start: a previous fit (an OE fit gives ``a = f`` and ``k = 0``, i.e. ``C = A``;
        an ARMAX fit gives all), a mapping by name, or None for zeros.
    degree, na, nb, nc, nk :
        Degree of ``f`` and the orders of ``A``, ``B``, ``C`` and the delay.
    max_iterations :
        Levenberg-Marquardt iteration limit.

    Returns
    -------
    HammersteinFit
        ``linear_block = "armax"`` with ``c_i = a_i + k_i`` (eq. 32), criterion
        ``"one_step"``, ``cost`` = W (held-past initial conditions, zero past
        innovations, as `sysid.criteria.one_step_mse`).

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
    where = "fit_hammerstein_armax"
    y_arr, ds_arr = _check_arrays(y, ds, where)
    structure = hammerstein_armax_structure(degree=degree, na=na, nb=nb, nc=nc, nk=nk)
    _check_excitation(ds_arr, degree, structure.n_parameters, where)
    if isinstance(initial, HammersteinFit) and initial.linear_block != "armax":
        values = initial.values()
        for i in range(1, initial.a.size):
            if f"f{i}" in values:
                values[f"a{i}"] = values.pop(f"f{i}")
        names = structure.parameter_names
        start = {k: v for k, v in values.items() if k in names}
        label = "initial-values"
    else:
        start, label = _start_values(initial, structure.parameter_names)
    structure = hammerstein_armax_structure(
        degree=degree, na=na, nb=nb, nc=nc, nk=nk, initial_values=start
    )
    result = fit_greybox(
        structure, y_arr, ds_arr, criterion="one_step", max_iterations=max_iterations,
        warn=False,
    )
    _warn_unconverged(result, where)
    return _fit_from_greybox(
        result, linear_block="armax", degree=degree, nb=nb, na=na, nc=nc, nk=nk, start=label
    )


def _warn_unconverged(result: GreyBoxResult, where: str) -> None:
    if not result.converged:
        warnings.warn(
            f"{where}: the prediction-error search did not converge after "
            f"{result.n_iterations} iterations ({result.message}); the best iterate is kept",
            IdentificationWarning,
            stacklevel=3,
        )

