"""What the loop makes of one read of a node: a value in czmpc's units and its quality.

A sample's time is its source timestamp; a server that sends none (some embedded
servers, a PLC tag without a source clock) falls back to its server timestamp
(`sample_time`), so that stale and repeated samples are still told apart.
"""

from __future__ import annotations

import datetime as dt
import math
from typing import Any

from czmpc.runtime.node_types import LinearScale, NodeValueError, decode


def sample_time(dv: Any) -> tuple[dt.datetime | None, bool]:
    """A DataValue's time in UTC (a naive one is UTC), and True for the source timestamp:
    the source timestamp, else the server's (False), else ``(None, False)``."""
    for ts, is_source in ((dv.SourceTimestamp, True), (dv.ServerTimestamp, False)):
        if ts is not None:
            return (ts.replace(tzinfo=dt.UTC) if ts.tzinfo is None else ts), is_source
    return None, False


def age_s(dv: Any) -> float | None:
    """Age of a DataValue [wall s]: now minus its `sample_time` (None without one)."""
    ts, _ = sample_time(dv)
    return None if ts is None else float((dt.datetime.now(dt.UTC) - ts).total_seconds())


def measurement(dv: Any, max_age_s: float, previous_time: dt.datetime | None = None,
                scale: LinearScale | None = None) -> tuple[float, str]:
    """Value [czmpc's units, scaled from raw] and a quality word from a DataValue; NaN
    unless ``"good"``.

    ``"bad"`` and ``"uncertain"`` come from the status code, ``"stale"`` from a sample
    time older than ``max_age_s``, ``"repeated"`` from one not later than
    ``previous_time`` (the plant has not published since the previous read).
    """
    status = dv.StatusCode
    if status is not None and not status.is_good():
        return math.nan, "uncertain" if status.is_uncertain() else "bad"
    age = age_s(dv)
    if age is not None and age > max_age_s:
        return math.nan, "stale"
    ts, _ = sample_time(dv)
    if ts is not None and previous_time is not None and ts <= previous_time:
        return math.nan, "repeated"
    try:
        value = decode(dv.Value.Value, scale)
    except (NodeValueError, AttributeError):
        return math.nan, "bad"
    return (value, "good") if math.isfinite(value) else (math.nan, "bad")


__all__ = ["age_s", "measurement", "sample_time"]
