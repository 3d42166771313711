"""Suite parsing, tolerance and band rules, first divergence, executors (regression suites)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from czmpc.campaigns.regression import (
    DEFAULT_METRICS,
    FLOAT_ATOL,
    FLOAT_RTOL,
    SOLVER_SAFETY,
    RegressError,
    derived_tolerance,
    first_divergence,
    load_suite,
    run_cases,
    suite_from_dict,
    trajectory_band,
)

BASE = {"scenarios": ["staircase"], "controllers": [{"kind": "mpc"}], "plants": [{"kind": "model"}]}


def test_a_suite_expands_controllers_x_plants_x_scenarios_x_seeds(user_suite: Path) -> None:
    suite = load_suite(user_suite)
    assert [c.case_id for c in suite.expand()] == [
        "tuned/model/recipe_a/s3", "tuned/perturbed g1.1 m1 d+0/recipe_a/s3"]
    assert suite.controllers[0].settings_path == str(user_suite.parent.resolve() / "puller7_settings.toml")
    doc = dict(BASE, seeds=[1, 2], scenarios=["staircase", "large_step"],
               plants=[{"kind": "model"}, {"kind": "heater"}],
               tolerances={"iae_kw_s": "2%", "ise_kw2_s": 0.5})
    big = suite_from_dict(doc)
    assert len(big.expand()) == 1 * 2 * 2 * 2
    assert big.tolerances["iae_kw_s"].of(50.0) == pytest.approx(1.0, rel=1e-12)
    assert big.tolerances["ise_kw2_s"].of(50.0) == 0.5


@pytest.mark.parametrize(("change", "message"), [
    ({"controllers": [{"kind": "lqr"}]}, "expected kind one of"),
    ({"plants": [{"kind": "model", "gain": 2}]}, "unknown key(s) ['gain']"),
    ({"scenarios": ["nowhere"]}, "scenario 'nowhere' is not shipped"),
    ({"seeds": [1, 1]}, "or a list of different integers >= 0"),
    ({"metrics": ["iae"]}, "expected 'metrics' a list of different names"),
    ({"tolerances": {"iae_kw_s": "-1%"}}, "[tolerances] iae_kw_s: expected a number >= 0"),
    ({"tolerances": {"n_steps": 1}}, "'n_steps' is not a held metric"),
    ({"time_scale": 0}, "expected 'time_scale' in (0, 1]"),
    ({"colour": "red"}, "unknown key(s) ['colour']"),
])
def test_invalid_suites_are_refused_naming_the_key(change: dict[str, object], message: str) -> None:
    with pytest.raises(RegressError) as info:
        suite_from_dict(dict(BASE, **change), source="s.toml")
    assert message in str(info.value) and "suite s.toml" in str(info.value)


def test_derived_tolerances_are_the_solver_share_or_the_float_share_and_counts_exact() -> None:
    # an independent statement of the rule: max(10 x |nominal - tight|, 1e-6 x |nominal|, 1e-9)
    assert (SOLVER_SAFETY, FLOAT_RTOL, FLOAT_ATOL) == (10.0, 1e-6, 1e-9)
    assert derived_tolerance("iae_kw_s", 50.0, 50.001) == pytest.approx(0.01, rel=1e-9)
    assert derived_tolerance("iae_kw_s", 50.0, 50.0) == pytest.approx(5e-5, rel=1e-12)
    assert derived_tolerance("max_overshoot_kw", 0.0, 0.0) == 1e-9
    assert derived_tolerance("max_overshoot_kw", 1.0, math.nan) == pytest.approx(1e-6, rel=1e-12)
    for count in ("n_limit_violations", "n_rate_violations", "n_solver_failures"):
        assert count in DEFAULT_METRICS and derived_tolerance(count, 3.0, 4.0) == 0.0
    assert derived_tolerance("iae_kw_s", math.nan, math.nan) == FLOAT_ATOL


def test_the_band_is_the_solver_share_or_the_float_share_plus_float32_rounding() -> None:
    nominal = np.array([10.0, 20.0, 40.0])
    tight = nominal + np.array([0.0, 1e-3, -2e-3])
    rounding = float(np.max(np.abs(nominal - nominal.astype(np.float32))))
    assert trajectory_band(nominal, tight) == pytest.approx(SOLVER_SAFETY * 2e-3 + rounding, rel=1e-12)
    assert trajectory_band(nominal, nominal) == pytest.approx(FLOAT_RTOL * 40.0 + rounding, rel=1e-12)


def _traj(power: list[float], triac: list[float]) -> dict[str, np.ndarray]:
    n = len(power)
    return {"time_s": 2.0 * np.arange(n), "setpoint_kw": np.zeros(n),
            "power_true_kw": np.array(power), "triac_pct": np.array(triac)}


def test_first_divergence_is_the_earliest_sample_outside_the_band_of_either_signal() -> None:
    band = {"power_true_kw": 0.5, "triac_pct": 0.1}
    golden = _traj([1.0] * 6, [5.0] * 6)
    assert first_divergence(golden, _traj([1.4, 0.6, 1.0, 1.0, 1.0, 1.0], [5.05] * 6), band) is None
    late_power = _traj([1.0, 1.0, 1.0, 1.0, 2.0, 1.0], [5.0, 5.0, 5.0, 5.2, 5.0, 5.0])
    d = first_divergence(golden, late_power, band)
    assert d is not None and (d.signal, d.time_s, d.new, d.golden, d.band) == (
        "triac_pct", 6.0, 5.2, 5.0, 0.1)
    nan = _traj([1.0, math.nan, 1.0, 1.0, 1.0, 1.0], [5.0] * 6)
    d = first_divergence(golden, nan, band)
    assert d is not None and d.time_s == 2.0 and d.signal == "power_true_kw"
    assert first_divergence(nan, nan, band) is None
    short = _traj([1.0] * 4, [5.0] * 4)
    d = first_divergence(golden, short, band)
    assert d is not None and d.time_s == 6.0  # the end of the shorter run


@pytest.mark.slow
def test_processes_and_dask_give_the_same_numbers_as_serial(user_suite: Path) -> None:
    tasks = [replace(c, tight=t) for c in load_suite(user_suite).expand() for t in (False, True)]
    serial = run_cases(tasks)
    for executor in ("processes", "dask"):
        other = run_cases(tasks, executor=executor, workers=2)
        assert [r.case_id for r in other] == [r.case_id for r in serial]
        for a, b in zip(serial, other, strict=True):
            assert a.error == b.error == ""
            np.testing.assert_equal(dict(a.metrics), dict(b.metrics))  # bit for bit: pure cases
            np.testing.assert_array_equal(a.trajectory["power_true_kw"], b.trajectory["power_true_kw"])
    with pytest.raises(RegressError, match="expected executor one of"):
        run_cases(tasks, executor="threads")
