"""The shipped bench and robustness specs give the numbers of `czmpc bench` and
`czmpc robustness` (same code path for the plant, controller and seed: compared to
IDENTITY_RTOL)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest

from czmpc.campaigns.bench import BENCH_SEED, BenchModels, run_case, run_row
from czmpc.campaigns.campaign import execute_run, load_spec, spec_from_dict
from czmpc.campaigns.robustness import RobustnessGrid, run_robustness
from czmpc.shipped import shipped_path
from sim.scenario import load_scenario
from sysid.modelfile import load_model
from tests.tolerances import IDENTITY_RTOL

SCALE = 0.02


def test_shipped_specs_expand_to_the_commands_cases() -> None:
    bench = load_spec(shipped_path("campaign_bench.toml"))
    assert len(bench.expand()) == 6 * 2 * 7
    assert {r.fixed_seed for r in bench.expand()} == {BENCH_SEED}
    robust = load_spec(shipped_path("campaign_robustness.toml"))
    assert len(robust.expand()) == 5 * 3 * 2 + 1
    assert {r.fixed_seed for r in robust.expand()} == {1}


@pytest.mark.parametrize(("controller", "plant"), [
    ("mpc", "heater"), ("linear_mpc", "model"), ("pi_gs", "model"), ("pi", "heater"),
    ("open_loop", "model")])
def test_bench_spec_rows_equal_czmpc_bench(controller: str, plant: str) -> None:
    spec = load_spec(shipped_path("campaign_bench.toml"), time_scale=SCALE,
                     controllers=[controller])
    run = next(r for r in spec.expand()
               if r.plant.kind == plant and Path(r.scenario).stem == "staircase")
    row = execute_run(run)
    assert row["status"] == "ok", row["error"]
    ref = run_row(run_case(load_scenario("staircase").shortened(SCALE), plant, controller,
                           BenchModels.shipped()))
    assert row["seed"] == ref["seed"] == BENCH_SEED
    assert row["n_steps"] == ref["n_steps"]
    for key in ("iae_kw_s", "ise_kw2_s", "max_overshoot_kw", "max_abs_steady_state_error_kw",
                "input_total_variation_pct"):
        assert row[key] == pytest.approx(ref[key], rel=IDENTITY_RTOL), key
    for key in ("n_limit_violations", "n_rate_violations"):
        assert row[key] == ref[key], key


def _robustness_spec(time_scale: float) -> dict[str, Any]:
    doc = tomllib.loads(shipped_path("campaign_robustness.toml").read_text(encoding="utf-8"))
    doc["time_scale"] = time_scale
    doc["plants"] = [{"kind": "perturbed", "gain_factors": [0.7, 1.0],
                      "time_constant_factors": [1.0, 2.0], "extra_delays_steps": [0]},
                     {"kind": "heater"}]
    return doc


def test_robustness_spec_rows_equal_czmpc_robustness() -> None:
    scale = 0.05
    spec = spec_from_dict(_robustness_spec(scale))
    rows = {r["plant"]: r for r in (execute_run(run) for run in spec.expand())}
    report = run_robustness(
        load_model(shipped_path("cz_heater_model.json")),
        load_scenario("staircase").shortened(scale),
        grid=RobustnessGrid(gain_factors=(0.7, 1.0), time_constant_factors=(1.0, 2.0),
                            extra_delays_steps=(0,)))
    assert len(report.results) == len(rows) == 5
    n_unreachable = 0
    for result in report.results:
        v = result.variant
        label = ("heater" if v.kind == "heater" else
                 f"perturbed g{v.gain_factor:g} m{v.time_constant_factor:g} d+{v.extra_delay_steps}")
        row = rows[label]
        assert row["status"] == "ok", row["error"]
        assert row["iae_changes_reachable_kw_s"] == pytest.approx(result.iae_kw_s, rel=IDENTITY_RTOL)
        assert row["max_abs_steady_state_error_reachable_kw"] == pytest.approx(
            result.max_abs_steady_state_error_kw, rel=IDENTITY_RTOL)
        assert row["max_overshoot_reachable_kw"] == pytest.approx(result.max_overshoot_kw,
                                                                  rel=IDENTITY_RTOL, abs=1e-12)
        assert row["offset_free"] == result.offset_free
        assert row["n_unreachable_changes"] == result.n_unreachable_changes
        assert row["n_allowed_range_violations"] == result.n_input_violations
        assert row["n_fallbacks"] == result.n_solver_fallbacks
        n_unreachable += result.n_unreachable_changes
    assert n_unreachable > 0  # gain x0.7 cannot reach the top of the staircase: clipping tested


def test_a_settings_file_tunes_the_controller_as_czmpc_bench_settings(tmp_path: Path) -> None:
    settings = tmp_path / "slow.toml"
    settings.write_text("horizon_steps = 20\nmove_weight = 2.0\n", encoding="utf-8")
    (tmp_path / "s.toml").write_text(
        'scenarios = ["staircase"]\ntime_scale = 0.02\nseed = 7\n'
        '[[controllers]]\nname = "slow"\nsettings = "slow.toml"\n'
        '[[controllers]]\nname = "default"\npreset = "mpc"\n'
        '[[plants]]\nkind = "model"\n', encoding="utf-8")
    spec = load_spec(tmp_path / "s.toml")
    assert spec.controllers[0].preset == "mpc"
    assert spec.controllers[0].settings_path == str(settings)
    rows = {r["controller"]: r for r in (execute_run(run) for run in spec.expand())}
    scenario = load_scenario("staircase").shortened(0.02)
    ref = run_row(run_case(scenario, "model", "mpc", BenchModels.shipped(),
                           settings_doc={"horizon_steps": 20, "move_weight": 2.0}))
    assert rows["slow"]["iae_kw_s"] == pytest.approx(ref["iae_kw_s"], rel=IDENTITY_RTOL)
    assert rows["slow"]["iae_kw_s"] != pytest.approx(rows["default"]["iae_kw_s"], rel=1e-6)


def test_a_bad_settings_file_is_refused_naming_the_key(tmp_path: Path) -> None:
    from czmpc.campaigns.campaign import CampaignError

    (tmp_path / "bad.toml").write_text("horizon_stepz = 20\n", encoding="utf-8")
    doc = {"scenarios": ["staircase"], "plants": [{"kind": "model"}],
           "controllers": [{"settings": "bad.toml"}]}
    with pytest.raises(CampaignError, match="horizon_stepz"):
        spec_from_dict(doc, base_dir=tmp_path)
