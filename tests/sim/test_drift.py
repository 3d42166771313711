"""Plant variations and drifts (sim.drift): each option changes the response as stated."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.drift import (
    DriftEvent,
    PlantVariation,
    heater_time_constant_s,
    model_time_constant_s,
    parse_drift,
    vary_heater,
    vary_model_plant,
)
from sim.errors import PlantError
from sim.heater import HeaterParams
from sysid.model import HammersteinModel
from tests.tolerances import HEATER_VARIATION_RTOL, IDENTITY_RTOL, RISE_TIME_ATOL_S

QUIET = HeaterParams(sensor_noise_std_kw=0.0, grid_wander_std=0.0)


def _model_step(model: HammersteinModel, variation: PlantVariation, *, n: int,
                s1: float = 50.0) -> tuple[float, np.ndarray]:
    plant = vary_model_plant(model, variation, noise=False)
    y0 = plant.reset(0)
    return y0, np.array([plant.step(s1) for _ in range(n)])


def _rise_time_s(y: np.ndarray, ts_s: float) -> float:
    """63 % time of the sag that follows the instantaneous jump (y[0] is the jump)."""
    frac = (y - y[0]) / (y[-1] - y[0])
    return float(np.argmax(frac >= 1.0 - math.exp(-1.0))) * ts_s


def test_model_plant_gain_factor_scales_the_static_gain(paper_armax_model: HammersteinModel) -> None:
    m = paper_armax_model
    y0, y = _model_step(m, PlantVariation(gain_factor=0.8), n=6000)
    expected = 0.8 * m.linear_static_gain * float(m.input_nonlinearity(np.array([5.0]))[0])
    np.testing.assert_allclose(y[-1] - y0, expected, rtol=1e-9, atol=0.0)


def test_model_plant_tau_sets_the_63_percent_time(paper_armax_model: HammersteinModel) -> None:
    m = paper_armax_model
    assert model_time_constant_s(m) == pytest.approx(-2.0 / math.log(0.99), rel=IDENTITY_RTOL)
    _, y = _model_step(m, PlantVariation(tau_s=600.0), n=6000)
    assert abs(_rise_time_s(y, m.ts_s) - 600.0) <= RISE_TIME_ATOL_S
    _, y_nom = _model_step(m, PlantVariation(), n=6000)
    np.testing.assert_allclose(y[-1], y_nom[-1], rtol=1e-9, atol=0.0)  # static gain held
    np.testing.assert_allclose(y[0], y_nom[0], rtol=IDENTITY_RTOL, atol=0.0)  # jump held


def test_model_plant_extra_delay_shifts_the_response_exactly(paper_armax_model: HammersteinModel) -> None:
    _, y = _model_step(paper_armax_model, PlantVariation(extra_delay_samples=2), n=50)
    y0, y_nom = _model_step(paper_armax_model, PlantVariation(), n=48)
    np.testing.assert_array_equal(y[:2], [y0, y0])
    np.testing.assert_array_equal(y[2:], y_nom)


def test_model_plant_gain_drift_acts_from_its_time(paper_armax_model: HammersteinModel) -> None:
    m = paper_armax_model
    drift = PlantVariation(drifts=(parse_drift("gain=0.75@4000"),))
    y0, y = _model_step(m, drift, n=6000)
    _, y_nom = _model_step(m, PlantVariation(), n=6000)
    k_drift = 2000   # first sample applied with the new gain: t = 4000 s
    np.testing.assert_array_equal(y[:k_drift], y_nom[:k_drift])
    assert y[k_drift] != y_nom[k_drift]
    np.testing.assert_allclose(y[-1] - y0, 0.75 * (y_nom[-1] - y0), rtol=1e-9, atol=0.0)


def test_model_plant_tau_drift_keeps_the_state(paper_armax_model: HammersteinModel) -> None:
    m = paper_armax_model
    drift = PlantVariation(drifts=(DriftEvent(quantity="tau", value=1000.0, at_s=0.0),))
    _, y = _model_step(m, drift, n=8000)
    assert abs(_rise_time_s(y, m.ts_s) - 1000.0) <= RISE_TIME_ATOL_S


def test_heater_gain_factor_scales_a_small_step_gain() -> None:
    def gain(variation: PlantVariation) -> float:
        plant = vary_heater(variation, QUIET, rng=0)
        y0 = plant.reset(0)
        y = [plant.step(47.0) for _ in range(3000)]
        return (y[-1] - y0) / 2.0

    ratio = gain(PlantVariation(gain_factor=0.8)) / gain(PlantVariation())
    np.testing.assert_allclose(ratio, 0.8, rtol=HEATER_VARIATION_RTOL, atol=0.0)


def test_heater_tau_sets_the_63_percent_time() -> None:
    plant = vary_heater(PlantVariation(tau_s=600.0), QUIET, rng=0)
    plant.reset(0)
    y = np.array([plant.step(47.0) for _ in range(5000)])
    np.testing.assert_allclose(_rise_time_s(y, QUIET.ts_s), 600.0, rtol=HEATER_VARIATION_RTOL,
                               atol=RISE_TIME_ATOL_S)
    assert heater_time_constant_s(QUIET) == pytest.approx(198.6, abs=0.1)


def test_heater_extra_delay_shifts_the_response_exactly() -> None:
    def response(variation: PlantVariation, n: int) -> tuple[float, list[float]]:
        plant = vary_heater(variation, QUIET, rng=0)
        y0 = plant.reset(0)
        return y0, [plant.step(47.0) for _ in range(n)]

    y0, y = response(PlantVariation(extra_delay_samples=2), 40)
    _, y_nom = response(PlantVariation(), 38)
    np.testing.assert_allclose(y[:2], [y0, y0], rtol=IDENTITY_RTOL, atol=0.0)
    np.testing.assert_array_equal(y[2:], y_nom)


def test_reset_undoes_the_drifts(paper_armax_model: HammersteinModel) -> None:
    plant = vary_model_plant(paper_armax_model, PlantVariation(
        drifts=(parse_drift("gain=0.5@2"),)), noise=False)
    plant.reset(0)
    first = [plant.step(50.0) for _ in range(5)]
    assert plant.gain_factor == 0.5
    plant.reset(0)
    assert plant.gain_factor == 1.0
    np.testing.assert_array_equal([plant.step(50.0) for _ in range(5)], first)
    assert plant.gain_factor == 0.5


@pytest.mark.parametrize("text", ["gain=0.75", "tau=x@3", "delay=2@3", "gain=-1@3", "gain=1@-5"])
def test_parse_drift_rejects_bad_text(text: str) -> None:
    with pytest.raises(PlantError, match="(?i)drift"):
        parse_drift(text)


def test_variation_rejects_bad_values() -> None:
    with pytest.raises(PlantError, match="gain_factor"):
        PlantVariation(gain_factor=0.0)
    with pytest.raises(PlantError, match="tau_s"):
        PlantVariation(tau_s=math.inf)
    with pytest.raises(PlantError, match="extra_delay_samples"):
        PlantVariation(extra_delay_samples=-1)


def test_describe_names_every_change() -> None:
    v = PlantVariation(gain_factor=0.8, tau_s=600.0, extra_delay_samples=2,
                       drifts=(parse_drift("tau=1200@7200"), parse_drift("gain=0.75@3600")))
    assert v.describe() == ("gain x0.8, tau 600 s, +2 samples delay, gain->x0.75 @ 3600 s, "
                            "tau->1200 s @ 7200 s")
    assert PlantVariation().is_nominal


def test_model_plant_set_model_refuses_another_shape(paper_armax_model: HammersteinModel) -> None:
    plant = vary_model_plant(paper_armax_model, PlantVariation(), noise=False)
    other = paper_armax_model.with_updates(b=np.array([0.0, 0.0, 1.0, -0.991]))
    with pytest.raises(PlantError, match="same Ts"):
        plant.plant.set_model(other)  # type: ignore[attr-defined]
