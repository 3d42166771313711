"""Everything ``czmpc tune-pid`` writes: the tables, the vendor forms, ``report.md`` and its figures.

`write_outputs` writes ``pid_table.csv`` and ``characterizer.csv`` (`czmpc.pid.table`),
``sampled_integral.csv`` where a row is integral-dominant, one ``vendor_<form>.csv`` per
asked vendor form (`czmpc.pid.vendor`) and the report: the schedule, the sampling time
and discretization the numbers hold for, the margins in each sampled form, step and load
responses per row. Figures are drawn with matplotlib's object API on the Agg canvas (no
display needed), every axis with its unit. The responses are of the law as sampled in
each form of the table's discretization (`simulate_row`; ``forward`` is
`czmpc.pid.controller.ScheduledPID`, one row fixed) on the row's local sampled plant, in
deviation from the breakpoint: a setpoint step of `SETPOINT_STEP_KW` and a load step of
`LOAD_STEP_PCT` added to the TRIAC input.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from czmpc.pid.controller import ScheduledPID, TableSchedule
from czmpc.pid.design import MIN_TI_SAMPLES
from czmpc.pid.discretization import (
    FORM_DESCRIPTIONS,
    INTEGRAL_FORMS,
    Discretization,
    IntegralForm,
    describe,
    forms_of,
)
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.plant import LocalPlant
from czmpc.pid.rules import PIDTuning
from czmpc.pid.schedule import PIDSchedule, Region, merge_regions
from czmpc.pid.table import (
    COLUMN_MEANINGS,
    COLUMNS,
    integral_dominant_note,
    row_values,
    write_characterizer,
    write_pid_table,
    write_sampled_integral,
)
from czmpc.pid.table import characterizer_error_pct as interpolation_error_pct
from czmpc.pid.vendor import Spans, VendorTable, vendor_csv_text, vendor_table
from sysid._typing import FloatArray
from sysid.atomic import atomic_write_text
from sysid.model import HammersteinModel

PID_TABLE_FILE = "pid_table.csv"
CHARACTERIZER_FILE = "characterizer.csv"
SAMPLED_INTEGRAL_FILE = "sampled_integral.csv"
#: Regions of the merged schedule (DeltaV's gain-scheduling template has three).
N_REGIONS = 3

#: Setpoint step of the response figures [kW].
SETPOINT_STEP_KW = 1.0
#: Load step at the TRIAC input of the response figures [%].
LOAD_STEP_PCT = 1.0
#: Length of the response figures [samples].
RESPONSE_SAMPLES = 40
FIGURE_FILES = ("schedule.png", "margins.png", "responses.png")


def simulate_row(tuning: PIDTuning, plant: LocalPlant, *, setpoint_kw: float, load_pct: float,
                 n_samples: int = RESPONSE_SAMPLES,
                 form: IntegralForm = "forward") -> tuple[FloatArray, FloatArray]:
    """Power [kW] and TRIAC input [%] deviations of the loop after a step at sample 0.

    ``y_k = g (sum_i b_i (u + d)_{k-i} - sum_{i>0} a_i y_{k-i})`` with the controller's
    law in ``form`` (`czmpc.pid.discretization`) run step by step, unbounded (no limits):
    ``forward`` is `czmpc.pid.controller.ScheduledPID` itself, the others its velocity law
    with their integral and derivative filter.
    """
    a, b, g, ts = plant.a, plant.b, plant.gain_kw_per_pct, plant.ts_s
    law = _law(tuning, ts, form)
    y, u = np.zeros(n_samples), np.zeros(n_samples)
    for k in range(n_samples):
        acc = sum(g * b[i] * (u[k - i] + load_pct) for i in range(1, len(b)) if k - i >= 0)
        acc -= sum(a[i] * y[k - i] for i in range(1, len(a)) if k - i >= 0)
        y[k] = acc
        u[k] = law(float(y[k]), setpoint_kw)
    return y, u


def _law(tuning: PIDTuning, ts_s: float, form: IntegralForm) -> Callable[[float, float], float]:
    """``step(power_kw, setpoint_kw) -> triac_pct`` of one row in ``form``, from rest at 0."""
    if form == "forward":
        pid = ScheduledPID(schedule=TableSchedule(breakpoints_pct=(0.0,), tunings=(tuning,)),
                           ts_s=ts_s, initial_triac_pct=0.0, triac_limits_pct=(-1e9, 1e9))
        return lambda y, r: pid.step(power_kw=y, setpoint_kw=r)
    kc, r_i, td, tf = tuning.kc_pct_per_kw, ts_s / tuning.ti_s, tuning.td_s, tuning.td_filter_s
    state = {"u": 0.0, "p": 0.0, "d": 0.0, "e": 0.0, "y": math.nan}

    def step(y: float, r: float) -> float:
        e, p, d = r - y, tuning.setpoint_weight * r - y, 0.0
        if td > 0 and math.isfinite(state["y"]):
            dy = y - state["y"]
            d = ((2 * tf - ts_s) * state["d"] - 2 * td * dy) / (2 * tf + ts_s) \
                if form == "tustin" else (tf * state["d"] - td * dy) / (tf + ts_s)
        integral = r_i * (e if form == "backward" else (e + state["e"]) / 2.0)
        state["u"] += kc * (p - state["p"] + d - state["d"] + integral)
        state.update(p=p, d=d, e=e, y=y)
        return state["u"]
    return step


def _save(fig: Figure, axes: Sequence[Axes], path: Path) -> None:
    """Grid every panel, lay the figure out tightly and write it to ``path`` (PNG)."""
    for ax in axes:
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=110)


def _schedule_figure(schedule: PIDSchedule, path: Path) -> None:
    lo, hi = schedule.triac_range_pct
    s = np.array(schedule.breakpoints_pct + (hi,))
    def steps(values: Sequence[float]) -> FloatArray:
        return np.append(np.asarray(values, dtype=float), values[-1])
    fig = Figure(figsize=(7.0, 7.0))
    axes = fig.subplots(3, 1, sharex=True)
    rows = schedule.rows
    axes[0].plot(s[:-1], [r.plant.gain_kw_per_pct for r in rows], "o-")
    axes[0].set_ylabel("f'(s) [kW/%]")
    axes[0].set_title(f"gain schedule ({schedule.spec.describe()}, Ts = {schedule.ts_s:g} s)")
    axes[1].step(s, steps([r.tuning.kc_pct_per_kw for r in rows]), where="post")
    axes[1].set_ylabel("Kc [%/kW]")
    axes[2].step(s, steps([r.tuning.ti_s for r in rows]), where="post", label="Ti")
    if any(r.tuning.td_s > 0 for r in rows):
        axes[2].step(s, steps([r.tuning.td_s for r in rows]), where="post", label="Td")
        axes[2].legend()
    axes[2].set_ylabel("Ti, Td [s]")
    axes[2].set_xlabel("TRIAC input s [%]")
    for ax in axes:
        for x in s[:-1]:
            ax.axvline(x, color="0.8", lw=0.6)
    _save(fig, axes, path)


def _margins_figure(schedule: PIDSchedule, path: Path, ms_bound: float | None,
                    discretization: Discretization) -> None:
    s = schedule.breakpoints_pct
    rows = schedule.rows
    forms = forms_of(discretization)
    fig = Figure(figsize=(7.0, 7.0))
    axes = fig.subplots(3, 1, sharex=True)
    for form in forms:
        line, = axes[0].plot(s, [r.margins_by_form[form].ms for r in rows], "o-",
                             label=f"Ms at the breakpoint, {form}")
        axes[0].plot(s, [r.worst_ms_to_next_by_form[form] for r in rows], "s--",
                     color=line.get_color(), label=f"worst Ms to the next, {form}")
        axes[1].plot(s, [r.margins_by_form[form].phase_margin_deg for r in rows], "o-",
                     color=line.get_color(), label=form)
        axes[2].plot(s, [r.margins_by_form[form].gain_margin for r in rows], "o-",
                     color=line.get_color(), label=form)
    if ms_bound is not None:
        axes[0].axhline(ms_bound, color="r", lw=0.8, label=f"bound {ms_bound:g}")
    axes[0].set_ylabel("Ms [-]")
    axes[0].legend(fontsize=7)
    axes[0].set_title(f"robustness of the sampled loop (Ts = {schedule.ts_s:g} s, hold and "
                      "delay included)", fontsize=10)
    axes[1].set_ylabel("phase margin [deg]")
    axes[1].legend(fontsize=7)
    axes[2].set_ylabel("gain margin [-]")
    axes[2].set_xlabel("TRIAC input s [%]")
    _save(fig, axes, path)


def _responses_figure(schedule: PIDSchedule, path: Path, discretization: Discretization) -> None:
    fig = Figure(figsize=(9.0, 6.5))
    axes = fig.subplots(2, 2, sharex=True)
    t = np.arange(RESPONSE_SAMPLES) * schedule.ts_s
    styles = dict(zip(INTEGRAL_FORMS, ("-", "--", ":"), strict=True))
    forms = forms_of(discretization)
    for j, r in enumerate(schedule.rows):
        color = f"C{j % 10}"
        for form in forms:
            label = f"row at {r.triac_pct:g} %" if form == forms[0] else None
            kw = {"where": "post", "color": color, "ls": styles[form]}
            y, u = simulate_row(r.tuning, r.plant, setpoint_kw=SETPOINT_STEP_KW, load_pct=0.0,
                                form=form)
            axes[0, 0].step(t, y, label=label, **kw)
            axes[1, 0].step(t, u, **kw)
            y, u = simulate_row(r.tuning, r.plant, setpoint_kw=0.0, load_pct=LOAD_STEP_PCT,
                                form=form)
            axes[0, 1].step(t, y, **kw)
            axes[1, 1].step(t, u, **kw)
    axes[0, 0].set_title(f"setpoint step {SETPOINT_STEP_KW:g} kW")
    axes[0, 1].set_title(f"load step {LOAD_STEP_PCT:g} % at the TRIAC input")
    axes[0, 0].set_ylabel("power deviation [kW]")
    axes[1, 0].set_ylabel("TRIAC deviation [%]")
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    if len(forms) > 1:
        for form in forms:
            axes[0, 1].plot([], [], color="0.3", ls=styles[form], label=f"{form} integral")
        axes[0, 1].legend(fontsize=7)
    axes[0, 0].legend(fontsize=7)
    _save(fig, list(axes.flat), path)


def write_report(
    schedule: PIDSchedule, directory: str | os.PathLike[str], *, command: str, model_source: str,
    files: Sequence[str], characterizer_error_pct: float, regions: tuple[Region, ...],
    vendor_tables: Sequence[VendorTable] = (), discretization: Discretization | None = None,
) -> tuple[Path, ...]:
    """Write ``report.md`` and `FIGURE_FILES` into ``directory``; return their paths.

    Parameters
    ----------
    schedule :
        The tuned schedule.
    directory :
        Output directory (exists).
    command :
        The command line that made it (for the record).
    model_source :
        The model file.
    files :
        The other files written (named in the report).
    characterizer_error_pct :
        Largest TRIAC error of the characterizer's interpolation [%].
    regions :
        The three-region merge (`czmpc.pid.schedule.merge_regions`).
    vendor_tables :
        The vendor forms written, whose notes the report repeats.
    discretization :
        The discretization ``pid_table.csv`` states (its margins); None: the schedule's.
    """
    out = Path(directory)
    bound = schedule.spec.ms_bound
    disc = schedule.spec.discretization if discretization is None else discretization
    _schedule_figure(schedule, out / FIGURE_FILES[0])
    _margins_figure(schedule, out / FIGURE_FILES[1], bound, disc)
    _responses_figure(schedule, out / FIGURE_FILES[2], disc)
    lo, hi = schedule.triac_range_pct
    lines = [
        "# PID gain schedule", "",
        f"- model: `{model_source}`, sampling time {schedule.ts_s:g} s (the tuning is for "
        "this sampling time and the loop's one-sample delay: the block must run every "
        f"{schedule.ts_s:g} s)",
        f"- rule: {schedule.spec.describe()}",
        f"- discretization of `pid_table.csv`: {describe(disc)}",
        *[f"  - {form}: {FORM_DESCRIPTIONS[form]}" for form in forms_of(disc)],
        f"- TRIAC range covered: {lo:g} .. {hi:g} %",
        f"- command: `{command}`",
        f"- files: {', '.join(f'`{f}`' for f in files)}", "",
        "Gains are in the ideal ISA form `u = Kc (e + (1/Ti) integral e dt + Td de/dt)` in "
        "engineering units (Kc in % TRIAC per kW, times in seconds). Row i holds from its "
        "`triac_pct` up to the next row's, chosen by the TRIAC input last applied. A block "
        "runs these numbers through its own difference equation; the margins below are of "
        "the sampled loop in each form of the discretization above, and the table's are the "
        "worst of them.", "",
        "## Rows", "",
        "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in schedule.rows:
        values = row_values(r, disc)
        lines.append("| " + " | ".join(f"{values[c]:.4g}" for c in COLUMNS) + " |")
    lines += ["", "Columns:", ""] + [f"- `{c}`: {COLUMN_MEANINGS[c]}" for c in COLUMNS] + [""]
    lines += _form_lines(schedule)
    lines += _integral_dominant_lines(schedule)
    lines += ["## Does the schedule hold?", ""]
    if schedule.added_breakpoints_pct:
        lines.append("Breakpoints added where the schedule did not hold: "
                     + ", ".join(f"{p:g} %" for p in schedule.added_breakpoints_pct) + ".")
    worst = max(r.margins_for(disc)[1] for r in schedule.rows)
    lines.append(f"Largest Ms between breakpoints ({', '.join(forms_of(disc))}): {worst:.3f}"
                 + (f" (bound {bound:g})." if bound is not None else "."))
    lines += [f"- WARNING: {w}" for w in schedule.warnings] or ["No warnings."]
    lines += ["", "## Fewer regions (for blocks with a fixed number of regions)", ""]
    for j, reg in enumerate(regions, start=1):
        t = reg.row.tuning
        lines.append(f"- region {j}: {reg.lo_pct:g} .. {reg.hi_pct:g} %: Kc "
                     f"{t.kc_pct_per_kw:.4g} %/kW, Ti {t.ti_s:.4g} s, Td {t.td_s:.4g} s (row at "
                     f"{reg.row.triac_pct:g} %); worst Ms in the region "
                     f"({', '.join(schedule.spec.forms)}) {reg.worst_ms:.3f}")
    lines += ["", "## Characterizer instead of a schedule", "",
              "`characterizer.csv` maps the output x [%] of one fixed PI to the TRIAC input "
              "y [%] so that the PI sees the plant at the operating point everywhere; use the "
              "tuning of the row at the operating point with it. Linear interpolation between "
              f"its points misses f^-1 by at most {characterizer_error_pct:.3g} % TRIAC.", ""]
    for vt in vendor_tables:
        lines += [f"## {vt.block} (`vendor_{vt.form}.csv`)", ""] + [f"- {n}" for n in vt.notes]
        lines.append("")
    lines += ["## Figures", "",
              "![schedule](schedule.png)", "", "![margins](margins.png)", "",
              "![responses](responses.png)", ""]
    atomic_write_text(out / "report.md", "\n".join(lines))
    return (out / "report.md",) + tuple(out / f for f in FIGURE_FILES)


def _form_lines(schedule: PIDSchedule) -> list[str]:
    """The margins of every row in each of the three forms, whatever the table states."""
    head = ["triac_pct"] + [f"Ms {f}" for f in INTEGRAL_FORMS] + [
        f"worst Ms to next, {f}" for f in INTEGRAL_FORMS] + [
        f"phase margin {f} [deg]" for f in INTEGRAL_FORMS]
    lines = ["## Margins in each sampled form", "",
             "The same numbers as three sampled laws (forward, backward and trapezoidal "
             f"integration; the design covers {', '.join(schedule.spec.forms)}):", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in schedule.rows:
        cells = ([r.triac_pct] + [r.margins_by_form[f].ms for f in INTEGRAL_FORMS]
                 + [r.worst_ms_to_next_by_form[f] for f in INTEGRAL_FORMS]
                 + [r.margins_by_form[f].phase_margin_deg for f in INTEGRAL_FORMS])
        lines.append("| " + " | ".join(f"{v:.4g}" for v in cells) + " |")
    return [*lines, ""]


def _integral_dominant_lines(schedule: PIDSchedule) -> list[str]:
    """The integral-dominant rows and the integral-only law of every row, if any."""
    note = integral_dominant_note(schedule)
    if note is None:
        return []
    ts = schedule.ts_s
    lines = ["## Integral-dominant loop", "",
             note[0].upper() + note[1:] + ".", "",
             f"Below Ti = {MIN_TI_SAMPLES * ts:g} s the forms are different controllers: "
             "forward Euler's proportional action at the Nyquist frequency, "
             "Kc (1 - Ts/(2 Ti)), vanishes at Ti = Ts/2 while backward Euler's, "
             "Kc (1 + Ts/(2 Ti)), grows, so no one set of ISA numbers means one loop.", "",
             f"The integral-only law `u_k = u_{{k-1}} + Ki Ts e_k` (`{SAMPLED_INTEGRAL_FILE}`) is "
             "one difference equation whatever the block: an I-only block that integrates "
             "the current error runs it, and so does an ISA PI with a forward Euler integral "
             f"(Kc = Ki Ts, Ti = {ts:g} s) or a trapezoidal one (Kc = Ki Ts/2, Ti = "
             f"{ts / 2:g} s); backward Euler cannot hold it (Kc = 0).", "",
             "| triac_pct | Ki [%/(kW s)] | Ki Ts [%/kW] | Ms | worst Ms to next | phase margin [deg] |",
             "|---|---|---|---|---|---|"]
    for r in schedule.rows:
        law = r.sampled_integral
        if law is None:
            continue
        lines.append(f"| {r.triac_pct:.4g} | {law.law.ki_pct_per_kw_s:.4g} | "
                     f"{law.law.move_gain_pct_per_kw:.4g} | {law.margins.ms:.4g} | "
                     f"{law.worst_ms_to_next:.4g} | {law.margins.phase_margin_deg:.4g} |")
    return [*lines, ""]


def write_outputs(
    schedule: PIDSchedule, model: HammersteinModel, directory: str | os.PathLike[str], *,
    forms: Sequence[str] = (), spans: Spans | None = None, command: str = "",
    model_source: str = "", discretization: Discretization | None = None,
) -> tuple[Path, ...]:
    """Write the tables, vendor forms and report of ``schedule`` into ``directory``.

    Parameters
    ----------
    schedule :
        The tuned schedule.
    model :
        The model it was tuned on.
    directory :
        Output directory (created).
    forms :
        Vendor forms to write (`czmpc.pid.vendor.FORMS`).
    spans :
        The block's PV and output ranges; required when ``forms`` is not empty.
    command, model_source :
        Recorded in the report.
    discretization :
        The discretization ``pid_table.csv`` states and its margins are of (one the
        schedule's design covers); None: the schedule's own.

    Raises
    ------
    PIDTuningError
        A vendor form without spans or one the schedule's design does not cover, or a
        discretization it does not cover (checked before anything is written).
    """
    disc = schedule.spec.discretization if discretization is None else discretization
    if not set(forms_of(disc)) <= set(schedule.spec.forms):
        raise PIDTuningError(
            f"pid_table.csv: expected a discretization the schedule was designed for "
            f"({schedule.spec.discretization}); got {disc!r}")
    regions = merge_regions(schedule, model, N_REGIONS)
    tables = [vendor_table(schedule, form, spans, regions) for form in forms]
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    written = [write_pid_table(schedule, out / PID_TABLE_FILE, disc),
               write_characterizer(model, schedule.triac_range_pct, out / CHARACTERIZER_FILE)]
    sampled = write_sampled_integral(schedule, out / SAMPLED_INTEGRAL_FILE)
    if sampled is not None:
        written.append(sampled)
    for vt in tables:
        path = out / f"vendor_{vt.form}.csv"
        atomic_write_text(path, vendor_csv_text(vt))
        written.append(path)
    written += write_report(
        schedule, out, command=command, model_source=model_source,
        files=[p.name for p in written],
        characterizer_error_pct=interpolation_error_pct(model, schedule.triac_range_pct),
        regions=regions, vendor_tables=tables, discretization=disc)
    return tuple(written)


__all__ = ["CHARACTERIZER_FILE", "FIGURE_FILES", "LOAD_STEP_PCT", "N_REGIONS", "PID_TABLE_FILE",
           "RESPONSE_SAMPLES", "SAMPLED_INTEGRAL_FILE", "SETPOINT_STEP_KW", "simulate_row",
           "write_outputs", "write_report"]
