"""``pid_table.csv`` and ``characterizer.csv``: the schedule and the input linearisation as files.

``pid_table.csv`` has one row per breakpoint and exactly the columns `COLUMNS`, each
name with its unit (`COLUMN_MEANINGS`). The gains are those of the ideal ISA form
``u = Kc (e + (1/Ti) integral e dt + Td de/dt)`` in engineering units, tuned for the
model's sampling time. Numbers are written with Python's shortest round-trip repr, so
reading gives the same floats.

``characterizer.csv`` is for DCS blocks that linearise the input instead of scheduling:
an X-Y table from the output ``x`` of one fixed PI [%] to the TRIAC input ``y`` [%], with
``x = s_nom + f(s - s_nom)/f'(0)``, so the PI sees the nominal plant ``f'(0) B/A`` at
every input (``f^-1`` scaled to TRIAC percent).
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from czmpc.inversion import evaluate, slope
from czmpc.pid.controller import TableSchedule
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.rules import PIDTuning
from czmpc.pid.schedule import PIDSchedule, ScheduleRow
from sysid.atomic import atomic_write_text
from sysid.model import HammersteinModel

#: Columns of ``pid_table.csv``, in order.
COLUMNS: tuple[str, ...] = (
    "triac_pct", "power_kw", "gain_kw_per_pct", "tau_s", "dead_time_s", "kc_pct_per_kw",
    "ti_s", "td_s", "td_filter_s", "setpoint_weight", "ms", "gain_margin",
    "phase_margin_deg", "crossover_rad_per_s", "worst_ms_to_next",
)
#: What each column holds, with its unit (for reports and the guide).
COLUMN_MEANINGS: dict[str, str] = {
    "triac_pct": "breakpoint: TRIAC input where the row starts to hold [%]",
    "power_kw": "the model's steady power at that input [kW]",
    "gain_kw_per_pct": "gain k of the plant the rule tuned on [kW/%]",
    "tau_s": "its time constant [s] (0: a gain with dead time)",
    "dead_time_s": "its dead time, with half a sample for the hold [s]",
    "kc_pct_per_kw": "proportional gain Kc, ideal ISA form [% TRIAC per kW]",
    "ti_s": "integral time Ti [s]",
    "td_s": "derivative time Td [s] (0: a PI)",
    "td_filter_s": "time constant of the derivative's measurement filter [s]",
    "setpoint_weight": "weight b of the setpoint in the proportional term [-]",
    "ms": "peak sensitivity Ms of the sampled loop at the breakpoint [-]",
    "gain_margin": "gain margin, a factor (not dB) [-]",
    "phase_margin_deg": "phase margin [deg]",
    "crossover_rad_per_s": "gain crossover frequency [rad/s]",
    "worst_ms_to_next": "largest Ms of this row's controller up to the next breakpoint [-]",
}
#: Columns of ``characterizer.csv``.
CHARACTERIZER_COLUMNS: tuple[str, ...] = ("x_linearized_pct", "y_triac_pct")
#: Points of the characterizer table (a common size of DCS characterizer blocks).
CHARACTERIZER_POINTS = 21


def row_values(row: ScheduleRow) -> dict[str, float]:
    """The ``pid_table.csv`` values of one row, keyed by `COLUMNS`."""
    rp = row.rule_plant
    t, m = row.tuning, row.margins
    return {
        "triac_pct": row.triac_pct, "power_kw": row.plant.power_kw,
        "gain_kw_per_pct": rp.gain_kw_per_pct if rp else row.plant.static_gain_kw_per_pct,
        "tau_s": rp.tau1_s if rp else math.nan,
        "dead_time_s": rp.dead_time_s if rp else (row.plant.delay_steps + 0.5) * row.plant.ts_s,
        "kc_pct_per_kw": t.kc_pct_per_kw, "ti_s": t.ti_s, "td_s": t.td_s,
        "td_filter_s": t.td_filter_s, "setpoint_weight": t.setpoint_weight, "ms": m.ms,
        "gain_margin": m.gain_margin, "phase_margin_deg": m.phase_margin_deg,
        "crossover_rad_per_s": m.crossover_rad_per_s, "worst_ms_to_next": row.worst_ms_to_next,
    }


def _csv_text(header: tuple[str, ...], rows: list[list[float]]) -> str:
    lines = [",".join(header)]
    lines += [",".join(repr(float(v)) for v in row) for row in rows]
    return "\n".join(lines) + "\n"


def write_pid_table(schedule: PIDSchedule, path: str | os.PathLike[str]) -> Path:
    """Write ``pid_table.csv`` of ``schedule`` to ``path`` (atomically); return the path."""
    rows = [[row_values(r)[c] for c in COLUMNS] for r in schedule.rows]
    atomic_write_text(Path(path), _csv_text(COLUMNS, rows))
    return Path(path)


@dataclass(frozen=True, slots=True, kw_only=True)
class PIDTable:
    """A ``pid_table.csv`` as read: the schedule it runs and its other columns.

    Parameters
    ----------
    schedule :
        Breakpoints and tunings.
    values :
        Every column of every row, as written.
    source :
        The file it was read from.
    """

    schedule: TableSchedule
    values: tuple[dict[str, float], ...]
    source: str


def read_pid_table(path: str | os.PathLike[str]) -> PIDTable:
    """Read a ``pid_table.csv`` written by `write_pid_table` (or edited by hand).

    Parameters
    ----------
    path :
        The file.

    Raises
    ------
    PIDTuningError
        A header other than `COLUMNS`, a value that is not a number, a tuning that is not
        valid (the message names the file, line and column), or no row.
    OSError
        The file cannot be read.
    """
    name = str(path)
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = tuple(next(reader, ()))
        if header != COLUMNS:
            raise PIDTuningError(
                f"{name}, line 1: expected the pid_table.csv header {','.join(COLUMNS)}; "
                f"got {','.join(header) or '(empty file)'}")
        values = []
        for line_no, raw in enumerate(reader, start=2):
            if not raw:
                continue
            if len(raw) != len(COLUMNS):
                raise PIDTuningError(f"{name}, line {line_no}: expected {len(COLUMNS)} values; "
                                     f"got {len(raw)}")
            row = {}
            for column, text in zip(COLUMNS, raw, strict=True):
                try:
                    row[column] = float(text)
                except ValueError:
                    raise PIDTuningError(f"{name}, line {line_no}, column '{column}': expected "
                                         f"a number; got {text!r}") from None
            values.append((line_no, row))
    if not values:
        raise PIDTuningError(f"{name}: expected at least one row after the header; got none")
    tunings = []
    for line_no, row in values:
        try:
            tunings.append(PIDTuning(kc_pct_per_kw=row["kc_pct_per_kw"], ti_s=row["ti_s"],
                                     td_s=row["td_s"], td_filter_s=row["td_filter_s"],
                                     setpoint_weight=row["setpoint_weight"]))
        except PIDTuningError as exc:
            raise PIDTuningError(f"{name}, line {line_no}: {exc}") from None
    try:
        schedule = TableSchedule(breakpoints_pct=tuple(r["triac_pct"] for _, r in values),
                                 tunings=tuple(tunings))
    except PIDTuningError as exc:
        raise PIDTuningError(f"{name}, column 'triac_pct': {exc}") from None
    return PIDTable(schedule=schedule, values=tuple(r for _, r in values), source=name)


def characterizer_points(model: HammersteinModel, triac_range_pct: tuple[float, float],
                         n_points: int = CHARACTERIZER_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` of the characterizer: linearised PI output [%] and TRIAC input [%].

    ``y`` is evenly spaced over the range; ``x = s_nom + f(y - s_nom)/f'(0)`` (module notes).
    """
    coefficients = tuple(float(v) for v in model.input_poly)
    s_nom = model.operating_point.triac_pct
    y = np.linspace(triac_range_pct[0], triac_range_pct[1], n_points)
    x = np.array([s_nom + evaluate(coefficients, v - s_nom) / slope(coefficients, 0.0)
                  for v in y])
    return x, y


def characterizer_error_pct(model: HammersteinModel, triac_range_pct: tuple[float, float],
                            n_points: int = CHARACTERIZER_POINTS) -> float:
    """Largest TRIAC error [%] of the table's linear interpolation against ``f^-1``.

    Checked on 50 points per segment: the input the interpolation gives for ``x`` against
    the input whose ``f`` gives ``x`` exactly.
    """
    x, y = characterizer_points(model, triac_range_pct, n_points)
    fine_y = np.linspace(y[0], y[-1], 50 * n_points)
    fine_x, _ = characterizer_points(model, triac_range_pct, fine_y.size)
    return float(np.max(np.abs(np.interp(fine_x, x, y) - fine_y)))


def write_characterizer(model: HammersteinModel, triac_range_pct: tuple[float, float],
                        path: str | os.PathLike[str]) -> Path:
    """Write ``characterizer.csv`` (module notes) to ``path`` (atomically); return the path."""
    x, y = characterizer_points(model, triac_range_pct)
    atomic_write_text(Path(path), _csv_text(CHARACTERIZER_COLUMNS,
                                            [[a, b] for a, b in zip(x, y, strict=True)]))
    return Path(path)


__all__ = ["CHARACTERIZER_COLUMNS", "CHARACTERIZER_POINTS", "COLUMNS", "COLUMN_MEANINGS",
           "PIDTable", "characterizer_error_pct", "characterizer_points", "read_pid_table",
           "row_values", "write_characterizer", "write_pid_table"]
