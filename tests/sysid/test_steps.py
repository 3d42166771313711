"""Step analysis: detection against noise, instantaneous gains, delays, units, errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter, lfilter_zi

from sysid.data import Dataset
from sysid.errors import IdentificationError
from sysid.steps import (
    InputStep,
    default_step_threshold,
    detect_steps,
    format_step_table,
)
from tests.tolerances import IDENTITY_RTOL

#: lfilter and the gain's subtraction/division of O(50) numbers: a few ulps of 50.
LFILTER_ATOL_KW_PER_PCT = 1e-10


def _dataset(triac_pct: np.ndarray, power_kw: np.ndarray, **units: str) -> Dataset:
    return Dataset(time_s=np.arange(len(triac_pct)) * 2.0, triac_pct=triac_pct,
                   power_kw=power_kw, ts_s=2.0, **units)


def _staircase(levels: list[float], hold: int) -> np.ndarray:
    return np.repeat(np.asarray(levels, dtype=float), hold)


def test_gain_equals_the_jump_of_f_for_a_hammerstein_model_simulated_by_lfilter() -> None:
    # Paper eq. 27 shape: dP_k + a1 dP_{k-1} = f(ds_{k-1}) + b2 f(ds_{k-2}). From a steady
    # state the first response to a step is exactly f(ds_after) - f(ds_before) (eq. 15).
    a1, b2, d1, d2 = -0.99, -0.991, 1.4, -0.007
    ds = _staircase([0.0, 5.0, 10.0, 15.0, 20.0], hold=3000) - 10.0
    w = d1 * ds + d2 * ds**2
    b, a = [0.0, 1.0, b2], [1.0, a1]
    dp = lfilter(b, a, w, zi=lfilter_zi(b, a) * w[0])[0]
    data = _dataset(ds + 45.0, dp + 45.0)
    steps = detect_steps(data)
    assert [s.k for s in steps] == [3000, 6000, 9000, 12000]
    expected = [((d1 * hi + d2 * hi**2) - (d1 * lo + d2 * lo**2)) / 5.0
                for lo, hi in [(-10, -5), (-5, 0), (0, 5), (5, 10)]]
    np.testing.assert_allclose([s.gain_kw_per_pct for s in steps], expected, rtol=0.0,
                               atol=LFILTER_ATOL_KW_PER_PCT)


def test_step_fields_read_the_samples_around_the_delay() -> None:
    triac_pct = np.array([10.0, 10.0, 10.0, 20.0, 20.0, 20.0])
    power_kw = np.array([1.0, 1.1, 1.2, 1.3, 9.0, 9.5])
    (step,) = detect_steps(_dataset(triac_pct, power_kw))
    assert step == InputStep(k=3, time_s=6.0, triac_before_pct=10.0, triac_after_pct=20.0,
                             power_before_kw=1.3, power_after_kw=9.0,
                             gain_kw_per_pct=(9.0 - 1.3) / 10.0)
    assert step.step_pct == 10.0
    (no_delay,) = detect_steps(_dataset(triac_pct, power_kw), delay_steps=0)
    assert (no_delay.power_before_kw, no_delay.power_after_kw) == (1.2, 1.3)
    (two,) = detect_steps(_dataset(triac_pct, power_kw), delay_steps=2)
    assert (two.power_before_kw, two.power_after_kw) == (9.0, 9.5)


def test_downward_steps_have_a_positive_gain_for_a_rising_curve() -> None:
    triac_pct = _staircase([50.0, 40.0], hold=5)
    power_kw = _staircase([60.0, 47.0], hold=5)
    power_kw = np.r_[power_kw[0], power_kw[:-1]]          # one sample of delay
    (step,) = detect_steps(_dataset(triac_pct, power_kw))
    assert step.step_pct == -10.0
    np.testing.assert_allclose(step.gain_kw_per_pct, 1.3, rtol=IDENTITY_RTOL, atol=0.0)


def test_noise_on_the_input_is_not_taken_for_steps(rng: np.random.Generator) -> None:
    triac_pct = _staircase([30.0, 35.0, 40.0], hold=2000) + rng.normal(0.0, 0.1, 6000)
    power_kw = 45.0 + rng.normal(0.0, 0.01, 6000)
    steps = detect_steps(_dataset(triac_pct, power_kw))
    assert [s.k for s in steps] == [2000, 4000]
    threshold = default_step_threshold(triac_pct)
    # 5 robust sigmas of the changes (sigma_change = 0.1 * sqrt(2)) exceed 5 % of the range.
    assert 0.6 < threshold < 0.8


def test_default_threshold_is_5_pct_of_the_range_for_a_clean_staircase() -> None:
    triac_pct = _staircase([20.0, 23.0, 26.0, 60.0], hold=10)
    np.testing.assert_allclose(default_step_threshold(triac_pct), 0.05 * 40.0,
                               rtol=IDENTITY_RTOL, atol=0.0)
    assert default_step_threshold(np.full(10, 3.0)) == 0.0


def test_small_changes_need_an_explicit_threshold() -> None:
    triac_pct = _staircase([40.0, 40.5, 60.0], hold=10)
    power_kw = np.linspace(40.0, 60.0, 30)
    data = _dataset(triac_pct, power_kw)
    assert [s.k for s in detect_steps(data)] == [20]                # 0.5 < 5 % of 20
    assert [s.k for s in detect_steps(data, min_step=0.25)] == [10, 20]
    assert detect_steps(data, min_step=19.5) == ()


def test_a_step_whose_response_is_after_the_record_is_not_listed() -> None:
    triac_pct = np.array([10.0, 10.0, 10.0, 10.0, 20.0])
    assert detect_steps(_dataset(triac_pct, np.arange(5.0))) == ()
    assert len(detect_steps(_dataset(triac_pct, np.arange(5.0)), delay_steps=0)) == 1


def test_table_shows_the_data_sets_units_for_other_rigs() -> None:
    # A rig with the input in volts and the output a temperature in degC.
    triac_pct = _staircase([2.0, 4.0], hold=5)
    power_kw = np.r_[np.full(6, 300.0), np.full(4, 340.0)]
    data = _dataset(triac_pct, power_kw, input_unit="V", output_unit="degC")
    with pytest.warns(DeprecationWarning, match="format_table"):
        text = format_step_table(detect_steps(data), input_unit=data.input_unit,
                                 output_unit=data.output_unit)
    header, row = text.splitlines()
    assert "input [V]" in header and "output [degC]" in header and "r [degC/V]" in header
    assert row.split() == ["5", "10.0", "2.00", "->", "4.00", "300.000", "->", "340.000",
                           "20.0000"]
    with pytest.warns(DeprecationWarning):
        assert format_step_table(()) == "no input steps found\n"


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"min_step": -1.0}, r"min_step must be a finite number >= 0; got -1.0"),
        ({"min_step": float("nan")}, r"min_step must be a finite number >= 0; got nan"),
        ({"delay_steps": -1}, r"delay_steps must be an int >= 0; got -1"),
        ({"delay_steps": 1.5}, r"delay_steps must be an int >= 0; got 1.5"),
        ({"delay_steps": True}, r"delay_steps must be an int >= 0; got True"),
    ],
    ids=["negative-step", "nan-step", "negative-delay", "float-delay", "bool-delay"],
)
def test_bad_options_are_refused(options: dict[str, object], match: str) -> None:
    data = _dataset(np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0, 3.0]))
    with pytest.raises(IdentificationError, match=match):
        detect_steps(data, **options)  # type: ignore[arg-type]
