"""Setpoint shaper and limit ramp, against lfilter and hand-computed ramps."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal

from czmpc.errors import SettingsError
from czmpc.inversion import InputMap, build_input_map
from czmpc.supervision import MAX_SETPOINT_KW, LimitRamp, SetpointShaper
from sysid.model import HammersteinModel

#: The shaper's recursion and lfilter's differ in arithmetic order only.
FILTER_ATOL_KW = 1e-12


def test_ramped_and_filtered_setpoint_is_lfilter_of_the_rate_limited_steps() -> None:
    ts_s, ramp_kw_per_s, tau_s = 2.0, 0.25, 10.0
    shaper = SetpointShaper(ts_s=ts_s, ramp_kw_per_s=ramp_kw_per_s, filter_time_s=tau_s,
                            power_min_kw=0.0, power_max_kw=None)
    shaper.reset(45.0)
    raw = np.r_[np.full(5, 45.0), np.full(40, 50.0), np.full(30, 47.0)]
    used = np.array([shaper.shape(float(r)).used_kw for r in raw])
    # Reference: the ramp by hand (at most 0.5 kW per sample), then a first-order lag.
    ramped, prev = [], 45.0
    for r in raw:
        prev += min(ramp_kw_per_s * ts_s, max(-ramp_kw_per_s * ts_s, r - prev))
        ramped.append(prev)
    alpha = 1.0 - math.exp(-ts_s / tau_s)
    ref, _ = scipy.signal.lfilter([alpha], [1.0, alpha - 1.0], np.array(ramped) - 45.0,
                                  zi=[(1.0 - alpha) * 0.0])
    np.testing.assert_allclose(used, ref + 45.0, rtol=0.0, atol=FILTER_ATOL_KW)


@pytest.mark.parametrize(("bad", "verdict"), [
    (None, "missing"), (math.nan, "not finite"), (math.inf, "not finite"),
    (-1.0, "below power_min_kw"), (2 * MAX_SETPOINT_KW, "beyond MAX_SETPOINT_KW"),
    (90.0, "above power_max_kw")])
def test_a_rejected_setpoint_holds_the_last_valid_one_and_leaves_no_trace(
        bad: float | None, verdict: str) -> None:
    def shaper() -> SetpointShaper:
        out = SetpointShaper(ts_s=2.0, ramp_kw_per_s=0.5, filter_time_s=6.0,
                             power_min_kw=0.0, power_max_kw=80.0)
        out.reset(45.0)
        return out

    with_bad, held = shaper(), shaper()
    a = [with_bad.shape(v) for v in (50.0, 50.0, bad, bad, 52.0, 52.0)]
    b = [held.shape(v) for v in (50.0, 50.0, 50.0, 50.0, 52.0, 52.0)]
    assert [s.used_kw for s in a] == [s.used_kw for s in b]
    assert [s.verdict for s in a] == ["valid", "valid", verdict, verdict, "valid", "valid"]
    np.testing.assert_array_equal(a[2].received_kw, math.nan if bad is None else bad)


@pytest.fixture(scope="module")
def input_map(paper_armax_model: HammersteinModel) -> InputMap:
    return build_input_map(paper_armax_model, triac_min_pct=0.0, triac_max_pct=100.0,
                           validity_margin_pct=5.0)


def test_a_tightened_limit_moves_in_from_the_input_at_its_ramp(input_map: InputMap) -> None:
    s_nom = input_map.operating_triac_pct
    limits = LimitRamp(input_map, ramp_pct_per_step=1.0)
    limits.set(0.0, 50.0, ds_now_pct=60.0 - s_nom)   # input at 60 %: the max starts there
    highs = [limits.triac_pct[1]]
    for _ in range(12):
        limits.ramp()
        highs.append(limits.triac_pct[1])
    assert highs == [60.0 - i for i in range(11)] + [50.0, 50.0]
    assert limits.map.ds_max_pct == 50.0 - s_nom
    assert limits.map.w_max == pytest.approx(input_map.f(50.0 - s_nom), rel=1e-15)
    assert limits.triac_pct[0] == input_map.ds_min_pct + s_nom  # clipped to the allowed range
    limits.set(0.0, 100.0, ds_now_pct=0.0)                    # widening applies at once
    assert limits.map is input_map


@pytest.mark.parametrize(("lo", "hi", "message"), [
    (math.nan, 50.0, "expected finite min < max"), (60.0, 50.0, "expected finite min < max"),
    (99.5, 99.9, "expected limits overlapping the allowed range")])
def test_bad_limits_are_refused_with_the_values(lo: float, hi: float, message: str,
                                                input_map: InputMap) -> None:
    with pytest.raises(SettingsError, match=message):
        LimitRamp(input_map, ramp_pct_per_step=1.0).set(lo, hi, ds_now_pct=0.0)
