"""`compare_pid_table` passes a scenario's preview and measured voltage to every controller (issue 40)."""

from __future__ import annotations

import dataclasses

import pytest

from czmpc.campaigns.pid_comparison import compare_pid_table
from czmpc.pid.controller import TableSchedule
from czmpc.pid.design import DesignSpec
from czmpc.pid.schedule import tune_schedule
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sim.scenario import load_scenario
from sysid.model import HammersteinModel
from sysid.modelfile import load_model

#: The shipped MPC's IAE on this noise-free sag before issue 40 [kW s] (measured at
#: 317d35c; the issue's goal: at most 0.6 of it with the voltage measured).
MPC_BEFORE_ISSUE_40_KW_S = 23.78


@pytest.fixture(scope="module")
def model() -> HammersteinModel:
    return load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))


@pytest.fixture(scope="module")
def table(model: HammersteinModel) -> TableSchedule:
    return tune_schedule(model, DesignSpec(ms=1.4), triac_range_pct=(28.0, 70.0)).table_schedule()


def _iae(model: HammersteinModel, table: TableSchedule, scenario: str, **keys: object
         ) -> dict[str, float]:
    sc = dataclasses.replace(load_scenario(scenario), **keys)  # type: ignore[arg-type]
    out = compare_pid_table(model, table, sc, plant="heater", seed=3, noise=False)
    return {s.name: s.iae_kw_s for s in out}


def test_a_measured_sag_helps_both_sides(model: HammersteinModel, table: TableSchedule) -> None:
    blind = _iae(model, table, "voltage_sag")
    seen = _iae(model, table, "voltage_sag", measured_voltage=True)
    # Noise-free heater, seed 3: the MPC 18.3 -> 13.9 kW s (23.8 before issue 40, which
    # took the sag's level change at the filter's rate); the table's PI 17.4 -> 14.2.
    assert seen["mpc"] < 0.85 * blind["mpc"]
    assert seen["mpc"] < 0.6 * MPC_BEFORE_ISSUE_40_KW_S
    assert seen["pi_table"] < 0.9 * blind["pi_table"]
    assert seen["mpc"] <= seen["pi_table"]


def test_only_the_mpc_uses_the_preview(model: HammersteinModel, table: TableSchedule) -> None:
    plain = _iae(model, table, "staircase")
    ahead = _iae(model, table, "staircase", setpoint_preview_s=60.0)
    assert ahead["pi_table"] == plain["pi_table"] and ahead["pi_fixed"] == plain["pi_fixed"]
    # Noise-free heater: 79.9 -> 34.3 kW s; the table's PI 83.5.
    assert ahead["mpc"] < 0.5 * plain["mpc"]
    assert ahead["mpc"] < 0.45 * ahead["pi_table"]
