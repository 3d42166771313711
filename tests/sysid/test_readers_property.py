"""Readers under arbitrary input: a valid value or their own typed error, never anything else.

read_csv -> Dataset | DataFileError; load_model -> HammersteinModel | ModelFileError;
load_scenario -> Scenario | ScenarioError. Valid data round-trips bit for bit through
write_csv/read_csv and save_model/load_model. (Warnings are errors in this suite, so a
reader that only warns on strange input fails here too.)
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sim.errors import ScenarioError
from sim.scenario import Scenario, load_scenario
from sysid.data import Dataset, read_csv, write_csv
from sysid.errors import DataFileError, ModelFileError
from sysid.model import Criteria, HammersteinModel, OperatingPoint, Provenance
from sysid.modelfile import load_model, model_to_dict, save_model
from tests.conftest import REPO

#: Examples per property: enough to hit every branch of the readers in a few seconds
#: (set CZMPC_PROPERTY_EXAMPLES for a longer search).
N_EXAMPLES = int(os.environ.get("CZMPC_PROPERTY_EXAMPLES", "250"))
PROPERTY = settings(max_examples=N_EXAMPLES, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])

SHIPPED_MODEL = json.loads((REPO / "data" / "cz_heater_model.json").read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def scratch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One directory for the whole module (hypothesis reuses it across examples)."""
    return tmp_path_factory.mktemp("readers")


# --- read_csv ------------------------------------------------------------------------------
#: Cells that probe number parsing: signs, exponents, overflow, subnormals, specials,
#: Python-only spellings, whitespace, quotes, control characters and non-ASCII digits.
TRICKY_CELLS = (
    "0", "1", "-1", "2.5", " 3 ", "1e308", "-1e308", "1e309", "1e-320", "nan", "NaN", "inf",
    "-inf", "", " ", "1_0", "0x10", "1,5", '"4"', '"5,6"', "\r", "\x00", "\ufeff1", "١٢",
    "1e", "--1", "+7", ".5", "5.", "\t8",
)
HEADERS = (
    "time_s,triac_pct,power_kw", "time_s,power_kw,triac_pct", "time_s,triac_pct",
    "time_s,triac_pct,power_kw,extra", "time_s,time_s,power_kw", "\ufefftime_s,triac_pct,power_kw",
    " time_s , triac_pct , power_kw ", "", "a,b,c",
)
cell = st.one_of(st.sampled_from(TRICKY_CELLS),
                 st.floats(allow_nan=True, allow_infinity=True).map(repr),
                 st.integers(-10**30, 10**30).map(str),
                 st.text(max_size=4))
csv_row = st.lists(cell, min_size=0, max_size=5).map(",".join)
csv_text = st.builds(
    lambda header, rows, newline, tail: header + newline + newline.join(rows) + tail,
    st.sampled_from(HEADERS), st.lists(csv_row, max_size=8),
    st.sampled_from(["\n", "\r\n", "\r"]), st.sampled_from(["", "\n", "\n\n", "\r"]),
)
#: Logs that are valid except perhaps for one cell: the reader must get past the header.
nearly_valid_csv = st.builds(
    lambda n, ts, k, bad: "time_s,triac_pct,power_kw\n" + "".join(
        f"{i * ts!r},{45.0 + i!r},{bad if i == k else repr(40.0 + i)}\n" for i in range(n)),
    st.integers(1, 8), st.sampled_from([2.0, 0.1, 1e-300, 1e300]), st.integers(0, 8),
    st.sampled_from(TRICKY_CELLS),
)


def _assert_valid_dataset(data: Dataset) -> None:
    assert data.n_samples >= 3
    for arr in (data.time_s, data.triac_pct, data.power_kw):
        assert arr.shape == (data.n_samples,) and np.all(np.isfinite(arr))
    assert np.all(np.diff(data.time_s) > 0)
    assert math.isfinite(data.ts_s) and data.ts_s > 0


def _read_csv_bytes(path: Path, raw: bytes) -> None:
    path.write_bytes(raw)
    try:
        data = read_csv(path)
    except DataFileError as exc:
        assert exc.path == str(path)
        return
    _assert_valid_dataset(data)


@PROPERTY
@given(raw=st.binary(max_size=300))
def test_read_csv_of_any_bytes_returns_a_dataset_or_raises_data_file_error(
    scratch: Path, raw: bytes
) -> None:
    _read_csv_bytes(scratch / "any.csv", raw)


@PROPERTY
@given(text=st.one_of(csv_text, nearly_valid_csv, st.text(max_size=200)))
def test_read_csv_of_any_text_returns_a_dataset_or_raises_data_file_error(
    scratch: Path, text: str
) -> None:
    _read_csv_bytes(scratch / "text.csv", text.encode("utf-8", "surrogatepass"))


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@st.composite
def datasets(draw: st.DrawFn) -> Dataset:
    n = draw(st.integers(3, 40))
    ts_s = draw(st.floats(1e-3, 1e3))
    t0 = draw(st.floats(-1e6, 1e6))
    k = np.arange(n, dtype=float)
    return Dataset(
        time_s=t0 + ts_s * k,
        triac_pct=np.array(draw(st.lists(finite, min_size=n, max_size=n))),
        power_kw=np.array(draw(st.lists(finite, min_size=n, max_size=n))),
        ts_s=ts_s,
    )


@PROPERTY
@given(data=datasets())
def test_write_csv_then_read_csv_returns_every_value_bit_for_bit(
    scratch: Path, data: Dataset
) -> None:
    path = scratch / "round.csv"
    write_csv(data, path)
    back = read_csv(path)
    for name in ("time_s", "triac_pct", "power_kw"):
        np.testing.assert_array_equal(getattr(back, name), getattr(data, name))
    assert back.ts_s == float(np.median(np.diff(data.time_s)))


# --- load_model ----------------------------------------------------------------------------
json_leaf = st.one_of(
    st.none(), st.booleans(), st.integers(-2**70, 2**70), st.floats(allow_nan=False),
    st.sampled_from([0.0, 1.0, -1.0, 1e308, -1e-320, 0.999999, 1.000001]), st.text(max_size=6),
    st.sampled_from(["czmpc-model/1", "hammerstein", "linear", "armax", "oe", "arx"]),
)
json_value = st.recursive(
    json_leaf,
    lambda children: st.one_of(st.lists(children, max_size=4),
                               st.dictionaries(st.text(max_size=8), children, max_size=4)),
    max_leaves=12,
)
MODEL_PATHS: tuple[tuple[str, ...], ...] = (
    ("format",), ("kind",), ("linear_block",), ("ts_s",), ("operating_point",),
    ("operating_point", "triac_pct"), ("operating_point", "power_kw"), ("A",), ("A", 1),
    ("B",), ("B", 0), ("B", 1), ("B", 2), ("C",), ("C", 1), ("input_poly",),
    ("input_poly", 0), ("noise_std_kw",), ("input_range_pct",), ("input_range_pct", 1),
    ("criteria",), ("criteria", "V"), ("provenance",), ("provenance", "preprocessing"),
    ("provenance", "data_file"), ("unknown_key",), ("units",), ("units", "input"),
    ("covariance",),
)


@st.composite
def mutated_model_dicts(draw: st.DrawFn) -> Any:
    """The shipped model file with 1-3 fields replaced by any JSON value or deleted."""
    obj = json.loads(json.dumps(SHIPPED_MODEL))
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(MODEL_PATHS))
        parent: Any = obj
        for key in path[:-1]:
            parent = parent[key] if isinstance(parent, dict) and key in parent else None
        last = path[-1]
        if isinstance(parent, dict) or (isinstance(parent, list) and isinstance(last, int)
                                        and last < len(parent)):
            if draw(st.booleans()) or isinstance(parent, list):
                parent[last] = draw(json_value)
            else:
                parent.pop(last, None)
    return obj


def _load_model_text(path: Path, raw: bytes) -> None:
    path.write_bytes(raw)
    try:
        model = load_model(path)
    except ModelFileError as exc:
        assert str(exc).startswith(str(path))
        return
    assert isinstance(model, HammersteinModel)


@PROPERTY
@given(obj=st.one_of(json_value, mutated_model_dicts()))
def test_load_model_of_any_json_value_returns_a_model_or_raises_model_file_error(
    scratch: Path, obj: Any
) -> None:
    _load_model_text(scratch / "model.json", json.dumps(obj).encode("utf-8"))


@PROPERTY
@given(raw=st.one_of(st.binary(max_size=200),
                     st.sampled_from([b"[" * 100_000, b'{"a":' * 50_000, b"NaN", b"\xff{}"])))
def test_load_model_of_any_bytes_raises_model_file_error(scratch: Path, raw: bytes) -> None:
    _load_model_text(scratch / "bytes.json", raw)


@st.composite
def models(draw: st.DrawFn) -> HammersteinModel:
    block = draw(st.sampled_from(["armax", "oe", "arx"]))
    kind = draw(st.sampled_from(["hammerstein", "linear"]))
    a = [1.0, draw(st.floats(-0.999, 0.999))]
    c = a if block == "oe" else [1.0] if block == "arx" else [1.0, draw(st.floats(-0.99, 0.99))]
    delay = draw(st.integers(0, 3))
    b = [0.0] * delay + [1.0] + draw(st.lists(st.floats(-5, 5), max_size=3))
    degree = 1 if kind == "linear" else draw(st.integers(1, 4))
    lo = draw(st.floats(0, 99))
    return HammersteinModel(
        kind=kind, linear_block=block, ts_s=draw(st.floats(1e-3, 1e3)),  # type: ignore[arg-type]
        operating_point=OperatingPoint(triac_pct=draw(finite), power_kw=draw(finite)),
        a=a, b=b, c=c, input_poly=draw(st.lists(finite, min_size=degree, max_size=degree)),
        noise_std_kw=draw(st.floats(1e-150, 1e3)), input_range_pct=(lo, lo + draw(st.floats(0.5, 50))),
        criteria=Criteria(ballistic_mse_kw2=draw(st.none() | finite),
                          one_step_mse_kw2=draw(st.none() | finite)),
        provenance=Provenance(data_file=draw(st.none() | st.text(max_size=10)),
                              method=draw(st.none() | st.text(max_size=10)),
                              preprocessing=({"what": "interpolate_spike", "sample": 3},),
                              extra={"note": draw(st.text(max_size=10))}),
    )


@PROPERTY
@given(model=models())
def test_save_model_then_load_model_returns_every_field_exactly(
    scratch: Path, model: HammersteinModel
) -> None:
    path = scratch / "round.json"
    save_model(model, path)
    assert model_to_dict(load_model(path)) == model_to_dict(model)


# --- load_scenario ------------------------------------------------------------------------
def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        text = repr(value)
        return text if any(ch in text for ch in ".en") else text + ".0"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(v)}" for k, v in value.items()) + "}"


SCENARIO_KEYS = (
    "name", "description", "duration_s", "ts_s", "plant_noise", "initial_setpoint_kw",
    "initial_triac_pct", "limits", "setpoint", "disturbance", "fault", "duraton_s",
)
EVENT_KEYS = (
    "kind", "at_s", "power_kw", "start_s", "end_s", "factor", "duration_s", "offset_kw",
    "spike_kw", "probability_per_sample", "triac_min_pct", "triac_max_pct",
    "max_move_pct_per_step",
)
EVENT_KINDS = ("step", "ramp", "voltage_step", "voltage_ramp", "power_shift", "spike",
               "random_spikes", "missing_samples", "bogus")
toml_number = st.one_of(
    st.integers(-2**63, 2**63 - 1), st.integers(-10**400, 10**400), st.floats(),
    st.sampled_from([0, 1, 2, 0.5, 2.0, 1e-300, 1e300, 600, 7200, -1, 0.999, 1.001]),
)
toml_leaf = st.one_of(toml_number, st.booleans(), st.text(max_size=4), st.sampled_from(EVENT_KINDS))
toml_value = st.recursive(
    toml_leaf,
    lambda children: st.one_of(st.lists(children, max_size=3),
                               st.dictionaries(st.sampled_from(EVENT_KEYS), children, max_size=4)),
    max_leaves=10,
)
toml_event = st.dictionaries(st.sampled_from(EVENT_KEYS), st.one_of(toml_number, toml_value),
                             max_size=6)
scenario_docs = st.fixed_dictionaries(
    {"name": st.just("fuzz"), "duration_s": toml_number, "initial_setpoint_kw": toml_number},
    optional={key: st.one_of(toml_value, st.lists(toml_event, min_size=1, max_size=3))
              for key in SCENARIO_KEYS if key not in ("name", "duration_s",
                                                      "initial_setpoint_kw")},
)


def _load_scenario_bytes(path: Path, raw: bytes) -> None:
    path.write_bytes(raw)
    try:
        scenario = load_scenario(path)
    except ScenarioError as exc:
        assert str(exc).startswith(str(path))
        return
    assert isinstance(scenario, Scenario) and scenario.n_steps >= 1


@PROPERTY
@given(doc=scenario_docs)
def test_load_scenario_of_any_toml_document_returns_a_scenario_or_raises_scenario_error(
    scratch: Path, doc: dict[str, Any]
) -> None:
    text = "\n".join(f"{json.dumps(key)} = {_toml_value(value)}" for key, value in doc.items())
    _load_scenario_bytes(scratch / "doc.toml", text.encode("utf-8"))


@PROPERTY
@given(raw=st.one_of(st.binary(max_size=200), st.text(max_size=200).map(str.encode)))
def test_load_scenario_of_any_text_raises_scenario_error(scratch: Path, raw: bytes) -> None:
    _load_scenario_bytes(scratch / "any.toml", raw)


@pytest.mark.parametrize(
    ("text", "match"),
    [('setpoint = [{kind = [1]}]', "setpoint\\[1\\].kind"),
     ('setpoint = [{kind = {a = 1}}]', "setpoint\\[1\\].kind"),
     ('ts_s = 1e-300\nduration_s = 1e300', "MAX_TIME_S"),   # bounded before its samples are counted
     ('duration_s = 1e-300', "whole number \\(>= 1\\) of samples"),
     ('duration_s = 1' + '0' * 400, "finite number")],
)
def test_load_scenario_maps_each_found_escape_to_scenario_error(
    tmp_path: Path, text: str, match: str
) -> None:
    body = 'name = "x"\ninitial_setpoint_kw = 1.0\n'
    if "duration_s" not in text:
        body += "duration_s = 100\n"
    path = tmp_path / "bad.toml"
    path.write_text(body + text + "\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match=match):
        load_scenario(path)


def test_found_escapes_of_read_csv_and_load_model_are_typed(tmp_path: Path) -> None:
    csv_path = tmp_path / "cr.csv"
    csv_path.write_bytes(b'time_s,triac_pct,power_kw\n0,1,"2\r"x\n')
    with pytest.raises(DataFileError, match="line 2"):
        read_csv(csv_path)
    model_path = tmp_path / "latin1.json"
    model_path.write_bytes(b'{"format": "\xff"}')
    with pytest.raises(ModelFileError, match="UTF-8"):
        load_model(model_path)
