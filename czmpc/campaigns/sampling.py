"""Plants drawn from an identified model's parameter uncertainty (Monte Carlo).

A Hammerstein model file names its estimated parameters (``provenance.parameter_names``,
e.g. ``b2, d1, d2, a1, k1``) and may carry their full covariance (``covariance``, in that
order). A *sampled plant* is the model with its parameter vector replaced by a draw
``theta* ~ N(theta, Sigma)``:

* the names map onto the coefficients as the fits estimated them (`sysid.uncertainty`,
  which this module uses for the mapping, the distribution and the draws): ``b<j>`` is
  ``B[j]``, ``d<i>`` is ``input_poly[i-1]``, ``a<i>`` (``f<i>`` for OE) is ``A[i]`` and
  ``k<i>`` is ``C[i] - A[i]`` (ARMAX), so ``C = A + K`` moves with ``A``;
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

import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from czmpc.errors import CzmpcError
from sysid import uncertainty as _uncertainty
from sysid._typing import FloatArray
from sysid.errors import ModelFileError
from sysid.model import HammersteinModel
from sysid.uncertainty import (
    ParameterDistribution,
    ParameterError,
    ParameterSource,
    draw_parameters,
    static_gain_kw_per_pct,
)

#: Draws tried per sampled plant before it is given up as an error.
MAX_DRAWS = 1000
#: Points of the static-gain sign check over the model's identified input range.
GAIN_CHECK_POINTS = 101


class SamplingError(CzmpcError, ValueError):
    """A model whose parameters cannot be sampled (no names, no uncertainty, bad draws)."""


@contextmanager
def _as_sampling_error() -> Iterator[None]:
    """Re-raise `sysid.uncertainty`'s refusals as `SamplingError` (this module's error)."""
    try:
        yield
    except ParameterError as exc:
        raise SamplingError(f"sampled plant: {exc}") from exc


def parameter_distribution(model: HammersteinModel) -> ParameterDistribution:
    """The distribution sampled plants are drawn from (full covariance, else std errors).

    Raises
    ------
    SamplingError
        The model names no parameters, or has neither a covariance nor finite
        standard errors for every parameter.
    """
    with _as_sampling_error():
        return _uncertainty.parameter_distribution(model)


def rejection_reason(nominal: HammersteinModel, names: tuple[str, ...],
                     values: FloatArray) -> tuple[str, HammersteinModel | None]:
    """Why a draw is rejected ("" if accepted) and the drawn model (None if unbuildable).

    Raises
    ------
    SamplingError
        A name that is no coefficient of the model.
    """
    try:
        with _as_sampling_error():
            drawn = _uncertainty.model_with_parameters(nominal, names, values)
    except ModelFileError as exc:  # the draw breaks the model contract (e.g. an unstable A)
        return f"not a valid model ({exc})", None
    sign = np.sign(static_gain_kw_per_pct(nominal, np.array(nominal.operating_point.triac_pct)))
    gains = static_gain_kw_per_pct(drawn, np.linspace(*nominal.input_range_pct, GAIN_CHECK_POINTS))
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


__all__ = ["GAIN_CHECK_POINTS", "MAX_DRAWS", "ParameterDistribution", "SampledPlant", "SamplingError",
           "draw_parameters", "parameter_distribution", "plant_rng", "rejection_reason", "sample_plant",
           "static_gain_kw_per_pct"]
