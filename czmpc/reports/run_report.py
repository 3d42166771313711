"""A run log of `czmpc run` drawn for an operator: power, input, quality, timing, model health.

`RunRecord` is a run log as arrays (read by `czmpc.runtime.runlog.read_run_record`,
which joins the parts of a rotated log and the runs of a log directory as identification
does; columns a log lacks are NaN, so older logs draw too), `plot_run` draws one figure
of five panels on the plant-time axis, and `write_run_report` writes it with a short
Markdown summary:

1. power [kW]: measured (good samples), the model's one-step prediction, setpoint;
2. TRIAC input [%]: the command and the input the plant reports applied, with the
   samples written to the plant marked;
3. status and link: the controller status (GOOD / PREDICTED / CLAMPED / HELD / SHED),
   the samples that were not good (bad, uncertain, stale, repeated, disconnected), and
   the stretches without a link shaded on every panel;
4. timing [ms]: lateness of each step's start against its deadline and the step's
   latency, with overruns (skipped periods) marked;
5. model health [-]: the stale-model test's figure (``czmpc.health``; the alarm limit is
   1) and the moment the alarm was raised.

Rows written by the safe action after a stop (no time, status ``SAFE_RAMP``) are
counted in the summary and left out of the time panels. The summary lists what happened
(`incidents`): link losses and shed periods with their start and duration, mode
changes, refused writes, aborts and configuration errors, from the log's ``connected``,
``status`` and ``event`` columns.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from czmpc.reports.figure_style import FigureError, stacked_axes
from czmpc.reports.figure_style import legend_above as _legend_above
from czmpc.reports.figure_style import save_figure as _save
from sysid._typing import FloatArray

#: Size of the five-panel figure [inch].
RUN_FIGSIZE_IN = (10.0, 11.0)
#: Modes, for the summary's counts.
MODES = ("OFF", "PREDICT", "ON")
#: Controller statuses in the order they are drawn on the status axis.
STATUSES = ("GOOD", "PREDICTED", "CLAMPED", "HELD", "SHED")


@dataclass(frozen=True, eq=False, kw_only=True)
class RunRecord:
    """A run log as arrays (one entry per loop step; safe-action rows counted apart).

    Parameters
    ----------
    source :
        The file read.
    time_s :
        Plant time of each step [s].
    power_kw, setpoint_kw, triac_pct, applied_triac_pct, predicted_kw :
        Measured power, setpoint, command, applied input [%], one-step prediction
        (NaN where the log has none) [kW or %].
    good :
        True where the sample's quality was good.
    mode :
        Controller mode per step ("OFF", "PREDICT", "ON").
    written :
        True where the command was written to the plant.
    lateness_s, latency_s :
        Step start after its deadline, and the step's duration [s wall].
    skipped :
        Periods skipped after each step (overruns).
    health :
        The model-health figure [-] (NaN where the log has none).
    candidate_predicted_kw :
        The shadow candidate model's one-step prediction [kW] (NaN where the log has none:
        no ``[controller] candidate``).
    stale_alarm :
        True from the stale alarm on.
    n_safe_rows :
        Rows of the safe action after the stop.
    status :
        Controller status per step (empty in logs without the column).
    connected :
        True where the link was up at the step (all True in logs without the column).
    event :
        The event column per step (what the loop said: link lost, refused write, ...).
    """

    source: str
    time_s: FloatArray = field(repr=False)
    power_kw: FloatArray = field(repr=False)
    setpoint_kw: FloatArray = field(repr=False)
    triac_pct: FloatArray = field(repr=False)
    applied_triac_pct: FloatArray = field(repr=False)
    predicted_kw: FloatArray = field(repr=False)
    good: np.ndarray = field(repr=False)
    mode: tuple[str, ...] = field(repr=False)
    written: np.ndarray = field(repr=False)
    lateness_s: FloatArray = field(repr=False)
    latency_s: FloatArray = field(repr=False)
    skipped: np.ndarray = field(repr=False)
    health: FloatArray = field(repr=False)
    stale_alarm: np.ndarray = field(repr=False)
    candidate_predicted_kw: FloatArray = field(repr=False)
    n_safe_rows: int = 0
    status: tuple[str, ...] = field(default=(), repr=False)
    connected: np.ndarray = field(default_factory=lambda: np.ones(0, dtype=bool), repr=False)
    event: tuple[str, ...] = field(default=(), repr=False)

    @property
    def n_steps(self) -> int:
        """Loop steps in the log."""
        return int(self.time_s.size)

    @property
    def alarm_time_s(self) -> float | None:
        """Plant time the stale alarm was first raised [s], or None."""
        hits = np.flatnonzero(self.stale_alarm)
        return float(self.time_s[hits[0]]) if hits.size else None


@dataclass(frozen=True, slots=True)
class Incident:
    """One thing that happened in a run: what, from when [plant s], for how long [s]."""

    what: str
    time_s: float
    duration_s: float | None = None
    detail: str = ""


def _stretches(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last + 1) index pairs of the runs of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def incidents(record: RunRecord) -> list[Incident]:
    """Link losses and shed periods (with durations), mode changes, refused writes, aborts
    and configuration errors, in time order."""
    t = record.time_s
    out: list[Incident] = []

    def span(a: int, b: int) -> float | None:
        return None if b >= t.size else float(t[b] - t[a])   # None: to the end of the run

    for a, b in _stretches(~record.connected):
        out.append(Incident("link lost", float(t[a]), span(a, b),
                            "never restored" if b >= t.size else "restored"))
    shed = np.array([s == "SHED" for s in record.status], dtype=bool)
    for a, b in _stretches(shed):
        out.append(Incident("shed", float(t[a]), span(a, b)))
    for i in range(1, len(record.mode)):
        if record.mode[i] != record.mode[i - 1] and record.mode[i] and record.mode[i - 1]:
            out.append(Incident("mode", float(t[i]), None,
                                f"{record.mode[i - 1]} -> {record.mode[i]}"))
    for i, text in enumerate(record.event):
        for part in (p.strip() for p in text.split(";")):
            if part.startswith(("write refused", "ABORT", "CONFIGURATION ERROR",
                                "ANOTHER WRITER")):
                out.append(Incident(part.split(":")[0], float(t[i]), None, part))
    return sorted(out, key=lambda x: x.time_s)


def plot_run(record: RunRecord, path: str | os.PathLike[str]) -> Figure:
    """Draw the five panels (module docstring) and write them to ``path`` (PNG).

    Raises
    ------
    FigureError
        A record without steps.
    """
    if record.n_steps == 0:
        raise FigureError("plot_run: expected a run with at least one step; got none")
    t = record.time_s
    fig, axes = stacked_axes(5, figsize_in=RUN_FIGSIZE_IN)
    ax_p, ax_u, ax_q, ax_t, ax_h = axes
    measured = np.where(record.good, record.power_kw, np.nan)
    ax_p.plot(t, measured, color="black", linewidth=0.9, label="measured (good samples)")
    if np.any(np.isfinite(record.predicted_kw)):
        ax_p.plot(t, record.predicted_kw, color="tab:blue", linewidth=0.8, alpha=0.8,
                  label="model one-step prediction")
    if np.any(np.isfinite(record.candidate_predicted_kw)):
        ax_p.plot(t, record.candidate_predicted_kw, color="tab:orange", linewidth=0.8,
                  linestyle=":", label="candidate model (shadow) one-step prediction")
    ax_p.plot(t, record.setpoint_kw, color="tab:red", linestyle="--", linewidth=1.0,
              drawstyle="steps-post", label="setpoint")
    ax_p.set_ylabel("power [kW]")
    ax_p.ticklabel_format(axis="y", useOffset=False)
    _legend_above(ax_p)
    ax_u.plot(t, record.triac_pct, color="tab:green", linewidth=0.9, drawstyle="steps-post",
              label="command")
    if np.any(np.isfinite(record.applied_triac_pct)):
        ax_u.plot(t, record.applied_triac_pct, color="tab:gray", linewidth=0.8,
                  drawstyle="steps-post", label="applied (plant)")
    if np.any(record.written):
        ax_u.plot(t[record.written], record.triac_pct[record.written], linestyle="none",
                  marker="|", markersize=3, color="tab:green", alpha=0.4, label="written")
    ax_u.set_ylabel("TRIAC input [%]")
    _legend_above(ax_u)
    if record.status:
        level = np.array([STATUSES.index(s) if s in STATUSES else np.nan for s in record.status])
        ax_q.plot(t, level, color="tab:purple", drawstyle="steps-post", label="status")
    bad = ~record.good
    if np.any(bad):
        ax_q.plot(t[bad], np.full(int(bad.sum()), -0.7), linestyle="none", marker="|",
                  color="tab:red", label="sample not good")
    down = _stretches(~record.connected) if record.connected.size else []
    for i, (a, b) in enumerate(down):
        end = t[b] if b < t.size else t[-1]
        for ax in axes:
            ax.axvspan(t[a], end, color="tab:red", alpha=0.12, linewidth=0,
                       label="link down" if ax is ax_q and i == 0 else None)
    ax_q.set_yticks([-0.7, *range(len(STATUSES))], ["not good", *STATUSES])
    ax_q.set_ylim(-1.2, len(STATUSES) - 0.5)
    ax_q.set_ylabel("status, quality [-]")
    _legend_above(ax_q)
    ax_t.plot(t, 1e3 * record.lateness_s, color="tab:orange", linewidth=0.8, label="lateness")
    ax_t.plot(t, 1e3 * record.latency_s, color="tab:brown", linewidth=0.8,
              label="step latency")
    over = record.skipped > 0
    if np.any(over):
        ax_t.plot(t[over], 1e3 * record.latency_s[over], linestyle="none", marker="x",
                  color="tab:red", label="overrun (periods skipped)")
    ax_t.set_ylabel("time [ms wall]")
    _legend_above(ax_t)
    if np.any(np.isfinite(record.health)):
        ax_h.plot(t, record.health, color="tab:blue", linewidth=0.9, label="model health F/F_limit")
        ax_h.axhline(1.0, color="tab:red", linestyle=":", linewidth=1.0, label="alarm limit")
    else:
        ax_h.text(0.5, 0.5, "no model-health columns in this log", transform=ax_h.transAxes,
                  ha="center", va="center")
    alarm = record.alarm_time_s
    if alarm is not None:
        for ax in axes:
            ax.axvline(alarm, color="tab:red", linewidth=1.0, alpha=0.7)
        ax_h.plot([alarm], [1.0], marker="v", color="tab:red", linestyle="none",
                  label=f"stale-model alarm at {alarm:g} s")
    ax_h.set_ylabel("model health [-]")
    ax_h.set_xlabel("plant time [s]")
    _legend_above(ax_h)
    return _save(fig, path)


def _duration_words(incident: Incident) -> str:
    if incident.duration_s is not None:
        return f"{incident.duration_s:g}"
    return "to the end" if incident.what in ("link lost", "shed") else ""


def summary_markdown(record: RunRecord, figure_name: str) -> str:
    """A short Markdown summary of the run, with the figure."""
    good = record.good
    err = (record.power_kw - record.setpoint_kw)[good]
    lat = record.latency_s[np.isfinite(record.latency_s)]
    late = record.lateness_s[np.isfinite(record.lateness_s)]
    alarm = record.alarm_time_s
    modes = {m: record.mode.count(m) for m in MODES if m in record.mode}
    lines = [
        f"# Run report: {', '.join(Path(p).name for p in record.source.split(', '))}",
        "",
        f"- steps: {record.n_steps} over {record.time_s[-1] - record.time_s[0]:g} s of plant "
        f"time; modes: " + ", ".join(f"{m} {n}" for m, n in modes.items()),
        f"- samples not good: {int((~good).sum())}; commands written: {int(record.written.sum())}",
        f"- overruns: {int((record.skipped > 0).sum())} ({int(record.skipped.sum())} periods "
        "skipped)",
    ]
    if late.size:
        lines.append(f"- lateness median {1e3 * np.median(late):.1f} ms, max "
                     f"{1e3 * late.max():.1f} ms; step latency median "
                     f"{1e3 * np.median(lat):.1f} ms, max {1e3 * lat.max():.1f} ms")
    if err.size:
        lines.append(f"- measured minus setpoint (good samples): mean {np.nanmean(err):+.3f} kW, "
                     f"mean absolute {np.nanmean(np.abs(err)):.3f} kW")
    if np.any(np.isfinite(record.health)):
        lines.append(f"- model health: largest {np.nanmax(record.health):.2f} (alarm at 1); "
                     + ("no stale-model alarm" if alarm is None
                        else f"**stale-model alarm at {alarm:g} s**"))
    both = (record.good & np.isfinite(record.predicted_kw)
            & np.isfinite(record.candidate_predicted_kw))
    if np.any(both):
        rms = [float(np.sqrt(np.mean((record.power_kw[both] - p[both]) ** 2)))
               for p in (record.predicted_kw, record.candidate_predicted_kw)]
        lines.append(f"- one-step prediction, RMS error over {int(both.sum())} samples: active "
                     f"model {rms[0]:.4g} kW, candidate model (shadow) {rms[1]:.4g} kW")
    if record.n_safe_rows:
        lines.append(f"- safe action after the stop: {record.n_safe_rows} rows")
    found = incidents(record)
    losses = [x for x in found if x.what == "link lost"]
    restored = [x for x in losses if x.detail == "restored"]
    lines.append(f"- link losses: {len(losses)}; reconnections: {len(restored)}"
                 + ("; **the link was down at the end**" if len(restored) < len(losses) else ""))
    if found:
        lines += ["", "## What happened", "", "| plant time [s] | what | for [s] | detail |",
                  "|---:|---|---:|---|"]
        lines += [f"| {x.time_s:g} | {x.what} | {_duration_words(x)} | "
                  f"{x.detail.replace('|', '/')} |" for x in found]
    lines += ["", f"![run]({figure_name})", ""]
    return "\n".join(lines)


def write_run_report(record: RunRecord, out_dir: str | os.PathLike[str]) -> list[Path]:
    """Write ``run.png`` and ``report.md`` of a run into ``out_dir``; return their paths."""
    from sysid.atomic import atomic_write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figure = out / "run.png"
    plot_run(record, figure)
    report = out / "report.md"
    atomic_write_text(report, summary_markdown(record, figure.name))
    return [figure, report]


__all__ = ["STATUSES", "Incident", "RunRecord", "incidents", "plot_run", "summary_markdown",
           "write_run_report"]
