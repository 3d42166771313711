"""Controller regression tests: fresh runs against tests/golden/*.json (czmpc.campaigns.golden)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from czmpc.campaigns.bench import CONTROLLERS, PLANTS, BenchModels
from czmpc.campaigns.golden import (
    FLOAT_ATOL,
    FLOAT_RTOL,
    GOLDEN_DIR,
    GOLDEN_METRICS,
    SOLVER_SAFETY,
    GoldenError,
    check_golden_file,
    compare,
    load_golden,
    tolerances,
)
from sim.scenario import list_scenarios

GOLDEN_FILES = sorted(GOLDEN_DIR.glob("*.json"))


@pytest.fixture(scope="module")
def models() -> BenchModels:
    return BenchModels.shipped()


def test_golden_set_covers_every_shipped_scenario_plant_and_controller() -> None:
    assert [p.stem for p in GOLDEN_FILES] == sorted(list_scenarios())
    for path in GOLDEN_FILES:
        runs = load_golden(path)["runs"]
        assert set(runs) == {f"{p}/{c}" for p in PLANTS for c in CONTROLLERS}
        for metrics in runs.values():
            assert set(metrics) == set(GOLDEN_METRICS)


@pytest.mark.casadi
@pytest.mark.parametrize("path", GOLDEN_FILES, ids=lambda p: p.stem)
def test_fresh_runs_match_the_golden_metrics(path: Path, models: BenchModels) -> None:
    mismatches = check_golden_file(path, models=models)
    assert not mismatches, "\n".join(map(str, mismatches))


def test_a_much_larger_move_weight_is_caught_as_a_regression(models: BenchModels) -> None:
    path = GOLDEN_DIR / "staircase.json"
    assert not check_golden_file(path, models=models, cases=["model/mpc"])
    worse = check_golden_file(path, models=models, cases=["model/mpc"],
                              settings_updates={"move_weight": 10.0})
    assert {m.metric for m in worse} >= {"iae_kw_s", "ise_kw2_s"}
    iae = next(m for m in worse if m.metric == "iae_kw_s")
    assert iae.actual > iae.expected + 10 * iae.tolerance  # far outside, not marginal
    assert "staircase-short/model/mpc: iae_kw_s" in str(iae)


def test_compare_flags_values_outside_tolerance_and_missing_metrics() -> None:
    golden = {"a": {"value": 1.0, "tol": 0.1}, "b": {"value": None, "tol": 0.0},
              "c": {"value": 2.0, "tol": 0.0}}
    assert compare("x", golden, {"a": 1.05, "b": math.nan, "c": 2.0}) == ()
    bad = compare("x", golden, {"a": 1.2, "b": 0.0})
    assert [m.metric for m in bad] == ["a", "b", "c"]
    assert math.isnan(bad[2].actual)


def test_tolerances_are_the_larger_of_solver_and_float_allowances() -> None:
    nominal = dict.fromkeys(GOLDEN_METRICS, 100.0)
    tight = dict(nominal, iae_kw_s=100.5)
    tol = tolerances(nominal, tight)
    assert tol["iae_kw_s"] == pytest.approx(SOLVER_SAFETY * 0.5, rel=1e-12)
    assert tol["ise_kw2_s"] == pytest.approx(FLOAT_RTOL * 100.0, rel=1e-12)
    assert tol["n_solver_failures"] == 0.0
    assert tolerances(dict(nominal, ise_kw2_s=0.0), dict(tight, ise_kw2_s=0.0))["ise_kw2_s"] \
        == FLOAT_ATOL


def test_unreadable_golden_files_are_refused(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "other"}), encoding="utf-8")
    with pytest.raises(GoldenError, match="expected format 'czmpc-golden/1'"):
        load_golden(bad)
    with pytest.raises(GoldenError, match="readable JSON"):
        load_golden(tmp_path / "missing.json")
