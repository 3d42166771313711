"""The identified model: general polynomial Hammerstein form and its metadata.

Notation
--------
The one general form of every model the project stores (docs/reference/model_file.rst)::

    A(q) dP_k = B(q) f(ds_k) + C(q) e_k,      f(ds) = sum_i p_i ds^i,  i = 1..n

``dP = P - P_nom`` [kW] and ``ds = s - s_nom`` [%] are deviations from the operating
point (paper sec. 5.1). ``A``, ``B``, ``C`` hold ascending powers of q^-1; ``B``'s
leading zeros are the delay ``nk`` and its first non-zero coefficient is 1 (the
normalization of paper eqs. 22-25, which moves the gain into ``f``). ``e`` is white
with standard deviation ``noise_std_kw``.

* ARX (eq. 5): ``C = [1]``.  ARMAX (eq. 6): ``C`` free.  OE (eq. 7): stored with
  ``C = A`` so that ``dP = B/A f(ds) + e``.
* A linear model has ``kind = "linear"`` and one input coefficient ``p_1 = b_1``.
* The paper's final models are eq. 27 (OE block) and eq. 30 (ARMAX block).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from sysid._arrays import readonly_array
from sysid._typing import FloatArray
from sysid.errors import ModelFileError, SamplingTimeError, UnstableModelError
from sysid.polynomials import is_stable, max_root_modulus

ModelKind = Literal["hammerstein", "linear"]
LinearBlock = Literal["armax", "oe", "arx"]

#: |b_first| within this of 1 counts as normalized (JSON round trips are exact, so
#: this only absorbs arithmetic in user code that builds models by hand).
NORMALIZATION_ATOL = 1e-9


def _frozen_array(values: Any, name: str) -> FloatArray:
    arr = readonly_array(values)
    if arr.ndim != 1 or arr.size == 0:
        raise ModelFileError(f"{name} must be a non-empty 1-D list of numbers; got {values!r}")
    if not np.all(np.isfinite(arr)):
        raise ModelFileError(f"{name} must hold finite numbers; got {arr.tolist()}")
    return arr


def _poly_eval(input_poly: FloatArray, ds: FloatArray | float) -> FloatArray:
    """``f(ds) = sum_i p_i ds^i`` (no constant term) by Horner's rule."""
    ds = np.asarray(ds, dtype=float)
    out = np.zeros_like(ds)
    for coef in np.asarray(input_poly)[::-1]:
        out = (out + coef) * ds
    return out


@dataclass(frozen=True, kw_only=True)
class OperatingPoint:
    """Steady operating point the deviation variables are taken about (paper sec. 5.1).

    Parameters
    ----------
    triac_pct :
        Nominal TRIAC input ``s_nom`` [%].
    power_kw :
        Nominal heater power ``P_nom`` [kW].
    """

    triac_pct: float
    power_kw: float

    def __post_init__(self) -> None:
        for name in ("triac_pct", "power_kw"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ModelFileError(f"OperatingPoint.{name} must be a finite number; got {value!r}")
            object.__setattr__(self, name, float(value))


@dataclass(frozen=True, kw_only=True)
class Criteria:
    """Fit criteria of a model on its identification data (paper eqs. 9-10).

    Parameters
    ----------
    ballistic_mse_kw2 :
        ``V``: mean squared ballistic simulation error [kW^2] (eq. 9), or None.
    one_step_mse_kw2 :
        ``W``: mean squared one-step-ahead prediction error [kW^2] (eq. 10), or None.
    """

    ballistic_mse_kw2: float | None = None
    one_step_mse_kw2: float | None = None


@dataclass(frozen=True, kw_only=True)
class Units:
    """What the model's input and output measure (model-file key ``"units"``).

    The file's field names (``triac_pct``, ``power_kw``, ``noise_std_kw``) name the
    roles input and output; these strings say what they measure on the rig.

    Parameters
    ----------
    input :
        Unit of the input signal (``"%"`` for a CZ puller's TRIAC).
    output :
        Unit of the output signal (``"kW"`` for heater power).

    Raises
    ------
    ModelFileError
        A unit that is not a non-empty string of at most `MAX_UNIT_CHARS` characters.
    """

    input: str = "%"
    output: str = "kW"

    def __post_init__(self) -> None:
        for name in ("input", "output"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value.strip() or len(value) > MAX_UNIT_CHARS:
                raise ModelFileError(
                    f"units.{name} must be a non-empty string of at most {MAX_UNIT_CHARS} "
                    f"characters; got {value!r}")


#: Longest unit string accepted (a unit, not a description).
MAX_UNIT_CHARS = 32

#: The units a model has when its file has no ``"units"`` object.
DEFAULT_UNITS = Units()


@dataclass(frozen=True, kw_only=True, eq=False)
class Provenance:
    """Where a model came from: data, preprocessing, method, date.

    Parameters
    ----------
    data_file :
        Name of the identification data file, or None.
    data_sha256 :
        SHA-256 of that file's bytes, or None.
    preprocessing :
        Every change made to the data before fitting, in order; each a JSON-able
        mapping with at least ``"what"`` (see `sysid.preprocess`).
    method :
        How the model was fitted (for example ``"pem-one-step"``).
    created_utc :
        ISO-8601 creation time, or None.
    extra :
        Any other keys of the file's ``provenance`` object, kept for round trips
        (for example ``parameter_names``, ``parameters``, ``std_errors``).
    """

    data_file: str | None = None
    data_sha256: str | None = None
    preprocessing: tuple[Mapping[str, Any], ...] = ()
    method: str | None = None
    created_utc: str | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    @property
    def parameter_names(self) -> tuple[str, ...] | None:
        """Names of the estimated parameters (``extra["parameter_names"]``), or None.

        These name the rows and columns of `HammersteinModel.covariance`.
        """
        names = self.extra.get("parameter_names")
        if not isinstance(names, (list, tuple)) or not all(isinstance(n, str) for n in names):
            return None
        return tuple(names)


@dataclass(frozen=True, kw_only=True, eq=False)
class HammersteinModel:
    """A SISO polynomial model ``A dP = B f(ds) + C e`` about an operating point.

    Parameters
    ----------
    kind :
        ``"hammerstein"`` (polynomial ``f``) or ``"linear"`` (``f(ds) = b1 ds``).
    linear_block :
        ``"arx"``, ``"armax"`` or ``"oe"``: which noise model the linear block has.
    ts_s :
        Sampling time [s].
    operating_point :
        ``(s_nom, P_nom)``.
    a, b, c :
        ``A(q)``, ``B(q)``, ``C(q)`` in ascending powers of q^-1; ``a[0] = c[0] = 1``;
        the first non-zero of ``b`` is 1.
    input_poly :
        ``[p_1, ..., p_n]`` with ``f(ds) = sum p_i ds^i`` [kW per %^i]; no constant.
    noise_std_kw :
        Standard deviation of the innovation ``e`` [kW].
    input_range_pct :
        ``(s_min, s_max)``: range of the TRIAC input seen in the identification data [%].
    criteria :
        ``V`` and ``W`` on the identification data.
    provenance :
        Data, preprocessing and method.
    units :
        What input and output measure, or None (then ``%`` and ``kW``; see
        `effective_units`).
    covariance :
        Full covariance of the estimated parameters, a symmetric ``p x p`` matrix in
        the order of ``provenance.parameter_names`` (when those are recorded), or None.

    Raises
    ------
    ModelFileError
        Wrong lengths, non-finite numbers, a non-monic ``A``/``C``, an un-normalized
        ``B``, an inverted input range, ``noise_std_kw`` negative or not finite,
        or a covariance that is not a finite symmetric
        square matrix with a non-negative diagonal matching the parameter names.
    UnstableModelError
        ``A`` or ``C`` with a root on or outside the unit circle.

    Examples
    --------
    >>> m = HammersteinModel(kind="hammerstein", linear_block="oe", ts_s=2.0,
    ...     operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
    ...     a=[1.0, -0.99], b=[0.0, 1.0, -0.991], c=[1.0, -0.99],
    ...     input_poly=[1.35, -0.0065], noise_std_kw=0.013, input_range_pct=(20.0, 65.0))
    >>> round(float(m.steady_state_power_kw(50.0)), 3)
    50.929
    """

    kind: ModelKind
    linear_block: LinearBlock
    ts_s: float
    operating_point: OperatingPoint
    a: FloatArray
    b: FloatArray
    c: FloatArray
    input_poly: FloatArray
    noise_std_kw: float
    input_range_pct: tuple[float, float]
    criteria: Criteria = field(default_factory=Criteria)
    provenance: Provenance = field(default_factory=Provenance)
    units: Units | None = None
    covariance: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("hammerstein", "linear"):
            raise ModelFileError(f"kind must be 'hammerstein' or 'linear'; got {self.kind!r}")
        if self.linear_block not in ("armax", "oe", "arx"):
            raise ModelFileError(f"linear_block must be 'armax', 'oe' or 'arx'; got {self.linear_block!r}")
        if not isinstance(self.ts_s, (int, float)) or not (math.isfinite(self.ts_s) and self.ts_s > 0):
            raise ModelFileError(f"ts_s must be a finite number > 0 [s]; got {self.ts_s!r}")
        object.__setattr__(self, "ts_s", float(self.ts_s))
        for name in ("a", "b", "c", "input_poly"):
            object.__setattr__(self, name, _frozen_array(getattr(self, name), name))
        for name in ("a", "c"):
            poly = getattr(self, name)
            if poly[0] != 1.0:
                raise ModelFileError(f"{name.upper()}(q) must be monic ({name}[0] = 1); got {poly[0]}")
        nonzero = np.flatnonzero(self.b)
        if nonzero.size == 0:
            raise ModelFileError("B(q) must have a non-zero coefficient; got all zeros")
        if abs(self.b[nonzero[0]] - 1.0) > NORMALIZATION_ATOL:
            raise ModelFileError(
                "B(q)'s first non-zero coefficient must be normalized to 1 (the gain lives "
                f"in input_poly); got {self.b[nonzero[0]]}")
        if self.kind == "linear" and self.input_poly.size != 1:
            raise ModelFileError(
                f"a linear model has one input coefficient (b1); got input_poly of "
                f"length {self.input_poly.size}")
        if not (math.isfinite(self.noise_std_kw) and self.noise_std_kw >= 0.0):
            raise ModelFileError(
                f"noise_std_kw must be finite and >= 0 (0: a noise-free model, which the "
                f"controller runs); got {self.noise_std_kw!r}")
        object.__setattr__(self, "noise_std_kw", float(self.noise_std_kw))
        lo, hi = (float(v) for v in self.input_range_pct)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ModelFileError(
                f"input_range_pct must be finite with min < max [%]; got {self.input_range_pct!r}")
        object.__setattr__(self, "input_range_pct", (lo, hi))
        if self.units is not None and not isinstance(self.units, Units):
            raise ModelFileError(f"units must be a Units or None; got {self.units!r}")
        if self.covariance is not None:
            object.__setattr__(self, "covariance", _checked_covariance(
                self.covariance, self.provenance.parameter_names))
        for name in ("a", "c"):  # the roots only for the message (the test: a few flops)
            if is_stable(getattr(self, name)):
                continue
            rho = max_root_modulus(getattr(self, name))
            if rho >= 1.0:
                raise UnstableModelError(
                    f"{name.upper()}(q) has a root at |z| = {rho:.4g}, outside the unit circle; "
                    "the model is unstable")

    # --- structure -------------------------------------------------------------
    @property
    def effective_units(self) -> Units:
        """`units`, or ``%`` and ``kW`` when the model does not say."""
        return DEFAULT_UNITS if self.units is None else self.units

    @property
    def covariance_matrix(self) -> FloatArray | None:
        """`covariance` as a read-only ``(p, p)`` array, or None."""
        return None if self.covariance is None else readonly_array(self.covariance)

    @property
    def delay_steps(self) -> int:
        """Input delay ``nk`` [samples]: the number of leading zeros of ``B``."""
        return int(np.flatnonzero(self.b)[0])

    @property
    def input_degree(self) -> int:
        """Degree ``n`` of the input polynomial ``f``."""
        return int(self.input_poly.size)

    # --- the input nonlinearity --------------------------------------------------
    def input_nonlinearity(self, ds_pct: FloatArray | float) -> FloatArray:
        """Evaluate ``f(ds) = sum_i p_i ds^i`` (eq. 28) [kW-equivalent input].

        Parameters
        ----------
        ds_pct :
            TRIAC deviation from the operating point [%], scalar or array.
        """
        return _poly_eval(self.input_poly, ds_pct)

    def input_nonlinearity_slope(self, ds_pct: FloatArray | float) -> FloatArray:
        """Evaluate ``f'(ds)`` [kW/%] (the instantaneous gain of the paper's sec. 7.3)."""
        ds = np.asarray(ds_pct, dtype=float)
        out = np.zeros_like(ds)
        for i in range(self.input_poly.size, 0, -1):
            out = out * ds + i * self.input_poly[i - 1]
        return out

    # --- steady state ------------------------------------------------------------
    @property
    def linear_static_gain(self) -> float:
        """``B(1)/A(1)``: steady-state gain of the linear block [kW per unit of f]."""
        return float(np.sum(self.b) / np.sum(self.a))

    def steady_state_power_kw(self, triac_pct: FloatArray | float) -> FloatArray:
        """Steady power ``P_nom + B(1)/A(1) f(s - s_nom)`` [kW] for a constant input [%]."""
        ds = np.asarray(triac_pct, dtype=float) - self.operating_point.triac_pct
        return self.operating_point.power_kw + self.linear_static_gain * self.input_nonlinearity(ds)

    def with_updates(self, **changes: Any) -> HammersteinModel:
        """Return a copy with the given fields replaced (validated again)."""
        return replace(self, **changes)

    def check_ts(self, ts_s: float, *, what: str = "data") -> None:
        """Raise `SamplingTimeError` unless ``ts_s`` equals this model's sampling time."""
        if not math.isclose(ts_s, self.ts_s, rel_tol=1e-9, abs_tol=1e-12):
            raise SamplingTimeError(f"{what} has sampling time {ts_s} s but the model has {self.ts_s} s")


#: Relative asymmetry ``|C - C^T| / max|C|`` tolerated in a covariance (rounding of a
#: product ``J^T J`` computed in floating point; a real asymmetry is far larger).
COVARIANCE_SYMMETRY_RTOL = 1e-9


def _checked_covariance(values: Any, names: tuple[str, ...] | None) -> tuple[tuple[float, ...], ...]:
    """Validate a covariance matrix and return it as a tuple of float tuples."""
    try:
        arr = np.array(values, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ModelFileError(
            f"covariance must be a square matrix of finite numbers; got {values!r}"[:300]) from None
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or arr.size == 0:
        raise ModelFileError(f"covariance must be a non-empty square matrix; got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelFileError("covariance must hold finite numbers; got a NaN or infinity")
    if names is not None and len(names) != arr.shape[0]:
        raise ModelFileError(
            f"covariance is {arr.shape[0]} x {arr.shape[0]} but provenance.parameter_names "
            f"lists {len(names)} parameters {list(names)}")
    scale = float(np.max(np.abs(arr)))
    asym = float(np.max(np.abs(arr - arr.T)))
    if asym > COVARIANCE_SYMMETRY_RTOL * max(scale, np.finfo(float).tiny):
        raise ModelFileError(f"covariance must be symmetric; got |C - C^T| up to {asym:.3g}")
    diag = np.diag(arr)
    if np.any(diag < 0):
        k = int(np.flatnonzero(diag < 0)[0])
        raise ModelFileError(f"covariance diagonal must be >= 0; got {diag[k]!r} at [{k}][{k}]")
    return tuple(tuple(float(v) for v in row) for row in arr)


def normalize_input_gain(
    b: FloatArray, input_poly: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Move B's first non-zero coefficient into ``f`` (paper eqs. 22-24).

    Returns ``(b / b_first, input_poly * b_first)``, which describes the same
    input-output map with ``B`` normalized as the model file requires.
    """
    b = np.asarray(b, dtype=float)
    nonzero = np.flatnonzero(b)
    if nonzero.size == 0:
        raise ModelFileError("B(q) is all zeros: the input has no effect on the output")
    scale = b[nonzero[0]]
    return b / scale, np.asarray(input_poly, dtype=float) * scale


__all__ = [
    "Criteria", "HammersteinModel", "LinearBlock", "ModelKind", "OperatingPoint", "Provenance",
    "Units", "normalize_input_gain"
]
