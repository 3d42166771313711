"""PNG figure of a designed identification test (`czmpc design-test --plot`).

Three panels (`plot_test_signal`):

1. the signal: TRIAC input [%] against time [s], with the staircase's levels;
2. levels against the time constant: every constant stretch of the signal as its level
   [%] and its hold time in time constants [tau] (log scale), with the staircase's
   rule (`sysid.design.HOLD_TAUS`) and one tau marked: holds of several tau show the
   static gain, holds near tau the dynamics;
3. the spectrum: one-sided periodogram of the mean-removed signal [%^2 s] against
   angular frequency [rad/s] (log-log), with the expected plant bandwidth ``1/tau`` and
   the GBN corner ``2/tau`` marked.
"""

from __future__ import annotations

import os

import numpy as np
from matplotlib.figure import Figure

from czmpc.reports.figure_style import legend_above, save_figure, stacked_axes
from sysid.design import HOLD_TAUS, ExcitationSignal

#: Size of the three-panel figure [inch].
DESIGN_FIGSIZE_IN = (9.0, 9.0)


def plot_test_signal(signal: ExcitationSignal, path: str | os.PathLike[str]) -> Figure:
    """Draw the three panels (module docstring) and write them to ``path`` (PNG)."""
    spec = signal.spec
    tau = spec.tau_s
    fig, (ax_u, ax_h, ax_s) = stacked_axes(3, sharex=False, figsize_in=DESIGN_FIGSIZE_IN)
    ax_u.plot(signal.time_s, signal.triac_pct, color="tab:blue", linewidth=0.9,
              drawstyle="steps-post", label="TRIAC input")
    for i, level in enumerate(signal.levels_pct):
        ax_u.axhline(float(level), color="tab:gray", linewidth=0.5, linestyle=":",
                     label="staircase levels" if i == 0 else None)
    ax_u.set_xlabel("time [s]")
    ax_u.set_ylabel("TRIAC input [%]")
    legend_above(ax_u)
    change = np.flatnonzero(np.diff(signal.triac_pct) != 0.0) + 1
    starts = np.concatenate(([0], change))
    holds_tau = signal.hold_times_s() / tau
    ax_h.scatter(signal.triac_pct[starts], holds_tau, s=12, color="tab:blue",
                 label="constant stretches")
    ax_h.axhline(HOLD_TAUS, color="tab:green", linestyle="--", linewidth=1.0,
                 label=f"staircase hold {HOLD_TAUS:g} tau (settled to 2 %)")
    ax_h.axhline(1.0, color="tab:orange", linestyle=":", linewidth=1.0, label="1 tau")
    ax_h.set_yscale("log")
    ax_h.set_xlabel("level [%]")
    ax_h.set_ylabel(f"hold time [tau = {tau:g} s]")
    legend_above(ax_h)
    omega, power = signal.spectrum()
    keep = (omega > 0) & (power > 0)
    ax_s.loglog(omega[keep], power[keep], color="tab:blue", linewidth=0.6, alpha=0.8,
                label="periodogram")
    ax_s.axvline(1.0 / tau, color="tab:red", linestyle="--", linewidth=1.0,
                 label=f"plant bandwidth 1/tau = {1.0 / tau:.3g} rad/s")
    ax_s.axvline(2.0 / tau, color="tab:orange", linestyle=":", linewidth=1.0,
                 label="GBN corner 2/tau")
    ax_s.set_xlabel("angular frequency [rad/s]")
    ax_s.set_ylabel("power [%^2 s]")
    legend_above(ax_s)
    return save_figure(fig, path)


__all__ = ["DESIGN_FIGSIZE_IN", "plot_test_signal"]
