"""The czmpc-model/1 contract: round trips, and every refusal of a bad file."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from czmpc.cli import main
from sysid.errors import ModelFileError, UnstableModelError
from sysid.model import Criteria, HammersteinModel, OperatingPoint, Provenance, Units
from sysid.modelfile import load_model, model_to_dict, save_model
from tests.tolerances import IDENTITY_RTOL

GOOD = Path(__file__).resolve().parents[1] / "data" / "models" / "paper_armax.json"


def _write(tmp_path: Path, obj: object, name: str = "m.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(obj), encoding="utf-8")
    return path


def _good_dict() -> dict:
    return json.loads(GOOD.read_text(encoding="utf-8"))


def test_shipped_example_model_loads_with_contract_values() -> None:
    model = load_model(GOOD)
    assert model.kind == "hammerstein" and model.linear_block == "armax"
    assert model.delay_steps == 1
    np.testing.assert_allclose(model.b, [0.0, 1.0, -0.991], rtol=0, atol=0)
    assert model.provenance.extra["note"].startswith("paper-like")


def test_round_trip_is_exact_including_unknown_provenance_keys(
    tmp_path: Path, paper_armax_model: HammersteinModel
) -> None:
    model = paper_armax_model.with_updates(
        criteria=Criteria(ballistic_mse_kw2=0.032, one_step_mse_kw2=1.8e-4),
        provenance=Provenance(
            data_file="x.csv",
            preprocessing=({"what": "level_shift", "from_time_s": 20714.0, "shift_kw": 0.15},),
            extra={"operator": "shift B"},
        ),
    )
    save_model(model, tmp_path / "m.json")
    again = load_model(tmp_path / "m.json")
    assert model_to_dict(again) == model_to_dict(model)


finite = st.floats(min_value=-50, max_value=50, allow_nan=False, allow_infinity=False)
stable_coef = st.floats(min_value=-0.999, max_value=0.999, allow_nan=False)


unit_text = st.text(alphabet=st.characters(blacklist_categories=["Cs"]), min_size=1,
                    max_size=32).filter(lambda u: u.strip() != "")


@settings(max_examples=60, deadline=None)
@given(a1=stable_coef, c1=stable_coef, b2=finite, d1=finite, d2=finite,
       noise=st.floats(min_value=1e-150, max_value=5),
       units=st.none() | st.builds(Units, input=unit_text, output=unit_text),
       cov_factor=st.none() | st.lists(st.lists(finite, min_size=4, max_size=4), min_size=4,
                                       max_size=4))
def test_save_load_round_trips_exactly_for_any_valid_model(
    tmp_path_factory: pytest.TempPathFactory,
    a1: float, c1: float, b2: float, d1: float, d2: float, noise: float,
    units: Units | None, cov_factor: list[list[float]] | None,
) -> None:
    covariance = None
    if cov_factor is not None:
        f = np.array(cov_factor)
        cov = f @ f.T
        covariance = tuple(tuple(float(v) for v in row) for row in (cov + cov.T) / 2)
    model = HammersteinModel(
        kind="hammerstein", linear_block="armax", ts_s=2.0,
        operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
        a=[1.0, a1], b=[0.0, 1.0, b2], c=[1.0, c1], input_poly=[d1, d2],
        noise_std_kw=noise, input_range_pct=(10.0, 65.0),
        provenance=Provenance(extra={"parameter_names": ["a1", "b2", "d1", "d2"]}),
        units=units, covariance=covariance,
    )
    path = tmp_path_factory.mktemp("rt") / "m.json"
    save_model(model, path)
    again = load_model(path)
    for name in ("a", "b", "c", "input_poly"):
        assert np.array_equal(getattr(again, name), getattr(model, name))
    assert again.noise_std_kw == model.noise_std_kw
    assert again.units == model.units
    assert again.covariance == model.covariance
    assert model_to_dict(again) == model_to_dict(model)


@pytest.mark.parametrize(
    ("mutate", "error", "pattern"),
    [
        (lambda d: d.update(format="czmpc-model/2"), ModelFileError, r"format must be 'czmpc-model/1'"),
        (lambda d: d.pop("B"), ModelFileError, r"missing key\(s\) \['B'\]"),
        (lambda d: d.update(A=[1.0, float("nan")]), ModelFileError, r"A\[1\] must be a finite number"),
        (lambda d: d.update(ts_s="2"), ModelFileError, r"ts_s must be a finite number"),
        (lambda d: d.update(A=[0.5, -0.99]), ModelFileError, r"A\(q\) must be monic"),
        (lambda d: d.update(B=[0.0, 2.0, -0.991]), ModelFileError, r"normalized to 1"),
        (lambda d: d.update(kind="linear"), ModelFileError, r"input_poly must have 1 entries"),
        (lambda d: d.update(input_range_pct=[70.0, 10.0]), ModelFileError, r"min < max"),
        (lambda d: d.update(input_range_pct=[10.0]), ModelFileError, r"must have 2 entries"),
        (lambda d: d.update(linear_block="bj"), ModelFileError, r"linear_block must be"),
        (lambda d: d.update(A=[1.0, -1.04]), UnstableModelError, r"A\(q\) has a root at \|z\| = 1.04"),
        (lambda d: d.update(C=[1.0, 1.5]), UnstableModelError, r"C\(q\) has a root at \|z\| = 1.5"),
        (lambda d: d.update(noise_std_kw=-1.0), ModelFileError, r"noise_std_kw must be finite and >= 0 "),
        (lambda d: d.update(ts_s=10**400), ModelFileError, r"ts_s must be a finite number within float"),
        (lambda d: d.update(units={"input": "degC"}), ModelFileError, r"units must be"),
        (lambda d: d.update(units={"input": "", "output": "V"}), ModelFileError, r"units.input must be"),
        (lambda d: d.update(covariance=[[1.0, 0.0]]), ModelFileError, r"square list of lists"),
        (lambda d: d.update(covariance=[[1.0, 2.0], [0.0, 1.0]]), ModelFileError, r"must be symmetric"),
        (lambda d: d.update(covariance=[[-1.0]]), ModelFileError, r"diagonal must be >= 0"),
        (lambda d: d.update(covariance=[[1e400]]), ModelFileError, r"covariance\[0\]\[0\] must be a finite"),
    ],
    ids=["format", "missing-B", "nan", "ts-type", "non-monic-A", "unnormalized-B",
         "linear-with-poly2", "inverted-range", "range-length", "block", "unstable-A",
         "unstable-C", "negative-noise", "huge-int", "units-keys", "empty-unit",
         "cov-not-square", "cov-asymmetric", "cov-negative-variance", "cov-overflow"],
)
def test_load_model_refuses_bad_files_with_file_name_and_reason(
    tmp_path: Path, mutate, error: type[Exception], pattern: str
) -> None:
    obj = _good_dict()
    mutate(obj)
    path = _write(tmp_path, obj)
    with pytest.raises(error, match=pattern) as info:
        load_model(path)
    assert str(path) in str(info.value)


def test_unknown_keys_are_ignored_and_units_covariance_load(tmp_path: Path) -> None:
    obj = _good_dict()
    obj["colour"] = "red"
    obj["units"] = {"input": "V", "output": "degC"}
    names = obj["provenance"].get("parameter_names")
    p = len(names) if names else 2
    cov = [[float(i == j) * (i + 1) * 1e-4 for j in range(p)] for i in range(p)]
    obj["covariance"] = cov
    model = load_model(_write(tmp_path, obj))
    assert (model.units.input, model.units.output) == ("V", "degC")  # type: ignore[union-attr]
    assert model.covariance is not None and model.covariance[1][1] == 2e-4
    assert "colour" not in model_to_dict(model)


def test_covariance_must_match_parameter_names(tmp_path: Path) -> None:
    obj = _good_dict()
    obj["provenance"]["parameter_names"] = ["a1", "b2", "d1"]
    obj["covariance"] = [[1.0, 0.0], [0.0, 1.0]]
    with pytest.raises(ModelFileError, match=r"covariance is 2 x 2 but provenance.parameter_names"):
        load_model(_write(tmp_path, obj))


def test_integer_with_thousands_of_digits_is_a_model_file_error(tmp_path: Path) -> None:
    text = GOOD.read_text(encoding="utf-8").replace('"ts_s": 2.0', '"ts_s": ' + "9" * 5000)
    path = tmp_path / "m.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ModelFileError, match="not a model file") as info:
        load_model(path)
    assert str(path) in str(info.value) and len(str(info.value)) < 400


def test_show_model_exits_2_without_traceback_on_huge_numbers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = GOOD.read_text(encoding="utf-8").replace('"ts_s": 2.0', '"ts_s": 1e400')
    path = tmp_path / "m.json"
    path.write_text(text, encoding="utf-8")
    assert main(["show-model", str(path)]) == 2
    err = capsys.readouterr().err
    assert "czmpc: error:" in err and "Traceback" not in err and "within float range" in err


def test_load_model_refuses_non_json_with_line(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    path.write_text('{"format": "czmpc-model/1",\n  oops}', encoding="utf-8")
    with pytest.raises(ModelFileError, match=r"not valid JSON \(line 2"):
        load_model(path)


def test_nan_literal_in_json_is_refused(tmp_path: Path) -> None:
    text = GOOD.read_text(encoding="utf-8").replace('"noise_std_kw": 0.0134', '"noise_std_kw": NaN')
    path = tmp_path / "m.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ModelFileError, match="noise_std_kw must be a finite number"):
        load_model(path)


def test_steady_state_gain_matches_analytic_b1_over_a1(paper_armax_model: HammersteinModel) -> None:
    m = paper_armax_model
    ds = 5.0
    expected = m.operating_point.power_kw + (1 - 0.991) / (1 - 0.99) * (1.35 * ds - 0.0065 * ds**2)
    assert math.isclose(float(m.steady_state_power_kw(45.0 + ds)), expected, rel_tol=IDENTITY_RTOL)
    np.testing.assert_allclose(m.input_nonlinearity_slope(ds), 1.35 - 2 * 0.0065 * ds,
                               rtol=IDENTITY_RTOL, atol=0)


def test_model_check_ts_refuses_other_sampling_time(paper_armax_model: HammersteinModel) -> None:
    from sysid.errors import SamplingTimeError

    with pytest.raises(SamplingTimeError, match="sampling time 1.0 s but the model has 2.0 s"):
        paper_armax_model.check_ts(1.0)


def test_cli_refuses_bad_model_file_with_exit_2_and_no_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    obj = _good_dict()
    obj["A"] = [1.0, -1.04]
    path = _write(tmp_path, obj)
    code = main(["show-model", str(path)])
    err = capsys.readouterr().err
    assert code == 2
    assert "outside the unit circle" in err and "Traceback" not in err
