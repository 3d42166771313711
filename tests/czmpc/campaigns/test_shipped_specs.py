"""The shipped bench and robustness specs: what they expand to, and their rows against
closed loops built by hand (same plant, controller and seed: IDENTITY_RTOL)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest

from czmpc.campaigns.campaign import CampaignError, execute_run, load_spec, spec_from_dict
from czmpc.campaigns.simulation import run_simulation
from czmpc.peers.pi import PIController
from czmpc.settings import MPCSettings
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sim.loop import run_closed_loop
from sim.metrics import compute_metrics
from sim.model_plant import ModelPlant
from sim.scenario import load_scenario
from sysid.modelfile import load_model
from tests.tolerances import IDENTITY_RTOL

SCALE = 0.02


def test_shipped_specs_expand_to_their_grids_with_one_seed() -> None:
    bench = load_spec(shipped_path("campaign_bench.toml"))
    assert len(bench.expand()) == 6 * 2 * 7
    assert {r.seed for r in bench.expand()} == {7}
    robust = load_spec(shipped_path("campaign_robustness.toml"))
    assert len(robust.expand()) == 5 * 3 * 2 + 1
    assert {r.seed for r in robust.expand()} == {1}


def test_bench_spec_mpc_on_the_heater_is_czmpc_simulate() -> None:
    spec = load_spec(shipped_path("campaign_bench.toml"), time_scale=SCALE, controllers=["mpc"])
    run = next(r for r in spec.expand()
               if r.plant.kind == "heater" and Path(r.scenario).stem == "staircase")
    row = execute_run(run)
    assert row["status"] == "ok", row["error"]
    ref = run_simulation(load_model(shipped_path(HAMMERSTEIN_MODEL_JSON)),
                         load_scenario("staircase").shortened(SCALE), plant="heater", seed=7)
    expected = compute_metrics(ref.result)
    assert row["seed"] == 7 and row["n_steps"] == ref.result.n_steps
    for key in ("iae_kw_s", "ise_kw2_s", "input_total_variation_pct"):
        assert row[key] == pytest.approx(getattr(expected, key), rel=IDENTITY_RTOL), key
    assert row["n_limit_violations"] == expected.n_limit_violations


def test_bench_spec_scheduled_pi_is_the_pi_tuned_by_hand() -> None:
    spec = load_spec(shipped_path("campaign_bench.toml"), time_scale=SCALE, controllers=["pi_gs"])
    run = next(r for r in spec.expand()
               if r.plant.kind == "model" and Path(r.scenario).stem == "large_step")
    row = execute_run(run)
    model = load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))
    scenario = load_scenario("large_step").shortened(SCALE)
    plant = ModelPlant.for_scenario(model, scenario)
    settings = MPCSettings.default_for(model)
    rate = min(r for r in (settings.max_move_pct_per_step, scenario.max_move_pct_per_step)
               if r is not None)
    pi = PIController.tuned_for(model, gain_scheduled=True, initial_triac_pct=plant.initial_triac_pct,
                                triac_limits_pct=(28.0, 70.0), max_move_pct_per_step=rate,
                                validity_margin_pct=settings.validity_margin_pct)
    expected = compute_metrics(run_closed_loop(plant, pi, scenario, rng=7))
    assert row["iae_kw_s"] == pytest.approx(expected.iae_kw_s, rel=IDENTITY_RTOL)
    assert row["n_rate_violations"] == expected.n_rate_violations == 0


def _robustness_spec(time_scale: float) -> dict[str, Any]:
    doc = tomllib.loads(shipped_path("campaign_robustness.toml").read_text(encoding="utf-8"))
    doc["time_scale"] = time_scale
    doc["plants"] = [{"kind": "perturbed", "gain_factors": [0.7, 1.0],
                      "time_constant_factors": [1.0, 2.0], "extra_delays_steps": [0]},
                     {"kind": "heater"}]
    return doc


def test_robustness_spec_tracks_the_gain_1_plants_and_counts_the_unreachable() -> None:
    spec = spec_from_dict(_robustness_spec(0.05))
    rows = {r["plant"]: r for r in (execute_run(run) for run in spec.expand())}
    assert len(rows) == 5 and all(r["status"] == "ok" for r in rows.values())
    assert all(r["n_allowed_range_violations"] == 0 for r in rows.values())
    for plant in ("perturbed g1 m1 d+0", "perturbed g1 m2 d+0", "heater"):
        assert rows[plant]["offset_free"] and rows[plant]["n_unreachable_changes"] == 0, plant
    # gain x0.7 cannot reach the top of the staircase (P_ss(70 %) = 58.8 kW)
    assert rows["perturbed g0.7 m1 d+0"]["n_unreachable_changes"] > 0


def test_a_settings_file_tunes_the_controller_as_simulate_settings(tmp_path: Path) -> None:
    settings = tmp_path / "slow.toml"
    settings.write_text("horizon_steps = 20\nmove_weight = 2.0\n", encoding="utf-8")
    (tmp_path / "s.toml").write_text(
        'scenarios = ["staircase"]\ntime_scale = 0.02\nseeds = [7]\n'
        '[[controllers]]\nname = "slow"\nsettings = "slow.toml"\n'
        '[[controllers]]\nname = "default"\npreset = "mpc"\n'
        '[[plants]]\nkind = "model"\n', encoding="utf-8")
    spec = load_spec(tmp_path / "s.toml")
    assert spec.controllers[0].kind == "mpc"
    assert spec.controllers[0].settings_path == str(settings.resolve())
    rows = {r["controller"]: r for r in (execute_run(run) for run in spec.expand())}
    model = load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))
    ref = run_simulation(model, load_scenario("staircase").shortened(0.02), plant="model", seed=7,
                         settings=MPCSettings.default_for(model).with_updates(
                             horizon_steps=20, move_weight=2.0))
    assert rows["slow"]["iae_kw_s"] == pytest.approx(compute_metrics(ref.result).iae_kw_s,
                                                     rel=IDENTITY_RTOL)
    assert rows["slow"]["iae_kw_s"] != pytest.approx(rows["default"]["iae_kw_s"], rel=1e-6)


def test_a_bad_settings_file_is_refused_naming_the_key(tmp_path: Path) -> None:
    (tmp_path / "bad.toml").write_text("horizon_stepz = 20\n", encoding="utf-8")
    doc = {"scenarios": ["staircase"], "plants": [{"kind": "model"}],
           "controllers": [{"settings": "bad.toml"}]}
    with pytest.raises(CampaignError, match="horizon_stepz"):
        spec_from_dict(doc, base_dir=tmp_path)
