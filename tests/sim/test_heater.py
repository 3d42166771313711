"""VirtualHeater: steady state, voltage scaling, delay, sag, reproducibility, validation."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim.errors import PlantError
from sim.heater import HeaterParams, VirtualHeater, power_fraction, steady_state
from sim.protocols import Exogenous, Plant
from sysid.data import Dataset
from sysid.steps import detect_steps
from tests.tolerances import IDENTITY_RTOL

#: A heater without sensor noise and grid wander: deterministic physics only.
QUIET = HeaterParams(sensor_noise_std_kw=0.0, grid_wander_std=0.0)

#: In one 2 s sample 10 kW more heat warms the 27 kJ/K element by < 1 K, which raises
#: its resistance by < 3.5e-4 relative (alpha = 3.5e-4 /K).
ONE_SAMPLE_HEATING_RTOL = 5e-4


def _run(heater: VirtualHeater, triac_pct: np.ndarray) -> np.ndarray:
    """Measured power y_0..y_n for inputs s_0..s_{n-1} (y_{k+1} responds to s_k)."""
    return np.array([heater.reset(5)] + [heater.step(float(s)) for s in triac_pct])


def test_heater_implements_the_plant_protocol() -> None:
    heater = VirtualHeater(rng=1)
    assert isinstance(heater, Plant)
    assert heater.ts_s == 2.0


def test_holding_45_pct_settles_at_45_kw() -> None:
    # Start far away (30 %) and hold 45 % for 20 time constants.
    heater = VirtualHeater(dataclasses.replace(QUIET, initial_triac_pct=30.0), rng=0)
    for _ in range(2000):
        heater.step(45.0)
    assert abs(heater.true_power_kw - 45.0) < 0.1  # calibration target (a)
    power_kw, _ = steady_state(45.0, QUIET)
    np.testing.assert_allclose(heater.true_power_kw, power_kw, rtol=1e-9, atol=0.0,
                               err_msg="simulation converges to the closed-form steady state")


def test_reset_starts_at_the_steady_state_of_the_initial_input() -> None:
    heater = VirtualHeater(dataclasses.replace(QUIET, initial_triac_pct=60.0), rng=0)
    first_kw = heater.true_power_kw
    for _ in range(50):
        heater.step(60.0)
    np.testing.assert_allclose(heater.true_power_kw, first_kw, rtol=1e-9, atol=0.0,
                               err_msg="a steady state stays put")


def test_power_scales_with_grid_voltage_squared() -> None:
    nominal = VirtualHeater(QUIET, rng=0)
    raised = VirtualHeater(QUIET, rng=0)
    p_nominal = nominal.step(45.0)
    p_raised = raised.step(45.0, Exogenous(grid_voltage_factor=1.1))
    np.testing.assert_allclose(p_raised / p_nominal, 1.1**2, rtol=ONE_SAMPLE_HEATING_RTOL,
                               atol=0.0)
    # Exactly v^2 once the slightly warmer element's resistance is accounted for.
    alpha, t_ref = QUIET.resistance_tc_per_k, QUIET.reference_temp_k
    resistance_ratio = (1 + alpha * (raised.element_temp_k - t_ref)) / (
        1 + alpha * (nominal.element_temp_k - t_ref))
    np.testing.assert_allclose(p_raised / p_nominal * resistance_ratio, 1.1**2,
                               rtol=IDENTITY_RTOL, atol=0.0)


def test_power_offset_adds_to_the_true_power() -> None:
    nominal = VirtualHeater(QUIET, rng=0)
    shifted = VirtualHeater(QUIET, rng=0)
    nominal.step(45.0)
    shifted.step(45.0, Exogenous(power_offset_kw=0.15))
    np.testing.assert_allclose(shifted.true_power_kw - nominal.true_power_kw, 0.15,
                               rtol=0.0, atol=45.0 * ONE_SAMPLE_HEATING_RTOL)


def test_input_shows_in_power_exactly_one_sample_later() -> None:
    triac_pct = np.r_[np.full(10, 45.0), np.full(10, 50.0)]   # s changes at k = 10
    power_kw = _run(VirtualHeater(QUIET, rng=0), triac_pct)
    np.testing.assert_allclose(power_kw[:11], power_kw[0], rtol=1e-12, atol=0.0,
                               err_msg="nothing moves up to and including sample 10")
    assert power_kw[11] - power_kw[10] > 6.0           # the step arrives at k = 11
    data = Dataset(time_s=np.arange(triac_pct.size) * 2.0, triac_pct=triac_pct,
                   power_kw=power_kw[:-1], ts_s=2.0)
    # Aligned as a log (P_k beside s_k), the jump sits one sample after the input step.
    (step,) = detect_steps(data, delay_steps=1)
    assert step.k == 10 and step.power_after_kw - step.power_before_kw > 6.0
    (late,) = detect_steps(data, delay_steps=2)
    assert abs(late.power_after_kw - late.power_before_kw) < 0.1


def test_step_sags_about_12_pct_with_a_time_constant_near_200_s() -> None:
    heater = VirtualHeater(QUIET, rng=0)
    before_kw = heater.true_power_kw
    after_kw = [heater.step(50.0) for _ in range(1500)]
    instantaneous_kw = after_kw[0] - before_kw
    settled_kw = after_kw[-1] - before_kw
    assert 0.85 < settled_kw / instantaneous_kw < 0.92       # steady ~0.9 x instantaneous
    sag = (np.asarray(after_kw) - after_kw[-1]) / (after_kw[0] - after_kw[-1])
    time_constant_s = 2.0 * (np.argmax(sag < math.exp(-1.0)))
    assert 150.0 < time_constant_s < 260.0


def test_instantaneous_gain_falls_as_the_operating_point_rises() -> None:
    gains = []
    for level in (25.0, 35.0, 45.0, 55.0, 65.0):
        heater = VirtualHeater(dataclasses.replace(QUIET, initial_triac_pct=level), rng=0)
        before_kw = heater.true_power_kw
        gains.append((heater.step(level + 5.0) - before_kw) / 5.0)
    assert np.all(np.diff(gains) < 0.0)


def test_same_seed_gives_identical_runs_and_another_seed_does_not() -> None:
    triac_pct = 45.0 + 5.0 * np.sin(np.arange(300) / 20.0)
    first = _run(VirtualHeater(rng=3), triac_pct)
    again = _run(VirtualHeater(rng=3), triac_pct)
    assert np.array_equal(first, again)                # _run resets with seed 5 each time
    heater = VirtualHeater()
    seeded = [heater.reset(11)] + [heater.step(float(s)) for s in triac_pct]
    other = [heater.reset(12)] + [heater.step(float(s)) for s in triac_pct]
    assert not np.array_equal(seeded, other)


def test_a_generator_seeds_a_run_like_an_int_seed_gives_reproducible_runs() -> None:
    a = VirtualHeater(rng=np.random.default_rng(8))
    b = VirtualHeater(rng=np.random.default_rng(8))
    assert np.array_equal([a.step(40.0) for _ in range(20)], [b.step(40.0) for _ in range(20)])


def test_sensor_noise_stream_does_not_shift_when_the_wander_is_switched_off() -> None:
    triac_pct = np.full(200, 45.0)
    noises = []
    for params in (HeaterParams(), HeaterParams(grid_wander_std=0.0)):
        heater = VirtualHeater(params)
        measured = [heater.reset(21)]
        true = [heater.true_power_kw]
        for s in triac_pct:
            measured.append(heater.step(float(s)))
            true.append(heater.true_power_kw)
        noises.append(np.asarray(measured) - np.asarray(true))
    np.testing.assert_allclose(noises[0], noises[1], rtol=0.0, atol=1e-12,
                               err_msg="same sensor noise draws with and without wander")
    assert np.std(noises[0]) > 0.005


def test_power_is_never_negative() -> None:
    heater = VirtualHeater(dataclasses.replace(HeaterParams(), initial_triac_pct=0.0), rng=4)
    measured = [heater.step(0.0) for _ in range(500)]
    assert heater.true_power_kw == 0.0
    assert min(measured) >= 0.0 and max(measured) > 0.0   # noise is clipped, not removed
    heater.step(0.0, Exogenous(power_offset_kw=-5.0))
    assert heater.true_power_kw == 0.0


def test_power_fraction_is_zero_below_the_threshold_and_one_at_full_input() -> None:
    params = HeaterParams()
    assert power_fraction(params.firing_threshold_pct, params) == 0.0
    np.testing.assert_allclose(power_fraction(100.0, params), 1.0, rtol=IDENTITY_RTOL, atol=0.0)
    values = [power_fraction(s, params) for s in np.linspace(0.0, 100.0, 201)]
    assert np.all(np.diff(values) >= 0.0)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("ts_s", 0.0, r"HeaterParams.ts_s must be > 0; got 0.0"),
        ("rated_power_kw", -1.0, r"rated_power_kw must be > 0"),
        ("heat_capacity_kj_per_k", math.nan, r"heat_capacity_kj_per_k must be finite"),
        ("sensor_noise_std_kw", -0.1, r"sensor_noise_std_kw must be >= 0"),
        ("grid_wander_time_s", 0.0, r"grid_wander_time_s must be > 0"),
        ("firing_threshold_pct", 100.0, r"firing_threshold_pct must be in \[0, 100\)"),
        ("firing_droop", 1.0, r"firing_droop must be in \[0, 1\)"),
        ("firing_exponent", 0.5, r"firing_exponent must be >= 1"),
        ("initial_triac_pct", 101.0, r"initial_triac_pct must be in \[0, 100\]"),
        ("resistance_tc_per_k", 0.01, r"relative resistance at the wall temperature"),
        ("emissivity_area_m2", "big", r"emissivity_area_m2 must be a number; got 'big'"),
    ],
    ids=lambda v: str(v)[:24],
)
def test_invalid_params_are_refused(field: str, value: object, match: str) -> None:
    with pytest.raises(PlantError, match=match):
        HeaterParams(**{field: value})  # type: ignore[arg-type]


@pytest.mark.parametrize("triac_pct", [math.nan, -1.0, 100.5], ids=["nan", "negative", "above"])
def test_step_refuses_an_input_outside_0_100(triac_pct: float) -> None:
    heater = VirtualHeater(rng=0)
    with pytest.raises(PlantError, match=r"triac_pct must be a number in \[0, 100\]"):
        heater.step(triac_pct)


@pytest.mark.parametrize(
    ("exogenous", "match"),
    [
        (Exogenous(grid_voltage_factor=0.0), r"grid_voltage_factor must be finite and > 0"),
        (Exogenous(grid_voltage_factor=math.inf), r"grid_voltage_factor must be finite"),
        (Exogenous(power_offset_kw=math.nan), r"power_offset_kw must be finite"),
    ],
    ids=["zero-voltage", "inf-voltage", "nan-offset"],
)
def test_step_refuses_bad_exogenous_inputs(exogenous: Exogenous, match: str) -> None:
    heater = VirtualHeater(rng=0)
    with pytest.raises(PlantError, match=match):
        heater.step(45.0, exogenous)


def test_heater_refuses_params_of_the_wrong_type() -> None:
    with pytest.raises(PlantError, match="params must be a HeaterParams"):
        VirtualHeater({"ts_s": 2.0})  # type: ignore[arg-type]
