"""`czmpc show-model`: units from the model file and the warnings an engineer needs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from czmpc.cli import main
from czmpc.cli.show_model import model_warnings
from czmpc.shipped import shipped_path
from sysid.model import HammersteinModel, OperatingPoint


def _model(a: list[float], b: list[float], poly: list[float]) -> HammersteinModel:
    return HammersteinModel(
        kind="hammerstein", linear_block="oe", ts_s=2.0,
        operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
        a=a, b=b, c=a, input_poly=poly, noise_std_kw=0.01, input_range_pct=(20.0, 65.0))  # type: ignore[arg-type]


def test_shipped_models_show_without_warnings_in_percent_and_kw(
    capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["show-model", str(shipped_path("cz_heater_model.json"))]) == 0
    out = capsys.readouterr().out
    assert "WARNING" not in out
    assert "units: input %, output kW (the file has no units: % and kW assumed)" in out


def test_paper_drift_mode_is_not_taken_for_a_cancellation() -> None:
    # zero 0.991 vs pole 0.99: |z - p| = 0.1 |1 - p|, a real slow mode (paper eq. 30)
    assert model_warnings(_model([1.0, -0.99], [0.0, 1.0, -0.991], [1.35, -0.0065])) == ()


def test_near_cancellation_is_flagged() -> None:
    # |z - p| = 1e-4 = 0.001 |1 - p|: the mode carries 0.1 % of the static response
    warnings = model_warnings(_model([1.0, -0.9], [0.0, 1.0, -0.9001], [1.0]))
    assert len(warnings) == 1 and "nearly cancels pole z = 0.90000" in warnings[0]


def test_ill_conditioned_normalization_and_non_minimum_phase_are_flagged() -> None:
    # TCLab-like B = q^-1 + 105 q^-2: the zero at -105 is outside the unit circle too
    warnings = model_warnings(_model([1.0, -0.95], [0.0, 1.0, 105.0], [0.01]))
    assert any("105 times larger" in w for w in warnings)
    assert any("zero z = -105.00000" in w and "outside the unit circle" in w for w in warnings)


def test_negative_gain_and_near_integrator_are_flagged() -> None:
    warnings = model_warnings(_model([1.0, -0.999999], [0.0, 1.0], [-0.5]))
    assert any("within 1e-05 of the unit circle" in w for w in warnings)
    assert any("static gain at the operating point is -5e+05" in w for w in warnings)


def test_show_model_prints_units_of_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    obj = json.loads(shipped_path("cz_heater_model.json").read_text(encoding="utf-8"))
    obj["units"] = {"input": "V", "output": "degC"}
    path = tmp_path / "m.json"
    path.write_text(json.dumps(obj), encoding="utf-8")
    assert main(["show-model", str(path)]) == 0
    out = capsys.readouterr().out
    assert "units: input V, output degC\n" in out
    assert "noise std(e) = 0.01341 degC" in out and "kW" not in out


def test_show_model_draws_step_bode_and_poles_with_bands_and_exports_a_mat(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import scipy.io

    code = main(["show-model", str(shipped_path("cz_heater_model.json")), "--plot",
                 str(tmp_path / "fig"), "--levels-pct", "40", "55", "--draws", "50",
                 "--export-mat", str(tmp_path / "mat" / "model.mat")])
    assert code == 0
    out = capsys.readouterr().out
    assert "percentiles of 50 models drawn from the parameter covariance" in out
    for name in ("step.png", "bode.png", "poles_zeros.png"):
        assert (tmp_path / "fig" / name).stat().st_size > 10_000, name
    mat = scipy.io.loadmat(tmp_path / "mat" / "model.mat")
    assert mat["levels"].ravel().tolist() == [40.0, 55.0]
    assert "wrote" in out and "linearized at 40, 55 %" in out


def test_show_model_without_draws_says_there_are_no_bands(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["show-model", str(shipped_path("cz_heater_model.json")), "--plot",
                 str(tmp_path), "--draws", "0"]) == 0
    assert "no bands (no draws asked for)" in capsys.readouterr().out
