"""The run-config and campaign-spec references document exactly what the validators accept."""

from __future__ import annotations

import sys
from ast import literal_eval
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from czmpc.campaigns.campaign import CampaignError, spec_from_dict
from czmpc.runtime.config import RunConfigError, run_config_from_dict
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def contracts() -> ModuleType:
    sys.path.insert(0, str(REPO / "docs" / "_ext"))
    try:
        import czmpc_contracts  # noqa: F401
    finally:
        sys.path.remove(str(REPO / "docs" / "_ext"))
    return sys.modules["czmpc_contracts"]


def _minimal_run_config() -> dict[str, Any]:
    return {"plant": {"endpoint": "opc.tcp://127.0.0.1:4840/czmpc/", "ts_s": 2.0},
            "nodes": {"power_kw": "ns=2;s=Heater.Power", "triac_pct": "ns=2;s=Heater.TriacCommand"},
            "controller": {"model": "model.json"},
            "run": {"setpoint_kw": 45.0}}


def _full_run_config(tmp_path: Path) -> dict[str, Any]:
    """Every documented key with a valid value (run.schedule separately: it excludes setpoint_kw)."""
    doc = _minimal_run_config()
    doc["plant"].update(time_scale=20.0, max_sample_age_s=4.0, connect_timeout_s=1.0,
                        security={"policy": "None"})
    doc["nodes"].update(applied_triac_pct="ns=2;s=A", setpoint_kw="ns=2;s=S",
                        heartbeat="ns=2;s=H", mode="ns=2;s=M", model_health="ns=2;s=MH")
    doc["controller"].update(settings="settings.toml", candidate="new.json")
    doc["run"].update(duration_s=10.0, log="log.csv")
    doc["safety"] = {"action": "ramp", "safe_triac_pct": 20.0}
    return doc


def test_documented_run_config_keys_are_the_validators(contracts: ModuleType, tmp_path: Path) -> None:
    from czmpc.runtime.config import _TABLES

    accepted = {f"{t}.{k}" for t, keys in _TABLES.items() for k in keys}
    assert set(contracts.RUN_CONFIG_KEYS) == accepted
    rst = contracts.run_config_rst()
    for table, keys in _TABLES.items():
        assert f"``[{table}]``" in rst
        assert all(f"   * - ``{key}``" in rst for key in keys)
    # every documented key is accepted ...
    full = _full_run_config(tmp_path)
    config = run_config_from_dict(full, base_dir=tmp_path)
    assert config.time_scale == 20.0 and config.period_s == pytest.approx(0.1)
    (tmp_path / "recipe.csv").write_text("time_s,setpoint_kw\n0,40\n100,45\n", encoding="utf-8")
    del full["run"]["setpoint_kw"]
    full["run"]["schedule"] = "recipe.csv"
    assert run_config_from_dict(full, base_dir=tmp_path).schedule is not None
    # ... and an undocumented one is refused, by name
    for table in _TABLES:
        doc = _minimal_run_config()
        doc.setdefault(table, {})["colour"] = "red"
        with pytest.raises(RunConfigError, match=rf"{table}\.colour: unknown key"):
            run_config_from_dict(doc, base_dir=tmp_path)


def test_a_candidate_needs_an_active_model(tmp_path: Path) -> None:
    doc = _minimal_run_config()
    assert run_config_from_dict(doc, base_dir=tmp_path).candidate_path is None
    doc["controller"]["candidate"] = "new.json"
    assert run_config_from_dict(doc, base_dir=tmp_path).candidate_path == tmp_path / "new.json"
    del doc["controller"]["model"]          # a candidate beside no active model
    with pytest.raises(RunConfigError, match="controller.model: missing"):
        run_config_from_dict(doc, base_dir=tmp_path)


def test_documented_required_run_config_keys_are_required(contracts: ModuleType, tmp_path: Path) -> None:
    required = {k for k, v in contracts.RUN_CONFIG_KEYS.items() if v[1] == "required"}
    assert required == {"plant.endpoint", "plant.ts_s", "nodes.power_kw", "nodes.triac_pct",
                        "controller.model"}
    for dotted in required:
        table, key = dotted.split(".")
        doc = _minimal_run_config()
        del doc[table][key]
        with pytest.raises(RunConfigError, match=rf"{table}\.{key}"):
            run_config_from_dict(doc, base_dir=tmp_path)


def test_documented_run_config_defaults_are_the_validators(contracts: ModuleType, tmp_path: Path) -> None:
    keys = contracts.RUN_CONFIG_KEYS
    config = run_config_from_dict(_minimal_run_config(), base_dir=tmp_path)
    assert config.time_scale == float(keys["plant.time_scale"][1])
    assert config.connect_timeout_s == float(keys["plant.connect_timeout_s"][1])
    assert keys["plant.max_sample_age_s"][1] == "2 ts_s" and config.max_sample_age_s == 2 * config.ts_s
    assert config.log_path == tmp_path / keys["run.log"][1]
    assert config.safe_action == keys["safety.action"][1]
    assert config.duration_s is None and config.settings_path is None
    assert config.security.policy == "None"


def test_a_run_config_drift_stops_the_docs_build(contracts: ModuleType,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    from sphinx.errors import ExtensionError

    monkeypatch.delitem(contracts.RUN_CONFIG_KEYS, "safety.safe_triac_pct")
    with pytest.raises(ExtensionError, match="safe_triac_pct"):
        contracts.run_config_rst()


def _minimal_spec() -> dict[str, Any]:
    return {"scenarios": ["staircase"], "controllers": [{"preset": "mpc"}], "plants": [{"kind": "model"}]}


def test_documented_campaign_keys_are_the_validators(contracts: ModuleType) -> None:
    accepted = contracts.accepted_campaign_keys()
    assert set(accepted["top"]) == set(contracts.CAMPAIGN_KEYS)
    assert set(accepted["controllers"]) == set(contracts.CAMPAIGN_CONTROLLER_KEYS)
    assert set(accepted["plants"]) == set(contracts.CAMPAIGN_PLANT_KEYS)
    assert accepted["plants-other"] == ["kind"]
    rst = contracts.campaign_spec_rst()
    for table in (contracts.CAMPAIGN_KEYS, contracts.CAMPAIGN_CONTROLLER_KEYS,
                  contracts.CAMPAIGN_PLANT_KEYS):
        assert all(f"   * - ``{key}``" in rst for key in table)
    # every documented top-level and plant key is accepted together
    spec = spec_from_dict({
        "name": "all", "model": HAMMERSTEIN_MODEL_JSON, "seeds": 2, "base_seed": 3, "noise": False,
        "time_scale": 0.5, "scenarios": ["staircase"],
        "controllers": [{"name": "a", "preset": "mpc"}, {"name": "b", "preset": "pi"}],
        "plants": [{"kind": "perturbed", "gain_factors": [0.8, 1.2], "time_constant_factors": [2.0],
                    "extra_delays_steps": [0, 1]}]})
    assert len(spec.expand()) == 2 * 4 * 1 * 2


def test_documented_required_campaign_keys_and_defaults_are_the_validators(
        contracts: ModuleType, tmp_path: Path) -> None:
    keys = contracts.CAMPAIGN_KEYS
    assert {k for k, v in keys.items() if v[1] == "required"} == {"scenarios", "controllers", "plants"}
    for key in ("scenarios", "controllers", "plants"):
        doc = _minimal_spec()
        del doc[key]
        with pytest.raises(CampaignError, match=key):
            spec_from_dict(doc)
    spec = spec_from_dict(_minimal_spec(), source=str(tmp_path / "mine.toml"), base_dir=tmp_path)
    assert spec.name == "mine"                              # "the file's stem"
    assert Path(spec.model_path) == shipped_path(keys["model"][1])
    assert spec.seeds == int(keys["seeds"][1]) and spec.base_seed == int(keys["base_seed"][1])
    assert spec.noise is (keys["noise"][1] == "true")
    assert spec.time_scale == float(keys["time_scale"][1])
    plants = spec_from_dict({**_minimal_spec(), "plants": [{"kind": "perturbed"}]}).plants
    plant_keys = contracts.CAMPAIGN_PLANT_KEYS
    documented = tuple(literal_eval(plant_keys[k][1])[0]
                       for k in ("gain_factors", "time_constant_factors", "extra_delays_steps"))
    assert [(p.gain_factor, p.time_constant_factor, p.extra_delay_steps) for p in plants] == [documented]
    controllers = spec_from_dict(_minimal_spec()).controllers
    assert controllers[0].name == "mpc" and contracts.CAMPAIGN_CONTROLLER_KEYS["name"][1] == "the preset"


def test_a_campaign_spec_drift_stops_the_docs_build(contracts: ModuleType,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    from sphinx.errors import ExtensionError

    monkeypatch.setitem(contracts.CAMPAIGN_PLANT_KEYS, "colour", ("string", "-", "not a key"))
    with pytest.raises(ExtensionError, match="colour"):
        contracts.campaign_spec_rst()


def test_a_controller_settings_file_is_read_into_the_spec(contracts: ModuleType,
                                                         tmp_path: Path) -> None:
    # The reference says [[controllers]] settings names an MPC settings file: the
    # validator reads it (a missing file is refused naming it) and keeps its path.
    assert ":doc:`settings_file`" in contracts.CAMPAIGN_CONTROLLER_KEYS["settings"][2]
    doc = {**_minimal_spec(), "controllers": [{"preset": "mpc", "settings": "mine.toml"}]}
    with pytest.raises(CampaignError, match="mine.toml: cannot read the settings file"):
        spec_from_dict(doc, base_dir=tmp_path)
    (tmp_path / "mine.toml").write_text("move_weight = 0.5\n", encoding="utf-8")
    spec = spec_from_dict(doc, base_dir=tmp_path)
    assert spec.controllers[0].settings_path.endswith("mine.toml")


def _shipped_model() -> Any:
    from sysid.modelfile import load_model

    return load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))


def test_documented_settings_keys_are_the_readers(contracts: ModuleType) -> None:
    from czmpc.errors import SettingsError
    from czmpc.settings_file import TABLES, settings_from_dict

    keys = contracts.settings_keys()
    accepted = contracts.accepted_settings_keys()
    assert [r[0].strip("`") for r in keys[""]] + list(TABLES) == accepted[""]
    for table in TABLES:
        assert [r[0].strip("`") for r in keys[table]] == accepted[table]
    rst = contracts.settings_file_rst()
    assert all(f"``[{t}]``" in rst for t in TABLES)
    assert all(row[4].strip(".") for rows in keys.values() for row in rows)   # every key means something
    with pytest.raises(SettingsError, match="colour"):
        settings_from_dict({"reliability": {"colour": 1}}, _shipped_model())


def _toml_scalar(text: str) -> Any:
    """A documented default back as the TOML value it stands for."""
    value = text.removesuffix(" (from the model)")
    return literal_eval(value) if value not in ("true", "false", "off") and not value.isalpha() else (
        {"true": True, "false": False}.get(value, value))


def test_documented_settings_defaults_are_what_the_reader_builds(contracts: ModuleType) -> None:
    # A file that writes every documented default explicitly gives the default settings.
    from czmpc.settings import MPCSettings
    from czmpc.settings_file import settings_from_dict

    keys = contracts.settings_keys()
    doc: dict[str, Any] = {}
    for table, rows in keys.items():
        target = doc if not table else doc.setdefault(table, {})
        for key, _, default, _, _ in rows:
            target[key.strip("`")] = _toml_scalar(default)
    model = _shipped_model()
    assert settings_from_dict(doc, model) == MPCSettings.default_for(model)
    # and "(from the model)" marks exactly the values default_for derives from the model
    derived = {r[0].strip("`") for rows in keys.values() for r in rows if "from the model" in r[2]}
    assert derived == {"horizon_steps", "max_move_pct_per_step"}
    changed = dict(doc, horizon_steps=doc["horizon_steps"] + 1)
    assert settings_from_dict(changed, model) != MPCSettings.default_for(model)


def test_a_settings_key_without_a_meaning_stops_the_docs_build(
        contracts: ModuleType, monkeypatch: pytest.MonkeyPatch) -> None:
    from sphinx.errors import ExtensionError

    from czmpc import settings_file

    real = settings_file.field_docs
    monkeypatch.setattr(settings_file, "field_docs",
                        lambda cls: {k: v for k, v in real(cls).items() if k != "move_weight"})
    with pytest.raises(ExtensionError, match="move_weight"):
        contracts.settings_file_rst()
