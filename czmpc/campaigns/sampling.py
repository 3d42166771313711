"""Plants drawn from an identified model's parameter uncertainty (Monte Carlo).

A Hammerstein model file names its estimated parameters (``provenance.parameter_names``,
e.g. ``b2, d1, d2, a1, k1``) and may carry their full covariance (``covariance``, in that
order). A *sampled plant* is the model with its parameter vector replaced by a draw
``theta* ~ N(theta, Sigma)``:

* ``b<j>`` is ``B[j]``, ``d<i>`` is ``input_poly[i-1]``, ``a<i>`` (``f<i>`` for OE) is
  ``A[i]`` and ``k<i>`` is ``C[i] - A[i]`` (ARMAX), so ``C = A + K`` moves with ``A``
  (OE keeps ``C = A``) - the parametrisation the fit estimated (`sysid.hammerstein`);
* ``Sigma`` is the file's ``covariance``; a file without one falls back to
  ``diag(std_errors^2)`` (the provenance's standard errors), which drops the
  correlations and, for this model's almost perfectly correlated ``a1`` and ``b2``,
  overstates the spread of the static gain. `parameter_distribution` says which one it
  used and why (`ParameterDistribution.warning`).

**Rejection rule** (`rejection_reason`): a draw is rejected and drawn again when

1. ``A`` or ``C`` has a root on or outside the unit circle (the plant or its noise
   model is unstable; `sysid.model.HammersteinModel` refuses it), or
2. the static gain ``dP_ss/ds = B(1)/A(1) * f'(ds)`` does not have, at every point of a
   101-point grid over the model's identified input range ``input_range_pct``, the sign
   the nominal model has at its operating point (a plant whose power falls when the
   heater input rises, or whose static map folds over inside the range, is not the
   process that was identified).

At most `MAX_DRAWS` draws are made per plant; the number rejected before the accepted
one is returned with it (a row column), and a plant with no accepted draw is an error.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from typing import Literal

import numpy as np

from czmpc.errors import CzmpcError
from sysid._typing import FloatArray
from sysid.errors import ModelFileError
from sysid.model import HammersteinModel

#: Draws tried per sampled plant before it is given up as an error.
MAX_DRAWS = 1000
#: Points of the static-gain sign check over the model's identified input range.
GAIN_CHECK_POINTS = 101

ParameterSource = Literal["covariance", "std_errors"]


class SamplingError(CzmpcError, ValueError):
    """A model whose parameters cannot be sampled (no names, no uncertainty, bad draws)."""


@dataclass(frozen=True, kw_only=True, eq=False)
class ParameterDistribution:
    """``N(theta, covariance)`` of a model's estimated parameters.

    Parameters
    ----------
    names :
        Parameter names (``provenance.parameter_names``).
    theta :
        Their values in the model, shape ``(p,)``.
    covariance :
        Shape ``(p, p)``: the file's covariance, or ``diag(std_errors^2)``.
    source :
        ``"covariance"`` or ``"std_errors"`` (the fallback).
    warning :
        Why the fallback was used ("" with the full covariance).
    """

    names: tuple[str, ...]
    theta: FloatArray
    covariance: FloatArray
    source: ParameterSource
    warning: str = ""


def _slot(model: HammersteinModel, name: str) -> tuple[str, int]:
    """Which coefficient a parameter name is: (``"a"|"b"|"c"|"p"``, index)."""
    letter, digits = name[:1], name[1:]
    if not digits.isdigit() or int(digits) < 1:
        raise SamplingError(f"sampled plant: cannot map parameter {name!r} to a coefficient "
                            "(expected b<j>, d<i>, a<i>, f<i> or k<i>)")
    i = int(digits)
    sizes = {"b": model.b.size, "d": model.input_poly.size + 1, "a": model.a.size,
             "f": model.a.size, "k": model.c.size}
    if letter not in sizes or i >= sizes[letter]:
        raise SamplingError(f"sampled plant: parameter {name!r} does not exist in this "
                            f"{model.linear_block} model (A {model.a.size - 1}, B {model.b.size - 1}, "
                            f"C {model.c.size - 1} coefficients, f of degree {model.input_degree})")
    if letter == "k" and model.linear_block != "armax":
        raise SamplingError(f"sampled plant: parameter {name!r} needs an ARMAX model; got "
                            f"{model.linear_block}")
    return letter, i


def model_parameters(model: HammersteinModel, names: tuple[str, ...]) -> FloatArray:
    """The values of ``names`` in ``model`` (see the module docstring for the mapping)."""
    out = np.empty(len(names))
    for n, name in enumerate(names):
        letter, i = _slot(model, name)
        if letter == "b":
            out[n] = model.b[i]
        elif letter == "d":
            out[n] = model.input_poly[i - 1]
        elif letter in ("a", "f"):
            out[n] = model.a[i]
        else:
            out[n] = model.c[i] - (model.a[i] if i < model.a.size else 0.0)
    return out


def model_with_parameters(model: HammersteinModel, names: tuple[str, ...],
                          values: FloatArray) -> HammersteinModel:
    """``model`` with the parameters ``names`` set to ``values`` (validated again).

    Raises
    ------
    SamplingError
        A name that is no coefficient of the model.
    ModelFileError
        The result breaks the model contract; `sysid.errors.UnstableModelError` for an
        ``A`` or ``C`` outside the unit circle.
    """
    a, b, c = model.a.copy(), model.b.copy(), model.c.copy()
    poly = model.input_poly.copy()
    k = c - np.concatenate([a, np.zeros(max(0, c.size - a.size))])[: c.size]
    for name, value in zip(names, np.asarray(values, dtype=float), strict=True):
        letter, i = _slot(model, name)
        if letter == "b":
            b[i] = value
        elif letter == "d":
            poly[i - 1] = value
        elif letter in ("a", "f"):
            a[i] = value
        else:
            k[i] = value
    if model.linear_block == "oe":
        c = a.copy()
    elif model.linear_block == "armax":
        c = k + np.concatenate([a, np.zeros(max(0, c.size - a.size))])[: c.size]
        c[0] = 1.0
    return model.with_updates(a=a, b=b, c=c, input_poly=poly, covariance=None)


def parameter_distribution(model: HammersteinModel) -> ParameterDistribution:
    """The distribution sampled plants are drawn from (full covariance, else std errors).

    Raises
    ------
    SamplingError
        The model names no parameters, or has neither a covariance nor finite
        standard errors for every parameter.
    """
    names = model.provenance.parameter_names
    if not names:
        raise SamplingError("sampled plant: the model file names no estimated parameters "
                            "(provenance.parameter_names); identify it with `czmpc identify`")
    theta = model_parameters(model, names)
    cov = model.covariance_matrix
    if cov is not None:
        return ParameterDistribution(names=names, theta=theta, covariance=np.array(cov),
                                     source="covariance")
    std = model.provenance.extra.get("std_errors")
    if (not isinstance(std, (list, tuple)) or len(std) != len(names)
            or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in std)):
        raise SamplingError(
            "sampled plant: the model file has no covariance and no finite standard error "
            f"for every parameter of {list(names)}; got std_errors {std!r}")
    warning = ("the model file has no parameter covariance: plants are sampled from the "
               "standard errors alone (diagonal covariance, correlations dropped), which "
               "overstates the spread of correlated parameters; re-identify the model "
               "(`czmpc identify`) to get its full covariance")
    return ParameterDistribution(names=names, theta=theta,
                                 covariance=np.diag(np.square(np.asarray(std, dtype=float))),
                                 source="std_errors", warning=warning)


def draw_parameters(rng: np.random.Generator, theta: FloatArray, covariance: FloatArray,
                    n: int = 1) -> FloatArray:
    """``n`` draws of ``N(theta, covariance)``, shape ``(n, p)``.

    Uses the symmetric square root ``V sqrt(w) V^T`` of the covariance (its eigen-
    decomposition, negative rounding eigenvalues set to 0), so a singular covariance
    (perfectly correlated parameters) is sampled too.
    """
    w, v = np.linalg.eigh(0.5 * (covariance + covariance.T))
    root = v * np.sqrt(np.clip(w, 0.0, None))
    z = rng.standard_normal((n, theta.size))
    out: FloatArray = theta + z @ root.T
    return out


def static_gain_kw_per_pct(model: HammersteinModel, triac_pct: FloatArray) -> FloatArray:
    """``dP_ss/ds = B(1)/A(1) f'(s - s_nom)`` [kW/%] at inputs ``triac_pct`` [%]."""
    ds = np.asarray(triac_pct, dtype=float) - model.operating_point.triac_pct
    out: FloatArray = model.linear_static_gain * model.input_nonlinearity_slope(ds)
    return out


def _gain_grid(model: HammersteinModel) -> FloatArray:
    lo, hi = model.input_range_pct
    return np.linspace(lo, hi, GAIN_CHECK_POINTS)


def rejection_reason(nominal: HammersteinModel, names: tuple[str, ...],
                     values: FloatArray) -> tuple[str, HammersteinModel | None]:
    """Why a draw is rejected ("" if accepted) and the drawn model (None if unbuildable)."""
    try:
        drawn = model_with_parameters(nominal, names, values)
    except ModelFileError as exc:
        return f"not a valid model ({exc})", None
    grid = _gain_grid(nominal)
    sign = np.sign(static_gain_kw_per_pct(nominal, np.array(nominal.operating_point.triac_pct)))
    gains = static_gain_kw_per_pct(drawn, grid)
    if not np.all(np.sign(gains) == sign):
        return "static gain of the wrong sign inside the identified input range", drawn
    return "", drawn


def plant_rng(base_seed: int, sample_index: int) -> np.random.Generator:
    """The generator of sampled plant ``sample_index``: `SeedSequence` keyed by it.

    The key holds the plant only (not the controller or the scenario), so every
    controller and scenario of a campaign meets the same plant number k.
    """
    key = zlib.crc32(f"sampled-plant|{sample_index}".encode())
    return np.random.default_rng(np.random.SeedSequence(base_seed, spawn_key=(key,)))


@dataclass(frozen=True, kw_only=True, eq=False)
class SampledPlant:
    """One accepted draw.

    Parameters
    ----------
    model :
        The plant's model.
    parameters :
        The accepted parameter vector.
    n_rejected :
        Draws rejected before it.
    source :
        ``"covariance"`` or ``"std_errors"``.
    """

    model: HammersteinModel
    parameters: FloatArray
    n_rejected: int
    source: ParameterSource


def sample_plant(nominal: HammersteinModel, base_seed: int, sample_index: int) -> SampledPlant:
    """Sampled plant ``sample_index`` of ``nominal`` (a pure function of the three).

    Raises
    ------
    SamplingError
        No parameters to sample, or `MAX_DRAWS` draws all rejected.
    """
    dist = parameter_distribution(nominal)
    rng = plant_rng(base_seed, sample_index)
    last = ""
    for n_rejected in range(MAX_DRAWS):
        values = draw_parameters(rng, dist.theta, dist.covariance)[0]
        last, drawn = rejection_reason(nominal, dist.names, values)
        if not last and drawn is not None:
            return SampledPlant(model=drawn, parameters=values, n_rejected=n_rejected,
                                source=dist.source)
    raise SamplingError(f"sampled plant #{sample_index}: all {MAX_DRAWS} draws rejected "
                        f"(last: {last})")


__all__ = [
    "GAIN_CHECK_POINTS",
    "MAX_DRAWS",
    "ParameterDistribution",
    "SampledPlant",
    "SamplingError",
    "draw_parameters",
    "model_parameters",
    "model_with_parameters",
    "parameter_distribution",
    "plant_rng",
    "rejection_reason",
    "sample_plant",
    "static_gain_kw_per_pct",
]
