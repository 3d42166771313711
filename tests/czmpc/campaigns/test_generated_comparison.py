"""czmpc.campaigns.generated_comparison and ``czmpc simulate --controller c:DIR``: the C step
in closed loop beside the Python MPC it was generated from."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from czmpc.campaigns.generated_comparison import compare_generated
from czmpc.cli import main
from czmpc.codegen.errors import CodegenError
from czmpc.errors import SettingsError
from czmpc.settings import MPCSettings
from sim.scenario import load_scenario
from sysid.model import HammersteinModel
from sysid.modelfile import model_to_dict


def test_the_c_step_follows_the_python_mpc_through_a_voltage_sag_with_the_recipe_known(
        generated_step: Path, shipped_model: HammersteinModel) -> None:
    # The heater (model mismatch, noise), the sag measured and the recipe 60 s ahead:
    # every stage of the step runs. Measured: 1.4e-14 % apart, statuses equal.
    scenario = dataclasses.replace(load_scenario("voltage_sag").shortened(0.2),
                                   setpoint_preview_s=60.0, measured_voltage=True)
    cmp = compare_generated(shipped_model, generated_step, scenario, plant="heater", seed=3, noise=True)
    assert cmp.n_steps == 360
    assert cmp.max_triac_difference_pct < 1e-6
    assert cmp.first_difference_k is None
    assert cmp.status_differences == 0
    assert cmp.bit_equal_steps > 0
    assert not cmp.float32
    iae_c, iae_py = cmp.c_step.metrics.iae_kw_s, cmp.mpc.metrics.iae_kw_s
    assert iae_c == pytest.approx(iae_py, rel=1e-9)
    assert cmp.c_step.controller == "c_step" and cmp.mpc.controller == "mpc"
    assert "mode, status or fallback differ at 0 samples" in cmp.table()


def test_a_step_of_another_model_or_other_limits_is_refused(
        generated_step: Path, shipped_model: HammersteinModel) -> None:
    scenario = load_scenario("staircase").shortened(0.05)
    other = dataclasses.replace(shipped_model, noise_std_kw=2 * shipped_model.noise_std_kw)
    with pytest.raises(SettingsError, match="another model"):
        compare_generated(other, generated_step, scenario, plant="model", seed=0, noise=False)
    narrow = dataclasses.replace(scenario, triac_limits_pct=(20.0, 70.0))
    with pytest.raises(SettingsError, match=r"triac_max_pct 100\.0 -> 70\.0.*--settings"):
        compare_generated(shipped_model, generated_step, narrow, plant="model", seed=0, noise=False)
    with pytest.raises(CodegenError, match="not a directory written by 'czmpc codegen'"):
        compare_generated(shipped_model, generated_step / "nowhere", scenario, plant="model", seed=0,
                          noise=False)


def test_simulate_runs_the_c_step_beside_the_mpc_and_writes_both(
        generated_step: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sim"
    rc = main(["simulate", "--model", str(generated_step / "model.json"), "--scenario", "staircase",
               "--short", "0.1", "--plant", "model", "--controller", f"c:{generated_step}",
               "--out", str(out)])
    text = capsys.readouterr().out
    assert rc == 0
    assert "C step (double) against the Python MPC over 390 samples" in text
    for name in ("c_step", "mpc"):
        assert (out / name / "trajectory.csv").is_file()
    header = (out / "c_step" / "trajectory.csv").read_text().splitlines()[0]
    assert header.endswith("mode,status,solver_status,fallback")
    rc = main(["simulate", "--model", str(generated_step / "model.json"), "--scenario", "staircase",
               "--controller", f"c:{generated_step}", "--preset", "smooth", "--out", str(out)])
    assert rc == 2
    assert "drop --settings/--preset" in capsys.readouterr().err


def test_the_directory_keeps_the_model_and_settings_it_was_generated_from(
        generated_step: Path, shipped_model: HammersteinModel) -> None:
    from czmpc.codegen.generate import read_sources

    model, settings = read_sources(generated_step)
    assert settings == MPCSettings.default_for(shipped_model)
    assert model_to_dict(model) == model_to_dict(shipped_model)
