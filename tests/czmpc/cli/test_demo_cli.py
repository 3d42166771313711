"""`czmpc demo` runs the whole job end to end and says what it found."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from czmpc.cli import main
from sysid.modelfile import load_model


@pytest.mark.slow
def test_demo_runs_experiment_identification_and_both_closed_loops(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)   # the shipped data is package data: no source tree needed
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "identical to the shipped cz_heater_experiment.csv" in text
    assert text.count("[x]") == 5 and "[ ]" not in text          # all five paper findings
    model = load_model(out / "identify" / "model.json")
    assert model.kind == "hammerstein" and model.linear_block == "armax"
    for plant in ("model", "heater"):
        metrics = json.loads((out / f"simulate-{plant}" / "metrics.json").read_text())
        assert metrics["metrics"]["n_constraint_violations"] == 0
        assert (out / f"simulate-{plant}" / "figure.png").stat().st_size > 10_000
    heater = json.loads((out / "simulate-heater" / "metrics.json").read_text())["metrics"]
    # zero mean offset on the mismatched plant: heater noise 0.0105 kW over a quarter
    # segment of 225 samples gives a standard error of 0.0007 kW; 0.01 kW is 14 of them
    assert max(abs(c["steady_state_error_kw"]) for c in heater["changes"]) < 0.01
