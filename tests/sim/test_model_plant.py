"""ModelPlant against scipy.signal.lfilter and the model's own one-step predictor."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from sim.errors import PlantError
from sim.model_plant import ModelPlant, steady_state_triac_pct
from sim.protocols import Exogenous, Plant
from sim.scenario import Scenario
from sysid.errors import SamplingTimeError
from sysid.model import HammersteinModel
from tests.tolerances import IDENTITY_RTOL

#: Recursions in plain floats vs lfilter's C loop: same operations in a different
#: order, a few ulps of a 50 kW signal per step, accumulated over a few thousand steps.
LFILTER_ATOL_KW = 1e-9
#: Innovations recovered by inverting C(q): the brief's ~1e-9 kW.
INNOVATION_ATOL_KW = 1e-9


@pytest.fixture(params=["oe", "armax"])
def model(request: pytest.FixtureRequest) -> HammersteinModel:
    return request.getfixturevalue(f"paper_{request.param}_model")


def _run(plant: ModelPlant, triac_pct: np.ndarray, seed: int = 0) -> tuple[np.ndarray, ...]:
    """Measured power y_0..y_n, true power and innovations, for inputs s_0..s_{n-1}."""
    measured = [plant.reset(seed)]
    true = [plant.true_power_kw]
    innov = [plant.innovation_kw]
    for s in triac_pct:
        measured.append(plant.step(float(s)))
        true.append(plant.true_power_kw)
        innov.append(plant.innovation_kw)
    return np.array(measured), np.array(true), np.array(innov)


def _w(model: HammersteinModel, triac_pct: np.ndarray) -> np.ndarray:
    return model.input_nonlinearity(np.asarray(triac_pct) - model.operating_point.triac_pct)


def test_model_plant_is_a_plant(model: HammersteinModel) -> None:
    assert isinstance(ModelPlant(model), Plant)


@pytest.mark.parametrize("s0", [45.0, 38.0], ids=["at-operating-point", "off-operating-point"])
def test_noise_free_constant_input_equals_lfilter_from_steady_state(
    model: HammersteinModel, s0: float
) -> None:
    n = 1500
    triac = np.full(n, 52.0)
    measured, true, _ = _run(ModelPlant(model, noise=False, initial_triac_pct=s0), triac)
    # y_k = P_k - P_nom; w_{k-1} drives y_k. From steady state (y_ss, w_ss), deviations
    # start from rest, so lfilter with zero initial conditions applies.
    w_ss = float(_w(model, s0))
    y_ss = model.linear_static_gain * w_ss
    w_dev = np.concatenate([[0.0], _w(model, triac) - w_ss])   # w_{k-1} - w_ss, k = 0..n
    b_no_delay = model.b[1:]                                   # the shift is in w_dev
    expected = model.operating_point.power_kw + y_ss + lfilter(b_no_delay, model.a, w_dev)
    np.testing.assert_allclose(measured, expected, rtol=0, atol=LFILTER_ATOL_KW)  # float order
    np.testing.assert_allclose(true, measured, rtol=0, atol=0)  # no noise: identical
    assert measured[-1] == pytest.approx(float(model.steady_state_power_kw(52.0)), abs=1e-3)


def test_noise_free_varying_input_equals_lfilter(model: HammersteinModel, rng: np.random.Generator) -> None:
    triac = np.repeat(rng.uniform(30.0, 65.0, size=40), 50)
    measured, _, _ = _run(ModelPlant(model, noise=False), triac)
    w = np.concatenate([[0.0], _w(model, triac)])
    expected = model.operating_point.power_kw + lfilter(model.b[1:], model.a, w)
    np.testing.assert_allclose(measured, expected, rtol=0, atol=LFILTER_ATOL_KW)  # float order


def test_innovations_reproduce_the_noise_model(model: HammersteinModel, rng: np.random.Generator) -> None:
    triac = np.repeat(rng.uniform(30.0, 65.0, size=40), 100)
    measured, true, injected = _run(ModelPlant(model, noise=True), triac, seed=11)
    y = measured - model.operating_point.power_kw
    w = np.concatenate([[0.0], _w(model, triac)])
    # one-step predictor residuals of A y = B w + C e from rest: e = (A y - B w) / C
    residuals = lfilter(model.a, model.c, y) - lfilter(model.b[1:], model.c, w)
    np.testing.assert_allclose(residuals, injected, rtol=0, atol=INNOVATION_ATOL_KW)  # brief
    # and the injected noise has the model's standard deviation: 4001 samples give
    # a relative standard error of 1/sqrt(2 n) = 1.1 %; 5 % is over 4 standard errors
    assert np.std(injected) == pytest.approx(model.noise_std_kw, rel=0.05)
    # the true power is the noise-free part
    noise_free, _, _ = _run(ModelPlant(model, noise=False), triac)
    np.testing.assert_allclose(true, noise_free, rtol=IDENTITY_RTOL, atol=0)  # same recursion


def test_same_seed_gives_identical_output_and_another_seed_does_not(model: HammersteinModel) -> None:
    triac = np.full(5000, 50.0)   # longer than one noise block
    first, _, _ = _run(ModelPlant(model), triac, seed=3)
    plant = ModelPlant(model)
    second, _, _ = _run(plant, triac, seed=3)
    again, _, _ = _run(plant, triac, seed=3)    # reset really restarts
    other, _, _ = _run(ModelPlant(model), triac, seed=4)
    assert np.array_equal(first, second) and np.array_equal(first, again)
    assert not np.array_equal(first, other)


def test_voltage_factor_scales_absolute_power_and_offset_adds(paper_oe_model: HammersteinModel) -> None:
    plant = ModelPlant(paper_oe_model, noise=False)
    p0 = plant.reset(0)
    p_sag = plant.step(45.0, Exogenous(grid_voltage_factor=0.97))
    assert p_sag == pytest.approx(0.97**2 * p0, rel=IDENTITY_RTOL)
    p_shift = plant.step(45.0, Exogenous(power_offset_kw=0.15))
    assert p_shift == pytest.approx(p0 + 0.15, rel=IDENTITY_RTOL)
    both = plant.step(45.0, Exogenous(grid_voltage_factor=1.02, power_offset_kw=-0.5))
    assert both == pytest.approx(1.02**2 * p0 - 0.5, rel=IDENTITY_RTOL)
    assert plant.true_power_kw == both


def test_noise_is_added_to_the_disturbed_true_power(paper_armax_model: HammersteinModel) -> None:
    plant = ModelPlant(paper_armax_model, noise=True)
    plant.reset(5)
    measured = plant.step(45.0, Exogenous(grid_voltage_factor=0.97))
    quiet = ModelPlant(paper_armax_model, noise=False)
    quiet.reset(5)
    assert plant.true_power_kw == quiet.step(45.0, Exogenous(grid_voltage_factor=0.97))
    assert measured != plant.true_power_kw


def test_power_is_clamped_at_zero_where_the_quadratic_goes_negative(
    paper_oe_model: HammersteinModel,
) -> None:
    assert float(paper_oe_model.steady_state_power_kw(0.0)) < 0.0    # the bad extrapolation
    plant = ModelPlant(paper_oe_model, noise=False, initial_triac_pct=0.0)
    assert plant.reset(0) == 0.0
    for _ in range(50):
        assert plant.step(0.0) == 0.0
    assert plant.step(45.0) > 0.0


def test_input_is_saturated_to_the_physical_triac_range(paper_oe_model: HammersteinModel) -> None:
    high, low = ModelPlant(paper_oe_model, noise=False), ModelPlant(paper_oe_model, noise=False)
    high.reset(0)
    low.reset(0)
    assert high.step(130.0) == low.step(100.0)


def test_step_refuses_nan_input_and_a_plant_not_reset(paper_oe_model: HammersteinModel) -> None:
    plant = ModelPlant(paper_oe_model)
    with pytest.raises(PlantError, match=r"reset"):
        plant.step(45.0)
    plant.reset(0)
    with pytest.raises(PlantError, match=r"finite triac_pct.*nan"):
        plant.step(math.nan)


def test_constructor_refuses_no_delay_and_bad_initial_input(paper_oe_model: HammersteinModel) -> None:
    no_delay = paper_oe_model.with_updates(b=[1.0, -0.991])
    with pytest.raises(PlantError, match=r"input delay of at least 1"):
        ModelPlant(no_delay)
    with pytest.raises(PlantError, match=r"initial_triac_pct.*0..100"):
        ModelPlant(paper_oe_model, initial_triac_pct=120.0)
    with pytest.raises(PlantError, match=r"triac_limits_pct"):
        ModelPlant(paper_oe_model, triac_limits_pct=(80.0, 20.0))


def test_steady_state_triac_inverts_steady_state_power(paper_armax_model: HammersteinModel) -> None:
    for power_kw in (20.0, 45.0, 60.0, 80.0):
        s = steady_state_triac_pct(paper_armax_model, power_kw)
        assert float(paper_armax_model.steady_state_power_kw(s)) == pytest.approx(power_kw, abs=1e-9)
    assert steady_state_triac_pct(paper_armax_model, 45.0) == pytest.approx(45.0, abs=1e-12)
    with pytest.raises(PlantError, match=r"200 kW"):
        steady_state_triac_pct(paper_armax_model, 200.0)


def test_for_scenario_starts_at_the_setpoint_or_the_given_input(
    paper_armax_model: HammersteinModel,
) -> None:
    scenario = Scenario(name="t", duration_s=20.0, initial_setpoint_kw=20.0, plant_noise=False)
    plant = ModelPlant.for_scenario(paper_armax_model, scenario)
    assert not plant.noise
    assert plant.reset(0) == pytest.approx(20.0, abs=1e-9)
    given = Scenario(name="t", duration_s=20.0, initial_setpoint_kw=20.0, initial_triac_pct=40.0)
    assert ModelPlant.for_scenario(paper_armax_model, given).initial_triac_pct == 40.0
    wrong_ts = Scenario(name="t", duration_s=20.0, ts_s=1.0, initial_setpoint_kw=45.0)
    with pytest.raises(SamplingTimeError, match=r"scenario 't'"):
        ModelPlant.for_scenario(paper_armax_model, wrong_ts)
