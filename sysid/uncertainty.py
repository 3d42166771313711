"""A model's estimated parameters, their covariance, and models drawn from it.

A model file names its estimated parameters (``provenance.parameter_names``, e.g.
``b2, d1, d2, a1, k1``) and may carry their full covariance (``covariance``, in that
order). The names map onto the model's coefficients as the fits estimated them
(`sysid.hammerstein`):

* ``b<j>`` is ``B[j]``; ``d<i>`` is ``input_poly[i-1]`` (the coefficient of ``ds^i``);
* ``a<i>`` (``f<i>`` for OE) is ``A[i]``;
* ``k<i>`` is ``C[i] - A[i]`` (the ARMAX fits' innovations-form gain), so that ``C``
  moves with ``A``; ``c<i>`` is ``C[i]`` itself; an OE model keeps ``C = A``.

`parameter_distribution` gives ``N(theta, Sigma)`` from the file's covariance, falling
back to ``diag(std_errors^2)`` with a stated warning; `draw_parameters` samples it (also
a singular covariance); `model_with_parameters` builds the model of a parameter vector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from sysid._typing import FloatArray
from sysid.errors import SysidError
from sysid.model import HammersteinModel

ParameterSource = Literal["covariance", "std_errors"]

__all__ = [
    "ParameterDistribution", "ParameterError", "ParameterSource", "draw_parameters",
    "model_parameters", "model_with_parameters", "parameter_distribution", "static_gain_kw_per_pct"
]


class ParameterError(SysidError, ValueError):
    """A parameter name that is no coefficient of the model, or no uncertainty to draw from."""


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
    """Which coefficient a parameter name is: (``"a"|"b"|"c"|"d"|"k"``, index)."""
    letter, digits = name[:1], name[1:]
    if not digits.isdigit() or int(digits) < 1:
        raise ParameterError(f"cannot map parameter {name!r} to a coefficient (expected b<j>, "
                             "d<i>, a<i>, f<i>, c<i> or k<i>)")
    i = int(digits)
    letter = "a" if letter == "f" else letter
    sizes = {"b": model.b.size, "d": model.input_poly.size + 1, "a": model.a.size,
             "c": model.c.size, "k": model.c.size}
    if letter not in sizes or i >= sizes[letter]:
        raise ParameterError(f"parameter {name!r} does not exist in this {model.linear_block} "
                             f"model (A {model.a.size - 1}, B {model.b.size - 1}, C "
                             f"{model.c.size - 1} coefficients, f of degree {model.input_degree})")
    if letter in "ck" and model.linear_block != "armax":
        raise ParameterError(f"parameter {name!r} needs an ARMAX model; got {model.linear_block}")
    return letter, i


def _padded(a: FloatArray, n: int) -> FloatArray:
    """``a`` cut or zero-padded to length ``n``."""
    out = np.zeros(max(n, a.size))
    out[: a.size] = a
    return out[:n]


def model_parameters(model: HammersteinModel, names: tuple[str, ...]) -> FloatArray:
    """The values of ``names`` in ``model`` (module docstring for the mapping).

    Raises
    ------
    ParameterError
        A name that is no coefficient of the model.
    """
    coefficients = {"b": model.b, "a": model.a, "c": model.c,
                    "k": model.c - _padded(model.a, model.c.size),
                    "d": np.concatenate([[0.0], model.input_poly])}   # d<i> is ds^i's
    out = np.empty(len(names))
    for n, name in enumerate(names):
        letter, i = _slot(model, name)
        out[n] = coefficients[letter][i]
    return out


def model_with_parameters(model: HammersteinModel, names: tuple[str, ...],
                          values: FloatArray) -> HammersteinModel:
    """``model`` with the parameters ``names`` set to ``values`` (validated again).

    Its ``covariance`` is dropped (it described the estimate, not this draw).

    Raises
    ------
    ParameterError
        A name that is no coefficient of the model.
    ModelFileError
        The result breaks the model contract; `sysid.errors.UnstableModelError` for an
        ``A`` or ``C`` outside the unit circle.
    """
    a, b, c = model.a.copy(), model.b.copy(), model.c.copy()
    poly = model.input_poly.copy()
    k = c - _padded(a, c.size)
    set_c: dict[int, float] = {}
    # where each letter's coefficient i lives (d<i> is input_poly[i-1]); c<i> is set last
    slots: dict[str, tuple[Any, int]] = {"a": (a, 0), "b": (b, 0), "d": (poly, 1), "k": (k, 0),
                                         "c": (set_c, 0)}
    for name, value in zip(names, np.asarray(values, dtype=float), strict=True):
        letter, i = _slot(model, name)
        array, shift = slots[letter]
        array[i - shift] = float(value)
    if model.linear_block == "oe":
        c = a.copy()
    elif model.linear_block == "armax":
        c = k + _padded(a, c.size)
        c[0] = 1.0
        for i, value in set_c.items():
            c[i] = value
    return model.with_updates(a=a, b=b, c=c, input_poly=poly, covariance=None)


def parameter_distribution(model: HammersteinModel) -> ParameterDistribution:
    """The distribution of the model's parameters (full covariance, else std errors).

    Raises
    ------
    ParameterError
        The model names no parameters, or has neither a covariance nor finite standard
        errors for every parameter.
    """
    names = model.provenance.parameter_names
    if not names:
        raise ParameterError("the model file names no estimated parameters "
                             "(provenance.parameter_names); identify it with `czmpc identify`")
    theta = model_parameters(model, names)
    cov = model.covariance_matrix
    if cov is not None:
        return ParameterDistribution(names=names, theta=theta, covariance=np.array(cov),
                                     source="covariance")
    std = model.provenance.extra.get("std_errors")
    if (not isinstance(std, (list, tuple)) or len(std) != len(names)
            or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in std)):
        raise ParameterError(
            "the model file has no covariance and no finite standard error for every "
            f"parameter of {list(names)}; got std_errors {std!r}")
    warning = ("the model file has no parameter covariance: the standard errors alone are "
               "used (diagonal covariance, correlations dropped), which overstates the "
               "spread of correlated parameters; re-identify the model (`czmpc identify`) "
               "to get its full covariance")
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
    """``dP_ss/ds = B(1)/A(1) f'(s - s_nom)`` [output unit per input unit] at ``triac_pct``."""
    ds = np.asarray(triac_pct, dtype=float) - model.operating_point.triac_pct
    out: FloatArray = model.linear_static_gain * model.input_nonlinearity_slope(ds)
    return out
