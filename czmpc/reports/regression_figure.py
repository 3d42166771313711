"""The figure of a regression case: its golden trajectory with the band, and the new run.

Takes plain arrays (the golden and the new trajectory as ``{signal: array}``, the band
per signal) and draws power and TRIAC input on shared time axes, with the new run's
difference from the golden power and the first divergence marked.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np
from matplotlib.figure import Figure

from czmpc.reports.figure_style import new_figure, save_figure

_SIGNAL_NAMES = {"power_true_kw": "true power [kW]", "triac_pct": "TRIAC input [%]"}


def plot_regression_case(golden: Mapping[str, np.ndarray], band: Mapping[str, float],
                         new: Mapping[str, np.ndarray], *, title: str,
                         path: str | os.PathLike[str],
                         divergence_time_s: float | None = None) -> Figure:
    """Golden trajectory with its band and the new one, power and TRIAC on shared time axes.

    Parameters
    ----------
    golden, new :
        ``time_s`` [s], ``setpoint_kw``, ``power_true_kw`` [kW] and ``triac_pct`` [%];
        ``new`` may be empty (nothing new to draw).
    band :
        Allowed deviation of ``power_true_kw`` [kW] and ``triac_pct`` [%].
    title :
        The case.
    path :
        The PNG to write.
    divergence_time_s :
        Where the new run first leaves the band [s], or None.
    """
    fig = new_figure((8.0, 8.0))
    axes = fig.subplots(3, 1, sharex=True, height_ratios=(3, 3, 2))
    for ax, signal in zip(axes[:2], ("power_true_kw", "triac_pct"), strict=True):
        t, g = golden["time_s"], golden[signal]
        if signal == "power_true_kw":
            ax.plot(t, golden["setpoint_kw"], color="black", linestyle="--", linewidth=0.8,
                    label="setpoint")
        ax.fill_between(t, g - band[signal], g + band[signal], color="tab:blue", alpha=0.25,
                        linewidth=0, label=f"golden band (+-{band[signal]:.3g})")
        ax.plot(t, g, color="tab:blue", linewidth=1.0, label="golden")
        if new:
            ax.plot(new["time_s"], new[signal], color="tab:red", linewidth=1.0, label="new")
        ax.set_ylabel(_SIGNAL_NAMES[signal])
    ax_d = axes[2]
    if new:
        k = min(len(golden["time_s"]), len(new["time_s"]))
        t = golden["time_s"][:k]
        diff = new["power_true_kw"][:k] - golden["power_true_kw"][:k]
        ax_d.fill_between(t, -band["power_true_kw"], band["power_true_kw"], color="tab:blue",
                          alpha=0.25, linewidth=0, label="golden band")
        ax_d.plot(t, diff, color="tab:red", linewidth=1.0, label="new - golden")
        ax_d.legend(loc="best", fontsize="small")
    ax_d.set_ylabel("new - golden power [kW]")
    for ax in axes:
        if divergence_time_s is not None:
            ax.axvline(divergence_time_s, color="tab:red", linestyle=":", linewidth=1.0,
                       label=f"first divergence t = {divergence_time_s:g} s")
        ax.grid(True, linewidth=0.5, alpha=0.6)
    axes[2].set_xlabel("time [s]")
    axes[0].set_title(title, fontsize="medium")
    axes[0].legend(loc="best", fontsize="small")
    return save_figure(fig, path)


__all__ = ["plot_regression_case"]
