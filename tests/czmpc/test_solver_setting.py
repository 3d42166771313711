"""MPCSettings.solver: validation, the settings file and `czmpc settings`, the missing extra."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

import pytest

from czmpc.cli import main
from czmpc.controller import OffsetFreeMPC
from czmpc.errors import SettingsError
from czmpc.qp import MPCQP
from czmpc.qp_daqp import DAQPMPCQP
from czmpc.settings import MPCSettings
from czmpc.settings_file import load_settings, settings_from_dict, settings_to_toml
from sysid.model import HammersteinModel

PIP_HINT = "pip install 'czmpc[daqp]'"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "settings.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_osqp_is_the_default_and_an_unknown_solver_is_refused_by_name() -> None:
    assert MPCSettings().solver == "osqp"
    with pytest.raises(SettingsError) as info:
        MPCSettings(solver="qpoases")  # type: ignore[arg-type]
    message = str(info.value)
    assert "MPCSettings.solver must be 'osqp'" in message and "'daqp'" in message
    assert "got 'qpoases'" in message and PIP_HINT in message


def test_the_setting_chooses_the_qp_class(shipped_model: HammersteinModel) -> None:
    pytest.importorskip("daqp")
    default = MPCSettings.default_for(shipped_model)
    assert type(OffsetFreeMPC(shipped_model, default).qp) is MPCQP
    assert type(OffsetFreeMPC(shipped_model, default.with_updates(solver="daqp")).qp) is DAQPMPCQP


def test_the_solver_key_round_trips_through_the_settings_file(
        tmp_path: Path, shipped_model: HammersteinModel) -> None:
    settings = MPCSettings.default_for(shipped_model).with_updates(solver="daqp")
    text = settings_to_toml(settings)
    (line,) = [row for row in text.splitlines() if row.startswith("solver = ")]
    assert line.startswith('solver = "daqp"') and "# The QP solver" in line
    assert load_settings(_write(tmp_path, text), shipped_model) == settings
    # Left out, it is the preset's: OSQP.
    assert settings_from_dict({}, shipped_model).solver == "osqp"
    assert settings_from_dict({"solver": "daqp"}, shipped_model) == settings


@pytest.mark.parametrize("value", ['"DAQP"', '"gurobi"', "1"])
def test_a_bad_solver_in_a_file_names_the_file_the_key_and_the_choices(
        value: str, tmp_path: Path, shipped_model: HammersteinModel) -> None:
    path = _write(tmp_path, f"solver = {value}\n")
    with pytest.raises(SettingsError) as info:
        load_settings(path, shipped_model)
    assert str(info.value) == (f"{path}: solver must be one of ['osqp', 'daqp']; "
                               f"got {tomllib.loads(f'v = {value}')['v']!r}")


def test_czmpc_settings_explains_the_key_and_a_file_with_daqp_reads_back(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("daqp")
    assert main(["settings", "--show"]) == 0
    shown = capsys.readouterr().out
    (line,) = [row for row in shown.splitlines() if row.startswith("solver = ")]
    assert line.split("#")[0].strip() == 'solver = "osqp"'
    assert line.split("#", 1)[1].strip().startswith('The QP solver: "osqp" (ADMM')
    assert '"daqp" (dual active set, exact, from the daqp extra)' in line
    path = _write(tmp_path, shown.replace('solver = "osqp"', 'solver = "daqp"', 1))
    assert main(["settings", "--settings", str(path), "--no-comments"]) == 0
    assert 'solver = "daqp"\n' in capsys.readouterr().out


# --- the optional extra ------------------------------------------------------------------------
def test_daqp_missing_names_the_extra_and_osqp_still_builds(
        shipped_model: HammersteinModel, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "daqp", None)   # `import daqp` raises ImportError
    settings = MPCSettings.default_for(shipped_model)
    with pytest.raises(SettingsError) as info:
        OffsetFreeMPC(shipped_model, settings.with_updates(solver="daqp"))
    assert str(info.value) == ("MPCSettings.solver = 'daqp' needs the package daqp, which is "
                               f"not installed: {PIP_HINT}")
    assert isinstance(info.value.__cause__, ImportError)
    assert OffsetFreeMPC(shipped_model, settings).step(45.0, 46.0) > 45.0


def test_daqp_missing_exits_2_from_the_command_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "daqp", None)
    path = _write(tmp_path, 'solver = "daqp"\n')
    assert main(["settings", "--settings", str(path)]) == 2
    err = capsys.readouterr().err
    assert PIP_HINT in err and "Traceback" not in err
