"""``pid_table.csv`` and ``characterizer.csv``: the schedule and the input linearisation as files.

``pid_table.csv`` has one row per breakpoint and exactly the columns `COLUMNS`, each
name with its unit (`COLUMN_MEANINGS`). The gains are those of the ideal ISA form
``u = Kc (e + (1/Ti) integral e dt + Td de/dt)`` in engineering units, tuned for the
model's sampling time. Numbers are written with Python's shortest round-trip repr, so
reading gives the same floats.

Comment lines (``#``) before the column header say which sampled law the numbers hold
for: the sampling time and the discretization of the integral and of the derivative
filter (`czmpc.pid.discretization`), as the keys ``# ts_s: 2.0`` and
``# discretization: worst`` that `read_pid_table` reads, then in words; and which rows are
integral-dominant. The margin columns are the worst over the forms of that
discretization.

``sampled_integral.csv`` is written where a row is integral-dominant
(`czmpc.pid.schedule.PIDSchedule.integral_dominant_pct`): per row the integral-only law
``u_k = u_{k-1} + Ki Ts e_k`` (`czmpc.pid.design.SampledIntegral`), `SAMPLED_INTEGRAL_COLUMNS`.

``characterizer.csv`` is for DCS blocks that linearise the input instead of scheduling:
an X-Y table from the output ``x`` of one fixed PI [%] to the TRIAC input ``y`` [%], with
``x = s_nom + f(s - s_nom)/f'(0)``, so the PI sees the nominal plant ``f'(0) B/A`` at
every input (``f^-1`` scaled to TRIAC percent).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from czmpc.inversion import evaluate, slope
from czmpc.pid.controller import TableSchedule
from czmpc.pid.design import MIN_TI_SAMPLES
from czmpc.pid.discretization import (
    FORM_DESCRIPTIONS,
    Discretization,
    checked_discretization,
    describe,
    forms_of,
)
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
    "ms": "peak sensitivity Ms of the sampled loop at the breakpoint, in the discretization "
          "of the header (worst: the largest of its three forms) [-]",
    "gain_margin": "gain margin, a factor (not dB), the smallest of the forms [-]",
    "phase_margin_deg": "phase margin, the smallest of the forms [deg]",
    "crossover_rad_per_s": "gain crossover frequency of that phase margin [rad/s]",
    "worst_ms_to_next": "largest Ms of this row's controller up to the next breakpoint, over "
                        "the same forms [-]",
}
#: Keys of the header comments that `read_pid_table` reads (``# key: value``).
HEADER_KEYS: tuple[str, ...] = ("ts_s", "discretization")
#: Columns of ``sampled_integral.csv``, in order.
SAMPLED_INTEGRAL_COLUMNS: tuple[str, ...] = (
    "triac_pct", "ki_pct_per_kw_s", "move_gain_pct_per_kw", "ms", "gain_margin",
    "phase_margin_deg", "crossover_rad_per_s", "worst_ms_to_next",
)
#: Columns of ``characterizer.csv``.
CHARACTERIZER_COLUMNS: tuple[str, ...] = ("x_linearized_pct", "y_triac_pct")
#: Points of the characterizer table (a common size of DCS characterizer blocks).
CHARACTERIZER_POINTS = 21


def row_values(row: ScheduleRow, discretization: Discretization | None = None) -> dict[str, float]:
    """The ``pid_table.csv`` values of one row, keyed by `COLUMNS`.

    The margins are those of ``discretization`` (`ScheduleRow.margins_for`); None: the
    row's own (its schedule's discretization).
    """
    rp = row.rule_plant
    t = row.tuning
    m, worst = ((row.margins, row.worst_ms_to_next) if discretization is None
                else row.margins_for(discretization))
    return {
        "triac_pct": row.triac_pct, "power_kw": row.plant.power_kw,
        "gain_kw_per_pct": rp.gain_kw_per_pct if rp else row.plant.static_gain_kw_per_pct,
        "tau_s": rp.tau1_s if rp else math.nan,
        "dead_time_s": rp.dead_time_s if rp else (row.plant.delay_steps + 0.5) * row.plant.ts_s,
        "kc_pct_per_kw": t.kc_pct_per_kw, "ti_s": t.ti_s, "td_s": t.td_s,
        "td_filter_s": t.td_filter_s, "setpoint_weight": t.setpoint_weight, "ms": m.ms,
        "gain_margin": m.gain_margin, "phase_margin_deg": m.phase_margin_deg,
        "crossover_rad_per_s": m.crossover_rad_per_s, "worst_ms_to_next": worst,
    }


def _csv_text(header: tuple[str, ...], rows: list[list[float]],
              comments: Sequence[str] = ()) -> str:
    lines = [f"# {c}" for c in comments] + [",".join(header)]
    lines += [",".join(repr(float(v)) for v in row) for row in rows]
    return "\n".join(lines) + "\n"


def integral_dominant_note(schedule: PIDSchedule) -> str | None:
    """Words for the rows whose rule asked for ``Ti`` below the floor; None when none did."""
    rows = [r for r in schedule.rows if r.integral_dominant]
    if not rows:
        return None
    where = ("every row" if len(rows) == len(schedule.rows) else
             "the rows at " + ", ".join(f"{r.triac_pct:g}" for r in rows) + " %")
    asked = sorted({round(r.rule_ti_s, 3) for r in rows})
    floor = MIN_TI_SAMPLES * schedule.ts_s
    return (f"integral-dominant: at {where} the rule asked for Ti = "
            f"{', '.join(f'{v:g}' for v in asked)} s, below the sampling time "
            f"{schedule.ts_s:g} s, where the discretizations are different controllers: the "
            "loop wants integral action only. Ti is raised to "
            f"{floor:g} s and Kc chosen for the bound in every form of the table; the "
            "integral-only law u_k = u_{k-1} + Ki Ts e_k of each row, which any block that "
            "integrates the current error runs as tuned, is in sampled_integral.csv")


def table_comments(schedule: PIDSchedule, discretization: Discretization | None = None
                   ) -> tuple[str, ...]:
    """The header comments of ``pid_table.csv`` (module notes), without the ``#``."""
    disc = schedule.spec.discretization if discretization is None else discretization
    bound = schedule.spec.ms_bound
    lines = [
        "czmpc pid_table: gain schedule, ideal ISA PID u = Kc (b r - y + (1/Ti) integral e dt "
        "- Td dy_f/dt), Kc in % TRIAC per kW, times in s; row i holds from its triac_pct up "
        "to the next row's",
        f"ts_s: {schedule.ts_s!r}",
        f"discretization: {disc}",
        f"sampling time {schedule.ts_s:g} s: the block must run the law every "
        f"{schedule.ts_s:g} s; the numbers hold for no other",
        f"integral and derivative filter: {describe(disc)}"
        + (f"; Ms <= {bound:g} holds in every form at and between the breakpoints"
           if bound is not None else ""),
    ]
    lines += [f"  {form}: {FORM_DESCRIPTIONS[form]}" for form in forms_of(disc)]
    if disc != schedule.spec.discretization:
        lines.append(f"designed for {schedule.spec.discretization} "
                     f"({', '.join(schedule.spec.forms)}), which covers it")
    note = integral_dominant_note(schedule)
    if note is not None:
        lines.append(note)
    return tuple(lines)


def write_pid_table(schedule: PIDSchedule, path: str | os.PathLike[str],
                    discretization: Discretization | None = None) -> Path:
    """Write ``pid_table.csv`` of ``schedule`` to ``path`` (atomically); return the path.

    Parameters
    ----------
    schedule :
        The tuned schedule.
    path :
        The file.
    discretization :
        The discretization the table states and its margins are of; None: the
        schedule's own. It must be one the design covers (its forms among the design's).

    Raises
    ------
    PIDTuningError
        A discretization the schedule was not designed for.
    """
    disc = schedule.spec.discretization if discretization is None else discretization
    if not set(forms_of(disc)) <= set(schedule.spec.forms):
        raise PIDTuningError(
            f"pid_table.csv: expected a discretization the schedule was designed for "
            f"({schedule.spec.discretization}: {', '.join(schedule.spec.forms)}); got {disc!r}")
    rows = [[row_values(r, disc)[c] for c in COLUMNS] for r in schedule.rows]
    atomic_write_text(Path(path), _csv_text(COLUMNS, rows, table_comments(schedule, disc)))
    return Path(path)


def write_sampled_integral(schedule: PIDSchedule, path: str | os.PathLike[str]) -> Path | None:
    """Write ``sampled_integral.csv`` (module notes) to ``path``; None (nothing written) without laws."""
    laws = [r.sampled_integral for r in schedule.rows]
    if any(law is None for law in laws):
        return None
    rows = [[r.triac_pct, law.law.ki_pct_per_kw_s, law.law.move_gain_pct_per_kw, law.margins.ms,
             law.margins.gain_margin, law.margins.phase_margin_deg,
             law.margins.crossover_rad_per_s, law.worst_ms_to_next]
            for r, law in zip(schedule.rows, laws, strict=True) if law is not None]
    ts = schedule.ts_s
    comments = (
        "czmpc sampled_integral: integral-only control on the current error, "
        "u_k = u_{k-1} + Ki Ts e_k = u_{k-1} + move_gain e_k, Ki in % TRIAC per kW and "
        "second; row i holds from its triac_pct up to the next row's",
        f"ts_s: {ts!r}",
        f"sampling time {ts:g} s: the law runs every {ts:g} s",
        "one difference equation, whatever the block's discretization: its margins are exact",
        f"as an ISA PI: forward Euler integral, Kc = move_gain, Ti = {ts:g} s; trapezoidal "
        f"integral, Kc = move_gain/2, Ti = {ts / 2:g} s; backward Euler cannot hold it "
        "(it needs Kc = 0): use the block's I-only action on the current error",
    )
    atomic_write_text(Path(path), _csv_text(SAMPLED_INTEGRAL_COLUMNS, rows, comments))
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
    ts_s :
        The sampling time its header comments state [s]; None when they state none.
    discretization :
        The discretization its header comments state; None when they state none.
    """

    schedule: TableSchedule
    values: tuple[dict[str, float], ...]
    source: str
    ts_s: float | None = None
    discretization: Discretization | None = None


def read_pid_table(path: str | os.PathLike[str]) -> PIDTable:
    """Read a ``pid_table.csv`` written by `write_pid_table` (or edited by hand).

    Comment lines (``#``) before the column header are skipped; those of `HEADER_KEYS`
    are read into `PIDTable.ts_s` and `PIDTable.discretization`.

    Parameters
    ----------
    path :
        The file.

    Raises
    ------
    PIDTuningError
        A header other than `COLUMNS`, a value that is not a number, a tuning that is not
        valid (the message names the file, line and column), no row, or a stated
        sampling time or discretization that is not one.
    OSError
        The file cannot be read.
    """
    name = str(path)
    with open(path, newline="", encoding="utf-8") as fh:
        lines = fh.read().splitlines()
    n_comments = 0
    stated: dict[str, str] = {}
    while n_comments < len(lines) and lines[n_comments].startswith("#"):
        key, sep, value = lines[n_comments][1:].strip().partition(":")
        if sep and key in HEADER_KEYS:
            stated[key] = value.strip()
        n_comments += 1
    ts_s, discretization = _stated(stated, name)
    reader = csv.reader(lines[n_comments:])
    header = tuple(next(reader, ()))
    if header != COLUMNS:
        raise PIDTuningError(
            f"{name}, line {n_comments + 1}: expected the pid_table.csv header "
            f"{','.join(COLUMNS)}; got {','.join(header) or '(empty file)'}")
    values = []
    for line_no, raw in enumerate(reader, start=n_comments + 2):
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
    return PIDTable(schedule=schedule, values=tuple(r for _, r in values), source=name,
                    ts_s=ts_s, discretization=discretization)


def _stated(stated: dict[str, str], name: str) -> tuple[float | None, Discretization | None]:
    """``(ts_s, discretization)`` of the header comments, checked."""
    ts_s = discretization = None
    if "ts_s" in stated:
        try:
            ts_s = float(stated["ts_s"])
        except ValueError:
            ts_s = math.nan
        if not (math.isfinite(ts_s) and ts_s > 0):
            raise PIDTuningError(f"{name}, header comment 'ts_s': expected a time > 0 [s]; "
                                 f"got {stated['ts_s']!r}")
    if "discretization" in stated:
        try:
            discretization = checked_discretization(stated["discretization"])
        except PIDTuningError as exc:
            raise PIDTuningError(f"{name}, header comment 'discretization': {exc}") from None
    return ts_s, discretization


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
           "HEADER_KEYS", "SAMPLED_INTEGRAL_COLUMNS", "PIDTable", "characterizer_error_pct",
           "characterizer_points", "integral_dominant_note", "read_pid_table", "row_values",
           "table_comments", "write_characterizer", "write_pid_table", "write_sampled_integral"]
