"""ThermalPlant: step response against independent computations, voltage, sensor, fixture."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from sim.errors import PlantError
from sim.protocols import NOMINAL, Exogenous, Plant
from sim.thermal_plant import (
    ThermalParams,
    ThermalPlant,
    heating_fraction,
    steady_state_degc,
    steady_state_triac_pct,
)
from sysid.modelfile import load_model
from sysid.polynomials import slowest_time_constant_samples

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "tests" / "data" / "models" / "thermal_model.json"
#: Noise-free and unquantised: the dynamics only.
QUIET = ThermalParams(sensor_noise_std_degc=0.0, sensor_quantum_degc=0.0)
#: The matrix exponential and the closed form agree to rounding (states of ~500 degC).
EXACT_ATOL_DEGC = 1e-9
#: solve_ivp at rtol 1e-10 on a 600 s run.
IVP_ATOL_DEGC = 1e-6


def _response(plant: ThermalPlant, triac_pct: list[float], exogenous: Exogenous = NOMINAL
              ) -> np.ndarray:
    plant.reset(0)
    return np.array([plant.step(s, exogenous) for s in triac_pct])


def test_thermal_plant_implements_the_plant_protocol() -> None:
    plant = ThermalPlant(rng=1)
    assert isinstance(plant, Plant)
    assert plant.ts_s == 2.0
    assert plant.true_power_kw == pytest.approx(steady_state_degc(50.0, plant.params))


def test_step_response_is_the_closed_form_of_two_lags() -> None:
    plant = ThermalPlant(dataclasses.replace(QUIET, initial_triac_pct=40.0))
    y = _response(plant, [60.0] * 300)
    t1, t2, gain = QUIET.element_time_s, QUIET.zone_time_s, QUIET.gain_degc
    t = QUIET.ts_s * np.arange(1, 301)
    rise = gain * (heating_fraction(60.0, QUIET) - heating_fraction(40.0, QUIET))
    expected = steady_state_degc(40.0, QUIET) + rise * (
        1.0 - (t1 * np.exp(-t / t1) - t2 * np.exp(-t / t2)) / (t1 - t2))
    np.testing.assert_allclose(y, expected, rtol=0.0, atol=EXACT_ATOL_DEGC)


def test_varying_input_and_voltage_match_solve_ivp() -> None:
    rng = np.random.default_rng(3)
    inputs = np.repeat(rng.uniform(20.0, 80.0, 30), 10)   # 300 samples, held for 20 s each
    volts = np.repeat(rng.uniform(0.9, 1.1, 30), 10)
    plant = ThermalPlant(QUIET)
    plant.reset(0)
    y = np.array([plant.step(float(s), Exogenous(grid_voltage_factor=float(v)))
                  for s, v in zip(inputs, volts, strict=True)])
    t1, t2 = QUIET.element_time_s, QUIET.zone_time_s
    x = np.full(2, steady_state_degc(50.0, QUIET) - QUIET.ambient_degc)
    expected = []
    for s, v in zip(inputs, volts, strict=True):
        drive = QUIET.gain_degc * v * v * heating_fraction(float(s), QUIET)
        sol = solve_ivp(lambda _t, z, d=drive: [(d - z[0]) / t1, (z[0] - z[1]) / t2],
                        (0.0, QUIET.ts_s), x, rtol=1e-10, atol=1e-10)
        x = sol.y[:, -1]
        expected.append(QUIET.ambient_degc + x[1])
    np.testing.assert_allclose(y, expected, rtol=0.0, atol=IVP_ATOL_DEGC)
    assert plant.grid_voltage_factor == volts[-1]


def test_voltage_scales_the_steady_rise_by_its_square_and_offset_shifts_the_output() -> None:
    plant = ThermalPlant(QUIET)
    y = _response(plant, [50.0] * 3000, Exogenous(grid_voltage_factor=0.9, power_offset_kw=2.0))
    rise = steady_state_degc(50.0, QUIET) - QUIET.ambient_degc
    assert y[-1] == pytest.approx(QUIET.ambient_degc + 0.81 * rise + 2.0, abs=1e-6)
    assert steady_state_degc(50.0, QUIET, grid_voltage_factor=0.9) == pytest.approx(
        QUIET.ambient_degc + 0.81 * rise)


def test_sensor_is_quantised_noisy_and_reproducible() -> None:
    plant = ThermalPlant(rng=4)
    y = np.array([plant.step(50.0) for _ in range(2000)])
    quantum = plant.params.sensor_quantum_degc
    np.testing.assert_allclose(y / quantum, np.round(y / quantum), atol=1e-6)
    # quantisation adds q^2/12 to the noise variance
    expected_std = math.hypot(plant.params.sensor_noise_std_degc, quantum / math.sqrt(12.0))
    assert np.std(y) == pytest.approx(expected_std, rel=0.1)
    again = ThermalPlant(rng=4)
    np.testing.assert_array_equal(y, [again.step(50.0) for _ in range(2000)])


@pytest.mark.parametrize("temp_degc", [25.0, 201.0, 306.25, 450.0, 525.0])
def test_steady_state_triac_pct_inverts_the_steady_state(temp_degc: float) -> None:
    s = steady_state_triac_pct(temp_degc, QUIET)
    assert steady_state_degc(s, QUIET) == pytest.approx(temp_degc, abs=1e-9)


def test_bad_values_are_refused_with_the_value() -> None:
    with pytest.raises(PlantError, match="zone_time_s must be > 0; got -1"):
        ThermalParams(zone_time_s=-1.0)
    with pytest.raises(PlantError, match="must differ"):
        ThermalParams(element_time_s=30.0, zone_time_s=30.0)
    with pytest.raises(PlantError, match="triac_pct must be a number in \\[0, 100\\]; got 101"):
        ThermalPlant().step(101.0)
    with pytest.raises(PlantError, match="grid_voltage_factor must be finite and > 0; got 0"):
        ThermalPlant().step(50.0, Exogenous(grid_voltage_factor=0.0))
    with pytest.raises(PlantError, match="steady temperature in \\[25, 525\\] degC"):
        steady_state_triac_pct(600.0, QUIET)


def test_fixture_model_has_the_plants_lags_and_gain() -> None:
    model = load_model(FIXTURE)
    poles = np.sort(np.abs(np.roots(model.a)))
    taus_s = -model.ts_s / np.log(poles)
    np.testing.assert_allclose(taus_s, [QUIET.element_time_s, QUIET.zone_time_s], rtol=0.02)
    assert slowest_time_constant_samples(model.a) == pytest.approx(70.0, rel=0.02)
    params = ThermalParams()
    slope = (steady_state_degc(55.0, params) - steady_state_degc(45.0, params)) / 10.0
    model_slope = float(model.steady_state_power_kw(55.0) - model.steady_state_power_kw(45.0)) / 10.0
    assert model_slope == pytest.approx(slope, rel=0.01)
    assert model.units is not None and model.units.output == "degC"
    assert json.loads(FIXTURE.read_text())["provenance"]["test_run"]["plant_seed"] == 1


@pytest.mark.slow
def test_the_fixture_is_what_the_regeneration_script_writes(tmp_path: Path) -> None:
    out = tmp_path / "thermal_model.json"
    subprocess.run([sys.executable, str(ROOT / "tools" / "regenerate_thermal_model.py"), str(out)],
                   check=True, cwd=ROOT, capture_output=True)
    fresh, shipped = json.loads(out.read_text()), json.loads(FIXTURE.read_text())
    for key in ("A", "B", "C", "input_poly", "noise_std_kw", "input_range_pct", "operating_point"):
        assert fresh[key] == shipped[key], key
