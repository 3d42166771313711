"""The generated references document exactly what the validators accept."""

from __future__ import annotations

import copy
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from czmpc.cli import main
from czmpc.cli._exit import MEANING, ExitCode
from czmpc.shipped import EXPERIMENT_CSV, HAMMERSTEIN_MODEL_JSON, shipped_path
from sysid import DataFileError, ModelFileError, read_csv
from sysid.data import CSV_COLUMNS
from sysid.modelfile import model_from_dict, model_to_dict

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def contracts() -> ModuleType:
    sys.path.insert(0, str(REPO / "docs" / "_ext"))
    try:
        import czmpc_contracts
    finally:
        sys.path.remove(str(REPO / "docs" / "_ext"))
    return czmpc_contracts


@pytest.fixture
def shipped_model() -> dict[str, Any]:
    obj: dict[str, Any] = json.loads(shipped_path(HAMMERSTEIN_MODEL_JSON).read_text(encoding="utf-8"))
    return obj


def test_every_documented_model_key_is_accepted_and_needed_as_documented(
    contracts: ModuleType, shipped_model: dict[str, Any]
) -> None:
    full = model_to_dict(model_from_dict(shipped_model))
    assert set(full) <= set(contracts.MODEL_KEYS)       # the writer writes only documented keys
    assert set(contracts.MODEL_KEYS) - set(full) == {"units"}   # optional, absent here
    model_from_dict(full)                               # and the reader accepts them all
    rst = contracts.model_file_rst()
    for key in full:
        partial = copy.deepcopy(full)
        del partial[key]
        required = f"   * - ``{key}``\n     - yes" in rst
        if required:
            with pytest.raises(ModelFileError, match=key):
                model_from_dict(partial)
        else:
            model_from_dict(partial)


def test_an_undocumented_model_key_is_ignored_as_documented(contracts: ModuleType,
                                                            shipped_model: dict[str, Any]) -> None:
    # DESIGN.md: readers ignore what they do not know (optional fields may be added).
    assert "colour" not in contracts.MODEL_KEYS and "are ignored" in contracts.model_file_rst()
    model = model_from_dict({**shipped_model, "colour": "red"})
    assert "colour" not in model_to_dict(model)


def test_documented_provenance_entries_are_the_written_ones(contracts: ModuleType,
                                                           shipped_model: dict[str, Any]) -> None:
    written = model_to_dict(model_from_dict(shipped_model))["provenance"]
    assert set(contracts.PROVENANCE_KEYS) <= set(written)


def test_documented_data_columns_are_the_readers(contracts: ModuleType, tmp_path: Path) -> None:
    assert tuple(contracts.DATA_COLUMNS) == CSV_COLUMNS
    header, *rows = shipped_path(EXPERIMENT_CSV).read_text(encoding="utf-8").splitlines()[:50]
    assert header == ",".join(contracts.DATA_COLUMNS)
    renamed = tmp_path / "renamed.csv"
    renamed.write_text("\n".join(["t,triac_pct,power_kw", *rows]) + "\n", encoding="utf-8")
    with pytest.raises(DataFileError, match="time_s"):
        read_csv(renamed)


def test_a_drift_stops_the_docs_build(contracts: ModuleType, monkeypatch: pytest.MonkeyPatch) -> None:
    from sphinx.errors import ExtensionError

    monkeypatch.setitem(contracts.MODEL_KEYS, "colour", "not a key")
    with pytest.raises(ExtensionError, match="colour"):
        contracts.model_file_rst()


def test_documented_exit_codes_are_what_the_cli_returns(
    contracts: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert set(MEANING) == set(ExitCode)
    rst = contracts.exit_codes_rst()
    for code in ExitCode:
        assert f"   * - {int(code)}\n     - ``{code.name}``" in rst
    assert main(["inspect", str(tmp_path / "missing.csv")]) == ExitCode.BAD_INPUT == 2
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,triac_pct,power_kw\n0,45,45\n2,x,45\n", encoding="utf-8")
    assert main(["inspect", str(bad)]) == ExitCode.BAD_INPUT
    assert capsys.readouterr().err.startswith("czmpc: error: ")
    assert "`sysid.DataFileError`" in rst and "`czmpc.SettingsError`" in rst


def test_documented_plant_security_keys_are_the_validators(contracts: ModuleType, tmp_path: Path) -> None:
    from czmpc.errors import SettingsError
    from czmpc.runtime.security import SECURITY_KEYS, parse_security

    assert tuple(contracts.PLANT_SECURITY_KEYS) == SECURITY_KEYS
    rst = contracts.plant_security_rst()
    assert all(f"``{key}``" in rst for key in SECURITY_KEYS)
    with pytest.raises(SettingsError, match="colour"):
        parse_security({"policy": "None", "colour": "red"}, endpoint="opc.tcp://127.0.0.1:4840",
                       base_dir=tmp_path)
