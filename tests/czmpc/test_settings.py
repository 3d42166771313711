"""MPCSettings and OSQPOptions: validation, defaults from a model, presets."""

from __future__ import annotations

import dataclasses
import math

import pytest

from czmpc.errors import SettingsError
from czmpc.settings import MPCSettings, OSQPOptions
from sysid.model import HammersteinModel


def test_default_for_paper_model_covers_30_percent_of_the_slow_mode(
    paper_armax_model: HammersteinModel,
) -> None:
    settings = MPCSettings.default_for(paper_armax_model)
    tau_steps = -1.0 / math.log(0.99)  # slow pole of A(q) = 1 - 0.99 q^-1
    assert settings.horizon_steps == math.ceil(0.3 * tau_steps) == 30
    assert settings.disturbance_model == "output"


def test_default_for_fast_model_uses_minimum_horizon(
    paper_oe_model: HammersteinModel,
) -> None:
    fast = paper_oe_model.with_updates(a=[1.0, -0.5], c=[1.0, -0.5])
    assert MPCSettings.default_for(fast).horizon_steps == 10


@pytest.mark.parametrize("name", ["default", "aggressive", "smooth"])
def test_presets_are_valid_and_share_the_model_horizon(
    name: str, paper_oe_model: HammersteinModel
) -> None:
    preset = MPCSettings.preset(name, paper_oe_model)  # type: ignore[arg-type]
    assert preset.horizon_steps == MPCSettings.default_for(paper_oe_model).horizon_steps


def test_aggressive_preset_penalizes_moves_less_than_smooth(
    paper_oe_model: HammersteinModel,
) -> None:
    aggressive = MPCSettings.preset("aggressive", paper_oe_model)
    smooth = MPCSettings.preset("smooth", paper_oe_model)
    assert aggressive.move_weight < MPCSettings().move_weight < smooth.move_weight


def test_unknown_preset_is_refused(paper_oe_model: HammersteinModel) -> None:
    with pytest.raises(SettingsError, match=r"preset: name must be one of .*got 'fast'"):
        MPCSettings.preset("fast", paper_oe_model)  # type: ignore[arg-type]


def test_settings_are_frozen() -> None:
    settings = MPCSettings()
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.horizon_steps = 3  # type: ignore[misc]


def test_with_updates_validates_again() -> None:
    with pytest.raises(SettingsError, match="horizon_steps"):
        MPCSettings().with_updates(horizon_steps=-2)


@pytest.mark.parametrize(
    ("changes", "pattern"),
    [
        ({"horizon_steps": 0}, r"MPCSettings\.horizon_steps must be an int >= 1; got 0"),
        ({"horizon_steps": 2.0}, r"horizon_steps must be an int >= 1; got 2\.0"),
        ({"horizon_steps": True}, r"horizon_steps must be an int >= 1; got True"),
        ({"output_weight": 0.0}, r"output_weight must be a number > 0; got 0\.0"),
        ({"move_weight": -1.0}, r"move_weight must be a number >= 0; got -1\.0"),
        ({"input_target_weight": math.nan}, r"input_target_weight must be a finite number"),
        ({"move_weight": 0.0, "input_target_weight": 0.0},
         r"move_weight \+ input_target_weight must be > 0"),
        ({"disturbance_model": "state"}, r"disturbance_model must be 'input' or 'output'"),
        ({"disturbance_noise": 0.0}, r"disturbance_noise must be a number > 0; got 0\.0"),
        ({"triac_min_pct": 50.0, "triac_max_pct": 40.0},
         r"expected 0 <= triac_min_pct < triac_max_pct <= 100"),
        ({"triac_max_pct": 120.0}, r"triac_max_pct <= 100 .*got .*120\.0"),
        ({"triac_min_pct": -1.0}, r"triac_min_pct must be a number >= 0"),
        ({"validity_margin_pct": -0.5}, r"validity_margin_pct must be a number >= 0"),
        ({"max_move_pct_per_step": 0.0}, r"max_move_pct_per_step must be a number > 0"),
        ({"soft_power_min_kw": 50.0, "soft_power_max_kw": 40.0},
         r"expected soft_power_min_kw < soft_power_max_kw"),
        ({"soft_power_max_kw": math.inf}, r"soft_power_max_kw must be a finite number"),
        ({"soft_limit_weight": 0.0}, r"soft_limit_weight must be a number > 0"),
        ({"initial_triac_pct": 101.0, "triac_max_pct": 90.0},
         r"initial_triac_pct must lie within \[triac_min_pct, triac_max_pct\]"),
        ({"osqp": {"eps_abs": 1e-5}}, r"osqp must be an OSQPOptions"),
    ],
    ids=lambda v: str(v) if isinstance(v, dict) else "",
)
def test_invalid_settings_are_refused_with_a_clear_message(
    changes: dict[str, object], pattern: str
) -> None:
    with pytest.raises(SettingsError, match=pattern):
        MPCSettings(**changes)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("changes", "pattern"),
    [
        ({"eps_abs": 0.0}, r"OSQPOptions\.eps_abs must be a number > 0; got 0\.0"),
        ({"eps_rel": math.nan}, r"OSQPOptions\.eps_rel must be a finite number"),
        ({"max_iter": 0}, r"OSQPOptions\.max_iter must be an int >= 1; got 0"),
        ({"polishing": 1}, r"OSQPOptions\.polishing must be a bool; got 1"),
        ({"time_limit_s": -1.0}, r"OSQPOptions\.time_limit_s must be a number > 0"),
        ({"check_termination": 0}, r"check_termination must be an int >= 1"),
        ({"adaptive_rho_interval": 0}, r"adaptive_rho_interval must be an int >= 1"),
    ],
    ids=lambda v: str(v) if isinstance(v, dict) else "",
)
def test_invalid_osqp_options_are_refused(changes: dict[str, object], pattern: str) -> None:
    with pytest.raises(SettingsError, match=pattern):
        OSQPOptions(**changes)  # type: ignore[arg-type]


def test_settings_error_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="horizon_steps"):
        MPCSettings(horizon_steps=0)


def test_flags_report_optional_constraints() -> None:
    assert not MPCSettings().has_rate_limit
    assert not MPCSettings().has_soft_power_limits
    assert MPCSettings(max_move_pct_per_step=2.0).has_rate_limit
    assert MPCSettings(soft_power_min_kw=30.0).has_soft_power_limits
