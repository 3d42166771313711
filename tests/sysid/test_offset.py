"""The sample-mean operating point moved onto the steady-state curve (sysid.offset)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from sysid.errors import IdentificationError
from sysid.offset import steady_state_offset_kw

#: Truth: dP = 0.05 q^-1 / (1 - 0.95 q^-1) f(ds), f = 1.3 ds - 0.02 ds^2 about s = 45 %.
D1, D2 = 1.3, -0.02


def _staircase(levels: list[float], hold: int) -> np.ndarray:
    return np.repeat(np.array(levels), hold)


def test_the_offset_is_the_curvature_bias_of_the_mean_power() -> None:
    rng = np.random.default_rng(5)
    s = _staircase([36.0, 40.5, 45.0, 49.5, 54.0, 49.5, 45.0, 40.5, 36.0] * 2, 80)
    ds_true = s - 45.0
    power = 44.0 + lfilter([0.0, 0.05], [1.0, -0.95], D1 * ds_true + D2 * ds_true**2,
                           zi=[0.0])[0] + 0.02 * rng.standard_normal(s.size)
    # the steady state at the mean input, from the truth (static gain 1)
    s_mean, p_mean = float(s.mean()), float(power.mean())
    d = s_mean - 45.0
    expected = 44.0 + D1 * d + D2 * d**2 - p_mean
    offset = steady_state_offset_kw([(power - p_mean, s - s_mean)], degree=2, nk=1)
    assert offset is not None
    # the bias is about D2 var(ds) = -0.02 * 33 = -0.66 kW; recovered within 0.02 kW
    # (noise 0.02 kW on 1,440 samples; the transient at the start costs a little more)
    assert abs(expected) > 0.4
    assert offset == pytest.approx(expected, abs=0.02)


def test_no_steady_state_and_bad_arguments() -> None:
    k = np.arange(400, dtype=float)
    ds = np.sign(np.sin(k / 20.0))
    ramp = np.concatenate([[0.0], np.cumsum(ds)[:-1]])   # y_k = y_{k-1} + ds_{k-1}: A(1) = 0
    assert steady_state_offset_kw([(ramp - ramp.mean(), ds)], degree=1, nk=1) is None
    assert steady_state_offset_kw([(ramp[:5], ds[:5])], degree=1, nk=1) is None
    with pytest.raises(IdentificationError, match="degree must be 1, 2 or 3; got 4"):
        steady_state_offset_kw([(ramp, ds)], degree=4, nk=1)
    with pytest.raises(IdentificationError, match="nk must be an int >= 0; got -1"):
        steady_state_offset_kw([(ramp, ds)], degree=1, nk=-1)
