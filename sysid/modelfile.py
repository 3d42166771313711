"""Read and write the ``czmpc-model/1`` JSON model file (docs/reference/model_file.rst).

This is the only place that maps between the file's keys (``"A"``, ``"B"``, ``"C"``,
``"V"``, ``"W"``) and the Python attribute names (``a``, ``b``, ``c``,
``ballistic_mse_kw2``, ``one_step_mse_kw2``).
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from sysid._typing import FloatArray
from sysid._version import SOFTWARE
from sysid.atomic import atomic_write_text
from sysid.errors import ModelFileError, UnstableModelError
from sysid.model import Criteria, HammersteinModel, OperatingPoint, Provenance, Units

FORMAT = "czmpc-model/1"
_TOP_KEYS = {
    "format", "kind", "linear_block", "ts_s", "operating_point", "A", "B", "C",
    "input_poly", "noise_std_kw", "input_range_pct", "criteria", "provenance",
    "units", "covariance",
}
_REQUIRED = _TOP_KEYS - {"criteria", "provenance", "units", "covariance"}
_PROVENANCE_KEYS = ("data_file", "data_sha256", "preprocessing", "method", "created_utc")


def model_to_dict(model: HammersteinModel) -> dict[str, Any]:
    """The JSON object of the model file for ``model``."""
    prov = model.provenance
    # Which czmpc wrote the model; a model read from a file keeps the version that made it.
    provenance: dict[str, Any] = {"software": SOFTWARE, **prov.extra,
                                  **{key: getattr(prov, key) for key in _PROVENANCE_KEYS},
                                  "preprocessing": [dict(step) for step in prov.preprocessing]}
    out: dict[str, Any] = {
        "format": FORMAT,
        "kind": model.kind,
        "linear_block": model.linear_block,
        "ts_s": model.ts_s,
        "operating_point": {
            "triac_pct": model.operating_point.triac_pct,
            "power_kw": model.operating_point.power_kw,
        },
        "A": model.a.tolist(),
        "B": model.b.tolist(),
        "C": model.c.tolist(),
        "input_poly": model.input_poly.tolist(),
        "noise_std_kw": model.noise_std_kw,
        "input_range_pct": list(model.input_range_pct),
        "criteria": {
            "V": model.criteria.ballistic_mse_kw2,
            "W": model.criteria.one_step_mse_kw2,
        },
        "provenance": provenance}
    if model.units is not None:
        out["units"] = {"input": model.units.input, "output": model.units.output}
    if model.covariance is not None:
        out["covariance"] = [list(row) for row in model.covariance]
    return out


def _short(obj: Any) -> str:
    """``repr`` of a file value, cut so that a huge value cannot flood a message."""
    try:
        text = repr(obj)
    except ValueError:  # an int too long to convert to text
        return f"an integer of more than {sys.get_int_max_str_digits()} digits"
    return text if len(text) <= 80 else text[:60] + f"... ({len(text)} characters)"


def _number(obj: Any, where: str) -> float:
    if isinstance(obj, bool) or not isinstance(obj, (int, float)):
        raise ModelFileError(f"{where} must be a finite number; got {_short(obj)}")
    try:
        value = float(obj)
    except OverflowError:
        value = math.inf
    if not math.isfinite(value):
        raise ModelFileError(
            f"{where} must be a finite number within float range; got {_short(obj)}")
    return value


def _numbers(obj: Any, where: str, *, length: int | None = None) -> FloatArray:
    if not isinstance(obj, list) or not obj:
        raise ModelFileError(f"{where} must be a non-empty list of numbers; got {obj!r}")
    if length is not None and len(obj) != length:
        raise ModelFileError(f"{where} must have {length} entries; got {len(obj)}")
    return np.array([_number(v, f"{where}[{i}]") for i, v in enumerate(obj)], dtype=float)


def model_from_dict(obj: Any) -> HammersteinModel:
    """Build a model from the JSON object of a model file, validating every field.

    Raises
    ------
    ModelFileError
        Unknown format, missing keys (unknown keys are ignored), wrong types or lengths,
        non-finite numbers or numbers beyond float range, malformed ``units`` or
        ``covariance``, or any invariant of `HammersteinModel`.
    UnstableModelError
        ``A`` or ``C`` with a root on or outside the unit circle.
    """
    if not isinstance(obj, dict):
        raise ModelFileError(f"expected a JSON object; got {type(obj).__name__}")
    fmt = obj.get("format")
    if fmt != FORMAT:
        raise ModelFileError(f"format must be {FORMAT!r}; got {fmt!r}")
    missing = sorted(_REQUIRED - set(obj))
    if missing:
        raise ModelFileError(f"missing key(s) {missing}")
    # Keys outside _TOP_KEYS are ignored: optional fields may be added to
    # czmpc-model/1 and readers ignore what they do not know (docs/reference/model_file.rst).
    op = obj["operating_point"]
    if not isinstance(op, dict) or set(op) != {"triac_pct", "power_kw"}:
        raise ModelFileError(f"operating_point must be {{'triac_pct': ..., 'power_kw': ...}}; got {op!r}")
    crit = obj.get("criteria") or {}
    if not isinstance(crit, dict) or not set(crit) <= {"V", "W"}:
        raise ModelFileError(f"criteria must be an object with keys V and W; got {crit!r}")
    prov_obj = obj.get("provenance") or {}
    if not isinstance(prov_obj, dict):
        raise ModelFileError(f"provenance must be an object; got {prov_obj!r}")
    steps = prov_obj.get("preprocessing") or []
    if not isinstance(steps, list) or not all(isinstance(s, dict) for s in steps):
        raise ModelFileError(f"provenance.preprocessing must be a list of objects; got {steps!r}")
    units_obj = obj.get("units")
    units: Units | None = None
    if units_obj is not None:
        if not isinstance(units_obj, dict) or set(units_obj) != {"input", "output"}:
            raise ModelFileError(
                f"units must be {{'input': ..., 'output': ...}}; got {_short(units_obj)}")
        units = Units(input=units_obj["input"], output=units_obj["output"])
    cov_obj = obj.get("covariance")
    covariance: tuple[tuple[float, ...], ...] | None = None
    if cov_obj is not None:
        if not isinstance(cov_obj, list) or not cov_obj or not all(
                isinstance(row, list) and len(row) == len(cov_obj) for row in cov_obj):
            raise ModelFileError(
                f"covariance must be a non-empty square list of lists; got {_short(cov_obj)}")
        covariance = tuple(
            tuple(_number(v, f"covariance[{i}][{j}]") for j, v in enumerate(row))
            for i, row in enumerate(cov_obj))
    kind = obj["kind"]
    lo_pct, hi_pct = _numbers(obj["input_range_pct"], "input_range_pct", length=2)
    poly = _numbers(obj["input_poly"], "input_poly", length=1 if kind == "linear" else None)
    return HammersteinModel(
        kind=kind,
        linear_block=obj["linear_block"],
        ts_s=_number(obj["ts_s"], "ts_s"),
        operating_point=OperatingPoint(
            triac_pct=_number(op["triac_pct"], "operating_point.triac_pct"),
            power_kw=_number(op["power_kw"], "operating_point.power_kw"),
        ),
        a=_numbers(obj["A"], "A"),
        b=_numbers(obj["B"], "B"),
        c=_numbers(obj["C"], "C"),
        input_poly=poly,
        noise_std_kw=_number(obj["noise_std_kw"], "noise_std_kw"),
        input_range_pct=(float(lo_pct), float(hi_pct)),
        criteria=Criteria(
            ballistic_mse_kw2=None if crit.get("V") is None else _number(crit["V"], "criteria.V"),
            one_step_mse_kw2=None if crit.get("W") is None else _number(crit["W"], "criteria.W"),
        ),
        provenance=Provenance(
            **{key: prov_obj.get(key) for key in _PROVENANCE_KEYS if key != "preprocessing"},
            preprocessing=tuple(steps),
            extra={k: v for k, v in prov_obj.items() if k not in _PROVENANCE_KEYS}),
        units=units,
        covariance=covariance)


def save_model(model: HammersteinModel, path: str | os.PathLike[str]) -> None:
    """Write ``model`` as a ``czmpc-model/1`` JSON file, atomically.

    Floats are written with full precision, so `load_model` returns the same numbers.
    """
    text = json.dumps(model_to_dict(model), indent=2, allow_nan=False) + "\n"
    atomic_write_text(path, text)


def load_model(path: str | os.PathLike[str]) -> HammersteinModel:
    """Read a ``czmpc-model/1`` JSON file.

    Raises
    ------
    ModelFileError
        Not JSON, unknown format, wrong keys or lengths, non-finite numbers; the
        message starts with the file name.
    UnstableModelError
        ``A`` or ``C`` has a root on or outside the unit circle.
    OSError
        The file cannot be read.
    """
    path = Path(path)
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ModelFileError(
            f"{path}: expected UTF-8 text; got undecodable byte at offset {exc.start}") from None
    try:
        obj = json.loads(text, parse_constant=lambda c: float(c))
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"{path}: not valid JSON (line {exc.lineno}: {exc.msg})") from None
    except RecursionError:
        raise ModelFileError(f"{path}: not a model file: JSON nested too deeply") from None
    except ValueError as exc:  # an integer literal beyond the int-to-text digit limit
        raise ModelFileError(f"{path}: not a model file: {exc}") from None
    try:
        return model_from_dict(obj)
    except UnstableModelError as exc:
        raise UnstableModelError(f"{path}: {exc}") from None
    except ModelFileError as exc:
        raise ModelFileError(f"{path}: {exc}") from None


__all__ = ["FORMAT", "load_model", "model_from_dict", "model_to_dict", "save_model"]
