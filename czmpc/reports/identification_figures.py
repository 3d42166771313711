"""PNG figures of the identification report, one function per figure of the paper.

Every function takes plain arrays and values (never a model or a pipeline result),
draws one figure as `czmpc.reports.figure_style` makes them, writes it to ``path``
as a PNG and returns it. Every axis is labelled with its unit in brackets, using the
names of `AXIS_LABELS`.

Paper figures (Komperød et al.) and the function that draws each::

    fig. 2, 7     plot_dataset            input and power versus time
    fig. 3, 6, 18 plot_residuals          one-step residuals, stacked panels
    fig. 4, 5     plot_outlier_zoom       residual and power around one candidate
    fig. 8, 12,   plot_simulations        ballistic simulations against the measurement
      13, 15
    fig. 9, 16    plot_simulation_errors  ballistic simulation errors
    (none)        plot_correlations       residual autocorrelation and input
                                          cross-correlation with confidence bounds
    (Table 3)     plot_gain_curve         instantaneous gain f'(ds) against the step gains r
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from czmpc.reports.figure_style import PALETTE, FigureError, legend_above, save_figure, stacked_axes, vector


def axis_labels(*, input_name: str = "TRIAC input s", input_unit: str = "%",
                output_name: str = "power P", output_unit: str = "kW",
                input_symbol: str = "ds", output_symbol: str = "dP") -> dict[str, str]:
    """Axis labels for a log of any rig, for the ``labels`` keyword of every ``plot_*`` function.

    The defaults give the CZ puller's labels (TRIAC input in %, power in kW); `AXIS_LABELS`
    are those with shorter names of the deviations.
    """
    return {
        "time": "time [s]",
        "power": f"{output_name} [{output_unit}]",
        "power_dev": f"{output_name} deviation {output_symbol} [{output_unit}]",
        "triac": f"{input_name} [{input_unit}]",
        "triac_dev": f"{input_name} deviation {input_symbol} [{input_unit}]",
        "residual": f"residual e [{output_unit}]",
        "sim_error": f"simulation error [{output_unit}]",
        "lag": "lag [samples]",
        "autocorr": "autocorrelation of e [-]",
        "crosscorr": f"cross-correlation of {input_symbol} and e [-]",
        "gain": f"gain [{output_unit}/{input_unit}]",
        "unit_out": output_unit,
    }


#: Axis labels with units, shared by all figures (and by the tests that check them): the
#: CZ puller's (the defaults of `axis_labels`), its deviations named shortly.
AXIS_LABELS: dict[str, str] = {**axis_labels(), "power_dev": "power deviation dP [kW]",
                               "triac_dev": "TRIAC deviation ds [%]"}


def _labels(labels: Mapping[str, str] | None) -> Mapping[str, str]:
    return AXIS_LABELS if labels is None else labels


_MEASURED_STYLE = {"color": "black", "linewidth": 1.2, "label": "measured"}


def _series(func: str, noun: str, what: str, series: Mapping[str, Sequence[float] | np.ndarray],
            n: int, *, allow_empty: bool = False) -> dict[str, np.ndarray]:
    """The labelled series ``what`` of ``func`` as arrays of ``n`` floats; none only if ``allow_empty``."""
    if not series and not allow_empty:
        raise FigureError(f"{func} needs at least one {noun} series; got none")
    return {name: vector(v, f"{what}[{name!r}]", n) for name, v in series.items()}


def _color(i: int) -> str:
    """Line colour of the ``i``-th series of a figure (`PALETTE`, from the start again when used up)."""
    return PALETTE[i % len(PALETTE)]


def _draw_input(ax: Axes, time_s: np.ndarray, input_pct: np.ndarray, *, color: str, label: str,
                ylabel: str) -> None:
    """The input against time on ``ax`` as a staircase (held between samples), with its y label."""
    ax.plot(time_s, input_pct, color=color, linewidth=1.0, drawstyle="steps-post", label=label)
    ax.set_ylabel(ylabel)


def _mark_times(axes: Sequence[Axes], times_s: Sequence[float], label: str) -> None:
    """Vertical dotted lines at ``times_s`` on every panel (one legend entry each), then its legend."""
    for ax in axes:
        for i, tm in enumerate(times_s):
            ax.axvline(tm, color="tab:purple", linestyle=":", linewidth=1.0,
                       label=label if i == 0 else None)
        legend_above(ax)


def _save_titled(fig: Figure, title: str, path: str | os.PathLike[str]) -> Figure:
    """Give ``fig`` its title, write it to ``path`` (`save_figure`) and return it."""
    fig.suptitle(title)
    return save_figure(fig, path)


def _rms(values: np.ndarray) -> float:
    """Root mean square over the finite samples (NaN marks "no value")."""
    return float(np.sqrt(np.nanmean(np.square(values))))


def plot_dataset(
    time_s: Sequence[float] | np.ndarray,
    triac_pct: Sequence[float] | np.ndarray,
    power_kw: Sequence[float] | np.ndarray,
    path: str | os.PathLike[str],
    *,
    deviation: bool = False,
    title: str = "Identification data",
    marked_time_s: Sequence[float] = (),
    marked_label: str = "marked",
    labels: Mapping[str, str] | None = None,
) -> Figure:
    """Input and power against time, two stacked panels (paper figs. 2 and 7).

    Parameters
    ----------
    time_s :
        Sample times [s], shape ``(n,)``.
    triac_pct :
        TRIAC input ``s`` [%] (or its deviation ``ds`` when `deviation`), shape ``(n,)``.
    power_kw :
        Heater power ``P`` [kW] (or ``dP`` when `deviation`), shape ``(n,)``.
    path :
        PNG file to write.
    deviation :
        True if the signals are deviations from the operating point (fig. 7).
    title :
        Figure title.
    marked_time_s :
        Times [s] to mark with vertical dotted lines (for example repaired samples).
    marked_label :
        Legend text of those lines.
    labels :
        Axis labels (`axis_labels`); None: `AXIS_LABELS`.

    Returns
    -------
    Figure
        The drawn figure (already written to `path`).

    Raises
    ------
    FigureError
        Arrays that are not 1-D, empty, or of different lengths.
    """
    t = vector(time_s, "time_s")
    s = vector(triac_pct, "triac_pct", t.size)
    p = vector(power_kw, "power_kw", t.size)
    lab = _labels(labels)
    fig, (ax_p, ax_s) = stacked_axes(2)
    ax_p.plot(t, p, color="tab:red", linewidth=1.0, label="dP" if deviation else "P")
    ax_p.set_ylabel(lab["power_dev" if deviation else "power"])
    _draw_input(ax_s, t, s, color="tab:blue", label="ds" if deviation else "s",
                ylabel=lab["triac_dev" if deviation else "triac"])
    ax_s.set_xlabel(lab["time"])
    _mark_times((ax_p, ax_s), marked_time_s, marked_label)
    return _save_titled(fig, title, path)


def plot_residuals(
    time_s: Sequence[float] | np.ndarray,
    residuals_kw: Mapping[str, Sequence[float] | np.ndarray],
    path: str | os.PathLike[str],
    *,
    title: str = "One-step-ahead prediction errors",
    marked_time_s: Sequence[float] = (),
    marked_label: str = "outlier candidate",
    labels: Mapping[str, str] | None = None,
) -> Figure:
    """One-step residuals against time, one panel per series, same y scale (figs. 3, 6, 18).

    Parameters
    ----------
    time_s, path, title, labels :
        As in `plot_dataset`.
    residuals_kw :
        Panel label -> residuals ``e`` [kW], each shape ``(n,)``; NaN marks samples
        without a prediction (the start of a high-order ARX model). Panels are
        stacked in the mapping's order and share both axes so that their sizes compare.
    marked_time_s :
        Times [s] to mark with a triangle above the largest residual there
        (the paper's blue arrows of fig. 3).
    marked_label :
        Legend text of the marks.

    Returns
    -------
    Figure

    Raises
    ------
    FigureError
        No series, or arrays of the wrong shape.
    """
    t = vector(time_s, "time_s")
    series = _series("plot_residuals", "residual", "residuals_kw", residuals_kw, t.size)
    fig, axes = stacked_axes(len(series))
    for ax in axes[1:]:
        ax.sharey(axes[0])
    lab = _labels(labels)
    marks = np.asarray(list(marked_time_s), dtype=float)
    for i, (ax, (name, e)) in enumerate(zip(axes, series.items(), strict=True)):
        ax.plot(t, e, color=_color(i), linewidth=0.8,
                label=f"{name} (RMS {_rms(e):.3g} {lab['unit_out']})")
        if marks.size:
            idx = np.clip(np.searchsorted(t, marks), 0, t.size - 1)
            top = float(np.nanmax(np.abs(e)))
            ax.plot(t[idx], np.full(idx.size, 1.05 * top), linestyle="none", marker="v",
                    markersize=9, color="tab:purple", label=marked_label)
        ax.set_ylabel(lab["residual"])
        legend_above(ax)
    axes[-1].set_xlabel(lab["time"])
    return _save_titled(fig, title, path)


def plot_outlier_zoom(
    time_s: Sequence[float] | np.ndarray,
    residual_kw: Sequence[float] | np.ndarray,
    power_dev_kw: Sequence[float] | np.ndarray,
    center_time_s: float,
    path: str | os.PathLike[str],
    *,
    half_width_s: float = 60.0,
    title: str = "Outlier candidate",
    labels: Mapping[str, str] | None = None,
) -> Figure:
    """Residual (upper) and measured ``dP`` (lower) around one candidate (figs. 4, 5).

    Parameters
    ----------
    time_s, path, title, labels :
        As in `plot_dataset`.
    residual_kw :
        One-step residuals ``e`` of the high-order ARX model [kW], shape ``(n,)``.
    power_dev_kw :
        Measured power deviation ``dP`` [kW], shape ``(n,)``.
    center_time_s :
        Time of the candidate [s]; the window is ``center +- half_width_s``.
    half_width_s :
        Half width of the zoom window [s].

    Returns
    -------
    Figure

    Raises
    ------
    FigureError
        Arrays of the wrong shape, or a window holding no sample.
    """
    t = vector(time_s, "time_s")
    e = vector(residual_kw, "residual_kw", t.size)
    p = vector(power_dev_kw, "power_dev_kw", t.size)
    window = np.abs(t - center_time_s) <= half_width_s
    if not np.any(window):
        raise FigureError(
            f"plot_outlier_zoom: expected samples within {half_width_s:g} s of "
            f"{center_time_s:g} s; got none in {t[0]:g}..{t[-1]:g} s"
        )
    lab = _labels(labels)
    fig, (ax_e, ax_p) = stacked_axes(2)
    ax_e.plot(t[window], e[window], marker=".", color="tab:blue", linewidth=0.8, label="e")
    ax_e.set_ylabel(lab["residual"])
    ax_p.plot(t[window], p[window], marker=".", color="tab:red", linewidth=0.8, label="dP")
    ax_p.set_ylabel(lab["power_dev"])
    ax_p.set_xlabel(lab["time"])
    _mark_times((ax_e, ax_p), [center_time_s], f"candidate at {center_time_s:g} s")
    return _save_titled(fig, title, path)


def plot_simulations(
    time_s: Sequence[float] | np.ndarray,
    measured_kw: Sequence[float] | np.ndarray,
    simulated_kw: Mapping[str, Sequence[float] | np.ndarray],
    path: str | os.PathLike[str],
    *,
    title: str = "Ballistic simulations",
    input_pct: Sequence[float] | np.ndarray | None = None,
    labels: Mapping[str, str] | None = None,
) -> Figure:
    """Ballistic simulations of several models against the measured ``dP`` (figs. 8, 12, 13, 15).

    Parameters
    ----------
    time_s, path, title, labels :
        As in `plot_dataset`.
    measured_kw :
        Measured power deviation ``dP`` [kW], shape ``(n,)``.
    simulated_kw :
        Legend label -> simulated ``dP`` [kW], each shape ``(n,)``. Labels should
        carry the criterion, for example ``"OE(2,1), V = 0.043 kW^2"``.
    input_pct :
        TRIAC deviation ``ds`` [%], shape ``(n,)``; if given, drawn in a lower panel.

    Returns
    -------
    Figure

    Raises
    ------
    FigureError
        No simulation, or arrays of the wrong shape.
    """
    t = vector(time_s, "time_s")
    y = vector(measured_kw, "measured_kw", t.size)
    sims = _series("plot_simulations", "simulated", "simulated_kw", simulated_kw, t.size)
    lab = _labels(labels)
    fig, axes = stacked_axes(1 if input_pct is None else 2)
    ax = axes[0]
    ax.plot(t, y, **_MEASURED_STYLE)  # type: ignore[arg-type]
    for i, (name, sim) in enumerate(sims.items()):
        ax.plot(t, sim, color=_color(i), linewidth=1.0,
                linestyle=("--", "-.", ":", (0, (5, 1)))[i % 4], label=name)
    ax.set_ylabel(lab["power_dev"])
    legend_above(ax)
    if input_pct is not None:
        u = vector(input_pct, "input_pct", t.size)
        _draw_input(axes[1], t, u, color="tab:gray", label="ds", ylabel=lab["triac_dev"])
        legend_above(axes[1])
    axes[-1].set_xlabel(lab["time"])
    return _save_titled(fig, title, path)


def plot_simulation_errors(
    time_s: Sequence[float] | np.ndarray,
    errors_kw: Mapping[str, Sequence[float] | np.ndarray],
    path: str | os.PathLike[str],
    *,
    title: str = "Ballistic simulation errors",
    labels: Mapping[str, str] | None = None,
) -> Figure:
    """Ballistic simulation errors ``eps = dP - dP_sim`` against time (figs. 9, 16).

    Parameters
    ----------
    time_s, path, title, labels :
        As in `plot_dataset`.
    errors_kw :
        Legend label -> simulation error [kW], each shape ``(n,)``; the legend adds
        each series' mean square (the criterion ``V`` of eq. 9).

    Returns
    -------
    Figure

    Raises
    ------
    FigureError
        No series, or arrays of the wrong shape.
    """
    t = vector(time_s, "time_s")
    errs = _series("plot_simulation_errors", "error", "errors_kw", errors_kw, t.size)
    lab = _labels(labels)
    fig, (ax,) = stacked_axes(1)
    ax.axhline(0.0, color="black", linewidth=0.8)
    for i, (name, eps) in enumerate(errs.items()):
        ax.plot(t, eps, color=_color(i), linewidth=1.0,
                label=f"{name} (V = {np.mean(eps ** 2):.3g} {lab['unit_out']}^2)")
    ax.set_ylabel(lab["sim_error"])
    ax.set_xlabel(lab["time"])
    legend_above(ax)
    return _save_titled(fig, title, path)


def plot_correlations(
    lags_steps: Sequence[float] | np.ndarray,
    autocorr: Sequence[float] | np.ndarray,
    autocorr_bound: float,
    cross_lags_steps: Sequence[float] | np.ndarray,
    crosscorr: Sequence[float] | np.ndarray,
    crosscorr_bound: float,
    path: str | os.PathLike[str],
    *,
    title: str = "Residual tests",
    confidence: float = 0.99,
    labels: Mapping[str, str] | None = None,
) -> Figure:
    """Residual autocorrelation (upper) and input-residual cross-correlation (lower).

    The whiteness and independence tests of a fitted model (Ljung 1999, sec. 16.6):
    bars outside the dashed bands ``+-bound`` reject the hypothesis at the given
    confidence. Lag 0 of the autocorrelation (always 1) is left out so that the
    scale shows the lags that matter.

    Parameters
    ----------
    lags_steps :
        Lags of the autocorrelation [samples], shape ``(m,)``.
    autocorr :
        Normalized autocorrelation of the residuals at those lags [-], shape ``(m,)``.
    autocorr_bound :
        Half width of its confidence band [-].
    cross_lags_steps :
        Lags of the cross-correlation [samples], shape ``(m2,)`` (may be negative).
    crosscorr :
        Normalized cross-correlation of input and residuals [-], shape ``(m2,)``.
    crosscorr_bound :
        Half width of its confidence band [-].
    path, title, labels :
        As in `plot_dataset`.
    confidence :
        Confidence level of the bands, for the legend [-].

    Returns
    -------
    Figure

    Raises
    ------
    FigureError
        Arrays of the wrong shape or a negative or non-finite bound.
    """
    lags = vector(lags_steps, "lags_steps")
    r_ee = vector(autocorr, "autocorr", lags.size)
    xlags = vector(cross_lags_steps, "cross_lags_steps")
    r_ue = vector(crosscorr, "crosscorr", xlags.size)
    for name, bound in (("autocorr_bound", autocorr_bound), ("crosscorr_bound", crosscorr_bound)):
        if not (np.isfinite(bound) and bound >= 0):
            raise FigureError(f"plot_correlations: {name} must be finite and >= 0; got {bound!r}")
    keep = lags != 0
    lags, r_ee = lags[keep], r_ee[keep]
    if lags.size == 0:
        raise FigureError("plot_correlations: autocorrelation needs a lag other than 0; got only lag 0")
    lab = _labels(labels)
    fig, axes = stacked_axes(2, sharex=False)
    panels = (
        (axes[0], lags, r_ee, autocorr_bound, "autocorr", "residual e"),
        (axes[1], xlags, r_ue, crosscorr_bound, "crosscorr", "input ds -> residual e"),
    )
    for ax, x, r, bound, key, name in panels:
        outside = np.abs(r) > bound
        ax.vlines(x, 0.0, r, color="tab:blue", linewidth=1.5, label=name)
        ax.plot(x[outside], r[outside], linestyle="none", marker="o", color="tab:red",
                markersize=4, label=f"outside band ({int(outside.sum())} of {r.size})")
        ax.axhline(bound, color="tab:gray", linestyle="--", linewidth=1.0,
                   label=f"{100 * confidence:g} % band +-{bound:.3g}")
        ax.axhline(-bound, color="tab:gray", linestyle="--", linewidth=1.0)
        ax.axhline(0.0, color="black", linewidth=0.6)
        ax.set_ylabel(lab[key])
        ax.set_xlabel(lab["lag"])
        legend_above(ax)
    return _save_titled(fig, title, path)


def plot_gain_curve(
    ds_grid_pct: Sequence[float] | np.ndarray,
    gain_kw_per_pct: Mapping[str, Sequence[float] | np.ndarray],
    path: str | os.PathLike[str],
    *,
    step_ds_pct: Sequence[float] | np.ndarray = (),
    step_gain_kw_per_pct: Sequence[float] | np.ndarray = (),
    title: str = "Instantaneous gain of the input nonlinearity",
    labels: Mapping[str, str] | None = None,
) -> Figure:
    """Instantaneous gains ``f'(ds)`` of models against the measured step gains ``r`` (Table 3).

    Parameters
    ----------
    ds_grid_pct :
        TRIAC deviations ``ds`` [%] to draw the curves over, shape ``(m,)``.
    gain_kw_per_pct :
        Legend label -> gain on that grid [kW/%], each shape ``(m,)``.
    path, title, labels :
        As in `plot_dataset`.
    step_ds_pct :
        Midpoints ``ds`` of the measured input steps [%], shape ``(k,)``.
    step_gain_kw_per_pct :
        Measured step gains ``r`` [kW/%], shape ``(k,)``.

    Returns
    -------
    Figure

    Raises
    ------
    FigureError
        Arrays of the wrong shape.
    """
    grid = vector(ds_grid_pct, "ds_grid_pct")
    curves = _series("plot_gain_curve", "gain", "gain_kw_per_pct", gain_kw_per_pct, grid.size,
                     allow_empty=True)
    step_ds = np.asarray(step_ds_pct, dtype=float)
    step_r = np.asarray(step_gain_kw_per_pct, dtype=float)
    if step_ds.shape != step_r.shape or step_ds.ndim != 1:
        raise FigureError(
            "plot_gain_curve: step_ds_pct and step_gain_kw_per_pct must be 1-D of equal length; "
            f"got shapes {step_ds.shape} and {step_r.shape}"
        )
    lab = _labels(labels)
    fig, (ax,) = stacked_axes(1)
    for i, (name, g) in enumerate(curves.items()):
        ax.plot(grid, g, color=_color(i), linewidth=1.2, label=name)
    if step_ds.size:
        ax.plot(step_ds, step_r, linestyle="none", marker="o", color="black",
                label="measured step gains r")
    ax.set_xlabel(lab["triac_dev"])
    ax.set_ylabel(lab["gain"])
    ax.legend(loc="upper right")
    return _save_titled(fig, title, path)


__all__ = ["AXIS_LABELS", "plot_correlations", "plot_dataset", "plot_gain_curve", "plot_outlier_zoom",
           "plot_residuals", "plot_simulation_errors", "plot_simulations"]
