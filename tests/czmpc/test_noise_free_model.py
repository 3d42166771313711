"""A noise-free model (``noise_std_kw = 0``) loads, runs offset-free and is monitored safely."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from czmpc.controller import OffsetFreeMPC
from czmpc.health import ModelHealthMonitor
from czmpc.mismatch import NOISE_FREE_STD_FRACTION, monitored_noise_std_kw
from sim.model_plant import ModelPlant
from sysid.model import HammersteinModel
from sysid.modelfile import load_model, save_model

#: Noise-free plant and model: the loop settles to rounding; 1e-6 kW is far above it and
#: far below any offset (the 0.15 kW shift of the controller tests).
SETTLED_ATOL_KW = 1e-6


@pytest.fixture
def noise_free(paper_armax_model: HammersteinModel, tmp_path: Path) -> HammersteinModel:
    path = tmp_path / "model.json"
    save_model(dataclasses.replace(paper_armax_model, noise_std_kw=0.0), path)
    return load_model(path)


def test_noise_free_model_runs_offset_free_on_its_model_plant(noise_free: HammersteinModel) -> None:
    assert noise_free.noise_std_kw == 0.0
    mpc = OffsetFreeMPC(noise_free)
    plant = ModelPlant(noise_free, noise=False, initial_triac_pct=45.0)
    power = plant.reset(np.random.default_rng(0))
    for k in range(900):
        # a step of the setpoint, then a 0.2 kW output shift the model does not know
        s = mpc.step(power, 45.0 if k < 50 else 47.0)
        power = plant.step(s) + (0.2 if k >= 400 else 0.0)
    last = mpc.last_step
    assert last is not None and math.isfinite(last.triac_pct)
    assert power == pytest.approx(47.0, abs=SETTLED_ATOL_KW)
    assert last.disturbance_power_kw == pytest.approx(0.2, abs=1e-3)
    assert last.mismatch is not None
    assert math.isfinite(last.mismatch.mean_z) and math.isfinite(last.mismatch.variance_ratio)


def test_monitors_divide_by_a_millionth_of_the_output_span_for_a_noise_free_model(
    noise_free: HammersteinModel, paper_armax_model: HammersteinModel,
) -> None:
    span_kw = float(np.ptp(noise_free.steady_state_power_kw(np.linspace(20.0, 70.0, 101))))
    assert span_kw > 10.0        # the paper's heater: tens of kW over 20..70 %
    assert monitored_noise_std_kw(noise_free) == pytest.approx(NOISE_FREE_STD_FRACTION * span_kw)
    assert monitored_noise_std_kw(paper_armax_model) == paper_armax_model.noise_std_kw
    # the health monitor on the noise-free model's own plant: finite statistics, no alarm
    health = ModelHealthMonitor(noise_free)
    plant = ModelPlant(noise_free, noise=False, initial_triac_pct=45.0)
    power = plant.reset(np.random.default_rng(0))
    triac = 45.0 + 5.0 * np.sign(np.sin(np.arange(600) / 40.0))
    applied = 45.0
    for s in triac:
        report = health.update(power, applied)      # the input applied before this sample
        applied = float(s)
        power = plant.step(applied)
    assert report.n_samples > 0
    assert math.isfinite(report.mean_z) and abs(report.mean_z) < 4.0
    assert math.isfinite(report.variance_ratio) and report.variance_ratio < 4.0
    assert not report.stale_alarm
