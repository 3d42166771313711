"""What the loop makes of one read of the power node (czmpc.runtime.measurement.measurement)."""

from __future__ import annotations

import datetime as dt
import math

import pytest

asyncua = pytest.importorskip("asyncua")
ua = asyncua.ua

from czmpc.runtime.measurement import measurement as _measurement  # noqa: E402

#: Long enough that no sample here is too old, however slowly the suite runs [s].
NO_AGE_LIMIT_S = math.inf
#: A fixed source time (the age test uses the clock).
NOW = dt.datetime(2026, 11, 24, 9, 0, tzinfo=dt.UTC)


def _dv(value: float, source: dt.datetime | None, *, status: int = 0,
        server: dt.datetime | None = None) -> object:
    return ua.DataValue(ua.Variant(value, ua.VariantType.Double),
                        StatusCode=ua.StatusCode(status), SourceTimestamp=source,
                        ServerTimestamp=server)


def test_a_fresh_sample_is_good() -> None:
    earlier = NOW - dt.timedelta(seconds=0.04)
    assert _measurement(_dv(41.5, NOW), NO_AGE_LIMIT_S, earlier) == (41.5, "good")
    assert _measurement(_dv(41.5, None), NO_AGE_LIMIT_S, NOW) == (41.5, "good")  # no timestamp
    assert _measurement(_dv(41.5, NOW), NO_AGE_LIMIT_S, None) == (41.5, "good")  # first read


def test_a_sample_read_again_is_repeated_and_missing() -> None:
    # the plant's step came after the read: the source timestamp has not moved on
    for previous in (NOW, NOW + dt.timedelta(microseconds=1)):
        value, quality = _measurement(_dv(41.5, NOW), NO_AGE_LIMIT_S, previous)
        assert math.isnan(value) and quality == "repeated"
    # a naive timestamp (asyncua's own) is UTC, as the previous read's
    value, quality = _measurement(_dv(41.5, NOW.replace(tzinfo=None)), NO_AGE_LIMIT_S, NOW)
    assert math.isnan(value) and quality == "repeated"


def test_the_status_and_the_age_come_before_the_repeat() -> None:
    bad = _measurement(_dv(41.5, NOW, status=ua.StatusCodes.BadSensorFailure),
                       NO_AGE_LIMIT_S, NOW)
    assert math.isnan(bad[0]) and bad[1] == "bad"
    old = dt.datetime.now(dt.UTC) - dt.timedelta(seconds=5.0)
    stale = _measurement(_dv(41.5, old), 1.0, old)
    assert math.isnan(stale[0]) and stale[1] == "stale"


def test_without_a_source_timestamp_the_server_timestamp_still_finds_repeats() -> None:
    # a server that stamps only its own time: a sample read twice keeps that time
    value, quality = _measurement(_dv(41.5, None, server=NOW), NO_AGE_LIMIT_S, NOW)
    assert math.isnan(value) and quality == "repeated"
    later = NOW + dt.timedelta(seconds=0.04)
    assert _measurement(_dv(41.5, None, server=later), NO_AGE_LIMIT_S, NOW) == (41.5, "good")
    old = dt.datetime.now(dt.UTC) - dt.timedelta(seconds=5.0)
    assert _measurement(_dv(41.5, None, server=old), 1.0, None)[1] == "stale"
    # the source timestamp wins where there is one
    assert _measurement(_dv(41.5, later, server=NOW), NO_AGE_LIMIT_S, NOW) == (41.5, "good")
