"""``czmpc check-model``: exit codes, the printed reasons, the check file (the gate: test_session)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from czmpc.cli import main
from czmpc.shipped import shipped_path
from sysid.modelfile import load_model, save_model

EXPERIMENT = str(shipped_path("cz_heater_experiment.csv"))


def _wrong_delay_model(tmp_path: Path) -> Path:
    model = load_model(shipped_path("cz_heater_model.json"))
    path = tmp_path / "late.json"
    save_model(model.with_updates(b=np.concatenate([[0.0], model.b])), path)
    return path


def test_a_not_ready_model_exits_1_with_every_reason_and_a_check_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    path = _wrong_delay_model(tmp_path)
    code = main(["check-model", str(path), "--data", EXPERIMENT, "--mc-runs", "0"])
    assert code == 1
    out = capsys.readouterr().out
    assert out.startswith("verdict: not ready\n")
    assert "[     fail] input-residual correlation:" in out
    assert "[  skipped] closed-loop Monte Carlo:" in out
    doc = json.loads((tmp_path / "late.check.json").read_text(encoding="utf-8"))
    assert doc["verdict"] == "not ready"
    assert doc["format"] == "czmpc-model-check/1"


def test_missing_data_file_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["check-model", str(shipped_path("cz_heater_model.json")), "--data",
                 str(tmp_path / "nope.csv"), "--no-write"])
    assert code == 2
    assert "czmpc: error:" in capsys.readouterr().err
