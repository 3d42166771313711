"""The settings TOML file: round trip, every key checked, the CLI that reads and shows it."""

from __future__ import annotations

import dataclasses
import json
import tomllib
from pathlib import Path

import pytest

from czmpc.cli import main
from czmpc.controller import OffsetFreeMPC
from czmpc.errors import SettingsError
from czmpc.settings import DEFAULT_RATE_FRACTION_OF_RANGE, MPCSettings
from czmpc.settings_file import (
    OFF,
    TABLES,
    field_docs,
    load_settings,
    settings_from_dict,
    settings_to_toml,
)
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sysid.model import HammersteinModel
from sysid.modelfile import load_model


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "settings.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("preset", ["default", "aggressive", "smooth"])
def test_the_shown_file_reads_back_to_the_same_settings(
    preset: str, shipped_model: HammersteinModel) -> None:
    settings = MPCSettings.preset(preset, shipped_model)  # type: ignore[arg-type]
    settings = settings.with_updates(soft_power_max_kw=60.0, initial_triac_pct=45.0)
    for comments in (True, False):
        text = settings_to_toml(settings, comments=comments)
        assert settings_from_dict(tomllib.loads(text), shipped_model) == settings


def test_every_field_of_every_table_is_written_and_documented() -> None:
    text = settings_to_toml(MPCSettings())
    doc = tomllib.loads(text)
    for cls, table in [(MPCSettings, doc), *((c, doc[n]) for n, c in TABLES.items())]:
        names = {f.name for f in dataclasses.fields(cls)} - set(TABLES)
        assert set(table) - set(TABLES) == names
        assert names <= set(field_docs(cls)), f"{cls.__name__} fields without a docstring entry"


def test_keys_left_out_come_from_the_preset_and_the_model(
    shipped_model: HammersteinModel, tmp_path: Path) -> None:
    path = _write(tmp_path, 'preset = "smooth"\nhorizon_steps = 12\n[reliability]\n'
                            'shed_triac_pct = 30\n')
    settings = load_settings(path, shipped_model)
    smooth = MPCSettings.preset("smooth", shipped_model)
    assert settings.horizon_steps == 12
    assert settings.move_weight == smooth.move_weight == 1.0
    assert settings.reliability.shed_triac_pct == 30.0
    assert settings.max_move_pct_per_step == smooth.max_move_pct_per_step


def test_the_default_rate_limit_is_five_percent_of_the_identified_range(
    shipped_model: HammersteinModel) -> None:
    lo, hi = shipped_model.input_range_pct
    rate = MPCSettings.default_for(shipped_model).max_move_pct_per_step
    assert rate == pytest.approx(DEFAULT_RATE_FRACTION_OF_RANGE * (hi - lo))
    assert rate == pytest.approx(0.05 * (hi - lo)) and 1.0 < rate < 2.0  # 33..65 %: 1.6 %/step


def test_off_switches_an_optional_setting_off(shipped_model: HammersteinModel) -> None:
    settings = settings_from_dict({"max_move_pct_per_step": OFF}, shipped_model)
    assert settings.max_move_pct_per_step is None and not settings.has_rate_limit


@pytest.mark.parametrize(("doc", "message"), [
    ({"horizon": 30}, "unknown key 'horizon' (did you mean 'horizon_steps'?)"),
    ({"reliability": {"shed_pct": 3}}, "[reliability] unknown key 'shed_pct'"),
    ({"osqp": {"polishing": 1}}, "[osqp] polishing must be true or false"),
    ({"horizon_steps": 2.5}, "horizon_steps must be an integer"),
    ({"horizon_steps": 0}, "horizon_steps must be an int >= 1; got 0"),
    ({"move_weight": "off"}, "move_weight must be a number; got 'off'"),
    ({"max_move_pct_per_step": "none"}, 'max_move_pct_per_step must be a number, or "off"'),
    ({"max_move_pct_per_step": -1.0}, "max_move_pct_per_step must be a number > 0"),
    ({"disturbance_model": "state"}, "disturbance_model must be one of ['input', 'output']"),
    ({"preset": "fast"}, "preset must be one of ['default', 'aggressive', 'smooth']"),
    ({"reliability": 3}, "[reliability] must be a table"),
    ({"reliability": {"stuck_samples": 1}}, "stuck_samples must be 0 (off) or >= 2"),
    ({"triac_min_pct": 60, "triac_max_pct": 50}, "expected 0 <= triac_min_pct < triac_max_pct"),
    ({"soft_power_min_kw": float("nan")}, "soft_power_min_kw must be a finite number"),
])
def test_a_bad_setting_names_the_file_and_the_key(
    doc: dict[str, object], message: str, shipped_model: HammersteinModel) -> None:
    with pytest.raises(SettingsError) as info:
        settings_from_dict(doc, shipped_model, source="plant.toml")
    assert str(info.value).startswith("plant.toml: ")
    assert message in str(info.value)


def test_a_file_that_is_not_toml_or_missing_is_a_settings_error(
    shipped_model: HammersteinModel, tmp_path: Path) -> None:
    with pytest.raises(SettingsError, match="not valid TOML"):
        load_settings(_write(tmp_path, "horizon_steps = = 3"), shipped_model)
    with pytest.raises(SettingsError, match="cannot read the settings file"):
        load_settings(tmp_path / "absent.toml", shipped_model)


def test_the_first_move_stays_within_the_rate_limit_of_the_plants_input(
    shipped_model: HammersteinModel) -> None:
    """The README's first step(): a heater at 45 % asked for +5 kW moves by one rate step."""
    mpc = OffsetFreeMPC(shipped_model, initial_triac_pct=45.0)
    rate = mpc.settings.max_move_pct_per_step
    assert rate is not None
    first = mpc.step(power_kw=44.8, setpoint_kw=50.0)
    assert abs(first - 45.0) <= rate + 1e-9
    assert first > 45.0 + 0.5 * rate  # it does move towards the setpoint
    # The keyword is the settings field: both give the same controller output.
    via_settings = OffsetFreeMPC(shipped_model, MPCSettings.default_for(shipped_model)
                                 .with_updates(initial_triac_pct=45.0))
    assert via_settings.step(power_kw=44.8, setpoint_kw=50.0) == first


# --- the command line -------------------------------------------------------------------
def test_settings_show_prints_a_file_that_simulate_reads(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["settings", "--show", "--preset", "smooth"]) == 0
    shown = capsys.readouterr().out
    doc = tomllib.loads(shown)
    assert doc["move_weight"] == 1.0 and doc["max_move_pct_per_step"] == pytest.approx(1.6)
    path = _write(tmp_path, shown.replace("move_weight = 1.0", "move_weight = 0.5", 1))
    assert main(["settings", "--settings", str(path), "--no-comments"]) == 0
    assert "move_weight = 0.5\n" in capsys.readouterr().out
    out = tmp_path / "sim"
    assert main(["simulate", "--model", str(shipped_path(HAMMERSTEIN_MODEL_JSON)),
                 "--scenario", "staircase", "--short", "0.1", "--settings", str(path),
                 "--out", str(out)]) == 0
    used = json.loads((out / "metrics.json").read_text())["controller_settings"]
    assert used["move_weight"] == 0.5


def test_a_bad_settings_file_exits_2_naming_the_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path, "horizon_steps = 30\nmove_wieght = 0.2\n")
    for argv in (["settings", "--settings", str(path)],
                 ["simulate", "--model", str(shipped_path(HAMMERSTEIN_MODEL_JSON)),
                  "--scenario", "staircase", "--settings", str(path),
                  "--out", str(tmp_path / "sim")],
                 ["campaign", "run", str(_write_spec(tmp_path, path)), "--out",
                  str(tmp_path / "campaign")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "unknown key 'move_wieght' (did you mean 'move_weight'?)" in err
    assert not (tmp_path / "sim").exists() and not (tmp_path / "campaign").exists()


def _write_spec(tmp_path: Path, settings: Path) -> Path:
    spec = tmp_path / "spec.toml"
    spec.write_text(f'scenarios = ["staircase"]\n[[controllers]]\nsettings = "{settings.name}"\n'
                    '[[plants]]\nkind = "model"\n', encoding="utf-8")
    return spec


def test_settings_that_build_no_controller_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path, "triac_min_pct = 90\ntriac_max_pct = 95\n")
    assert main(["settings", "--settings", str(path)]) == 2
    assert "must overlap the TRIAC limits [90, 95] %" in capsys.readouterr().err


def test_the_example_run_config_names_a_settings_file_that_loads(
    shipped_model: HammersteinModel) -> None:
    from czmpc.runtime.config import load_run_config

    example = Path(__file__).resolve().parents[2] / "examples" / "plant_link" / "run.toml"
    config = load_run_config(example)
    assert config.settings_path is not None
    settings = load_settings(config.settings_path, load_model(config.model_path))
    assert settings.max_move_pct_per_step == 1.0
    assert settings.reliability.shed_triac_pct == 33.0
    OffsetFreeMPC(shipped_model, settings)
