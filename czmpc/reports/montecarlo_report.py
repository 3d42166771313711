"""Monte-Carlo summary of a campaign over sampled plants: offset-free and in-limits shares.

Reads the rows of a campaign (`czmpc.campaigns.campaign.ROW_COLUMNS`) whose plants were
drawn from the model's parameter uncertainty (``plant = "sampled k"``) and gives, per
controller and scenario, the shares of runs offset-free (the row's ``offset_free``, against
the reachable setpoint) and `within_limits`, the IAE [kW s] quantiles and distribution
(`plot_iae_ecdf`), and the draws the sampling rule rejected (`czmpc.campaigns.sampling`);
the report's text (`format_montecarlo_markdown`) defines each.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from czmpc.reports.tables import format_table

if TYPE_CHECKING:
    from matplotlib.figure import Figure

Row = Mapping[str, Any]


def is_sampled(row: Row) -> bool:
    """A row of a plant drawn from the model's uncertainty."""
    return str(row.get("plant", "")).startswith("sampled ")


def within_limits(row: Row) -> bool:
    """No TRIAC-limit, rate-limit or allowed-range violation in a finished run."""
    return (int(row["n_limit_violations"]) == 0 and int(row["n_rate_violations"]) == 0
            and int(row.get("n_allowed_range_violations", 0)) == 0)


def _share(flags: Sequence[bool]) -> float:
    return float(np.mean(flags)) if flags else math.nan


def _pct(value: float) -> str:
    return "n/a" if math.isnan(value) else f"{100 * value:.1f}"


def montecarlo_summary(rows: Sequence[Row]) -> list[dict[str, Any]]:
    """Per (controller, scenario) over the sampled plants: counts, shares and IAE quantiles.

    Keys: ``controller``, ``scenario``, ``n_runs``, ``n_errors``, ``offset_free``,
    ``within_limits``, ``both`` (shares of the finished runs, [0, 1]),
    ``iae_median_kw_s``, ``iae_p5_kw_s``, ``iae_p95_kw_s``.
    """
    sampled = [r for r in rows if is_sampled(r)]
    out = []
    for name in dict.fromkeys(str(r["controller"]) for r in sampled):
        for scenario in dict.fromkeys(str(r["scenario"]) for r in sampled):
            mine = [r for r in sampled if r["controller"] == name and r["scenario"] == scenario]
            if not mine:
                continue
            ok = [r for r in mine if r["status"] == "ok"]
            iae = np.array([float(r["iae_kw_s"]) for r in ok])
            free = [bool(r["offset_free"]) for r in ok]
            inside = [within_limits(r) for r in ok]
            out.append({
                "controller": name, "scenario": scenario, "n_runs": len(mine),
                "n_errors": len(mine) - len(ok), "offset_free": _share(free),
                "within_limits": _share(inside),
                "both": _share([a and b for a, b in zip(free, inside, strict=True)]),
                "iae_median_kw_s": float(np.median(iae)) if ok else math.nan,
                "iae_p5_kw_s": float(np.percentile(iae, 5)) if ok else math.nan,
                "iae_p95_kw_s": float(np.percentile(iae, 95)) if ok else math.nan,
            })
    return out


def rejection_summary(rows: Sequence[Row]) -> tuple[int, int, str]:
    """(sampled plants, draws rejected over them, parameter source(s)) of the campaign."""
    by_plant: dict[str, Row] = {}
    for r in rows:
        if is_sampled(r) and r["status"] == "ok":
            by_plant.setdefault(str(r["plant"]), r)
    rejected = sum(max(0, int(r.get("n_rejected_draws", 0))) for r in by_plant.values())
    sources = sorted({str(r.get("plant_parameter_source", "")) for r in by_plant.values()})
    return len(by_plant), rejected, ", ".join(s for s in sources if s) or "-"


def format_montecarlo_markdown(rows: Sequence[Row], *, offset_free_threshold_kw: float,
                               figure: str | None = None, warnings: Sequence[str] = ()) -> str:
    """The Monte-Carlo section of a campaign report (empty when no plant was sampled).

    ``offset_free_threshold_kw`` is the threshold the rows' ``offset_free`` was judged by.
    """
    summary = montecarlo_summary(rows)
    if not summary:
        return ""
    n_plants, n_rejected, source = rejection_summary(rows)
    table = format_table(
        ["controller", "scenario", "runs", "crashed", "offset-free [%]", "within limits [%]",
         "both [%]", "IAE median [kW s]", "IAE p5 [kW s]", "IAE p95 [kW s]"],
        [[s["controller"], s["scenario"], str(s["n_runs"]), str(s["n_errors"]),
          _pct(s["offset_free"]), _pct(s["within_limits"]), _pct(s["both"]),
          f"{s['iae_median_kw_s']:.2f}", f"{s['iae_p5_kw_s']:.2f}", f"{s['iae_p95_kw_s']:.2f}"]
         for s in summary], markdown=True)
    lines = [
        "## Monte Carlo over the model's uncertainty", "",
        f"{n_plants} plants drawn from N(theta, Sigma) of the model's parameters "
        f"(Sigma from: {source}); {n_rejected} draws rejected (rule: A or C with a root on or "
        "outside the unit circle, or a static gain dP/ds whose sign differs from the nominal "
        "model's anywhere in the identified input range) and drawn again.", "",
        *[f"**Warning:** {w}\n" for w in warnings],
        f"Offset-free: every setpoint change ends with |mean measured error over the last "
        f"quarter of its segment| < {offset_free_threshold_kw:g} kW, error to the reachable "
        "setpoint (the setpoint clipped to what that plant holds in the allowed input "
        "range); a scenario without setpoint changes is judged over the last quarter of the "
        "run. Within limits: no sample outside the TRIAC limits or the allowed input range "
        "and no move beyond the rate limit. IAE: true power against the setpoint, whole run. "
        "(The campaign table above judges offset-free against the raw setpoint instead, so "
        "a plant that cannot reach a setpoint inside the allowed range fails there.)",
        "", table, ""]
    if figure:
        lines += [f"![IAE distribution per controller over the sampled plants]({figure})", ""]
    return "\n".join(lines)


def plot_iae_ecdf(rows: Sequence[Row], path: str | os.PathLike[str] | None = None) -> Figure:
    """Empirical distribution of the IAE over the sampled plants, per controller.

    One panel per scenario; x: IAE [kW s] (log scale when it spans more than a decade),
    y: share of the plants with an IAE at most x [-].
    """
    from czmpc.reports.figure_style import new_figure, save_figure

    ok = [r for r in rows if is_sampled(r) and r["status"] == "ok"]
    scenarios = list(dict.fromkeys(str(r["scenario"]) for r in ok)) or ["(none)"]
    names = list(dict.fromkeys(str(r["controller"]) for r in ok))
    fig = new_figure((5.0 * len(scenarios), 4.0))
    axes = fig.subplots(1, len(scenarios), squeeze=False)[0]
    for ax, scenario in zip(axes, scenarios, strict=True):
        values = []
        for name in names:
            iae = np.sort([float(r["iae_kw_s"]) for r in ok
                           if r["controller"] == name and r["scenario"] == scenario])
            if iae.size == 0:
                continue
            values.append(iae)
            share = np.arange(0, iae.size + 1) / iae.size
            ax.step(np.concatenate([iae[:1], iae]), share, where="post",
                    label=f"{name} (n = {iae.size})")
        finite = np.concatenate(values) if values else np.array([])
        finite = finite[np.isfinite(finite) & (finite > 0)]
        if finite.size and finite.max() > 10.0 * finite.min():
            ax.set_xscale("log")
        ax.set_xlabel("IAE of the true power [kW s]")
        ax.set_ylabel("share of sampled plants with IAE <= x [-]")
        ax.set_title(f"scenario '{scenario}'")
        ax.set_ylim(0.0, 1.02)
        ax.grid(True, alpha=0.3)
        if values:
            ax.legend(loc="lower right", fontsize="small")
    fig.suptitle("IAE distribution per controller over plants sampled from the model's "
                 "uncertainty", fontsize="medium")
    if path is not None:
        save_figure(fig, path)
    return fig


__all__ = ["format_montecarlo_markdown", "is_sampled", "montecarlo_summary", "plot_iae_ecdf",
           "rejection_summary", "within_limits"]
