"""Campaign specs, run seeds and one run's row against an independent closed-loop run."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from czmpc.campaigns.campaign import (
    ROW_COLUMNS,
    CampaignError,
    execute_run,
    load_spec,
    run_seed,
    spec_from_dict,
)
from czmpc.campaigns.simulation import run_simulation
from czmpc.shipped import shipped_path
from sim.metrics import compute_metrics
from sim.scenario import load_scenario
from sysid.modelfile import load_model
from tests.tolerances import IDENTITY_RTOL

BASE = {
    "name": "t", "seeds": 2, "base_seed": 7, "time_scale": 0.03, "scenarios": ["staircase"],
    "controllers": [{"name": "mpc", "preset": "mpc"}],
    "plants": [{"kind": "model"}],
}


def test_expand_counts_every_axis_and_grid_product() -> None:
    doc = {**BASE, "controllers": [{"preset": "mpc"}, {"preset": "pi"}],
           "plants": [{"kind": "model"}, {"kind": "perturbed", "gain_factors": [0.8, 1.2],
                                          "time_constant_factors": [1.0, 2.0],
                                          "extra_delays_steps": [0, 1]}]}
    runs = spec_from_dict(doc).expand()
    assert len(runs) == 2 * (1 + 8) * 1 * 2
    assert len({r.run_id for r in runs}) == len(runs)


@pytest.mark.parametrize(("change", "match"), [
    ({"colour": 1}, "unknown key"),
    ({"seeds": 0}, "'seeds' an integer >= 1"),
    ({"seeds": [3, 3]}, "a list of different integers"),
    ({"controllers": [{"preset": "mpc"}, {"kind": "mpc"}]}, "controller names must differ"),
    ({"time_scale": 1.5}, "time_scale"),
    ({"scenarios": ["no_such_scenario"]}, "no_such_scenario"),
    ({"controllers": [{"preset": "lqr"}]}, "'lqr'"),
    ({"controllers": [{"preset": "mpc", "settings": "x.toml"}]}, "x.toml: cannot read"),
    ({"plants": [{"kind": "perturbed", "gain_factors": [-1.0]}]}, "factors > 0"),
    ({"model": "missing.json"}, "missing.json"),
    ({"metrics": ["iae"]}, "expected 'metrics' a list of different names"),
])
def test_bad_specs_are_refused_naming_the_value(change: dict[str, object], match: str) -> None:
    with pytest.raises(CampaignError, match=match):
        spec_from_dict({**BASE, **change})


def test_shipped_specs_load() -> None:
    for name in ("campaign_smoke.toml", "campaign_robustness.toml", "campaign_bench.toml",
                 "campaign_montecarlo.toml", "campaign_throughput.toml"):
        assert len(load_spec(shipped_path(name)).expand()) > 0


def test_seed_depends_on_the_run_not_on_its_position() -> None:
    small = spec_from_dict(BASE).expand()
    big = spec_from_dict({**BASE, "controllers": [{"preset": "pi"}, {"preset": "mpc"}],
                          "plants": [{"kind": "heater"}, {"kind": "model"}]}).expand()
    by_id = {r.run_id: r for r in big}
    for run in small:
        assert run_seed(run) == run_seed(by_id[run.run_id])
    assert run_seed(small[0]) != run_seed(small[1])
    assert run_seed(small[0]) != run_seed(replace(small[0], base_seed=8))


def test_row_matches_an_independent_simulation(tmp_path: Path) -> None:
    run = spec_from_dict(BASE).expand()[0]
    row = execute_run(run)
    assert set(row) == set(ROW_COLUMNS)
    assert row["status"] == "ok", row["error"]
    scenario = load_scenario("staircase").shortened(0.03)
    ref = run_simulation(load_model(shipped_path("cz_heater_model.json")), scenario, plant="model",
                         seed=row["seed"], noise=True)
    expected = compute_metrics(ref.result)
    assert row["iae_kw_s"] == pytest.approx(expected.iae_kw_s, rel=IDENTITY_RTOL)
    assert row["ise_kw2_s"] == pytest.approx(expected.ise_kw2_s, rel=IDENTITY_RTOL)
    assert row["input_total_variation_pct"] == pytest.approx(
        expected.input_total_variation_pct, rel=IDENTITY_RTOL)
    assert row["n_steps"] == scenario.n_steps


def test_a_crashing_run_is_recorded_not_raised(monkeypatch: pytest.MonkeyPatch) -> None:
    import czmpc.campaigns.build as build

    def boom(*args: object, **kwargs: object) -> None:
        raise RuntimeError("solver exploded")

    monkeypatch.setattr(build, "build_controller", boom)
    row = execute_run(spec_from_dict(BASE).expand()[0])
    assert row["status"] == "error"
    assert "RuntimeError: solver exploded" in row["error"]
    assert row["n_steps"] == -1 and row["n_limit_violations"] == -1
    assert row["iae_kw_s"] != row["iae_kw_s"]  # NaN
