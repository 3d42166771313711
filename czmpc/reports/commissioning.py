"""Figures of the commissioning report (`czmpc commission`): the test, the held-out fit, the check.

Each function takes plain arrays and writes one PNG (matplotlib's object API, no
global state); the journey (`czmpc.commissioning.journey`) assembles the Markdown.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from czmpc.reports.figure_style import new_figure, save_figure
from sysid._typing import FloatArray

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


def _figure(n_rows: int) -> tuple[Figure, list[Axes]]:
    fig = new_figure((9.0, 2.6 * n_rows))
    axes = [fig.add_subplot(n_rows, 1, i + 1) for i in range(n_rows)]
    return fig, axes


def experiment_figure(path: Path, time_s: FloatArray, triac_pct: FloatArray, power_kw: FloatArray, *,
                band_kw: tuple[float, float], schedule_time_s: FloatArray,
                schedule_triac_pct: FloatArray) -> Path:
    """The test: designed and applied TRIAC input [%], measured power [kW] in its band."""
    fig, (ax_u, ax_p) = _figure(2)
    ax_u.step(schedule_time_s, schedule_triac_pct, where="post", color="0.6",
              label="designed")
    ax_u.step(time_s, triac_pct, where="post", label="applied")
    ax_u.set_ylabel("TRIAC input s [%]")
    ax_u.legend(loc="best")
    ax_p.plot(time_s, power_kw, lw=0.8, label="measured")
    for edge in band_kw:
        ax_p.axhline(edge, color="tab:red", ls="--", lw=0.8)
    ax_p.set_ylabel("power P [kW]")
    ax_p.set_xlabel("test time [s]")
    ax_p.legend(loc="best")
    save_figure(fig, path)
    return path


def fit_figure(path: Path, time_s: FloatArray, measured_kw: FloatArray, simulated_kw: FloatArray,
               *, fit_pct: float) -> Path:
    """Held-out data: measured power and the model's ballistic simulation [kW]."""
    fig, (ax,) = _figure(1)
    ax.plot(time_s, measured_kw, lw=0.8, label="measured")
    ax.plot(time_s, simulated_kw, lw=1.0, label=f"model (simulation), fit {fit_pct:.1f} %")
    ax.set_xlabel("test time [s]")
    ax.set_ylabel("power P [kW]")
    ax.legend(loc="best")
    save_figure(fig, path)
    return path


def monte_carlo_figure(path: Path, iae_ratios: Sequence[float]) -> Path:
    """Histogram of the closed-loop Monte Carlo: IAE against the nominal plant's [-]."""
    fig, (ax,) = _figure(1)
    ratios = np.asarray(iae_ratios, dtype=float)
    ax.hist(ratios[np.isfinite(ratios)], bins=max(5, min(30, ratios.size // 2)))
    ax.axvline(1.0, color="0.3", ls="--", lw=0.8)
    ax.set_xlabel("IAE on a drawn plant / IAE on the model itself [-]")
    ax.set_ylabel("plants [count]")
    save_figure(fig, path)
    return path


__all__ = ["experiment_figure", "fit_figure", "monte_carlo_figure"]
