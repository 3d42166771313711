"""Logs as process historians export them, loaded under explicit, recorded policies.

The strict reader (`sysid.data.read_csv`) refuses anything outside the data contract.
This module accepts the usual breaks of real exports, each under a stated policy, and
records what it did in a `LoadReport` (also in the data set's ``preprocessing``, hence
in every model file's provenance):

* **Time column**: seconds or ISO-8601 timestamps, with or without a zone
  (``2024-05-01T12:00:00``, ``2024-05-01 12:00:00.5+02:00``, ``...Z``), or stamps in a
  given `datetime.strptime` format (``time_format``, ``--time-format``). Zoned stamps are
  converted to UTC; naive ones are taken as written (a daylight-saving step backwards
  is refused as time going backwards). ``time_s`` counts seconds from the first
  stamp (`LoadReport.time_origin`).
* **Separators and decimal comma** (CSV): ``,``, ``;`` or tab, detected from the
  header unless given; a decimal comma detected in ``;`` or tab files unless given.
* **Missing data**: NaN, ``NA``, ``null`` or empty cells, rows without a time stamp,
  and gaps in time follow `LoadPolicy.gaps`: ``"refuse"`` (default; the error names
  ``--gaps split`` and ``--gaps fill``), ``"split"`` (segments of complete samples,
  each fitted with its own initial state) or ``"fill"`` (runs of at most
  `LoadPolicy.fill_max_samples` missing samples interpolated linearly, per signal;
  longer runs split).
* **Jitter**: an interval ``dt`` is ``m = round(dt / Ts)`` periods (``m > 1``: a gap of
  ``m - 1`` samples). If every interval is within `LoadPolicy.sampling_rtol` (1 %) of
  ``m Ts`` the logged times are kept; else, if every one is within `SNAP_MAX_JITTER`
  (25 % of Ts), every sample is **snapped** onto the grid ``t0 + k Ts`` (value kept);
  a larger deviation is refused, naming ``--resample linear``, which interpolates the
  signals onto that grid (instants inside an interval longer than
  `LINEAR_GAP_PERIODS` periods are missing samples).
* **Parquet** files and **pandas DataFrames** (`read_frame`, ``pip install
  czmpc[pandas]``); `write_parquet` and `to_frame` write a data set back.
"""

from __future__ import annotations

import io
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from sysid._arrays import true_runs
from sysid._checks import checked_int
from sysid._typing import FloatArray
from sysid.data import (
    CSV_COLUMNS,
    DEFAULT_SAMPLING_RTOL,
    GRID_VOLTAGE_COLUMN,
    GRID_VOLTAGE_RANGE,
    MIN_SAMPLES,
    Dataset,
    check_column_mapping,
    check_voltage_value,
    csv_table,
    decode_text,
    file_bytes,
    voltage_expectation,
)
from sysid.errors import DataFileError

GapPolicy = Literal["refuse", "split", "fill"]
ResamplePolicy = Literal["snap", "linear"]

#: The gap policies, default first.
GAP_POLICIES: tuple[str, ...] = ("refuse", "split", "fill")
#: The resampling policies, default first.
RESAMPLE_POLICIES: tuple[str, ...] = ("snap", "linear")
#: Longest run of missing samples ``--gaps fill`` interpolates by default (10 s at the
#: puller's Ts = 2 s: short against the heater's time constants).
DEFAULT_FILL_MAX_SAMPLES = 5
#: Largest deviation of an interval from a whole number of periods snapped onto the
#: grid [fraction of Ts]: past a quarter period a sample's slot is no longer clear.
SNAP_MAX_JITTER = 0.25
#: With ``--resample linear``, a grid instant inside an interval longer than this many
#: periods has no measurement near it: it is a missing sample (gap policy applies).
LINEAR_GAP_PERIODS = 2.0
#: Shortest segment kept by ``--gaps split``/``fill`` (a shorter one cannot carry its own
#: initial state and a model's lags; it is dropped and counted).
MIN_SEGMENT_SAMPLES = 10
#: Cell texts read as a missing value (compared in lower case, stripped).
MISSING_TOKENS = frozenset({"", "nan", "na", "n/a", "#n/a", "null", "none"})
#: Separators detected in a CSV header (``--sep``).
SEPARATORS: tuple[str, ...] = (",", ";", "\t")

_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+([eE][+-]?\d+)?$|^[+-]?\d+,\d*([eE][+-]?\d+)?$")
_COLUMNS_HINT = ("; pass --columns time_s=NAME,triac_pct=NAME,power_kw=NAME to map the log's "
                 "own column names")
_GAP_OPTIONS = "pass --gaps split (cut into segments) or --gaps fill (interpolate runs of up to"


def _gap_hint(policy: LoadPolicy) -> str:
    return f"{_GAP_OPTIONS} {policy.fill_max_samples} samples, split longer ones)"


@dataclass(frozen=True, kw_only=True)
class LoadPolicy:
    """How to treat missing data, gaps and irregular time stamps.

    Parameters
    ----------
    gaps :
        ``"refuse"``, ``"split"`` or ``"fill"`` (module docstring).
    fill_max_samples :
        Longest run of missing samples that ``"fill"`` interpolates.
    resample :
        ``"snap"`` (jitter up to `SNAP_MAX_JITTER` snapped onto the grid, more refused)
        or ``"linear"`` (interpolate onto the grid).
    ts_s :
        Sampling time [s] of the grid; default the median interval.
    sampling_rtol :
        Jitter (fraction of Ts) accepted with the logged times kept.
    min_segment_samples :
        Shortest segment kept (shorter runs of complete samples are dropped).

    Raises
    ------
    DataFileError
        An unknown policy name or an out-of-range number.
    """

    gaps: GapPolicy = "refuse"
    fill_max_samples: int = DEFAULT_FILL_MAX_SAMPLES
    resample: ResamplePolicy = "snap"
    ts_s: float | None = None
    sampling_rtol: float = DEFAULT_SAMPLING_RTOL
    min_segment_samples: int = MIN_SEGMENT_SAMPLES

    def __post_init__(self) -> None:
        if self.gaps not in GAP_POLICIES:
            raise DataFileError(f"gaps must be one of {list(GAP_POLICIES)}; got {self.gaps!r}")
        if self.resample not in RESAMPLE_POLICIES:
            raise DataFileError(
                f"resample must be one of {list(RESAMPLE_POLICIES)}; got {self.resample!r}")
        for name, value, low in (("fill_max_samples", self.fill_max_samples, 1),
                                 ("min_segment_samples", self.min_segment_samples, MIN_SAMPLES)):
            object.__setattr__(self, name, checked_int(value, low, name, DataFileError))
        if self.ts_s is not None and not (math.isfinite(self.ts_s) and self.ts_s > 0):
            raise DataFileError(f"ts_s must be a finite number > 0; got {self.ts_s!r}")
        if not (math.isfinite(self.sampling_rtol) and 0 <= self.sampling_rtol < SNAP_MAX_JITTER):
            raise DataFileError(
                f"sampling_rtol must be in [0, {SNAP_MAX_JITTER:g}); got {self.sampling_rtol!r}")


@dataclass(frozen=True, kw_only=True)
class LoadReport:
    """What loading a log did, for the report and the model's provenance.

    Parameters
    ----------
    source_format :
        ``"csv"``, ``"parquet"`` or ``"frame"``.
    separator, decimal :
        CSV separator and decimal mark used (None for other formats).
    time_format :
        ``"seconds"`` or ``"timestamp"`` (ISO-8601 text or a date-time type).
    time_origin :
        ISO-8601 text of the first sample's time stamp (``time_s = 0``), or None.
    ts_s :
        Sampling time [s] of the grid.
    columns, policy :
        Contract name -> the log's column name; the policy applied.
    n_rows, n_samples :
        Data rows read; samples of the result.
    n_missing_cells :
        Cells of the three mapped columns that held no value (NaN, empty, ...).
    n_gap_samples :
        Sampling instants with no row at all (gaps in time).
    n_filled :
        Samples of the result in which at least one signal was interpolated.
    n_dropped :
        Grid samples (rows or gap instants) left out: incomplete samples at a split or
        at the record's ends, and segments too short.
    n_snapped :
        Samples whose time was moved onto the grid (0 when times are kept).
    max_jitter :
        Largest deviation of an interval from a whole number of periods [fraction of Ts].
    resampled :
        True if the signals were interpolated onto the grid (``--resample linear``).
    segment_starts :
        First sample of each segment of the result.
    """

    source_format: str
    separator: str | None
    decimal: str | None
    time_format: str
    time_origin: str | None
    ts_s: float
    columns: Mapping[str, str]
    policy: LoadPolicy
    n_rows: int
    n_missing_cells: int
    n_gap_samples: int
    n_filled: int
    n_dropped: int
    n_snapped: int
    max_jitter: float
    resampled: bool
    segment_starts: tuple[int, ...]
    n_samples: int

    @property
    def changed_data(self) -> bool:
        """True if a value, a time or the record's shape differs from the rows read."""
        return bool(self.n_filled or self.n_dropped or self.n_snapped or self.resampled
                    or len(self.segment_starts) > 1)

    @property
    def is_plain_contract(self) -> bool:
        """True for what the strict reader accepts: contract CSV, seconds, untouched."""
        return (self.source_format == "csv" and self.separator == "," and self.decimal == "."
                and self.time_format == "seconds" and not self.changed_data
                and dict(self.columns) == {c: c for c in CSV_COLUMNS})

    def record(self) -> dict[str, Any]:
        """This report as one JSON-ready ``preprocessing`` entry (``what = "load_log"``)."""
        return {
            "what": "load_log",
            "format": self.source_format,
            "separator": self.separator,
            "decimal": self.decimal,
            "time_format": self.time_format,
            "time_origin": self.time_origin,
            "ts_s": self.ts_s,
            "columns": dict(self.columns),
            "gaps": self.policy.gaps,
            "fill_max_samples": self.policy.fill_max_samples,
            "resample": self.policy.resample,
            "n_rows": self.n_rows,
            "n_missing_cells": self.n_missing_cells,
            "n_gap_samples": self.n_gap_samples,
            "n_filled": self.n_filled,
            "n_dropped": self.n_dropped,
            "n_snapped": self.n_snapped,
            "max_jitter_fraction_of_ts": self.max_jitter,
            "resampled": self.resampled,
            "n_segments": len(self.segment_starts),
            "segment_starts": list(self.segment_starts)}

    def summary(self) -> str:
        """One sentence: what was read and every change made to it."""
        fmt = {"csv": f"CSV (separator {self.separator!r}, decimal {self.decimal!r})",
               "parquet": "Parquet", "frame": "DataFrame"}.get(self.source_format,
                                                                self.source_format)
        time = ("time in seconds" if self.time_format == "seconds"
                else f"time stamps from {self.time_origin}")
        parts = [f"{fmt}, {self.n_rows} rows, {time}, Ts = {self.ts_s:g} s"]
        if self.n_missing_cells or self.n_gap_samples:
            parts.append(f"{self.n_missing_cells} missing cell(s) and {self.n_gap_samples} "
                         f"missing sampling instant(s) under --gaps {self.policy.gaps}")
        if self.n_filled:
            parts.append(f"{self.n_filled} sample(s) filled by linear interpolation (runs of "
                         f"at most {self.policy.fill_max_samples})")
        if self.n_dropped:
            parts.append(f"{self.n_dropped} incomplete sample(s) dropped")
        if len(self.segment_starts) > 1:
            parts.append(f"split into {len(self.segment_starts)} segments")
        if self.resampled:
            parts.append("resampled by linear interpolation onto the grid t0 + k Ts")
        elif self.n_snapped:
            parts.append(f"{self.n_snapped} time stamp(s) snapped onto the grid t0 + k Ts "
                         f"(largest jitter {100 * self.max_jitter:.3g} % of Ts)")
        return "; ".join(parts) + f"; {self.n_samples} samples kept"


@dataclass(frozen=True, kw_only=True)
class LoadedLog:
    """A loaded log: the data set and what loading did."""

    data: Dataset
    report: LoadReport


# --- raw columns, whatever the source --------------------------------------------------

@dataclass(frozen=True, kw_only=True)
class _Raw:
    """The mapped columns as read, before any policy (NaN = missing)."""

    time: FloatArray           # seconds, NaN where the row has no time
    u: FloatArray
    y: FloatArray
    v: FloatArray | None = None   # grid voltage factor, if the log carries it
    lines: npt.NDArray[np.int64] | None   # 1-based file line of each row (CSV only)
    path: str | None
    names: Mapping[str, str]
    source_format: str
    separator: str | None = None
    decimal: str | None = None
    time_format: str = "seconds"
    time_origin: str | None = None
    sha256: str | None = None

    @property
    def n_missing_cells(self) -> int:
        """Cells of the mapped columns that hold no value (NaN)."""
        columns = (self.time, self.u, self.y) + (() if self.v is None else (self.v,))
        return int(sum(np.count_nonzero(np.isnan(a)) for a in columns))


def _row_error(message: str, row: int, *, lines: Sequence[int] | npt.NDArray[np.int64] | None,
               path: str | None, column: str | None) -> DataFileError:
    """An error at data row ``row`` (0-based): at its file line, else prefixed ``row N: ``."""
    if lines is not None:
        return DataFileError(message, path=path, line=int(lines[row]), column=column)
    return DataFileError(f"row {row + 1}: {message}", path=path, column=column)


def _fail(raw: _Raw, row: int, column: str | None, message: str) -> DataFileError:
    """`_row_error` at row ``row`` of ``raw``, in the log's own name of ``column``."""
    return _row_error(message, row, lines=raw.lines, path=raw.path,
                      column=None if column is None else raw.names[column])


# --- the policies (pure, on arrays) ----------------------------------------------------

def _fill_runs(values: FloatArray, max_run: int) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Interpolate interior NaN runs of at most ``max_run`` samples linearly (by index)."""
    out = values.copy()
    filled = np.zeros(values.size, dtype=bool)
    for lo, hi in true_runs(np.isnan(values)):
        if lo == 0 or hi == values.size or hi - lo > max_run:
            continue
        left, right = values[lo - 1], values[hi]
        w = np.arange(1, hi - lo + 1) / (hi - lo + 1)
        out[lo:hi] = left + w * (right - left)
        filled[lo:hi] = True
    return out, filled


def _first_bad_interval(bad: npt.NDArray[np.bool_]) -> int | None:
    """Sample ending the first interval flagged in ``bad`` (``bad[j]``: samples ``j, j+1``)."""
    hits = np.flatnonzero(bad)
    return int(hits[0]) + 1 if hits.size else None


def _grid_slots(raw: _Raw, time: FloatArray, ts_s: float, policy: LoadPolicy,
                rows: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], float]:
    """Grid index of each row (snap rule) and the largest jitter (fraction of Ts)."""
    dt = np.diff(time)
    m = np.rint(dt / ts_s)
    jitter = np.abs(dt - m * ts_s) / ts_s
    if (k := _first_bad_interval(m < 1)) is not None:
        raise _fail(raw, int(rows[k]), "time_s",
                    f"interval of {dt[k - 1]:g} s from {time[k - 1]:g} s is shorter than half "
                    f"the sampling time {ts_s:g} s; pass --ts-s with the logger's period, or "
                    "--resample linear to interpolate onto a uniform grid")
    if policy.resample == "snap" and (k := _first_bad_interval(jitter > SNAP_MAX_JITTER)) is not None:
        raise _fail(raw, int(rows[k]), "time_s",
                    f"interval of {dt[k - 1]:g} s from {time[k - 1]:g} s is {100 * jitter[k - 1]:.3g} "
                    f"% of Ts = {ts_s:g} s off a whole number of periods (snapping accepts up to "
                    f"{100 * SNAP_MAX_JITTER:g} %); pass --resample linear to interpolate onto "
                    "the grid t0 + k Ts, or --ts-s with the logger's period")
    slots = np.concatenate([[0], np.cumsum(m)]).astype(np.int64)
    return slots, float(np.max(jitter)) if jitter.size else 0.0


def _linear_grid(time: FloatArray, u: FloatArray, y: FloatArray, ts_s: float
                 ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Signals interpolated linearly onto ``t0 + k ts_s``; NaN inside long intervals."""
    n_grid = int(math.floor((time[-1] - time[0]) / ts_s + 1e-9)) + 1
    grid = time[0] + ts_s * np.arange(n_grid)
    hi = np.clip(np.searchsorted(time, grid, side="left"), 1, time.size - 1)
    lo = hi - 1
    span = time[hi] - time[lo]
    w = (grid - time[lo]) / span
    exact_lo = np.isclose(grid, time[lo], rtol=0.0, atol=1e-9 * ts_s)
    exact_hi = np.isclose(grid, time[hi], rtol=0.0, atol=1e-9 * ts_s)
    far = (span > LINEAR_GAP_PERIODS * ts_s) & ~exact_lo & ~exact_hi

    def on_grid(v: FloatArray) -> FloatArray:
        val = np.where(exact_lo, v[lo], np.where(exact_hi, v[hi], (1.0 - w) * v[lo] + w * v[hi]))
        return np.where(far, np.nan, val)

    return grid, on_grid(u), on_grid(y)


def _backwards_hint(raw: _Raw, step_s: float) -> str:
    """What to do about time that does not increase by ``step_s`` [s] (<= 0)."""
    zone_less = raw.time_origin is not None and datetime.fromisoformat(raw.time_origin).tzinfo is None
    if zone_less and 1800.0 < -step_s <= 3600.0:
        return ("(zone-less time stamps that go back by up to an hour: local clocks repeat an "
                "hour when daylight-saving time ends, and sorting would interleave the two; "
                "export the log in UTC or with UTC offsets, e.g. 2024-10-27T02:30:00+01:00)")
    return "(sort the export by time and remove duplicated rows)"


def _regularize(raw: _Raw, policy: LoadPolicy, *, input_unit: str, output_unit: str
                ) -> LoadedLog:
    """Apply the time, jitter and gap policies to raw columns; build the data set."""
    n_rows = raw.time.size
    rows = np.arange(n_rows, dtype=np.int64)
    no_time = np.isnan(raw.time)
    if no_time.any() and policy.gaps == "refuse":
        raise _fail(raw, int(np.argmax(no_time)), "time_s",
                    "no time stamp in this row (empty or NaN); " + _gap_hint(policy))
    rows = rows[~no_time]
    time, u, y = raw.time[rows], raw.u[rows], raw.y[rows]
    v = None if raw.v is None else raw.v[rows]
    if time.size < MIN_SAMPLES:
        raise DataFileError(f"expected at least {MIN_SAMPLES} samples; got {time.size}",
                            path=raw.path)
    if (k := _first_bad_interval(np.diff(time) <= 0)) is not None:
        raise _fail(raw, int(rows[k]), "time_s",
                    f"time must be strictly increasing; got {time[k]:g} s after {time[k - 1]:g} s "
                    + _backwards_hint(raw, float(time[k] - time[k - 1])))
    ts_s = float(np.median(np.diff(time))) if policy.ts_s is None else float(policy.ts_s)
    n_snapped = 0
    if policy.resample == "linear":
        t_slot, u_slot, y_slot = _linear_grid(time, u, y, ts_s)
        v_slot = None if v is None else _linear_grid(time, v, v, ts_s)[1]
        n_slots = t_slot.size
        line_rows = rows[np.searchsorted(time, t_slot, side="left").clip(0, time.size - 1)]
        absent = np.zeros(n_slots, dtype=bool)
        periods = np.diff(time) / ts_s
        max_jitter = float(np.max(np.abs(periods - np.rint(periods))))
    else:
        slots, max_jitter = _grid_slots(raw, time, ts_s, policy, rows)
        if policy.ts_s is None and max_jitter > policy.sampling_rtol:
            # jittered stamps: the mean period is a better Ts than the (biased) median
            ts_s = float(time[-1] - time[0]) / float(slots[-1])
            slots, max_jitter = _grid_slots(raw, time, ts_s, policy, rows)
        n_slots = int(slots[-1]) + 1
        t_slot, u_slot, y_slot = np.full((3, n_slots), np.nan)
        snap = max_jitter > policy.sampling_rtol
        grid = time[0] + ts_s * slots
        t_slot[slots] = grid if snap else time
        if snap:
            n_snapped = int(np.count_nonzero(np.abs(time - grid) > policy.sampling_rtol * ts_s))
        u_slot[slots] = u
        y_slot[slots] = y
        v_slot = None
        if v is not None:
            v_slot = np.full(n_slots, np.nan)
            v_slot[slots] = v
        absent = np.ones(n_slots, dtype=bool)
        absent[slots] = False
        # the row at or after each slot: a gap is reported at the row that ends it
        line_rows = rows[np.searchsorted(slots, np.arange(n_slots), side="left")]
    n_gap = int(np.count_nonzero(absent))
    missing = np.isnan(u_slot) | np.isnan(y_slot)
    if v_slot is not None:
        missing = missing | np.isnan(v_slot)
    if policy.gaps == "refuse" and missing.any():
        k = int(np.argmax(missing))
        if absent[k]:
            lo, hi = next((a, b) for a, b in true_runs(absent) if a == k)
            raise _fail(raw, int(line_rows[k]), "time_s",
                        f"a gap in time: {hi - lo} missing sample(s) between {t_slot[lo - 1]:g} s "
                        f"and the next row (Ts = {ts_s:g} s); " + _gap_hint(policy))
        column = ("triac_pct" if np.isnan(u_slot[k]) else "power_kw" if np.isnan(y_slot[k])
                  else GRID_VOLTAGE_COLUMN)
        what = (f"no value at grid instant t = {t_slot[k]:g} s (a NaN or empty cell beside "
                f"it, or no sample within {LINEAR_GAP_PERIODS:g} periods)"
                if policy.resample == "linear" else "a missing value (NaN or empty cell)")
        raise _fail(raw, int(line_rows[k]), column, what + "; " + _gap_hint(policy))
    filled = np.zeros(n_slots, dtype=bool)
    if policy.gaps == "fill":
        t_slot = _fill_runs(t_slot, n_slots)[0]
        u_slot, fu = _fill_runs(u_slot, policy.fill_max_samples)
        y_slot, fy = _fill_runs(y_slot, policy.fill_max_samples)
        filled = fu | fy
        if v_slot is not None:
            v_slot, fv = _fill_runs(v_slot, policy.fill_max_samples)
            filled = filled | fv
    keep = ~(np.isnan(u_slot) | np.isnan(y_slot))
    if v_slot is not None:
        keep = keep & ~np.isnan(v_slot)
    if keep.all():   # nothing cut: the strict reader's minimum applies, not the segments'
        segments = [(0, n_slots)]
    else:
        segments = [(a, b) for a, b in true_runs(keep) if b - a >= policy.min_segment_samples]
    if not segments:
        raise DataFileError(
            f"no run of at least {policy.min_segment_samples} complete samples is left after "
            f"--gaps {policy.gaps}; the log is too sparse (try --gaps fill with a larger "
            "--fill-max)", path=raw.path)
    index = np.concatenate([np.arange(a, b) for a, b in segments])
    starts = tuple(int(v) for v in np.cumsum([0] + [b - a for a, b in segments[:-1]]))
    report = LoadReport(
        source_format=raw.source_format, separator=raw.separator, decimal=raw.decimal,
        time_format=raw.time_format, time_origin=raw.time_origin, ts_s=ts_s,
        columns=dict(raw.names), policy=policy, n_rows=n_rows, n_missing_cells=raw.n_missing_cells,
        n_gap_samples=n_gap, n_filled=int(np.count_nonzero(filled[index])),
        n_dropped=n_slots - index.size, n_snapped=n_snapped, max_jitter=max_jitter,
        resampled=policy.resample == "linear", segment_starts=starts, n_samples=int(index.size))
    rtol = max(policy.sampling_rtol, DEFAULT_SAMPLING_RTOL)
    data = Dataset(
        time_s=t_slot[index], triac_pct=u_slot[index], power_kw=y_slot[index], ts_s=ts_s,
        input_unit=input_unit, output_unit=output_unit, source=raw.path, sha256=raw.sha256,
        preprocessing=() if report.is_plain_contract else (report.record(),),
        sampling_rtol=rtol, segment_starts=starts,
        grid_voltage_factor=None if v_slot is None else v_slot[index])
    return LoadedLog(data=data, report=report)


# --- time cells ------------------------------------------------------------------------

def _no_time_stamp(path: str | None, column: str) -> DataFileError:
    return DataFileError("the time column holds no time stamp", path=path, column=column)


def _iso_seconds(cells: Sequence[str | None], raw_names: Mapping[str, str], path: str | None,
                 lines: Sequence[int] | None, time_format: str | None = None,
                 ) -> tuple[FloatArray, str]:
    """Seconds from the first stamp, and that stamp in ISO-8601 (NaN where missing); each
    stamp ISO-8601 or, given `time_format`, in that `datetime.strptime` format."""
    def fail(i: int, message: str) -> DataFileError:
        return _row_error(message, i, lines=lines, path=path, column=raw_names["time_s"])

    def parsed(text: str) -> datetime:
        return (datetime.fromisoformat(text) if time_format is None
                else datetime.strptime(text, time_format))

    stamps: list[datetime | None] = []
    zoned: bool | None = None
    for i, cell in enumerate(cells):
        if cell is None or cell.strip().lower() in MISSING_TOKENS:
            stamps.append(None)
            continue
        text = cell.strip()
        try:
            stamp = parsed(text)
        except ValueError:
            raise fail(i, f"expected a time stamp in the format {time_format!r} (--time-format); "
                          f"got {text!r}" if time_format is not None else
                          "expected seconds or an ISO-8601 time stamp such as 2024-05-01T12:00:00 "
                          f"or 2024-05-01 12:00:00+02:00; got {text!r} (for another form pass "
                          "--time-format, e.g. '%d.%m.%Y %H:%M:%S')") from None
        has_zone = stamp.tzinfo is not None
        if zoned is None:
            zoned = has_zone
        elif zoned != has_zone:
            raise fail(i, f"time stamps mix zoned and zone-less forms; got {text!r} after "
                          + ("zoned" if zoned else "zone-less")
                          + " ones (export every stamp in one form)")
        stamps.append(stamp.astimezone(UTC) if has_zone else stamp)
    first = next((s for s in stamps if s is not None), None)
    if first is None:
        raise _no_time_stamp(path, raw_names["time_s"])
    seconds = np.array([math.nan if s is None else (s - first).total_seconds() for s in stamps])
    return seconds, first.isoformat()


def _looks_numeric(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# --- CSV -------------------------------------------------------------------------------

def detect_separator(header_line: str) -> str:
    """The most frequent of ``,``, ``;`` and tab in a CSV header line.

    Raises
    ------
    DataFileError
        None of them occurs (a single column).
    """
    counts = {sep: header_line.count(sep) for sep in SEPARATORS}
    best = max(SEPARATORS, key=lambda s: counts[s])
    if counts[best] == 0:
        raise DataFileError(
            f"cannot tell the separator: the header {header_line.strip()!r} holds no ',', ';' "
            "or tab; pass --sep")
    return best


def _parse_number(cell: str, decimal: str) -> float:
    text = cell.strip()
    if text.lower() in MISSING_TOKENS:
        return math.nan
    if decimal == ",":
        if "." in text:
            raise ValueError(text)
        text = text.replace(",", ".")
    return float(text)


def read_log_csv(
    path: str | os.PathLike[str],
    *,
    columns: Mapping[str, str] | None = None,
    policy: LoadPolicy | None = None,
    sep: str | None = None,
    decimal: str | None = None,
    input_unit: str = "%",
    output_unit: str = "kW",
    time_format: str | None = None,
) -> LoadedLog:
    """Read a CSV log as historians export it (see the module docstring for the rules).

    Parameters
    ----------
    path :
        The file (UTF-8 text, one header line).
    columns :
        Contract name -> the file's column name; default the contract's own names.
    policy :
        Gap, jitter and sampling policy; default `LoadPolicy()` (refuse gaps).
    sep :
        ``","``, ``";"`` or ``"\\t"``; default detected from the header.
    decimal :
        ``"."`` or ``","``; default ``","`` if the separator is not a comma and a value
        cell looks like ``12,5``.
    input_unit, output_unit :
        Units of the input and output columns.
    time_format :
        `datetime.strptime` format of the time stamps (``"%d.%m.%Y %H:%M:%S"``); default
        seconds or ISO-8601, told from the first row.

    Returns
    -------
    LoadedLog

    Raises
    ------
    DataFileError
        A malformed file, or data the policy refuses; the message names the file, line,
        column and the option that would accept the data, if any.
    OSError
        The file cannot be opened.
    """
    policy = LoadPolicy() if policy is None else policy
    p, blob, digest = file_bytes(path)
    text = decode_text(blob, p)
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise DataFileError("the file is empty; expected a header and rows", path=p)
    if sep is not None and sep not in SEPARATORS:
        raise DataFileError(f"sep must be one of {list(SEPARATORS)}; got {sep!r}", path=p)
    try:
        separator = detect_separator(lines[0]) if sep is None else sep
    except DataFileError as exc:
        later = next((i for i, line in enumerate(lines[1:20], start=2)
                      if any(c in line for c in SEPARATORS)), None)
        hint = "" if later is None else (
            f" (line {later} has one: if lines before the header, such as an export's title, "
            "come first, delete them; the header must be the first line)")
        raise DataFileError(str(exc) + hint, path=p, line=1) from None
    header, body = csv_table("\n".join(lines), p, separator)
    if len(header) == 1 and any(sep_ in header[0] for sep_ in SEPARATORS):
        raise DataFileError(
            f"the header is one field with the separator {separator!r}; got {header[0]!r} "
            "(pass --sep ',', ';' or tab)", path=p, line=1)
    names = check_column_mapping(
        header, columns, p, missing_hint=_COLUMNS_HINT,
        layout_hint="pass --columns time_s=NAME,triac_pct=NAME,power_kw=NAME")
    index = {c: header.index(names[c]) for c in CSV_COLUMNS}
    if len(body) < MIN_SAMPLES:
        raise DataFileError(f"expected at least {MIN_SAMPLES} samples; got {len(body)}", path=p)
    for i, row in enumerate(body):
        if policy.gaps == "refuse" and not any(c.strip() for c in row):
            raise DataFileError("blank line; expected a row of numbers (--gaps split or "
                                "--gaps fill skip it as a missing sample)", path=p, line=i + 2)
        if row and any(c.strip() for c in row) and len(row) != len(header):
            hint = "" if sep is not None else f" (separator {separator!r} detected; pass --sep)"
            raise DataFileError(f"expected {len(header)} cells like the header; got {len(row)}"
                                + hint, path=p, line=i + 2)
    if decimal is None:
        decimal = "," if separator != "," and any(
            len(row) > index[c] and _DECIMAL_COMMA.match(row[index[c]].strip())
            for row in body[:200] for c in ("triac_pct", "power_kw")) else "."
    elif decimal not in (".", ","):
        raise DataFileError(f"decimal must be '.' or ','; got {decimal!r}", path=p)
    if decimal == "," and separator == ",":
        raise DataFileError("a decimal comma needs another separator (pass --sep ';' or tab)",
                            path=p)

    def cell(row: list[str], c: str) -> str:
        return row[index[c]] if len(row) > index[c] else ""

    signals = ("triac_pct", "power_kw") + (
        (GRID_VOLTAGE_COLUMN,) if GRID_VOLTAGE_COLUMN in names else ())
    index.update({c: header.index(names[c]) for c in signals})
    values: dict[str, list[float]] = {c: [] for c in signals}
    for i, row in enumerate(body):
        for c in signals:
            raw_cell = cell(row, c)
            try:
                v = _parse_number(raw_cell, decimal)
            except ValueError:
                hint = ("" if decimal == "," or "," not in raw_cell
                        else " (a decimal comma? pass --decimal , with --sep ';')")
                raise DataFileError(f"expected a number; got {raw_cell.strip()!r}{hint}",
                                    path=p, line=i + 2, column=names[c]) from None
            if math.isinf(v):
                raise DataFileError(f"expected a finite number; got {raw_cell.strip()!r}",
                                    path=p, line=i + 2, column=names[c])
            if c == GRID_VOLTAGE_COLUMN and not math.isnan(v):   # NaN: missing, as u and y
                check_voltage_value(v, raw_cell, p, i + 2, names[c])
            values[c].append(v)
    time_cells = [cell(row, "time_s") for row in body]
    first = next((t.strip() for t in time_cells if t.strip().lower() not in MISSING_TOKENS), "")
    line_numbers = list(range(2, len(body) + 2))
    origin = None
    if time_format is None and _looks_numeric(first.replace(",", ".") if decimal == "," else first):
        time_kind = "seconds"
        secs = []
        for i, t in enumerate(time_cells):
            try:
                secs.append(_parse_number(t, decimal))
            except ValueError:
                raise DataFileError(f"expected a time in seconds like the first rows; got "
                                    f"{t.strip()!r}", path=p, line=i + 2,
                                    column=names["time_s"]) from None
        time = np.asarray(secs, dtype=float)
        if np.isinf(time).any():
            k = int(np.argmax(np.isinf(time)))
            raise DataFileError(f"expected a finite time; got {time_cells[k].strip()!r}",
                                path=p, line=k + 2, column=names["time_s"])
    else:
        time_kind = "timestamp"
        time, origin = _iso_seconds(time_cells, names, str(p), line_numbers, time_format)
    raw = _Raw(time=time, u=np.asarray(values["triac_pct"], dtype=float),
               y=np.asarray(values["power_kw"], dtype=float),
               v=(np.asarray(values[GRID_VOLTAGE_COLUMN], dtype=float)
                  if GRID_VOLTAGE_COLUMN in values else None),
               lines=np.asarray(line_numbers, dtype=np.int64), path=str(p), names=names,
               source_format="csv", separator=separator, decimal=decimal,
               time_format=time_kind, time_origin=origin, sha256=digest)
    return _regularize(raw, policy, input_unit=input_unit, output_unit=output_unit)


# --- Parquet ---------------------------------------------------------------------------

_NS_PER_UNIT = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}


def _arrow_time(column: Any, name: str, path: str | None) -> tuple[FloatArray, str, str | None]:
    """Seconds (from the first stamp if absolute), the time format and the origin."""
    import pyarrow as pa
    import pyarrow.compute as pc

    kind = column.type
    if pa.types.is_timestamp(kind):
        ns = pc.cast(pc.cast(column, pa.int64()), pa.float64()).to_numpy(zero_copy_only=False)
        ns = ns * _NS_PER_UNIT[kind.unit]
        valid = ns[~np.isnan(ns)]
        if valid.size == 0:
            raise _no_time_stamp(path, name)
        first_ns = int(valid[0])
        zone = UTC if kind.tz is not None else None
        origin = datetime.fromtimestamp(first_ns / 1e9, tz=UTC)
        origin_text = (origin if zone else origin.replace(tzinfo=None)).isoformat()
        return (ns - first_ns) / 1e9, "timestamp", origin_text
    if pa.types.is_string(kind) or pa.types.is_large_string(kind):
        cells = column.to_pylist()
        secs, origin_text = _iso_seconds(cells, {"time_s": name}, path, None)
        return secs, "timestamp", origin_text
    if pa.types.is_integer(kind) or pa.types.is_floating(kind):
        return (pc.cast(column, pa.float64()).to_numpy(zero_copy_only=False), "seconds", None)
    raise DataFileError(f"expected seconds or time stamps in the time column; got the Arrow "
                        f"type {kind}", path=path, column=name)


def _arrow_values(column: Any, name: str, path: str | None) -> FloatArray:
    import pyarrow as pa
    import pyarrow.compute as pc

    if not (pa.types.is_integer(column.type) or pa.types.is_floating(column.type)):
        raise DataFileError(f"expected a numeric column; got the Arrow type {column.type}",
                            path=path, column=name)
    out = np.asarray(pc.cast(column, pa.float64()).to_numpy(zero_copy_only=False), dtype=float)
    _check_finite_values(out, name, path)
    return out


def _check_finite_values(values: FloatArray, name: str, path: str | None) -> None:
    """Refuse an infinite value in a signal column (NaN is a missing value)."""
    bad = np.flatnonzero(np.isinf(values))
    if bad.size:
        raise _row_error(f"expected a finite number; got {values[bad[0]]}", int(bad[0]),
                         lines=None, path=path, column=name)


def _check_voltage_values(values: FloatArray, name: str, path: str | None) -> None:
    """Refuse a grid voltage factor outside its range (NaN is a missing value)."""
    lo, hi = GRID_VOLTAGE_RANGE
    bad = np.flatnonzero(~np.isnan(values) & ((values < lo) | (values > hi)))
    if bad.size:
        raise _row_error(f"{voltage_expectation()}; got {values[bad[0]]}", int(bad[0]),
                         lines=None, path=path, column=name)


def read_log_parquet(
    path: str | os.PathLike[str],
    *,
    columns: Mapping[str, str] | None = None,
    policy: LoadPolicy | None = None,
    input_unit: str = "%",
    output_unit: str = "kW",
) -> LoadedLog:
    """Read a Parquet log (time as seconds, a timestamp type or ISO text; nulls missing).

    Parameters and errors as `read_log_csv` (rows are named ``row N``, 1-based).
    """
    import pyarrow.parquet as pq

    policy = LoadPolicy() if policy is None else policy
    p, blob, digest = file_bytes(path)
    try:
        table = pq.read_table(io.BytesIO(blob))
    except Exception as exc:  # pyarrow raises several types for a damaged file
        raise DataFileError(f"not readable as Parquet: {exc}", path=p) from None
    names = check_column_mapping(table.column_names, columns, p, missing_hint=_COLUMNS_HINT)
    time, fmt, origin = _arrow_time(table.column(names["time_s"]), names["time_s"], str(p))
    u = _arrow_values(table.column(names["triac_pct"]), names["triac_pct"], str(p))
    y = _arrow_values(table.column(names["power_kw"]), names["power_kw"], str(p))
    v = None
    if GRID_VOLTAGE_COLUMN in names:
        v = _arrow_values(table.column(names[GRID_VOLTAGE_COLUMN]), names[GRID_VOLTAGE_COLUMN],
                          str(p))
        _check_voltage_values(v, names[GRID_VOLTAGE_COLUMN], str(p))
    raw = _Raw(time=np.asarray(time, dtype=float), u=u, y=y, v=v, lines=None, path=str(p),
               names=names, source_format="parquet", time_format=fmt, time_origin=origin,
               sha256=digest)
    return _regularize(raw, policy, input_unit=input_unit, output_unit=output_unit)


def _columns(data: Dataset) -> dict[str, Any]:
    """The contract's columns of ``data`` and ``segment`` (each sample's, 0-based)."""
    segment = np.repeat(np.arange(data.n_segments, dtype=np.int64),
                        [hi - lo for lo, hi in data.segment_bounds()])
    out = {"time_s": np.array(data.time_s), "triac_pct": np.array(data.triac_pct),
           "power_kw": np.array(data.power_kw), "segment": segment}
    if data.grid_voltage_factor is not None:
        out[GRID_VOLTAGE_COLUMN] = np.array(data.grid_voltage_factor)
    return out


def write_parquet(data: Dataset, path: str | os.PathLike[str]) -> None:
    """Write a data set as Parquet with the contract's column names (and ``segment``).

    ``read_log_parquet(path, policy=LoadPolicy(gaps="split"))`` reads it back; a data
    set of one segment also reads back under the default policy.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    from sysid.atomic import atomic_write_bytes

    sink = pa.BufferOutputStream()
    pq.write_table(pa.table(_columns(data)), sink)
    atomic_write_bytes(path, sink.getvalue().to_pybytes())


# --- pandas ----------------------------------------------------------------------------

def _pandas() -> Any:
    try:
        import pandas
    except ImportError:
        raise ImportError(
            "reading or writing a pandas DataFrame needs pandas: pip install 'czmpc[pandas]'") from None
    return pandas


def read_frame(
    frame: Any,
    *,
    columns: Mapping[str, str] | None = None,
    policy: LoadPolicy | None = None,
    input_unit: str = "%",
    output_unit: str = "kW",
) -> LoadedLog:
    """Read a pandas DataFrame (needs ``czmpc[pandas]``).

    Parameters
    ----------
    frame :
        A ``pandas.DataFrame``; the time is the column mapped to ``time_s``, else a
        ``DatetimeIndex`` or an index of that name.
    columns, policy, input_unit, output_unit :
        As `read_log_csv`.

    Returns
    -------
    LoadedLog

    Raises
    ------
    ImportError
        pandas is not installed (the message names the extra).
    DataFileError
        Not a DataFrame, missing columns, or data the policy refuses.
    """
    pd = _pandas()
    if not isinstance(frame, pd.DataFrame):
        raise DataFileError(f"expected a pandas DataFrame; got {type(frame).__name__}")
    wanted = {c: c for c in CSV_COLUMNS} if columns is None else dict(columns)
    time_name = wanted.get("time_s", "time_s")
    if time_name in frame.columns:
        time_series = frame[time_name]
    elif isinstance(frame.index, pd.DatetimeIndex) or frame.index.name == time_name:
        time_series = frame.index.to_series()
    else:   # a RangeIndex counts rows, not seconds: never take it for time
        raise DataFileError(
            f"no column '{time_name}' and the index is neither a DatetimeIndex nor named "
            f"'{time_name}'; got columns {[str(c) for c in frame.columns]} (map the time "
            "column with columns={'time_s': NAME, ...})", column=time_name)
    header = [str(c) for c in frame.columns] + ([] if time_name in frame.columns else [time_name])
    names = check_column_mapping(header, wanted, None)
    if pd.api.types.is_datetime64_any_dtype(time_series):
        zoned = getattr(time_series.dt, "tz", None) is not None
        utc = time_series.dt.tz_convert("UTC").dt.tz_localize(None) if zoned else time_series
        stamps = utc.to_numpy(dtype="datetime64[ns]")
        valid = ~np.isnat(stamps)
        if not valid.any():
            raise _no_time_stamp(None, time_name)
        first = stamps[valid][0]
        secs = np.where(valid, (stamps - first) / np.timedelta64(1, "ns") / 1e9, np.nan)
        origin = pd.Timestamp(first).tz_localize("UTC" if zoned else None).isoformat()
        time, fmt = np.asarray(secs, dtype=float), "timestamp"
    elif pd.api.types.is_numeric_dtype(time_series):
        time, fmt, origin = time_series.to_numpy(dtype=float, na_value=np.nan), "seconds", None
    else:
        cells = [None if v is None or (isinstance(v, float) and math.isnan(v)) else str(v)
                 for v in time_series.tolist()]
        time, origin = _iso_seconds(cells, names, None, None)
        fmt = "timestamp"
    signals = []
    for c in ("triac_pct", "power_kw") + (
            (GRID_VOLTAGE_COLUMN,) if GRID_VOLTAGE_COLUMN in names else ()):
        col = frame[names[c]]
        if not pd.api.types.is_numeric_dtype(col):
            raise DataFileError(f"expected a numeric column; got dtype {col.dtype}",
                                column=names[c])
        arr = col.to_numpy(dtype=float, na_value=np.nan)
        _check_finite_values(arr, names[c], None)
        signals.append(arr)
    if len(signals) > 2:
        _check_voltage_values(signals[2], names[GRID_VOLTAGE_COLUMN], None)
    raw = _Raw(time=np.asarray(time, dtype=float), u=signals[0], y=signals[1],
               v=signals[2] if len(signals) > 2 else None, lines=None,
               path=None, names=names, source_format="frame", time_format=fmt,
               time_origin=origin)
    return _regularize(raw, policy or LoadPolicy(), input_unit=input_unit,
                       output_unit=output_unit)


def to_frame(data: Dataset) -> Any:
    """The data set as a pandas DataFrame (contract columns and ``segment``; needs pandas)."""
    return _pandas().DataFrame(_columns(data))


def load_log(
    path: str | os.PathLike[str],
    *,
    columns: Mapping[str, str] | None = None,
    policy: LoadPolicy | None = None,
    sep: str | None = None,
    decimal: str | None = None,
    input_unit: str = "%",
    output_unit: str = "kW",
    time_format: str | None = None,
) -> LoadedLog:
    """Read a CSV or Parquet log (told by the file's first bytes): see `read_log_csv` and
    `read_log_parquet`."""
    p = Path(path)
    with p.open("rb") as fh:
        magic = fh.read(4)
    if magic == b"PAR1":
        if sep is not None or decimal is not None or time_format is not None:
            raise DataFileError("--sep, --decimal and --time-format apply to CSV files; this "
                                "is Parquet", path=p)
        return read_log_parquet(p, columns=columns, policy=policy, input_unit=input_unit,
                                output_unit=output_unit)
    return read_log_csv(p, columns=columns, policy=policy, sep=sep, decimal=decimal,
                        input_unit=input_unit, output_unit=output_unit, time_format=time_format)


__all__ = [
    "DEFAULT_FILL_MAX_SAMPLES", "GAP_POLICIES", "LINEAR_GAP_PERIODS", "LoadPolicy", "LoadReport",
    "LoadedLog", "MIN_SEGMENT_SAMPLES", "RESAMPLE_POLICIES", "SNAP_MAX_JITTER", "detect_separator",
    "load_log", "read_frame", "read_log_csv", "read_log_parquet", "to_frame", "write_parquet"
]
