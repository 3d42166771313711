"""run_simulation / czmpc simulate on a plant that differs from the model (sim.drift)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from czmpc.campaigns.simulation import run_simulation
from czmpc.cli import main
from czmpc.shipped import shipped_path
from sim.drift import PlantVariation
from sim.scenario import Scenario, SetpointStep
from sysid.modelfile import load_model

MODEL = load_model(shipped_path("cz_heater_model.json"))


def test_a_weaker_plant_needs_more_input_for_the_same_power() -> None:
    scenario = Scenario(name="one step", duration_s=1600.0, initial_setpoint_kw=45.0,
                        setpoints=(SetpointStep(at_s=100.0, power_kw=48.0),), plant_noise=False)
    nominal = run_simulation(MODEL, scenario, plant="model", seed=1, noise=False)
    weak = run_simulation(MODEL, scenario, plant="model", seed=1, noise=False,
                          variation=PlantVariation(gain_factor=0.8))
    tail = slice(-20, None)
    # both track the last setpoint offset-free ...
    for outcome in (nominal, weak):
        err = outcome.result.power_true_kw[tail] - outcome.result.setpoint_kw[tail]
        assert abs(float(np.mean(err))) < 0.1
    # ... the weaker plant with a larger input deviation from the operating point
    s_nom = MODEL.operating_point.triac_pct
    du_nominal = float(np.mean(nominal.result.triac_pct[tail])) - s_nom
    du_weak = float(np.mean(weak.result.triac_pct[tail])) - s_nom
    assert du_weak > du_nominal > 0.0


def test_simulate_cli_takes_the_variation_options(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["simulate", "--model", str(shipped_path("cz_heater_model.json")), "--scenario",
                 "staircase", "--short", "0.1", "--no-noise", "--drift", "gain=0.75@100",
                 "--extra-delay-samples", "1", "--out", str(tmp_path / "sim")])
    assert code == 0
    assert (tmp_path / "sim" / "trajectory.csv").is_file()
    assert main(["simulate", "--model", str(shipped_path("cz_heater_model.json")), "--scenario",
                 "staircase", "--drift", "tau=0@5", "--out", str(tmp_path / "bad")]) == 2
    assert "DriftEvent.value" in capsys.readouterr().err
