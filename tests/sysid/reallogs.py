"""Test support: readers for four public real-rig logs (DaISy heater and exchanger, TCLab, tanks).

Imported by the tests and the identification benchmark as ``tests.sysid.reallogs`` (both
run from the repository root); the logs are not in the wheel, so neither is this module.

These logs come from rigs other than the CZ puller, in other formats, units and
sampling (see ``data/real/README.md`` in the repository for provenance). Each reader keeps every
value as logged, records the file's SHA-256 and the units, and refuses a malformed
file with a `DataFileError` naming the file, the 1-based line and the column, like
`sysid.data.read_csv`. The signals still live in the `Dataset` fields ``triac_pct``
(input) and ``power_kw`` (output); their real units are in ``input_unit`` and
``output_unit``.
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
import os
from pathlib import Path
from typing import Literal

import numpy as np

from sysid._typing import FloatArray
from sysid.data import (
    DEFAULT_SAMPLING_RTOL,
    MIN_SAMPLES,
    Dataset,
    first_sampling_violation,
    read_csv,
    sampling_violation_message,
)
from sysid.errors import DataFileError

#: DaISy 99-001 sampling time [s] (its description file, item 3).
DAISY_TS_S = 2.0

#: DaISy 99-001 column names used in error messages (the file has no header).
DAISY_COLUMNS: tuple[str, str, str] = ("time_s", "lamp_voltage_v", "plate_temperature_degc")

#: DaISy 97-002 sampling time [s] (its description: "Sampling time: 1 s").
EXCHANGER_TS_S = 1.0

#: DaISy 97-002 column names used in error messages (the file has no header).
EXCHANGER_COLUMNS: tuple[str, str, str] = ("sample", "liquid_flow", "outlet_temperature_degc")

#: TCLab nominal sampling time [s] (a Python loop with ``time.sleep``).
TCLAB_TS_S = 1.0

#: TCLab interval tolerance, relative: the logged intervals run 0.990-1.021 s (clock
#: jitter of the host loop), so 5 % accepts them and still refuses a lost sample.
TCLAB_SAMPLING_RTOL = 0.05

#: Cascaded-tanks header fields; the trailing comma of every line adds an empty sixth.
TANKS_HEADER: tuple[str, ...] = ("uEst", "uVal", "yEst", "yVal", "Ts", "")

TanksRecord = Literal["estimation", "validation"]


def _read_text(path: Path) -> tuple[str, str]:
    """The file's text (UTF-8) and the SHA-256 of its bytes."""
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataFileError(f"expected UTF-8 text; got undecodable byte at offset {exc.start}",
                            path=path) from None
    if not text.strip():
        raise DataFileError("the file is empty; expected rows of numbers", path=path)
    return text, hashlib.sha256(raw).hexdigest()


def _number(cell: str, *, path: Path, line: int, column: str) -> float:
    text = cell.strip()
    try:
        value = float(text)
    except ValueError:
        raise DataFileError(f"expected a number; got {text!r}", path=path, line=line,
                            column=column) from None
    if not math.isfinite(value):
        raise DataFileError(f"expected a finite number; got {text!r}", path=path, line=line,
                            column=column)
    return value


def _without_trailing_blank(lines: list[str]) -> list[str]:
    """Drop blank lines at the end of the file only (a final newline, CRLF remnants)."""
    end = len(lines)
    while end and not lines[end - 1].strip():
        end -= 1
    return lines[:end]


def _check_count(n: int, path: Path) -> None:
    if n < MIN_SAMPLES:
        raise DataFileError(f"expected at least {MIN_SAMPLES} samples; got {n}", path=path)


def read_daisy_heating(path: str | os.PathLike[str]) -> Dataset:
    """Read DaISy data set 99-001 (heating system, Dullerud & Smith 1996).

    Parameters
    ----------
    path :
        The ``.dat`` file: whitespace-separated, no header, three columns: time [s],
        lamp drive voltage [V], plate temperature [degC]; one row per 2 s sample.

    Returns
    -------
    Dataset
        ``ts_s = 2.0``; input ``"V"`` (lamp voltage), output ``"degC"`` (plate
        temperature); 801 samples for the published file. The steady state before
        the experiment was u = 6.0 V, y = y[0] (the description file).

    Raises
    ------
    DataFileError
        An empty file; a blank line inside the data; a row without exactly three
        fields; a non-numeric or non-finite field; time not strictly increasing or not
        uniform at 2 s (within 1 %); fewer than 3 samples. Lines and columns are named.
    OSError
        The file cannot be opened.
    """
    values, digest = _read_columns(Path(path), DAISY_COLUMNS, "time [s], voltage [V], "
                                   "temperature [degC]")
    time_s = values[:, 0]
    _check_uniform(time_s, DAISY_TS_S, DEFAULT_SAMPLING_RTOL, path=Path(path), first_line=1,
                   column=DAISY_COLUMNS[0])
    return Dataset(time_s=time_s, triac_pct=values[:, 1], power_kw=values[:, 2],
                   ts_s=DAISY_TS_S, input_unit="V", output_unit="degC", source=str(path),
                   sha256=digest)


def read_daisy_exchanger(path: str | os.PathLike[str]) -> Dataset:
    """Read DaISy data set 97-002 (steam heat exchanger, Bittanti & Piroddi 1996).

    Parameters
    ----------
    path :
        The ``.dat`` file: whitespace-separated, no header, three columns: sample index
        (1, 2, ...), liquid flow rate (normalised), outlet liquid temperature; one row
        per 1 s sample.

    Returns
    -------
    Dataset
        ``ts_s = 1.0``, ``time_s = (index - 1) * 1 s``; input ``"-"`` (the normalised flow
        rate, DaISy states no unit), output ``"degC"`` (the outlet temperature; DaISy
        states no unit, the values 92.8..101.4 are degrees Celsius of water near boiling);
        4000 samples for the published file.

    Raises
    ------
    DataFileError
        An empty file; a blank line inside the data; a row without exactly three
        fields; a non-numeric or non-finite field; a sample index that does not count
        up by one; fewer than 3 samples. Lines and columns are named.
    OSError
        The file cannot be opened.
    """
    values, digest = _read_columns(Path(path), EXCHANGER_COLUMNS, "sample index, flow, "
                                   "temperature")
    index = values[:, 0]
    _check_uniform(index, 1.0, DEFAULT_SAMPLING_RTOL, path=Path(path), first_line=1,
                   column=EXCHANGER_COLUMNS[0])
    return Dataset(time_s=(index - index[0]) * EXCHANGER_TS_S, triac_pct=values[:, 1],
                   power_kw=values[:, 2], ts_s=EXCHANGER_TS_S, input_unit="-",
                   output_unit="degC", source=str(path), sha256=digest)


def _read_columns(path: Path, columns: tuple[str, str, str],
                  what: str) -> tuple[FloatArray, str]:
    """Rows of three whitespace-separated numbers (DaISy's format) and the file's SHA-256."""
    text, digest = _read_text(path)
    rows: list[list[float]] = []
    for line_no, line in enumerate(_without_trailing_blank(text.splitlines()), start=1):
        fields = line.split()
        if not fields:
            raise DataFileError("blank line; expected three numbers", path=path, line=line_no)
        if len(fields) != len(columns):
            raise DataFileError(
                f"expected {len(columns)} whitespace-separated fields ({what}); got "
                f"{len(fields)}", path=path, line=line_no,
            )
        rows.append([_number(cell, path=path, line=line_no, column=name)
                     for cell, name in zip(fields, columns, strict=True)])
    _check_count(len(rows), path)
    return np.asarray(rows), digest


def _check_uniform(time_s: FloatArray, ts_s: float, rtol: float, *, path: Path,
                   first_line: int, column: str) -> None:
    """Refuse a non-increasing or non-uniform time column, naming the line."""
    steps = np.diff(time_s)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise DataFileError(sampling_violation_message(time_s, k, ts_s, 0.0), path=path,
                            line=first_line + k, column=column)
    k_bad = first_sampling_violation(time_s, ts_s, rtol)
    if k_bad is not None:
        raise DataFileError(sampling_violation_message(time_s, k_bad, ts_s, rtol), path=path,
                            line=first_line + k_bad, column=column)


def read_tclab(
    path: str | os.PathLike[str],
    *,
    heater: Literal[1, 2] = 1,
    ts_s: float = TCLAB_TS_S,
    sampling_rtol: float = TCLAB_SAMPLING_RTOL,
) -> Dataset:
    """Read a TCLab (Arduino temperature control lab) step-test log, one heater.

    Parameters
    ----------
    path :
        CSV with the header ``Time (sec), Heater 1 (%), Heater 2 (%), Temperature 1
        (degC), Temperature 2 (degC), ...`` (APMonitor's ``data.txt``).
    heater :
        1 for ``Heater 1 (%) -> Temperature 1 (degC)``, 2 for heater 2.
    ts_s :
        Nominal sampling time [s]. The logged times are kept as they are.
    sampling_rtol :
        Accepted relative deviation of each logged interval from `ts_s` (the host's
        clock jitter; 0.990-1.021 s in the published file).

    Returns
    -------
    Dataset
        Input ``"%"`` (heater), output ``"degC"`` (temperature), the logged times,
        ``ts_s`` nominal; 599 samples for the published file.

    Raises
    ------
    DataFileError
        `heater` not 1 or 2; any `sysid.data.read_csv` error (header, cells, row
        lengths, sampling), naming file, line and column.
    OSError
        The file cannot be opened.

    Notes
    -----
    The other heater is a measured disturbance for a SISO model; it is not returned.
    """
    path = Path(path)
    if heater not in (1, 2):
        raise DataFileError(f"heater must be 1 or 2; got {heater!r}", path=path)
    return read_csv(
        path,
        columns={"time_s": "Time (sec)", "triac_pct": f"Heater {heater} (%)",
                 "power_kw": f"Temperature {heater} (degC)"},
        ts_s=ts_s, sampling_rtol=sampling_rtol, input_unit="%", output_unit="degC",
    )


def read_cascaded_tanks(
    path: str | os.PathLike[str], *, record: TanksRecord = "estimation"
) -> Dataset:
    """Read the cascaded-tanks benchmark (Schoukens, Mattsson, Wigren, Noel 2016).

    Parameters
    ----------
    path :
        ``dataBenchmark.csv``: CRLF lines, header ``"uEst","uVal","yEst","yVal","Ts",``
        (a trailing comma on every line), the sampling time only in the first data
        row's ``Ts`` cell.
    record :
        ``"estimation"`` (``uEst``, ``yEst``) or ``"validation"`` (``uVal``, ``yVal``).

    Returns
    -------
    Dataset
        Input ``"V"`` (pump voltage), output ``"V"`` (lower-tank level sensor),
        ``time_s = k * Ts`` from 0, ``ts_s`` from the file (4 s); 1024 samples each for
        the published file. The output clips at 10 V (overflow) in some samples; they
        are kept as logged.

    Raises
    ------
    DataFileError
        Unknown `record`; a header other than `TANKS_HEADER`; a row whose cell count
        differs from the header's; a blank line inside the data; a non-numeric or
        non-finite value; ``Ts`` missing, not > 0 in the first row, or present with
        another value later; fewer than 3 samples. Lines and columns are named.
    OSError
        The file cannot be opened.
    """
    path = Path(path)
    if record not in ("estimation", "validation"):
        raise DataFileError(f"record must be 'estimation' or 'validation'; got {record!r}",
                            path=path)
    u_name, y_name = ("uEst", "yEst") if record == "estimation" else ("uVal", "yVal")
    text, digest = _read_text(path)
    rows = list(csv.reader(io.StringIO("\n".join(_without_trailing_blank(text.splitlines())))))
    header = tuple(cell.strip() for cell in rows[0])
    if header != TANKS_HEADER:
        raise DataFileError(f"header must be {list(TANKS_HEADER)}; got {list(header)}",
                            path=path, line=1)
    col = {name: header.index(name) for name in ("Ts", u_name, y_name)}
    _check_count(len(rows) - 1, path)
    ts_s = 0.0
    u: list[float] = []
    y: list[float] = []
    for line_no, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            raise DataFileError("blank line; expected a row of numbers", path=path,
                                line=line_no)
        if len(row) != len(header):
            raise DataFileError(f"expected {len(header)} cells like the header; got {len(row)}",
                                path=path, line=line_no)
        ts_cell = row[col["Ts"]].strip()
        if line_no == 2:
            ts_s = _number(ts_cell, path=path, line=line_no, column="Ts")
            if ts_s <= 0:
                raise DataFileError(f"expected a sampling time > 0; got {ts_cell!r}",
                                    path=path, line=line_no, column="Ts")
        elif ts_cell and _number(ts_cell, path=path, line=line_no, column="Ts") != ts_s:
            raise DataFileError(f"expected Ts empty or equal to the first row's {ts_s:g}; got "
                                f"{ts_cell!r}", path=path, line=line_no, column="Ts")
        u.append(_number(row[col[u_name]], path=path, line=line_no, column=u_name))
        y.append(_number(row[col[y_name]], path=path, line=line_no, column=y_name))
    return Dataset(time_s=ts_s * np.arange(len(u), dtype=float), triac_pct=np.asarray(u),
                   power_kw=np.asarray(y), ts_s=ts_s, input_unit="V", output_unit="V",
                   source=str(path), sha256=digest)


__all__ = [
    "DAISY_COLUMNS",
    "DAISY_TS_S",
    "EXCHANGER_COLUMNS",
    "EXCHANGER_TS_S",
    "TANKS_HEADER",
    "TCLAB_SAMPLING_RTOL",
    "TCLAB_TS_S",
    "TanksRecord",
    "read_cascaded_tanks",
    "read_daisy_exchanger",
    "read_daisy_heating",
    "read_tclab",
]
