"""The model-health monitor (czmpc.health): residuals, the stale-model test, its alarm figures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from czmpc.errors import SettingsError
from czmpc.health import HealthSettings, ModelHealthMonitor
from czmpc.shipped import shipped_path
from sim.model_plant import ModelPlant
from sysid.model import HammersteinModel
from sysid.modelfile import load_model
from sysid.simulate import prediction_errors_arrays
from tests.tolerances import RESIDUAL_ATOL_KW

SHIPPED = load_model(shipped_path("cz_heater_model.json"))


def _open_loop(model: HammersteinModel, n: int, seed: int, *,
               plant_model: HammersteinModel | None = None) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    s0 = model.operating_point.triac_pct + 10.0
    triac = s0 + np.repeat(rng.uniform(-5.0, 5.0, n // 100 + 1), 100)[:n]
    plant = ModelPlant(plant_model or model, initial_triac_pct=s0)
    power = np.empty(n)
    innovation = np.empty(n)
    power[0] = plant.reset(seed)
    innovation[0] = plant.innovation_kw
    for k in range(n - 1):
        power[k + 1] = plant.step(float(triac[k]))
        innovation[k + 1] = plant.innovation_kw
    return power, triac, innovation, np.full(1, s0)


def test_residuals_are_the_plant_innovations() -> None:
    power, triac, innovation, s0 = _open_loop(SHIPPED, 3000, 5)
    monitor = ModelHealthMonitor(SHIPPED)
    previous = float(s0[0])
    got = []
    for k in range(len(power)):
        got.append(monitor.update(float(power[k]), previous).residual_kw)
        previous = float(triac[k])
    got_arr = np.array(got)
    valid = np.isfinite(got_arr)
    assert valid.sum() > 2900   # only the start transient of 1/C is left out
    # the start transient decays like |c1|^k: 1e-3 of its size when residuals begin ...
    first = int(np.argmax(valid))
    np.testing.assert_allclose(got_arr[first:], innovation[first:], rtol=0.0,
                               atol=1e-3 * abs(power[0] - SHIPPED.operating_point.power_kw))
    # ... and nothing after 100 samples
    np.testing.assert_allclose(got_arr[100:], innovation[100:], rtol=0.0, atol=RESIDUAL_ATOL_KW)
    # sysid's batch prediction errors give the same once their start transient has decayed
    op = SHIPPED.operating_point
    batch = prediction_errors_arrays(SHIPPED.a, SHIPPED.b, SHIPPED.c, power - op.power_kw,
                                     SHIPPED.input_nonlinearity(triac - op.triac_pct))
    np.testing.assert_allclose(batch[200:], innovation[200:], rtol=0.0, atol=1e-6)


def test_p_values_are_uniform_under_a_correct_model() -> None:
    """Non-overlapping windows: about 10 % of the p-values fall below 0.1 (binomial 99.9 %)."""
    settings = HealthSettings(window_samples=200, test_every_samples=200)
    power, triac, _, s0 = _open_loop(SHIPPED, 200 * 121, 9)
    monitor = ModelHealthMonitor(SHIPPED, settings)
    previous = float(s0[0])
    p_values = []
    last_f = math.nan
    for k in range(len(power)):
        h = monitor.update(float(power[k]), previous)
        previous = float(triac[k])
        if h.f_statistic != last_f and math.isfinite(h.f_statistic):
            p_values.append(h.p_value)
            last_f = h.f_statistic
    assert len(p_values) >= 110
    below = sum(p < 0.1 for p in p_values)
    assert 2 <= below <= 22, below
    assert monitor.stale_alarm is False


def test_a_noisier_sensor_is_no_stale_model() -> None:
    noisy = SHIPPED.with_updates(noise_std_kw=3.0 * SHIPPED.noise_std_kw)
    power, triac, _, s0 = _open_loop(SHIPPED, 6000, 3, plant_model=noisy)
    monitor = ModelHealthMonitor(SHIPPED)
    previous = float(s0[0])
    for k in range(len(power)):
        h = monitor.update(float(power[k]), previous)
        previous = float(triac[k])
    assert not h.stale_alarm
    assert h.variance_ratio == pytest.approx(9.0, rel=0.2)   # reported, not alarmed


def test_missing_samples_give_no_residual_and_resume() -> None:
    power, triac, innovation, s0 = _open_loop(SHIPPED, 400, 2)
    power[100:110] = math.nan
    monitor = ModelHealthMonitor(SHIPPED)
    previous = float(s0[0])
    got = []
    for k in range(len(power)):
        got.append(monitor.update(float(power[k]), previous).residual_kw)
        previous = float(triac[k])
    got_arr = np.array(got)
    assert np.all(np.isnan(got_arr[100:110]))
    assert np.isnan(got_arr[110])                     # the settling after the gap
    tail = slice(200, None)
    np.testing.assert_allclose(got_arr[tail], innovation[tail], rtol=0.0, atol=1e-6)


def test_false_alarm_bound_is_the_union_bound() -> None:
    settings = HealthSettings()
    assert settings.false_alarm_bound(86_400.0, 2.0) == pytest.approx(720 * 1e-6, rel=1e-12)
    assert HealthSettings(false_alarm_per_test=0.4).false_alarm_bound(86_400.0, 2.0) == 1.0


@pytest.mark.parametrize(("field", "value"), [("window_samples", 5), ("test_every_samples", 0),
                                              ("extra_input_lags", -1),
                                              ("false_alarm_per_test", 0.0)])
def test_health_settings_reject_bad_values(field: str, value: float) -> None:
    with pytest.raises(SettingsError, match=f"HealthSettings.{field}"):
        HealthSettings(**{field: value})  # type: ignore[arg-type]


@pytest.mark.parametrize("lags", [0, 2])
def test_residual_lags_keep_a_correct_model_quiet(lags: int) -> None:
    settings = HealthSettings(window_samples=300, test_every_samples=30, residual_lags=lags,
                              false_alarm_per_test=1e-3)
    power, triac, _, s0 = _open_loop(SHIPPED, 6000, 11)
    monitor = ModelHealthMonitor(SHIPPED, settings)
    previous = float(s0[0])
    for k in range(len(power)):
        h = monitor.update(float(power[k]), previous)
        previous = float(triac[k])
    assert not h.stale_alarm and 0 < h.health < 1.0
    assert h.dof == 5   # y_{k-1} and w_{k-1..k-4} directions, whatever the nuisance lags
