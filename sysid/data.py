"""Dataset type and the logged-data CSV contract (``time_s,triac_pct,power_kw``).

A `Dataset` is one uniformly sampled SISO record: time, TRIAC input, heater power.
`read_csv` refuses any file that breaks the contract with a `DataFileError` naming
the file, the 1-based line and the column; nothing is dropped, reordered or
interpolated on read. Logs from other rigs (other names, other units) are read
through an explicit column mapping; their units are recorded on the `Dataset`.
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from sysid._arrays import readonly_array as _readonly
from sysid._typing import FloatArray
from sysid.atomic import atomic_write_text
from sysid.errors import DataFileError

#: The CSV contract's header, in order.
CSV_COLUMNS: tuple[str, str, str] = ("time_s", "triac_pct", "power_kw")

#: Default tolerance on sampling-interval jitter, relative to the nominal interval.
#: 1 % accepts a logger's rounding of timestamps and refuses a skipped sample (100 %).
DEFAULT_SAMPLING_RTOL = 0.01

#: The fewest samples any model in this project can be fitted to.
MIN_SAMPLES = 3

#: The optional column of the grid voltage relative to nominal [-] (issue 40): the
#: heater's drive goes with its square. Absent: no voltage compensation.
GRID_VOLTAGE_COLUMN = "grid_voltage_factor"
#: Accepted range of the grid voltage factor [-]: outside it the value is not a
#: mains voltage relative to nominal (a voltage in volts, or a percentage).
GRID_VOLTAGE_RANGE: tuple[float, float] = (0.5, 1.5)


@dataclass(frozen=True, kw_only=True, eq=False)
class Dataset:
    """One uniformly sampled record of TRIAC input and heater power.

    Parameters
    ----------
    time_s :
        Sample times [s], strictly increasing, shape ``(n_samples,)``.
    triac_pct :
        TRIAC input signal ``s`` [%] (or `input_unit` for logs of other rigs).
    power_kw :
        Measured heater power ``P`` [kW] (or `output_unit`).
    ts_s :
        Nominal sampling time [s].
    input_unit, output_unit :
        Units of the two signals as logged (``"%"`` and ``"kW"`` for a CZ puller).
    source :
        File the data came from, or None.
    sha256 :
        SHA-256 of the source file's bytes, or None.
    preprocessing :
        Every change made to the data since it was read (see `sysid.preprocess`).
    sampling_rtol :
        Allowed relative deviation of any interval (within a segment) from ``ts_s``.
    segment_starts :
        Sample indices where each segment (experiment) starts: strictly increasing,
        the first 0. Each segment is uniformly sampled with ``ts_s``; across a
        segment boundary time may jump (a gap), but still increases.
    grid_voltage_factor :
        Grid voltage relative to nominal [-] at each sample (the optional log column
        `GRID_VOLTAGE_COLUMN`), each within `GRID_VOLTAGE_RANGE`; None (default) when
        the log does not carry it (no voltage compensation).

    Raises
    ------
    DataFileError
        Arrays of unequal length or other than 1-D, non-finite values, fewer than
        `MIN_SAMPLES` samples (in any segment), time not strictly increasing, a
        sampling interval within a segment that differs from ``ts_s`` by more than
        `DEFAULT_SAMPLING_RTOL`, malformed ``segment_starts``, or a grid voltage
        factor of another length, not finite or outside `GRID_VOLTAGE_RANGE`.
    """

    time_s: FloatArray
    triac_pct: FloatArray
    power_kw: FloatArray
    ts_s: float
    input_unit: str = "%"
    output_unit: str = "kW"
    source: str | None = None
    sha256: str | None = None
    preprocessing: tuple[Mapping[str, Any], ...] = field(default=())
    sampling_rtol: float = DEFAULT_SAMPLING_RTOL
    segment_starts: tuple[int, ...] = (0,)
    grid_voltage_factor: FloatArray | None = None

    def __post_init__(self) -> None:
        for name in CSV_COLUMNS:
            arr = _readonly(getattr(self, name))
            if arr.ndim != 1:
                raise self._error(f"{name} must be 1-D; got shape {arr.shape}")
            object.__setattr__(self, name, arr)
        n = self.time_s.size
        if self.triac_pct.size != n or self.power_kw.size != n:
            raise self._error("time_s, triac_pct and power_kw must have equal lengths; got "
                              f"{n}, {self.triac_pct.size}, {self.power_kw.size}")
        if n < MIN_SAMPLES:
            raise self._error(f"a data set needs at least {MIN_SAMPLES} samples; got {n}")
        for name in CSV_COLUMNS:
            values = getattr(self, name)
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                raise self._error(f"sample {bad[0]}: expected a finite number; got {values[bad[0]]}",
                                  column=name)
        if not (math.isfinite(self.ts_s) and self.ts_s > 0):
            raise self._error(f"ts_s must be a finite number > 0; got {self.ts_s}")
        object.__setattr__(self, "ts_s", float(self.ts_s))
        object.__setattr__(self, "segment_starts", self._checked_segment_starts(n))
        if self.grid_voltage_factor is not None:
            object.__setattr__(self, "grid_voltage_factor", self._checked_voltage(n))
        for lo, hi in self.segment_bounds():
            k = first_sampling_violation(self.time_s[lo:hi], self.ts_s, self.sampling_rtol)
            if k is not None:
                raise self._error(sampling_violation_message(
                    self.time_s, lo + k, self.ts_s, self.sampling_rtol), column="time_s")
        for lo in self.segment_starts[1:]:
            if not self.time_s[lo] > self.time_s[lo - 1]:
                raise self._error(
                    f"time must be strictly increasing across segments; segment at sample "
                    f"{lo} starts at {self.time_s[lo]:g} s after {self.time_s[lo - 1]:g} s",
                    column="time_s")

    def _error(self, message: str, *, column: str | None = None) -> DataFileError:
        """A `DataFileError` naming this data set's source file."""
        return DataFileError(message, path=self.source, column=column)

    def _checked_voltage(self, n: int) -> FloatArray:
        volt = _readonly(self.grid_voltage_factor)
        if volt.ndim != 1 or volt.size != n:
            raise self._error(f"{GRID_VOLTAGE_COLUMN} must be 1-D with one value per sample "
                              f"({n}); got shape {volt.shape}", column=GRID_VOLTAGE_COLUMN)
        bad = np.flatnonzero(~_voltage_ok(volt))
        if bad.size:
            raise self._error(f"sample {bad[0]}: {voltage_expectation()}; got {volt[bad[0]]}",
                              column=GRID_VOLTAGE_COLUMN)
        return volt

    def _checked_segment_starts(self, n: int) -> tuple[int, ...]:
        raw = self.segment_starts
        if isinstance(raw, (str, bytes)) or not hasattr(raw, "__iter__"):
            raise self._error(f"segment_starts must be a tuple of sample indices; got {raw!r}")
        starts = tuple(raw)
        if not starts or not all(
                isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in starts):
            raise self._error(f"segment_starts must be a non-empty tuple of integers; got {raw!r}")
        starts = tuple(int(v) for v in starts)
        if starts[0] != 0:
            raise self._error(f"segment_starts must begin with 0; got {starts[0]}")
        bounds = (*starts, n)
        if any(hi - lo < MIN_SAMPLES for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)):
            raise self._error(
                f"segment_starts must be strictly increasing with at least {MIN_SAMPLES} "
                f"samples per segment (n_samples = {n}); got {starts}")
        return starts

    @classmethod
    def from_frame(
        cls,
        frame: Any,
        *,
        columns: Mapping[str, str] | None = None,
        policy: Any = None,
        input_unit: str = "%",
        output_unit: str = "kW",
    ) -> Dataset:
        """A data set from a pandas DataFrame (needs ``pip install czmpc[pandas]``).

        See `sysid.historian.read_frame` for the columns, the time (a column or the
        index; seconds or time stamps) and the `sysid.historian.LoadPolicy` for NaN,
        gaps and jitter; what was done is recorded in ``preprocessing``.
        """
        from sysid.historian import read_frame

        return read_frame(frame, columns=columns, policy=policy, input_unit=input_unit,
                          output_unit=output_unit).data

    @property
    def n_segments(self) -> int:
        """Number of segments (experiments)."""
        return len(self.segment_starts)

    def segment_bounds(self) -> tuple[tuple[int, int], ...]:
        """``(start, stop)`` sample indices of each segment, in order."""
        bounds = (*self.segment_starts, self.n_samples)
        return tuple(zip(bounds[:-1], bounds[1:], strict=True))

    def segments(self) -> tuple[Dataset, ...]:
        """Each segment as a data set of its own (its own time axis, one segment each).

        A data set of one segment returns ``(self,)``. Each part records which samples
        of this data set it holds in its ``preprocessing``.
        """
        if self.n_segments == 1:
            return (self,)
        return tuple(self.segment(lo, hi) for lo, hi in self.segment_bounds())

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.time_s.size)

    @property
    def duration_s(self) -> float:
        """``time_s[-1] - time_s[0]`` [s]."""
        return float(self.time_s[-1] - self.time_s[0])

    def with_signals(
        self,
        *,
        triac_pct: FloatArray | None = None,
        power_kw: FloatArray | None = None,
        change: Mapping[str, Any] | None = None,
    ) -> Dataset:
        """Return a copy with new signal values and, if given, one more recorded change."""
        return replace(
            self,
            triac_pct=self.triac_pct if triac_pct is None else triac_pct,
            power_kw=self.power_kw if power_kw is None else power_kw,
            preprocessing=self.preprocessing + ((dict(change),) if change else ()))

    def segment(self, start: int, stop: int) -> Dataset:
        """Samples ``start:stop`` as a new data set (the change is recorded).

        Segment boundaries inside ``start:stop`` are kept.
        """
        if not (0 <= start < stop <= self.n_samples):
            raise self._error(
                f"segment must satisfy 0 <= start < stop <= {self.n_samples}; got {start}:{stop}")
        return replace(
            self,
            time_s=self.time_s[start:stop],
            triac_pct=self.triac_pct[start:stop],
            power_kw=self.power_kw[start:stop],
            grid_voltage_factor=None if self.grid_voltage_factor is None
            else self.grid_voltage_factor[start:stop],
            preprocessing=self.preprocessing
            + ({"what": "segment", "start_sample": start, "stop_sample": stop},),
            segment_starts=(0, *(b - start for b in self.segment_starts if start < b < stop)))


def _voltage_ok(values: FloatArray) -> npt.NDArray[np.bool_]:
    """True where a grid voltage factor is finite and inside `GRID_VOLTAGE_RANGE`."""
    lo, hi = GRID_VOLTAGE_RANGE
    with np.errstate(invalid="ignore"):
        ok: npt.NDArray[np.bool_] = np.isfinite(values) & (values >= lo) & (values <= hi)
    return ok


def voltage_expectation() -> str:
    """What a grid voltage factor must be, for error messages."""
    lo, hi = GRID_VOLTAGE_RANGE
    return (f"expected a finite grid voltage factor (voltage / nominal) within {lo:g}..{hi:g}")


def check_voltage_value(value: float, cell: str, path: str | Path | None, line: int | None,
                        column: str) -> None:
    """Refuse one read grid voltage factor outside `GRID_VOLTAGE_RANGE` (file, line, column)."""
    if not bool(_voltage_ok(np.array([value]))[0]):
        raise DataFileError(f"{voltage_expectation()}; got {cell.strip()!r}", path=path,
                            line=line, column=column)


def first_sampling_violation(time_s: FloatArray, ts_s: float, rtol: float) -> int | None:
    """Index ``k`` of the first sample whose interval ``t[k] - t[k-1]`` is off, or None."""
    steps = np.diff(time_s)
    bad = np.flatnonzero((steps <= 0) | (np.abs(steps - ts_s) > rtol * ts_s))
    return int(bad[0]) + 1 if bad.size else None


def sampling_violation_message(time_s: FloatArray, k: int, ts_s: float, rtol: float) -> str:
    """Explain why the interval ending at sample ``k`` breaks uniform sampling."""
    step = time_s[k] - time_s[k - 1]
    if step <= 0:
        return f"time must be strictly increasing; got {time_s[k]:g} s after {time_s[k - 1]:g} s"
    return (
        f"sampling must be uniform (interval {ts_s:g} s within {100 * rtol:g} %); got an "
        f"interval of {step:g} s from {time_s[k - 1]:g} s to {time_s[k]:g} s")


def file_bytes(path: str | os.PathLike[str]) -> tuple[Path, bytes, str]:
    """The file's path, its bytes and their SHA-256 (hex)."""
    p = Path(path)
    blob = p.read_bytes()
    return p, blob, hashlib.sha256(blob).hexdigest()


def decode_text(blob: bytes, path: str | Path) -> str:
    """A file's bytes as UTF-8 text (a byte-order mark dropped); `DataFileError` if not UTF-8."""
    try:
        return blob.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = blob.count(b"\n", 0, exc.start) + 1
        raise DataFileError(
            f"expected UTF-8 text; got the byte 0x{blob[exc.start]:02x} at offset {exc.start}"
            f" (line {line}), which UTF-8 does not allow: "
            "save the export as UTF-8 (Excel: 'CSV UTF-8'; Windows-1252 writes a degree sign "
            "as 0xb0)", path=path) from None


def csv_table(text: str, path: str | Path, delimiter: str = ",") -> tuple[list[str], list[list[str]]]:
    """The header (fields stripped, none twice) and the rows of CSV ``text``."""
    reader = csv.reader(io.StringIO(text), delimiter=delimiter)
    try:
        table = list(reader)
    except csv.Error as exc:    # e.g. a bare carriage return inside a field
        raise DataFileError(f"not readable as CSV: {exc}", path=path, line=reader.line_num) from None
    header = [h.strip() for h in table[0]]
    if len(set(header)) != len(header):
        dup = next(h for h in header if header.count(h) > 1)
        raise DataFileError(f"header field '{dup}' appears twice", path=path, line=1, column=dup)
    return header, table[1:]


def check_column_mapping(header: Sequence[str], columns: Mapping[str, str] | None,
                         path: str | Path | None, *, missing_hint: str = "",
                         layout_hint: str | None = None) -> dict[str, str]:
    """Contract name -> the log's column name (`columns`, default the contract's own).

    Refuses a mapping of other names or onto one column twice, and a mapped column
    missing from `header` (`missing_hint` ends that message when `columns` is None).
    With `layout_hint` and no `columns`, `header` must be exactly `CSV_COLUMNS`, or
    `CSV_COLUMNS` followed by `GRID_VOLTAGE_COLUMN`.

    The optional `GRID_VOLTAGE_COLUMN` is in the result when `columns` maps it, or
    when `header` holds a field of that name that no other contract name is mapped to.
    """
    wanted = {c: c for c in CSV_COLUMNS} if columns is None else dict(columns)
    if not (set(CSV_COLUMNS) <= set(wanted) <= {*CSV_COLUMNS, GRID_VOLTAGE_COLUMN}):
        raise DataFileError(
            f"the column mapping must map exactly {list(CSV_COLUMNS)} (and optionally "
            f"'{GRID_VOLTAGE_COLUMN}'); got {sorted(wanted)}",
            path=path)
    if len(set(wanted.values())) != len(wanted):
        raise DataFileError(
            f"the column mapping must map each name to a different column; got {wanted}",
            path=path)
    for contract, name in wanted.items():
        if name not in header:
            raise DataFileError(
                f"header must contain '{name}'"
                + ("" if name == contract else f" (mapped to {contract})")
                + f"; got fields {list(header)}" + ("" if columns is not None else missing_hint),
                path=path, line=1, column=name)
    if GRID_VOLTAGE_COLUMN not in wanted and GRID_VOLTAGE_COLUMN in header \
            and GRID_VOLTAGE_COLUMN not in wanted.values():
        wanted[GRID_VOLTAGE_COLUMN] = GRID_VOLTAGE_COLUMN
    if columns is None and layout_hint is not None and list(header) not in (
            list(CSV_COLUMNS), [*CSV_COLUMNS, GRID_VOLTAGE_COLUMN]):
        extra = [h for h in header if h not in (*CSV_COLUMNS, GRID_VOLTAGE_COLUMN)]
        detail = f"extra field(s) {extra}" if extra else f"fields in the order {list(header)}"
        raise DataFileError(
            f"header must be exactly 'time_s,triac_pct,power_kw'; got {detail} ({layout_hint} "
            f"to read other layouts; only an optional '{GRID_VOLTAGE_COLUMN}' may follow)",
            path=path, line=1, column=extra[0] if extra else None)
    return wanted


def read_csv(
    path: str | os.PathLike[str],
    *,
    columns: Mapping[str, str] | None = None,
    ts_s: float | None = None,
    sampling_rtol: float = DEFAULT_SAMPLING_RTOL,
    min_samples: int = MIN_SAMPLES,
    input_unit: str = "%",
    output_unit: str = "kW",
) -> Dataset:
    """Read a logged-data CSV file into a `Dataset`.

    Parameters
    ----------
    path :
        File to read. Its header must be exactly ``time_s,triac_pct,power_kw`` (or
        that followed by the optional ``grid_voltage_factor``) unless `columns` maps the
        contract's names to the file's.
    columns :
        Contract name (``time_s``, ``triac_pct``, ``power_kw``) -> the file's column
        name, for logs of other rigs (other columns are then allowed, and not read);
        it may also map ``grid_voltage_factor``, which is otherwise read when the file
        has a column of that name.
    ts_s :
        Nominal sampling time [s]; default: the median interval of the file.
    sampling_rtol :
        Allowed relative deviation of any interval from `ts_s`.
    min_samples :
        Fewest samples accepted (a model of orders na, nb, nk needs more than
        ``max(na, nb + nk)`` samples).
    input_unit, output_unit :
        Units of the input and output columns, recorded on the data set.

    Returns
    -------
    Dataset

    Raises
    ------
    DataFileError
        An empty file; missing, extra or duplicated header fields; a non-numeric,
        NaN or infinite cell; a grid voltage factor outside `GRID_VOLTAGE_RANGE`; a row
        with too many or too few cells; time not strictly
        increasing; non-uniform sampling; fewer than `min_samples` samples. The message
        names the file, the 1-based line and the column.
    OSError
        The file cannot be opened.
    """
    path, raw, digest = file_bytes(path)
    text = decode_text(raw, path)
    if not text.strip():
        raise DataFileError("the file is empty; expected a header 'time_s,triac_pct,power_kw' "
                            "and at least one row", path=path)
    header, rows = csv_table(text, path)
    wanted = check_column_mapping(header, columns, path, layout_hint="pass a column mapping")
    names = (*CSV_COLUMNS, *((GRID_VOLTAGE_COLUMN,) if GRID_VOLTAGE_COLUMN in wanted else ()))
    index = {name: header.index(wanted[name]) for name in names}
    values: dict[str, list[float]] = {name: [] for name in names}
    for line_no, row in enumerate(rows, start=2):
        if not row or all(not cell.strip() for cell in row):
            raise DataFileError("blank line; expected a row of numbers", path=path, line=line_no)
        if len(row) != len(header):
            raise DataFileError(
                f"expected {len(header)} cells like the header; got {len(row)}",
                path=path, line=line_no)
        for name in names:
            cell = row[index[name]].strip()
            try:
                value = float(cell)
            except ValueError:
                raise DataFileError(f"expected a number; got {cell!r}", path=path,
                                    line=line_no, column=wanted[name]) from None
            if not math.isfinite(value):
                raise DataFileError(f"expected a finite number; got {cell!r}", path=path,
                                    line=line_no, column=wanted[name])
            if name == GRID_VOLTAGE_COLUMN:
                check_voltage_value(value, cell, path, line_no, wanted[name])
            values[name].append(value)
    n = len(values["time_s"])
    if n < max(min_samples, MIN_SAMPLES):
        raise DataFileError(f"expected at least {max(min_samples, MIN_SAMPLES)} samples; got {n}", path=path)
    time_s = np.asarray(values["time_s"])
    nominal = float(np.median(np.diff(time_s))) if ts_s is None else float(ts_s)
    # time going backwards first (any interval passes rtol = inf), then uniform sampling
    for step_s, rtol in ((1.0, math.inf), (nominal, sampling_rtol)):
        if (k := first_sampling_violation(time_s, step_s, rtol)) is not None:
            raise DataFileError(sampling_violation_message(time_s, k, step_s, rtol), path=path,
                                line=k + 2, column=wanted["time_s"])
    return Dataset(
        time_s=time_s,
        triac_pct=np.asarray(values["triac_pct"]),
        power_kw=np.asarray(values["power_kw"]),
        ts_s=nominal,
        input_unit=input_unit,
        output_unit=output_unit,
        source=str(path),
        sha256=digest,
        sampling_rtol=sampling_rtol,
        grid_voltage_factor=(np.asarray(values[GRID_VOLTAGE_COLUMN])
                             if GRID_VOLTAGE_COLUMN in values else None))


def format_csv(data: Dataset) -> str:
    """Render a data set in the CSV contract (shortest round-trip float text), with the
    ``grid_voltage_factor`` column after the contract's if the data set carries it."""
    if data.grid_voltage_factor is not None:
        rows = (f"{float(t)!r},{float(s)!r},{float(p)!r},{float(v)!r}" for t, s, p, v in zip(
            data.time_s, data.triac_pct, data.power_kw, data.grid_voltage_factor, strict=True))
        return "\n".join([",".join((*CSV_COLUMNS, GRID_VOLTAGE_COLUMN)), *rows]) + "\n"
    rows = (f"{float(t)!r},{float(s)!r},{float(p)!r}"
            for t, s, p in zip(data.time_s, data.triac_pct, data.power_kw, strict=True))
    return "\n".join([",".join(CSV_COLUMNS), *rows]) + "\n"


def write_csv(data: Dataset, path: str | os.PathLike[str]) -> None:
    """Write a data set in the CSV contract, atomically (temporary file, then rename).

    Floats are written with Python's shortest round-trip representation, so
    ``read_csv(write_csv(d))`` reproduces every value bit for bit.
    """
    atomic_write_text(path, format_csv(data))


__all__ = ["CSV_COLUMNS", "DEFAULT_SAMPLING_RTOL", "Dataset", "GRID_VOLTAGE_COLUMN",
           "GRID_VOLTAGE_RANGE", "MIN_SAMPLES", "check_voltage_value", "format_csv", "read_csv",
           "voltage_expectation", "write_csv"]
