"""Scenario keys ``setpoint_preview_s`` and ``measured_voltage`` and what `run_closed_loop` passes."""

from __future__ import annotations

import numpy as np
import pytest

from sim.disturbances import VoltageStep
from sim.errors import ScenarioError
from sim.loop import run_closed_loop
from sim.model_plant import ModelPlant
from sim.scenario import Scenario, SetpointStep, scenario_from_dict
from sysid.model import HammersteinModel, OperatingPoint

BASE = {"name": "keys", "duration_s": 40.0, "initial_setpoint_kw": 45.0, "initial_triac_pct": 45.0}


def test_keys_default_off_and_are_read() -> None:
    plain = scenario_from_dict(BASE)
    assert plain.setpoint_preview_s == 0.0 and plain.measured_voltage is False
    assert plain.preview_steps == 0
    both = scenario_from_dict({**BASE, "setpoint_preview_s": 7.0, "measured_voltage": True})
    assert both.setpoint_preview_s == 7.0 and both.measured_voltage is True
    assert both.preview_steps == 4        # round(7 / 2): the nearest whole sample


@pytest.mark.parametrize(("key", "value", "says"), [
    ("setpoint_preview_s", -2.0, "expected a time >= 0"),
    ("setpoint_preview_s", "60", "setpoint_preview_s"),
    ("measured_voltage", "yes", "measured_voltage"),
    ("setpoint_preview_s", float("nan"), "setpoint_preview_s")])
def test_bad_values_name_the_key(key: str, value: object, says: str) -> None:
    with pytest.raises(ScenarioError, match=says):
        scenario_from_dict({**BASE, key: value}, source="bad.toml")


class Recorder:
    """A controller that holds its input and records what each step was given."""

    ts_s = 2.0

    def __init__(self) -> None:
        self.calls: list[dict[str, object]] = []

    def reset(self) -> None:
        self.calls.clear()

    def step(self, power_kw: float, setpoint_kw: float, **extra: object) -> float:
        self.calls.append({"setpoint_kw": setpoint_kw, **extra})
        return 45.0


def plant() -> ModelPlant:
    model = HammersteinModel(
        kind="hammerstein", linear_block="armax", ts_s=2.0,
        operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
        a=[1.0, -0.99], b=[0.0, 1.0, -0.991], c=[1.0, -0.9],
        input_poly=[1.35, -0.0065], noise_std_kw=0.0134, input_range_pct=(20.0, 70.0))
    return ModelPlant(model, noise=False, initial_triac_pct=45.0)


def test_the_runner_passes_the_next_setpoints_and_the_last_samples_voltage() -> None:
    scenario = Scenario(name="keys", duration_s=40.0, initial_setpoint_kw=45.0,
                        initial_triac_pct=45.0, setpoints=(SetpointStep(at_s=10.0, power_kw=50.0),),
                        disturbances=(VoltageStep(at_s=6.0, factor=0.97),),
                        setpoint_preview_s=6.0, measured_voltage=True)
    rec = Recorder()
    run_closed_loop(plant(), rec, scenario, rng=1, voltage_noise_std=0.0)
    profile = scenario.setpoint_profile_kw()
    n = scenario.n_steps
    for k, call in enumerate(rec.calls):
        preview = call["setpoint_preview_kw"]
        assert isinstance(preview, np.ndarray)
        np.testing.assert_array_equal(preview, profile[k + 1 : k + 4])   # 3 samples, fewer at the end
        # The voltage over the last sample: the step acts from sample 3 (t = 6 s) on.
        assert call["grid_voltage_factor"] == (0.97 if k >= 4 else 1.0)
    assert len(rec.calls[n - 1]["setpoint_preview_kw"]) == 0            # type: ignore[arg-type]
    assert len(rec.calls[n - 2]["setpoint_preview_kw"]) == 1            # type: ignore[arg-type]


def test_without_the_keys_the_controller_gets_no_keywords() -> None:
    rec = Recorder()
    run_closed_loop(plant(), rec, scenario_from_dict(BASE), rng=1)
    assert all(set(call) == {"setpoint_kw"} for call in rec.calls)


def test_the_voltage_reading_noise_is_seeded_and_stated() -> None:
    scenario = scenario_from_dict({**BASE, "measured_voltage": True})
    readings = []
    for _ in range(2):
        rec = Recorder()
        run_closed_loop(plant(), rec, scenario, rng=3, voltage_noise_std=1e-4)
        readings.append(np.array([c["grid_voltage_factor"] for c in rec.calls]))
    np.testing.assert_array_equal(readings[0], readings[1])
    assert 0.0 < np.std(readings[0] - 1.0) < 3e-4
