"""PNG figure of one closed-loop run: power, TRIAC input and disturbance estimate over time.

Three panels stacked on a shared time axis (`plot_closed_loop`):

1. power [kW]: measured (thin, grey), true noise-free power (black), setpoint (red,
   dashed) and the soft power limits if any (dotted);
2. TRIAC input [%] with the controller's allowed range (dashed) and the TRIAC limits if
   they are tighter than 0..100 %;
3. the controller's disturbance estimate as the steady power change it causes [kW].

Conventions as `czmpc.reports.identification_figures`: plain arrays in, the figure
written to ``path`` and returned.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from czmpc.reports.figure_style import FigureError, legend_above, save_figure, stacked_axes, vector
from czmpc.reports.identification_figures import AXIS_LABELS
from sysid._typing import FloatArray

#: Size of the three-panel figure [inch].
CLOSED_LOOP_FIGSIZE_IN = (9.0, 7.5)
#: Label of the disturbance panel's axis.
DISTURBANCE_LABEL = "disturbance estimate [kW]"
#: Largest magnitude drawn [kW or %]; values beyond it (up to +-inf) are drawn at this
#: bound. Matplotlib's autoscaling overflows on spans near the float range (a setpoint of
#: 1e308 kW crashed the figure), and no heater power is within orders of magnitude of it.
PLOT_LIMIT = 1e12


def _drawable(values: FloatArray) -> FloatArray:
    """``values`` clipped to ``+-PLOT_LIMIT`` (NaN kept: a gap in the line)."""
    clipped: FloatArray = np.clip(values, -PLOT_LIMIT, PLOT_LIMIT)
    return clipped


def plot_closed_loop(
    time_s: Sequence[float] | np.ndarray,
    setpoint_kw: Sequence[float] | np.ndarray,
    power_measured_kw: Sequence[float] | np.ndarray,
    power_true_kw: Sequence[float] | np.ndarray,
    triac_pct: Sequence[float] | np.ndarray,
    disturbance_kw: Sequence[float] | np.ndarray | None,
    *,
    allowed_triac_range_pct: tuple[float, float],
    triac_limits_pct: tuple[float, float] = (0.0, 100.0),
    soft_power_limits_kw: tuple[float | None, float | None] = (None, None),
    title: str,
    path: str | os.PathLike[str],
) -> Figure:
    """Draw a closed-loop run in three stacked panels and write it as PNG.

    Parameters
    ----------
    time_s :
        Sample times [s], shape ``(n,)``.
    setpoint_kw, power_measured_kw, power_true_kw :
        Setpoint, measured power (NaN where missing) and true power [kW], shape ``(n,)``.
        Values beyond ``+-PLOT_LIMIT`` (also infinite ones) are drawn at that bound.
    triac_pct :
        TRIAC input [%], shape ``(n,)``.
    disturbance_kw :
        The controller's disturbance estimate as a steady power change [kW], shape
        ``(n,)``, or None (the panel then says there is none).
    allowed_triac_range_pct :
        ``(s_min, s_max)`` the controller keeps the input in [%].
    triac_limits_pct :
        Hard TRIAC limits [%]; drawn only where tighter than 0..100 %.
    soft_power_limits_kw :
        ``(min, max)`` soft power limits [kW]; None for a missing one.
    title :
        Figure title.
    path :
        PNG file to write.

    Raises
    ------
    FigureError
        Arrays of different lengths, empty or not one-dimensional.
    """
    t = vector(time_s, "time_s")
    n = t.size
    setpoint = _drawable(vector(setpoint_kw, "setpoint_kw", n))
    measured = _drawable(vector(power_measured_kw, "power_measured_kw", n))
    true = _drawable(vector(power_true_kw, "power_true_kw", n))
    triac = _drawable(vector(triac_pct, "triac_pct", n))
    dist = (None if disturbance_kw is None
            else _drawable(vector(disturbance_kw, "disturbance_kw", n)))
    s_lo, s_hi = (float(v) for v in allowed_triac_range_pct)
    if not s_lo < s_hi:
        raise FigureError(f"allowed_triac_range_pct must be (min, max) with min < max; "
                          f"got {allowed_triac_range_pct!r}")

    fig, (ax_p, ax_s, ax_d) = stacked_axes(3)
    fig.set_size_inches(*CLOSED_LOOP_FIGSIZE_IN)
    fig.suptitle(title, fontsize="medium")

    ax_p.plot(t, measured, color="0.6", linewidth=0.6, label="measured")
    ax_p.plot(t, true, color="black", linewidth=1.1, label="true (noise-free)")
    ax_p.plot(t, setpoint, color="tab:red", linewidth=1.1, linestyle="--", label="setpoint")
    for value, name in zip(soft_power_limits_kw, ("soft min", "soft max"), strict=True):
        if value is not None:
            ax_p.axhline(value, color="tab:purple", linewidth=1.0, linestyle=":",
                         label=f"{name} {value:g} kW")
    ax_p.set_ylabel(AXIS_LABELS["power"])
    legend_above(ax_p)

    ax_s.plot(t, triac, color="tab:blue", linewidth=1.0, label="TRIAC input")
    ax_s.axhline(s_lo, color="tab:gray", linewidth=1.0, linestyle="--",
                 label=f"allowed range {s_lo:g}..{s_hi:g} %")
    ax_s.axhline(s_hi, color="tab:gray", linewidth=1.0, linestyle="--")
    lim_lo, lim_hi = triac_limits_pct
    if lim_lo > 0.0 or lim_hi < 100.0:
        ax_s.axhline(lim_lo, color="tab:red", linewidth=1.0, linestyle=":",
                     label=f"TRIAC limits {lim_lo:g}..{lim_hi:g} %")
        ax_s.axhline(lim_hi, color="tab:red", linewidth=1.0, linestyle=":")
    ax_s.set_ylabel(AXIS_LABELS["triac"])
    legend_above(ax_s)

    if dist is not None:
        ax_d.plot(t, dist, color="tab:green", linewidth=1.0,
                  label="estimated disturbance (steady power change)")
        ax_d.axhline(0.0, color="black", linewidth=0.6)
        legend_above(ax_d)
    else:
        ax_d.text(0.5, 0.5, "the controller reports no disturbance estimate",
                  transform=ax_d.transAxes, ha="center", va="center")
    ax_d.set_ylabel(DISTURBANCE_LABEL)
    ax_d.set_xlabel(AXIS_LABELS["time"])
    ax_d.set_xlim(float(t[0]), float(t[-1]))
    return save_figure(fig, path)


__all__ = ["CLOSED_LOOP_FIGSIZE_IN", "DISTURBANCE_LABEL", "PLOT_LIMIT", "plot_closed_loop"]
