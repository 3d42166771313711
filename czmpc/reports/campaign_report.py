"""Summary of a campaign's rows: Markdown text and figures (rows come in as arguments).

Rows are the dictionaries of `czmpc.campaigns.campaign.ROW_COLUMNS`; this module only
reads the keys it names, so it does not import the campaign room.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from itertools import product
from typing import TYPE_CHECKING, Any

import numpy as np

from czmpc.reports.tables import format_table

if TYPE_CHECKING:
    from matplotlib.figure import Figure

Row = Mapping[str, Any]


def _controllers(rows: Sequence[Row]) -> list[str]:
    return list(dict.fromkeys(str(r["controller"]) for r in rows))


def controller_summary(rows: Sequence[Row]) -> list[dict[str, Any]]:
    """Per controller: run and error counts, IAE median / p95 / max [kW s], violations.

    ``within_limits`` is the share of its finished runs with no limit or rate
    violation; ``offset_free`` the share whose largest |steady error| is below
    ``sse_threshold_kw`` (0.05 kW, as the robustness campaign).
    """
    out = []
    for name in _controllers(rows):
        mine = [r for r in rows if r["controller"] == name]
        ok = [r for r in mine if r["status"] == "ok"]
        iae = np.array([float(r["iae_kw_s"]) for r in ok])
        sse = np.array([float(r["max_abs_steady_state_error_kw"]) for r in ok])
        clean = [r for r in ok if r["n_limit_violations"] == 0 and r["n_rate_violations"] == 0]
        out.append({
            "controller": name, "n_runs": len(mine), "n_errors": len(mine) - len(ok),
            "iae_median_kw_s": float(np.median(iae)) if ok else math.nan,
            "iae_p95_kw_s": float(np.percentile(iae, 95)) if ok else math.nan,
            "iae_max_kw_s": float(iae.max()) if ok else math.nan,
            "within_limits": len(clean) / len(ok) if ok else math.nan,
            "offset_free": float(np.mean(np.nan_to_num(sse, nan=np.inf) < 0.05)) if ok else math.nan,
            "n_solver_failures": int(sum(max(0, int(r["n_solver_failures"])) for r in ok)),
        })
    return out


def format_summary_markdown(rows: Sequence[Row], *, title: str, figures: Sequence[str] = ()) -> str:
    """The campaign summary as Markdown: per-controller table, errors, worst runs, figures."""
    summary = controller_summary(rows)
    table = format_table(
        ["controller", "runs", "errors", "IAE median [kW s]", "IAE p95 [kW s]", "IAE max [kW s]",
         "within limits [%]", "offset-free [%]", "solver fallbacks"],
        [[s["controller"], str(s["n_runs"]), str(s["n_errors"]), f"{s['iae_median_kw_s']:.2f}",
          f"{s['iae_p95_kw_s']:.2f}", f"{s['iae_max_kw_s']:.2f}", f"{100 * s['within_limits']:.1f}",
          f"{100 * s['offset_free']:.1f}", str(s["n_solver_failures"])] for s in summary],
        markdown=True)
    lines = [f"# Campaign {title}", "", f"{len(rows)} runs. IAE of the true power against the "
             "setpoint; offset-free: largest |steady error| < 0.05 kW; within limits: no input "
             "limit or rate violation.", "", table, ""]
    errors = [r for r in rows if r["status"] != "ok"]
    if errors:
        lines += ["## Failed runs", ""]
        lines += [f"- `{r['run_id']}`: {r['error']}" for r in errors[:20]]
        if len(errors) > 20:
            lines.append(f"- ... and {len(errors) - 20} more")
        lines.append("")
    ok = sorted((r for r in rows if r["status"] == "ok"), key=lambda r: -float(r["iae_kw_s"]))
    if ok:
        lines += ["## Worst runs (highest IAE)", "", format_table(
            ["run", "IAE [kW s]", "overshoot [kW]", "largest steady error [kW]", "seed"],
            [[f"`{r['run_id']}`", f"{r['iae_kw_s']:.2f}", f"{r['max_overshoot_kw']:.3f}",
              f"{r['max_abs_steady_state_error_kw']:.4f}", str(r["seed"])] for r in ok[:10]],
            markdown=True), ""]
    lines += [f"![{f}]({f})" for f in figures]
    return "\n".join(lines) + "\n"


def plot_iae_distribution(rows: Sequence[Row], path: str | os.PathLike[str] | None = None) -> Figure:
    """Box plot of the IAE [kW s] of the finished runs, one box per controller."""
    from czmpc.reports.figure_style import new_figure, save_figure

    names = _controllers(rows)
    data = [[float(r["iae_kw_s"]) for r in rows if r["controller"] == n and r["status"] == "ok"]
            for n in names]
    fig = new_figure((max(4.0, 1.6 * len(names) + 2), 4.0))
    ax = fig.add_subplot()
    ax.boxplot([d if d else [math.nan] for d in data], tick_labels=names)
    ax.set_ylabel("IAE of the true power [kW s]")
    ax.set_xlabel("controller")
    ax.set_title("IAE distribution per controller")
    ax.grid(True, axis="y", alpha=0.3)
    if path is not None:
        save_figure(fig, path)
    return fig


def plot_perturbation_heatmaps(rows: Sequence[Row], path: str | os.PathLike[str] | None = None
                               ) -> Figure | None:
    """IAE ratio over gain x time-constant factor of the perturbed plants (robustness map).

    One row of panels per controller, one panel per extra delay. A cell is the median
    over scenarios and seeds of the IAE against the reachable setpoint
    (``iae_changes_reachable_kw_s``) over that of the nominal plant (gain 1, time
    constant 1, no extra delay) of the same controller, scenario and seed; each cell is
    annotated with its ratio, a red x marks a plant not tracked offset-free in some run,
    ``*`` one with setpoint changes out of its reach. None when no perturbed plant ran.
    """
    from matplotlib.colors import LogNorm

    from czmpc.reports.figure_style import new_figure, save_figure

    pert = [r for r in rows if str(r["plant"]).startswith("perturbed") and r["status"] == "ok"]
    if not pert:
        return None
    nominal = {(r["controller"], r["scenario"], r["seed"]): float(r["iae_changes_reachable_kw_s"])
               for r in pert if (r["gain_factor"], r["time_constant_factor"],
                                 r["extra_delay_steps"]) == (1.0, 1.0, 0)}
    names = [n for n in _controllers(rows) if any(r["controller"] == n for r in pert)]
    gains, taus, delays = (sorted({r[k] for r in pert}) for k in (
        "gain_factor", "time_constant_factor", "extra_delay_steps"))
    cells: dict[tuple[str, int, int, int], tuple[float, bool, bool]] = {}
    for name, (d, n), (t, m), (k, g) in product(names, enumerate(delays), enumerate(taus),
                                                enumerate(gains)):
        mine = [r for r in pert if r["controller"] == name and (
            r["gain_factor"], r["time_constant_factor"], r["extra_delay_steps"]) == (g, m, n)]
        ratios = [float(r["iae_changes_reachable_kw_s"])
                  / nominal.get((name, r["scenario"], r["seed"]), math.nan) for r in mine]
        cells[name, d, t, k] = (float(np.median(ratios)) if ratios else math.nan,
                                any(not r["offset_free"] for r in mine),
                                any(int(r["n_unreachable_changes"]) > 0 for r in mine))
    values = np.array([v for v, _, _ in cells.values()])
    finite = values[np.isfinite(values) & (values > 0)]
    norm = LogNorm(vmin=min(1.0, float(finite.min())) if finite.size else 0.5,
                   vmax=max(1.0 + 1e-9, float(finite.max())) if finite.size else 2.0)
    fig = new_figure(((0.62 * len(gains) + 1.8) * len(delays) + 1.2,
                      (0.42 * len(taus) + 1.8) * len(names)))
    axes = fig.subplots(len(names), len(delays), squeeze=False)
    image = None
    for i, name in enumerate(names):
        for d, n in enumerate(delays):
            ax = axes[i, d]
            grid = np.array([[cells[name, d, t, k][0] for k in range(len(gains))]
                             for t in range(len(taus))])
            image = ax.imshow(grid, origin="lower", cmap="viridis", norm=norm, aspect="auto")
            for t, k in product(range(len(taus)), range(len(gains))):
                value, fails, unreachable = cells[name, d, t, k]
                if fails:
                    ax.plot(k, t, marker="x", color="red", markersize=16, markeredgewidth=2.5)
                ax.text(k, t, f"{value:.2f}{'*' if unreachable else ''}", ha="center",
                        va="center", fontsize=7,
                        color="white" if np.isfinite(value) and norm(value) < 0.6 else "black")
            ax.set_xticks(range(len(gains)), [f"{g:g}" for g in gains])
            ax.set_yticks(range(len(taus)), [f"{m:g}" for m in taus])
            ax.set_xlabel("plant gain factor [-]")
            ax.set_ylabel("slow time-constant factor [-]")
            ax.set_title(f"{name}, extra delay +{n} sample{'s' if n != 1 else ''}", fontsize="medium")
    if image is not None:
        fig.colorbar(image, ax=axes.ravel().tolist(), shrink=0.9,
                     label="IAE / nominal plant's IAE [-]")
    if path is not None:
        save_figure(fig, path)
    return fig


def plot_trajectories(trajectories: Sequence[Mapping[str, Any]],
                      path: str | os.PathLike[str] | None = None) -> Figure:
    """Power and input of saved trajectories (the worst runs), one colour per run.

    Each mapping holds ``run_id``, ``time_s``, ``setpoint_kw``, ``power_true_kw``,
    ``triac_pct`` (as saved by `czmpc.campaigns.runner.save_trajectories`).
    """
    from czmpc.reports.figure_style import new_figure, save_figure

    fig = new_figure((9.0, 5.5))
    ax_p, ax_u = fig.subplots(2, 1, sharex=True)
    for tr in trajectories:
        t_min = np.asarray(tr["time_s"], dtype=float) / 60.0
        line = ax_p.plot(t_min, tr["power_true_kw"], lw=0.9, label=str(tr["run_id"]))[0]
        ax_p.plot(t_min, tr["setpoint_kw"], lw=0.7, ls="--", color=line.get_color())
        ax_u.plot(t_min, tr["triac_pct"], lw=0.9, color=line.get_color())
    ax_p.set_ylabel("true power [kW] (dashed: setpoint)")
    ax_u.set_ylabel("TRIAC input [%]")
    ax_u.set_xlabel("time [min]")
    ax_p.set_title("Worst runs redrawn")
    if trajectories:
        ax_p.legend(fontsize=7)
    if path is not None:
        save_figure(fig, path)
    return fig


__all__ = ["controller_summary", "format_summary_markdown", "plot_iae_distribution",
           "plot_perturbation_heatmaps", "plot_trajectories"]
