"""Read a plant's power and applied-input history over OPC UA and put it on the Ts grid.

Reading (`read_node_history`): HistoryRead of raw values, ``page_values`` per request,
following continuation points (and asking again from the last time stamp after a full
page without one, so a page limit never truncates silently), each call under a hard
deadline; a node without the ``HistoryRead`` access bit is refused at once
(`HistoryUnavailableError`). Aligning (`align_history`, pure): the power's time stamps
define the grid, one slot per ``ts_s / time_scale`` of wall time, each ``good``, ``bad``,
``uncertain`` or ``missing``, the inputs placed as a `czmpc run` log has them. Writing
(`write_history_log`): a run log with ``<log>.meta.json`` (docs/guides/history.rst).
"""

from __future__ import annotations

import csv
import datetime as dt
import hashlib
import io
import itertools
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from czmpc.errors import CzmpcError
from czmpc.runtime._opcua import asyncua
from czmpc.runtime.link import within
from czmpc.runtime.logfiles import LOG_COLUMNS, RUN_META_FORMAT, RunLogExistsError, meta_path
from czmpc.runtime.measurement import measurement, sample_time
from czmpc.runtime.node_types import NodeSpec
from sysid.atomic import atomic_write_text

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: Default ``NumValuesPerNode`` of one HistoryRead request (a day at Ts = 2 s: 44 requests).
DEFAULT_PAGE_VALUES = 1000
#: Words of the ``quality`` column (`czmpc.runtime.runlog` takes all but "good" as gaps).
QUALITY_WORDS = ("good", "bad", "uncertain", "missing")
#: What each refusal code means for the user (the fix), by OPC UA status code name.
_FIXES = {
    "BadNodeIdUnknown": "the server has no such node: check the node id in [nodes]",
    "BadNodeIdInvalid": "the node id is not valid: check it in [nodes]",
    "BadUserAccessDenied": "give czmpc's user HistoryRead access to that tag on the server",
    "BadContinuationPointInvalid": ("the server dropped the continuation point between "
                                    "requests: read a shorter range or raise --page-values"),
}
_ENABLE = "enable historizing for that tag on the server (and HistoryRead access for czmpc's user)"


class HistoryUnavailableError(CzmpcError, ValueError):
    """The server holds no readable history for a configured node (names the node and the fix)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class NodeHistory:
    """The raw history of one node in a time range, in time order.

    Parameters
    ----------
    key :
        The run config's ``[nodes]`` key (``"power_kw"``, ...).
    node_id :
        The node id as configured.
    epoch_s :
        Time of each value [s since 1970-01-01 UTC]: source timestamp, else server's.
    values :
        Values in czmpc's units (scaled from raw); NaN unless the quality is Good.
    qualities :
        ``"good"``, ``"bad"`` or ``"uncertain"`` for each value.
    n_requests :
        HistoryRead requests made.
    n_continuations :
        Requests that carried the server's continuation point.
    n_resumed :
        Requests that asked again from the last time stamp after a full page without one.
    """

    key: str
    node_id: str
    epoch_s: tuple[float, ...]
    values: tuple[float, ...]
    qualities: tuple[str, ...]
    n_requests: int
    n_continuations: int = 0
    n_resumed: int = 0

    @property
    def n_values(self) -> int:
        """Number of values read."""
        return len(self.epoch_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class AlignedHistory:
    """The history on the Ts grid: one row per slot, the run log's rows (`align_history`).

    ``epoch_s`` is the power sample's time where the slot has one, else the slot's
    time on the grid [s since the epoch]; ``n_moved`` counts power samples moved back
    one or more slots because they were stamped late into the next sample's slot.
    """

    epoch_s: FloatArray
    power_kw: FloatArray
    quality: tuple[str, ...]
    applied_triac_pct: FloatArray
    triac_pct: FloatArray
    period_s: float
    n_moved: int

    @property
    def n_rows(self) -> int:
        """Number of slots (rows of the log)."""
        return len(self.quality)

    def count(self, word: str) -> int:
        """Number of rows whose quality is ``word``."""
        return sum(q == word for q in self.quality)


def _refused(key: str, spec: NodeSpec, code: str, what: str = "{code}") -> HistoryUnavailableError:
    """The refusal of node ``key`` with ``code``: ``what`` (formatted with it) and the fix."""
    return HistoryUnavailableError(f"nodes.{key} = {spec.node_id!r}: {what.format(code=code)}: "
                                   f"{_FIXES.get(code, _ENABLE)}")


async def check_history_access(client: Any, key: str, spec: NodeSpec, *,
                               deadline_s: float) -> None:
    """Refuse a node whose ``UserAccessLevel`` lacks the ``HistoryRead`` bit.

    Raises
    ------
    HistoryUnavailableError
        The node does not exist, or this user may not read its history.
    CallDeadlineError
        The server did not answer within ``deadline_s`` [s].
    """
    ua = asyncua().ua
    node = client.get_node(spec.node_id)
    try:
        dv = await within(node.read_attribute(ua.AttributeIds.UserAccessLevel,
                                              raise_on_bad_status=False),
                          deadline_s, f"reading the access level of {key}")
    except ua.UaStatusCodeError as exc:
        raise _refused(key, spec, type(exc).__name__) from None
    if dv.StatusCode is not None and not dv.StatusCode.is_good():
        raise _refused(key, spec, dv.StatusCode.name)
    level = int(dv.Value.Value or 0)
    if not level & (1 << int(ua.AccessLevel.HistoryRead)):
        raise HistoryUnavailableError(
            f"nodes.{key} = {spec.node_id!r}: the server keeps no history of this node for "
            f"czmpc's user (UserAccessLevel {level} lacks HistoryRead): {_ENABLE}")


async def read_node_history(client: Any, key: str, spec: NodeSpec, *, start: dt.datetime,
                            end: dt.datetime, page_values: int = DEFAULT_PAGE_VALUES,
                            deadline_s: float, bounds: bool = False,
                            progress: Callable[[str], None] | None = None) -> NodeHistory:
    """Read the raw history of one node in ``[start, end]`` (module docstring).

    Parameters
    ----------
    client :
        A connected asyncua client (`czmpc.runtime.secure_client.connect`).
    key :
        The node's ``[nodes]`` key (named in messages).
    spec :
        Its node id and scaling.
    start, end :
        The time range (aware datetimes, UTC), both ends included.
    page_values :
        ``NumValuesPerNode`` of each request (>= 1).
    deadline_s :
        Hard deadline of each call [wall s].
    bounds :
        Ask for the bounding values too (``ReturnBounds``): the value in force at
        ``start`` of a tag stored on change (an input), where the server gives it.
    progress :
        Called with a line of text after each request.

    Raises
    ------
    HistoryUnavailableError
        The node has no readable history, or the server refused a request.
    CallDeadlineError
        A call missed its deadline.
    ValueError
        ``page_values`` below 1.
    """
    if page_values < 1:
        raise ValueError(f"page_values must be >= 1; got {page_values}")
    await check_history_access(client, key, spec, deadline_s=deadline_s)
    ua = asyncua().ua
    epoch: list[float] = []
    values: list[float] = []
    qualities: list[str] = []
    n_requests = n_continuations = n_resumed = 0
    page_start = start
    point: bytes | None = None
    resumed_at: float | None = None   # a resumed request reads the values at this time again
    try:
        while True:
            details = ua.ReadRawModifiedDetails(IsReadModified=False, StartTime=page_start,
                                                EndTime=end, NumValuesPerNode=page_values,
                                                ReturnBounds=bounds)
            result = await _history_read(client, key, spec, details, point, deadline_s)
            n_requests += 1
            n_continuations += point is not None
            point = result.ContinuationPoint or None
            page = list(getattr(result.HistoryData, "DataValues", None) or [])
            n_before = len(epoch)
            for dv in _skip_repeats(page, epoch, resumed_at):
                when, _ = sample_time(dv)
                if when is None:
                    continue
                value, word = measurement(dv, math.inf, None, spec.scale)
                epoch.append(when.timestamp())
                values.append(value)
                qualities.append(word)
            if progress is not None:
                progress(f"{key}: {len(epoch)} values read ({n_requests} HistoryRead requests)")
            if point is not None:
                resumed_at = None
                continue
            if len(page) < page_values or not epoch:
                break
            if resumed_at is not None and len(epoch) == n_before:
                raise HistoryUnavailableError(
                    f"nodes.{key} = {spec.node_id!r}: more than {page_values} values share the "
                    f"time stamp {page_start.isoformat()}: raise --page-values")
            # a full page and no continuation point: ask again from the last time stamp
            resumed_at = epoch[-1]
            page_start = dt.datetime.fromtimestamp(resumed_at, dt.UTC)
            n_resumed += 1
    finally:
        if point is not None:
            await _release(client, spec, point, deadline_s)
    return NodeHistory(key=key, node_id=spec.node_id, epoch_s=tuple(epoch),
                       values=tuple(values), qualities=tuple(qualities),
                       n_requests=n_requests, n_continuations=n_continuations,
                       n_resumed=n_resumed)


def _skip_repeats(page: Sequence[Any], epoch: Sequence[float], last: float | None) -> list[Any]:
    """The page without the values a resumed request read again (those at time ``last``)."""
    if last is None:
        return list(page)
    already = sum(1 for _ in itertools.takewhile(lambda t: t == last, reversed(epoch)))
    kept: list[Any] = []
    for dv in page:
        when, _ = sample_time(dv)
        stamp = None if when is None else when.timestamp()
        if stamp is not None and stamp < last:
            continue
        if stamp == last and already > 0:
            already -= 1
            continue
        kept.append(dv)
    return kept


def _history_params(spec: NodeSpec, details: Any, point: bytes | None, *,
                    release: bool) -> Any:
    """HistoryReadParameters of one node, with its continuation point."""
    ua = asyncua().ua
    return ua.HistoryReadParameters(
        HistoryReadDetails=details, TimestampsToReturn=ua.TimestampsToReturn.Both,
        ReleaseContinuationPoints=release, NodesToRead=[ua.HistoryReadValueId(
            NodeId=ua.NodeId.from_string(spec.node_id), ContinuationPoint=point)])


async def _history_read(client: Any, key: str, spec: NodeSpec, details: Any,
                        point: bytes | None, deadline_s: float) -> Any:
    ua = asyncua().ua
    params = _history_params(spec, details, point, release=False)
    refused = "the server refused HistoryRead ({code})"
    try:
        results = await within(client.uaclient.history_read(params), deadline_s,
                               f"HistoryRead of {key}")
    except ua.UaStatusCodeError as exc:
        raise _refused(key, spec, type(exc).__name__, refused) from None
    result = results[0]
    if result.StatusCode is not None and not result.StatusCode.is_good():
        raise _refused(key, spec, result.StatusCode.name, refused)
    return result


async def _release(client: Any, spec: NodeSpec, point: bytes, deadline_s: float) -> None:
    """Release a continuation point the read no longer needs (the server frees it)."""
    params = _history_params(spec, asyncua().ua.ReadRawModifiedDetails(), point, release=True)
    try:
        await within(client.uaclient.history_read(params), deadline_s,
                     "releasing a continuation point")
    except Exception:  # noqa: BLE001 - the server frees it with the session anyway
        pass


# --- the grid (pure) -------------------------------------------------------------------

def grid_reference_s(epoch_s: FloatArray, period_s: float) -> float:
    """Time of slot 0 [s since the epoch]: the first sample's slot, at the samples' mean phase.

    The phase is the circular mean of the times modulo ``period_s``, so that samples
    jittering around a slot boundary do not split the grid.
    """
    first = float(epoch_s[0])
    angle = 2.0 * np.pi * (epoch_s - first) / period_s
    phase = math.atan2(float(np.mean(np.sin(angle))), float(np.mean(np.cos(angle))))
    return first + phase / (2.0 * np.pi) * period_s


def grid_slots(epoch_s: FloatArray, period_s: float, ref_s: float) -> tuple[IntArray, int]:
    """Slot of each sample (nearest grid time), a late-stamped one moved back; and how many moved.

    ``epoch_s`` must be sorted. The slots returned increase strictly.
    """
    slots = np.rint((epoch_s - ref_s) / period_s).astype(np.int64)
    moved = 0
    for i in range(slots.size - 2, -1, -1):
        if slots[i] >= slots[i + 1]:
            slots[i] = slots[i + 1] - 1
            moved += 1
    return slots, moved


def _held(slots: IntArray, values: FloatArray, n_rows: int) -> FloatArray:
    """Value in force at each row: the last of ``values`` whose slot is at or before it."""
    last = np.searchsorted(slots, np.arange(n_rows), side="right") - 1
    out = np.full(n_rows, np.nan)
    known = last >= 0
    out[known] = values[last[known]]
    return out


def align_history(power: NodeHistory, applied: NodeHistory | None = None,
                  command: NodeHistory | None = None, *, period_s: float) -> AlignedHistory:
    """Put the histories on the grid of the power's time stamps.

    Each power sample takes the slot nearest its time (one stamped late into the next
    one's slot moves back to the free slot before it). ``applied_triac_pct`` of row ``j``
    is the last Good applied value at or before power sample ``j`` (a Bad one makes it
    NaN until the next Good one); ``triac_pct`` of row ``j`` is the last command written
    before power sample ``j + 1``.

    Parameters
    ----------
    power :
        The measured power's history (at least one value).
    applied :
        The applied input's history, or None.
    command :
        The command's history, or None.
    period_s :
        Wall time between samples [s]: ``ts_s / time_scale``.

    Raises
    ------
    ValueError
        No power value, or a period that is not > 0.
    """
    if power.n_values == 0:
        raise ValueError("align_history needs at least one power value")
    if not period_s > 0.0:
        raise ValueError(f"period_s must be > 0; got {period_s!r}")
    order = np.argsort(np.asarray(power.epoch_s), kind="stable")
    t = np.asarray(power.epoch_s)[order]
    ref_s = grid_reference_s(t, period_s)
    slots, moved = grid_slots(t, period_s, ref_s)
    ref_s += float(slots[0]) * period_s
    slots -= slots[0]
    n_rows = int(slots[-1]) + 1
    epoch = np.asarray(ref_s + np.arange(n_rows) * period_s, dtype=np.float64)
    epoch[slots] = t
    power_kw = np.full(n_rows, np.nan)
    power_kw[slots] = np.asarray(power.values)[order]
    quality = ["missing"] * n_rows
    for slot, word in zip(slots, np.asarray(power.qualities)[order], strict=True):
        quality[int(slot)] = str(word)

    def inputs(history: NodeHistory | None, *, before_next: bool) -> FloatArray:
        if history is None or history.n_values == 0:
            return np.full(n_rows, np.nan)
        idx = np.argsort(np.asarray(history.epoch_s), kind="stable")
        times = np.asarray(history.epoch_s)[idx]
        vals = np.asarray(history.values)[idx]
        if before_next:   # a command acts from the sample after it was written
            slot = np.floor((times - ref_s) / period_s).astype(np.int64)
        else:
            slot, _ = grid_slots(times, period_s, ref_s)
        return _held(slot, vals, n_rows)

    return AlignedHistory(
        epoch_s=epoch, power_kw=power_kw, quality=tuple(quality),
        applied_triac_pct=inputs(applied, before_next=False),
        triac_pct=inputs(command, before_next=True), period_s=period_s, n_moved=moved)


# --- the run log ----------------------------------------------------------------------

def _exact(value: float) -> str:
    return "nan" if math.isnan(value) else repr(float(value))


def history_csv(aligned: AlignedHistory, *, ts_s: float) -> str:
    """The run-log CSV text of ``aligned`` (`LOG_COLUMNS`; ``k`` from 0, ``time_s = k * ts_s``)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(LOG_COLUMNS)
    blank = dict.fromkeys(LOG_COLUMNS, "")
    for k in range(aligned.n_rows):
        writer.writerow((blank | {
            "k": k, "time_s": _exact(k * ts_s), "wall_time_s": f"{aligned.epoch_s[k]:.6f}",
            "power_kw": _exact(aligned.power_kw[k]), "quality": aligned.quality[k],
            "setpoint_kw": "nan", "triac_pct": _exact(aligned.triac_pct[k]),
            "applied_triac_pct": _exact(aligned.applied_triac_pct[k]),
        }).values())
    return buffer.getvalue()


def refuse_existing(path: Path) -> None:
    """Refuse to replace a log or its meta file (a run's evidence).

    Raises
    ------
    RunLogExistsError
        ``path`` or its ``.meta.json`` exists; the message names the way out (``--force``).
    """
    for existing in (path, meta_path(path)):
        if existing.exists():
            raise RunLogExistsError(f"{existing} exists: give another --out, or --force to "
                                  f"replace it")


def write_history_log(path: Path, aligned: AlignedHistory, *, ts_s: float,
                      meta: dict[str, object], overwrite: bool = False) -> Path:
    """Write the run log and its ``.meta.json`` (``"kind": "history"``); return the meta path.

    Raises
    ------
    RunLogExistsError
        The log or its meta file exists and ``overwrite`` is False.
    """
    meta_file = meta_path(path)
    if not overwrite:
        refuse_existing(path)
    text = history_csv(aligned, ts_s=ts_s)
    doc = {"format": RUN_META_FORMAT, "kind": "history", "closed_loop": False, **meta,
           "ts_s": ts_s, "log_sha256": hashlib.sha256(text.encode("utf-8")).hexdigest()}
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, text)
    atomic_write_text(meta_file, json.dumps(doc, indent=2) + "\n")
    return meta_file


__all__ = ["DEFAULT_PAGE_VALUES", "QUALITY_WORDS", "AlignedHistory", "HistoryUnavailableError",
           "NodeHistory", "align_history", "check_history_access", "grid_reference_s",
           "grid_slots", "history_csv", "read_node_history", "refuse_existing",
           "write_history_log"]
