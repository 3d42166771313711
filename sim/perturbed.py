"""Perturbed plants: a model with its gain, slow time constant or delay moved, for robustness runs.

`perturb_model` returns a new `HammersteinModel` to run as a `ModelPlant`, so the
controller (built from the unperturbed model) meets a plant that differs in one
controlled way:

* **gain** ``g``: ``f(ds) -> g f(ds)``: the instantaneous gain ``f'(ds)`` (paper
  Table 3) and the static gain ``B(1)/A(1) f'(ds)`` change by ``g``, the dynamics not.
* **slow time constant** ``m``: the slow pole ``p`` of ``A(q)`` (its real root in
  ``(0, 1)`` of largest modulus, ``tau = -Ts / ln p`` [s]; ``p = -a1`` in first order)
  moves to ``p' = exp(-Ts / (m tau))``; ``A'(q) = A(q) (1 - p' q^-1) / (1 - p q^-1)``
  keeps every other root. Held exactly (up to rounding):

  - the delay and ``b_1 = 1`` (``B``'s first non-zero coefficient), so the
    instantaneous response to an input step is unchanged;
  - the static gain ``B(1)/A(1)``: ``B``'s tail ``[b_2, ..., b_nb]`` is multiplied by
    ``lambda = (B(1)/A(1) * A'(1) - 1) / (b_2 + ... + b_nb)`` (for the paper's
    ``nb = 2``: ``b_2' = B(1)/A(1) * (1 + a1') - 1``);
  - ``C(q)`` and ``noise_std_kw`` of an ARX or ARMAX model; an OE model keeps
    ``C = A'`` (OE is stored with ``C = A``, docs/reference/model_file.rst).

  What moves: the speed of the sag after a step (paper Fig. 9).
* **extra delay** ``n``: ``B -> q^-n B(q)``; gains and dynamics are unchanged.

The three perturbations commute; the result records them in
``provenance.extra["perturbation"]``.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from sim.errors import PlantError
from sysid._typing import FloatArray
from sysid.model import HammersteinModel
from sysid.polynomials import roots_z

#: A root counts as real if its imaginary part is below this (relative to its modulus).
REAL_ROOT_RTOL = 1e-9
#: ``|b_2 + ... + b_nb|`` below this cannot carry the static gain (see `perturb_model`).
MIN_TAIL_SUM = 1e-12


def _check_factor(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) or not (
        math.isfinite(value) and value > 0
    ):
        raise PlantError(f"perturb_model.{name}: expected a finite number > 0; got {value!r}")
    return float(value)


def slow_pole(a: FloatArray, *, ts_s: float) -> tuple[float, float]:
    """The slow pole of ``A(q)`` and its time constant.

    Parameters
    ----------
    a :
        ``A(q)`` in ascending powers of q^-1, monic, degree >= 1.
    ts_s :
        Sampling time [s].

    Returns
    -------
    pole, time_constant_s
        ``p`` in ``(0, 1)`` and ``tau = -ts_s / ln p`` [s].

    Raises
    ------
    PlantError
        ``A`` has no root, or its root of largest modulus is not real in ``(0, 1)``.
    """
    roots = roots_z(np.asarray(a, dtype=float))
    if roots.size == 0:
        raise PlantError("slow_pole: expected A(q) of degree >= 1; got a constant A")
    top = roots[int(np.argmax(np.abs(roots)))]
    if abs(top.imag) > REAL_ROOT_RTOL * abs(top) or not 0.0 < top.real < 1.0:
        raise PlantError("slow_pole: expected A(q)'s root of largest modulus to be real in (0, 1) (a slow "
                         f"exponential mode); got {complex(top):.6g}")
    pole = float(top.real)
    return pole, -ts_s / math.log(pole)


def scale_slow_time_constant(
    a: FloatArray, b: FloatArray, *, ts_s: float, factor: float
) -> tuple[FloatArray, FloatArray]:
    """Move ``A``'s slow pole to ``factor`` times its time constant; hold ``b_1`` and ``B(1)/A(1)``.

    Parameters
    ----------
    a, b :
        ``A(q)`` (monic) and ``B(q)`` (first non-zero coefficient 1), ascending powers
        of q^-1.
    ts_s :
        Sampling time [s].
    factor :
        ``tau' / tau`` [-], > 0.

    Returns
    -------
    a_new, b_new
        ``A'`` and ``B'`` as described in the module docstring (same lengths).

    Raises
    ------
    PlantError
        No real slow pole in ``(0, 1)`` (see `slow_pole`), or ``B`` has no tail that can
        carry the static gain (``b_2 + ... + b_nb = 0``) while ``factor != 1``.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if factor == 1.0:
        return a.copy(), b.copy()
    pole, tau_s = slow_pole(a, ts_s=ts_s)
    new_pole = math.exp(-ts_s / (factor * tau_s))
    # As z^n + a1 z^(n-1) + ...: deflate by (z - p), multiply by (z - p').
    quotient, _ = np.polydiv(a, np.array([1.0, -pole]))
    a_new = np.polymul(quotient, np.array([1.0, -new_pole]))
    a_new[0] = 1.0
    first = int(np.flatnonzero(b)[0])
    tail = b[first + 1:]
    tail_sum = float(np.sum(tail))
    if abs(tail_sum) < MIN_TAIL_SUM:
        raise PlantError("scale_slow_time_constant: expected B(q) with coefficients after b_1 whose sum is "
                         "non-zero (they carry the static gain while b_1 = 1 is held); got "
                         f"B = {b.tolist()}")
    static_gain = float(np.sum(b) / np.sum(a))
    scale = (static_gain * float(np.sum(a_new)) - 1.0) / tail_sum
    b_new = b.copy()
    b_new[first + 1:] = scale * tail
    return np.asarray(a_new, dtype=float), b_new


def perturb_model(
    model: HammersteinModel,
    *,
    gain_factor: float = 1.0,
    time_constant_factor: float = 1.0,
    extra_delay_steps: int = 0,
) -> HammersteinModel:
    """Return ``model`` with its gain, slow time constant and delay perturbed (module notes).

    At the defaults the result equals ``model`` coefficient for coefficient.

    Parameters
    ----------
    model :
        The model to perturb.
    gain_factor :
        ``g`` > 0: multiplies the input polynomial ``f`` (so every gain) [-].
    time_constant_factor :
        ``m`` > 0: multiplies the slow time constant ``tau = -Ts / ln p`` [-].
    extra_delay_steps :
        ``n >= 0``: samples of delay added to ``B``.

    Returns
    -------
    HammersteinModel
        The perturbed model (validated again; ``provenance.extra["perturbation"]``
        records the three arguments).

    Raises
    ------
    PlantError
        A factor that is not a finite number > 0, a negative or non-integer delay, or a
        time-constant change the model's structure cannot carry (`scale_slow_time_constant`).

    Examples
    --------
    >>> from sysid.model import HammersteinModel, OperatingPoint
    >>> m = HammersteinModel(kind="hammerstein", linear_block="oe", ts_s=2.0,
    ...     operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
    ...     a=[1.0, -0.99], b=[0.0, 1.0, -0.991], c=[1.0, -0.99],
    ...     input_poly=[1.35, -0.0065], noise_std_kw=0.0134, input_range_pct=(20.0, 70.0))
    >>> p = perturb_model(m, gain_factor=1.2, time_constant_factor=2.0, extra_delay_steps=1)
    >>> p.delay_steps, round(p.linear_static_gain, 12), round(float(p.input_poly[0]), 12)
    (2, 0.9, 1.62)
    >>> round(float(np.log(0.99) / np.log(-p.a[1])), 12)   # tau' / tau
    2.0
    """
    gain = _check_factor(gain_factor, "gain_factor")
    factor = _check_factor(time_constant_factor, "time_constant_factor")
    if (isinstance(extra_delay_steps, bool) or not isinstance(extra_delay_steps, (int, np.integer))
            or extra_delay_steps < 0):
        raise PlantError(
            f"perturb_model.extra_delay_steps: expected an integer >= 0; got {extra_delay_steps!r}")
    a, b = scale_slow_time_constant(model.a, model.b, ts_s=model.ts_s, factor=factor)
    b = np.concatenate([np.zeros(int(extra_delay_steps)), b])
    c = a if model.linear_block == "oe" else model.c
    input_poly = model.input_poly if gain == 1.0 else gain * model.input_poly
    extra = dict(model.provenance.extra)
    extra["perturbation"] = {
        "gain_factor": gain,
        "time_constant_factor": factor,
        "extra_delay_steps": int(extra_delay_steps),
    }
    return model.with_updates(a=a, b=b, c=c, input_poly=input_poly,
                              provenance=replace(model.provenance, extra=extra))


__all__ = ["perturb_model", "scale_slow_time_constant", "slow_pole"]
