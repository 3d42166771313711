"""The identification experiment and the shipped CSV: regeneration, shape, calibration.

The calibration targets are computed from the shipped file through `sysid.steps`, not
from simulator internals: (a) 45 % held gives 45 kW; (b) the four steps after t = 1e4 s
reproduce paper Table 3; (c) one-step errors of a good model near 0.013 kW, and a sag
of about 10 % of each step.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim.errors import ScenarioError, SimError
from sim.experiment import (
    DEFAULT_SEED,
    PAPER_TABLE3,
    ExperimentSpec,
    identification_experiment,
    table3_comparison,
)
from sim.heater import HeaterParams
from sysid.data import Dataset, format_csv, read_csv
from sysid.steps import InputStep, detect_steps
from tests.conftest import SHIPPED_EXPERIMENT
from tests.tolerances import (
    IDENTITY_RTOL,
    TABLE3_GAIN_ATOL_KW_PER_PCT,
    TABLE3_LEVEL_ATOL_KW,
)

#: The paper's preprocessing (sec. 5.2): subtract 0.15 kW from P for t >= 20714 s.
SHIFT_TIME_S, SHIFT_KW = 20714.0, 0.15
DIP_TIME_S = ExperimentSpec().dip_time_s


@pytest.fixture(scope="module")
def shipped() -> Dataset:
    return read_csv(SHIPPED_EXPERIMENT)


@pytest.fixture(scope="module")
def table3_steps(shipped: Dataset) -> list[InputStep]:
    """Steps after t = 1e4 s of the shipped file, preprocessed as the paper did."""
    corrected = shipped.with_signals(
        power_kw=shipped.power_kw - np.where(shipped.time_s >= SHIFT_TIME_S, SHIFT_KW, 0.0)
    )
    return [step for step in detect_steps(corrected) if step.time_s > 1.0e4]


def test_shipped_csv_is_the_default_experiment_byte_for_byte() -> None:
    assert format_csv(identification_experiment()).encode() == SHIPPED_EXPERIMENT.read_bytes()


def test_same_seed_same_data_and_other_seed_other_noise() -> None:
    first = identification_experiment(rng=5)
    again = identification_experiment(rng=5)
    other = identification_experiment(rng=6)
    assert np.array_equal(first.power_kw, again.power_kw)
    assert not np.array_equal(first.power_kw, other.power_kw)
    assert np.array_equal(first.triac_pct, other.triac_pct)
    assert DEFAULT_SEED != 5


def test_experiment_has_the_papers_shape(shipped: Dataset) -> None:
    assert shipped.ts_s == 2.0
    assert shipped.n_samples == 12000
    assert 23_900.0 <= shipped.duration_s <= 24_100.0
    steady = (shipped.time_s >= 8700.0) & (shipped.time_s <= 10300.0)
    # Steady at 45 % over the whole window; the step at 10300 s acts from that sample on.
    assert np.all(shipped.triac_pct[steady & (shipped.time_s < 10300.0)] == 45.0)
    steps = detect_steps(shipped)
    assert steps[-1].time_s == 22170.0
    assert [s.triac_after_pct for s in steps if s.time_s > 1.0e4] == [50.0, 55.0, 60.0, 65.0]
    assert np.all(np.diff(shipped.triac_pct) >= 0.0)       # s rises through the run
    assert shipped.triac_pct[0] <= 35.0                   # starts well below the 45 % rest


def test_level_shift_of_0_15_kw_from_20714_s(shipped: Dataset) -> None:
    k = int(np.flatnonzero(shipped.time_s == SHIFT_TIME_S)[0])
    before_kw = shipped.power_kw[k - 5:k].mean()
    after_kw = shipped.power_kw[k:k + 5].mean()
    # 5-sample means: noise std 0.0105 * sqrt(2 / 5) ~ 0.007 kW, well inside 0.03.
    assert abs((after_kw - before_kw) - 0.15) < 0.03


def test_one_sample_grid_dip_before_1e4_s(shipped: Dataset) -> None:
    k = int(np.flatnonzero(shipped.time_s == DIP_TIME_S)[0])
    assert DIP_TIME_S < 1.0e4
    neighbours_kw = 0.5 * (shipped.power_kw[k - 1] + shipped.power_kw[k + 1])
    assert neighbours_kw - shipped.power_kw[k] > 0.5
    assert not np.any(np.abs(np.diff(shipped.triac_pct[k - 100:k + 100])) > 0)  # steady s


def test_power_does_not_fully_recover_after_the_dip() -> None:
    quiet = HeaterParams(sensor_noise_std_kw=0.0, grid_wander_std=0.0)
    with_dip = identification_experiment(params=quiet)
    without = identification_experiment(
        params=quiet,
        spec=dataclasses.replace(ExperimentSpec(), dip_voltage_factor=1.0,
                                 after_dip_voltage_factor=1.0),
    )
    k = int(np.flatnonzero(with_dip.time_s == DIP_TIME_S)[0])
    assert np.array_equal(with_dip.power_kw[:k], without.power_kw[:k])
    lost_kw = without.power_kw[k + 50:k + 200] - with_dip.power_kw[k + 50:k + 200]
    assert np.all((lost_kw > 0.005) & (lost_kw < 0.1))


def test_target_a_45_pct_held_gives_45_kw(shipped: Dataset) -> None:
    steady = (shipped.time_s >= 8700.0) & (shipped.time_s < 10300.0)
    assert abs(shipped.power_kw[steady].mean() - 45.0) < 0.1


def test_target_b_step_gains_reproduce_table3(table3_steps: list[InputStep]) -> None:
    assert len(table3_steps) == 4
    gains = np.array([step.gain_kw_per_pct for step in table3_steps])
    paper_gains = np.array([row[4] for row in PAPER_TABLE3])
    np.testing.assert_allclose(gains, paper_gains, rtol=0.0, atol=TABLE3_GAIN_ATOL_KW_PER_PCT)
    assert np.all(np.diff(gains) < 0.0)
    for step, (ds_before, ds_after, *_) in zip(table3_steps, PAPER_TABLE3, strict=True):
        assert (step.triac_before_pct - 45.0, step.triac_after_pct - 45.0) == (ds_before, ds_after)


def test_target_b_power_levels_reproduce_table3(table3_steps: list[InputStep]) -> None:
    # Deviations from the paper's operating point (45 %, 45 kW) of the data corrected
    # for the level shift as in the paper's preprocessing (the fixture does that).
    measured = np.array([[s.power_before_kw - 45.0, s.power_after_kw - 45.0]
                         for s in table3_steps])
    paper = np.array([[row[2], row[3]] for row in PAPER_TABLE3])
    np.testing.assert_allclose(measured, paper, rtol=0.0, atol=TABLE3_LEVEL_ATOL_KW)


def test_table3_comparison_reports_the_same_steps(shipped: Dataset,
                                                  table3_steps: list[InputStep]) -> None:
    rows = table3_comparison(shipped)
    np.testing.assert_allclose([r.gain_kw_per_pct for r in rows],
                               [s.gain_kw_per_pct for s in table3_steps],
                               rtol=IDENTITY_RTOL, atol=0.0)
    np.testing.assert_allclose([r.dp_after_kw for r in rows],
                               [s.power_after_kw - 45.0 for s in table3_steps],
                               rtol=IDENTITY_RTOL, atol=1e-12)
    assert [r.paper_gain_kw_per_pct for r in rows] == [1.35, 1.31, 1.23, 1.14]


def test_table3_comparison_refuses_a_record_without_the_four_steps(shipped: Dataset) -> None:
    with pytest.raises(SimError, match="expected 4 input steps after t = 10000 s; got 0"):
        table3_comparison(shipped.segment(0, 4000))


def _arx_residuals(data: Dataset, order: int) -> tuple[np.ndarray, np.ndarray]:
    """One-step residuals of an ARX(order, order), nk = 1, by numpy least squares."""
    y = data.power_kw - 45.0
    u = data.triac_pct - 45.0
    rows = range(order, data.n_samples)
    phi = np.array([np.r_[-y[k - order:k][::-1], u[k - order:k][::-1]] for k in rows])
    theta, *_ = np.linalg.lstsq(phi, y[order:], rcond=None)
    return y[order:] - phi @ theta, data.time_s[order:]


def test_target_c_arx10_one_step_errors_near_0_013_kw(shipped: Dataset) -> None:
    residual_kw, time_s = _arx_residuals(shipped, 10)
    events_s = [DIP_TIME_S, SHIFT_TIME_S] + [s.time_s for s in detect_steps(shipped)]
    away = np.all(np.abs(time_s[:, None] - np.asarray(events_s)[None, :]) > 30.0, axis=1)
    residual_std_kw = residual_kw[away].std()
    assert 0.012 <= residual_std_kw <= 0.015
    # The grid dip stands out of the residuals like the left arrow of the paper's Fig. 3.
    near_dip = np.abs(time_s - DIP_TIME_S) <= 10.0
    k = int(np.argmax(np.abs(residual_kw) * near_dip))
    assert time_s[k] == DIP_TIME_S and abs(residual_kw[k]) > 20.0 * residual_std_kw


def test_target_c_sag_is_about_10_pct_of_the_step(shipped: Dataset) -> None:
    k = int(np.flatnonzero(shipped.time_s == 10300.0)[0])
    jump_kw = shipped.power_kw[k + 1] - shipped.power_kw[k]
    sag_kw = shipped.power_kw[k + 1] - shipped.power_kw[k + 300:k + 400].mean()  # +600..800 s
    assert 0.07 < sag_kw / jump_kw < 0.16
    early_kw = shipped.power_kw[k + 1] - shipped.power_kw[k + 140:k + 160].mean()  # ~300 s
    assert early_kw > 0.6 * sag_kw                      # most of it within a few hundred s


def test_steady_state_gain_is_about_0_9_of_the_instantaneous(
        table3_steps: list[InputStep]) -> None:
    first, second = table3_steps[0], table3_steps[1]
    steady_gain = (second.power_before_kw - first.power_before_kw) / 5.0
    assert 0.85 < steady_gain / first.gain_kw_per_pct < 0.93


def test_experiment_refuses_a_heater_with_another_sampling_time() -> None:
    with pytest.raises(ScenarioError, match="HeaterParams.ts_s must equal"):
        identification_experiment(params=HeaterParams(ts_s=1.0))


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"n_samples": 2}, r"n_samples must be an int >= 3"),
        ({"ts_s": 0.0}, r"ts_s must be finite and > 0"),
        ({"input_steps": ((100.0, 50.0), (50.0, 60.0))}, r"increasing time"),
        ({"input_steps": ((101.0, 50.0),)}, r"on the 2 s grid"),
        ({"input_steps": ((100.0, 120.0),)}, r"must be in \[0, 100\]"),
        ({"level_shift_time_s": 30000.0}, r"level_shift_time_s: expected a time"),
        ({"power_decimals": 2.5}, r"power_decimals must be an int"),
    ],
    ids=["n", "ts", "order", "grid", "level", "outside", "decimals"],
)
def test_invalid_specs_are_refused(changes: dict[str, object], match: str) -> None:
    with pytest.raises(ScenarioError, match=match):
        dataclasses.replace(ExperimentSpec(), **changes)  # type: ignore[arg-type]
