"""`ModelHealthMonitor.predict_next_kw` (the `predicted_power_kw` node of czmpc run)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from czmpc.health import ModelHealthMonitor
from czmpc.shipped import shipped_path
from sysid.modelfile import load_model


def test_the_next_prediction_is_what_the_next_update_predicts_and_the_model_equation() -> None:
    model = load_model(shipped_path("cz_heater_model.json"))
    monitor = ModelHealthMonitor(model)
    assert math.isnan(monitor.predict_next_kw(45.0))          # nothing measured yet
    rng = np.random.default_rng(3)
    s0, p0 = model.operating_point.triac_pct, model.operating_point.power_kw
    u = 45.0 + rng.uniform(-8.0, 8.0, 80)
    u[0] = s0        # at rest at the operating point, as the monitor assumes of its first sample
    w = np.polyval([*model.input_poly[::-1], 0.0], u - s0)    # f(ds) = d1 ds + d2 ds^2
    # the noise-free response A y = B w from rest at the operating point, by scipy (b
    # carries the delay as its leading zero)
    y = p0 + lfilter(model.b, model.a, w)
    monitor.update(float(y[0]), float(u[0]))
    for k in range(1, len(u)):
        predicted = monitor.predict_next_kw(float(u[k - 1]))
        health = monitor.update(float(y[k]), float(u[k - 1]))
        assert predicted == pytest.approx(health.predicted_kw, abs=1e-12)
        # the data are the model's own: the one-step prediction is exact
        assert predicted == pytest.approx(float(y[k]), abs=1e-9)
