"""Data sets of several segments (experiments): validation and splitting."""

from __future__ import annotations

import numpy as np
import pytest

from sysid.data import Dataset
from sysid.errors import DataFileError


def _two_segments() -> Dataset:
    t = np.concatenate([2.0 * np.arange(5), 100.0 + 2.0 * np.arange(4)])
    u = np.arange(9, dtype=float)
    y = 10.0 * u
    return Dataset(time_s=t, triac_pct=u, power_kw=y, ts_s=2.0, segment_starts=(0, 5))


def test_gap_between_segments_is_accepted_and_segments_have_own_time_axis() -> None:
    data = _two_segments()
    assert data.n_segments == 2
    assert data.segment_bounds() == ((0, 5), (5, 9))
    first, second = data.segments()
    np.testing.assert_array_equal(first.time_s, [0.0, 2.0, 4.0, 6.0, 8.0])
    np.testing.assert_array_equal(second.time_s, [100.0, 102.0, 104.0, 106.0])
    np.testing.assert_array_equal(second.power_kw, [50.0, 60.0, 70.0, 80.0])
    assert first.segment_starts == (0,) and second.segment_starts == (0,)
    assert second.preprocessing[-1] == {"what": "segment", "start_sample": 5, "stop_sample": 9}


def test_single_segment_data_returns_itself() -> None:
    data = Dataset(time_s=[0.0, 1.0, 2.0], triac_pct=[1.0, 2.0, 3.0], power_kw=[1.0, 2.0, 3.0],
                   ts_s=1.0)
    assert data.segments() == (data,)


def test_the_same_gap_without_a_segment_boundary_is_refused() -> None:
    data = _two_segments()
    with pytest.raises(DataFileError, match=r"interval of 92 s from 8 s to 100 s"):
        Dataset(time_s=data.time_s, triac_pct=data.triac_pct, power_kw=data.power_kw, ts_s=2.0)


@pytest.mark.parametrize(
    ("starts", "pattern"),
    [((1, 5), "begin with 0"), ((0, 5, 5), "strictly increasing"), ((0, 7), "at least 3"),
     ((), "non-empty"), ((0, 2.5), "integers")],
)
def test_malformed_segment_starts_are_refused(starts: tuple, pattern: str) -> None:
    data = _two_segments()
    with pytest.raises(DataFileError, match=pattern):
        Dataset(time_s=data.time_s, triac_pct=data.triac_pct, power_kw=data.power_kw, ts_s=2.0,
                segment_starts=starts)


def test_time_going_back_across_a_boundary_is_refused() -> None:
    t = np.concatenate([2.0 * np.arange(4), 2.0 * np.arange(4)])
    with pytest.raises(DataFileError, match="strictly increasing across segments"):
        Dataset(time_s=t, triac_pct=np.zeros(8), power_kw=np.zeros(8), ts_s=2.0,
                segment_starts=(0, 4))


def test_slicing_and_new_signals_keep_the_boundaries() -> None:
    data = _two_segments()
    part = data.segment(2, 9)
    assert part.segment_starts == (0, 3)
    assert data.with_signals(power_kw=np.ones(9)).segment_starts == (0, 5)
