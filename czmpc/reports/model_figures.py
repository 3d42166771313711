"""Figures of a model for analysis: step responses, Bode plots, poles and zeros, with bands.

Each linearization is `sysid.export.linearize` at a TRIAC level. The confidence bands
are the `BAND_PERCENTILES` over models drawn from the parameter covariance
(`sysid.uncertainty`: the file's covariance, else its standard errors; without either,
no bands, and the figure says so); unstable draws are left out and counted. `czmpc
show-model --plot DIR` draws them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from czmpc.reports.figure_style import new_figure, save_figure
from sysid.errors import ModelFileError
from sysid.export import linearize
from sysid.model import HammersteinModel
from sysid.polynomials import slowest_time_constant_samples
from sysid.uncertainty import ParameterError, draw_parameters, model_with_parameters, parameter_distribution

#: Percentiles of the confidence band [%].
BAND_PERCENTILES = (2.5, 97.5)

__all__ = ["BAND_PERCENTILES", "ModelDraws", "bode_figure", "draw_models", "pole_zero_figure",
           "step_figure"]


@dataclass(frozen=True, kw_only=True, eq=False)
class ModelDraws:
    """Models drawn from the parameter uncertainty.

    Attributes
    ----------
    models :
        The accepted draws.
    n_rejected :
        Draws left out (not a valid model).
    note :
        What the bands are (or why there are none), for the figure titles.
    """

    models: tuple[HammersteinModel, ...]
    n_rejected: int
    note: str


def draw_models(model: HammersteinModel, n: int, *, seed: int = 0) -> ModelDraws:
    """``n`` draws of the model from its parameter distribution (none if it has none)."""
    if n == 0:
        return ModelDraws(models=(), n_rejected=0, note="no bands (no draws asked for)")
    try:
        dist = parameter_distribution(model)
    except ParameterError as exc:
        return ModelDraws(models=(), n_rejected=0, note=f"no bands: {exc}")
    rng = np.random.default_rng(seed)
    out, rejected = [], 0
    for values in draw_parameters(rng, dist.theta, dist.covariance, n):
        try:
            out.append(model_with_parameters(model, dist.names, values))
        except ModelFileError:
            rejected += 1
    source = "covariance" if dist.source == "covariance" else "standard errors only"
    return ModelDraws(models=tuple(out), n_rejected=rejected,
                      note=f"band: {BAND_PERCENTILES[0]:g}-{BAND_PERCENTILES[1]:g} percentiles "
                           f"of {len(out)} models drawn from the parameter {source}"
                           + (f" ({rejected} unstable draws left out)" if rejected else ""))


def _step_kw(model: HammersteinModel, triac_pct: float, step_pct: float, n: int) -> np.ndarray:
    """Output deviation after a TRIAC step of ``step_pct`` from ``triac_pct`` held long."""
    ds = triac_pct - model.operating_point.triac_pct
    dw = float(model.input_nonlinearity(ds + step_pct) - model.input_nonlinearity(ds))
    out: np.ndarray = dw * lfilter(model.b, model.a, np.ones(n))
    return out


def _band(values: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    if not values:
        return None
    lo, hi = np.percentile(np.vstack(values), BAND_PERCENTILES, axis=0)
    return lo, hi


def step_figure(path: Path, model: HammersteinModel, levels_pct: Sequence[float],
                draws: ModelDraws, *, step_pct: float = 1.0, duration_s: float | None = None,
                ) -> Path:
    """Output response to a ``step_pct`` TRIAC step from each level, with its band."""
    units = model.effective_units
    tau = model.ts_s * slowest_time_constant_samples(model.a)
    tau = tau if np.isfinite(tau) else 0.0
    duration = duration_s if duration_s is not None else max(10 * model.ts_s, 5.0 * tau)
    n = int(duration / model.ts_s) + 1
    t = np.arange(n) * model.ts_s
    fig = new_figure((9.0, 4.2))
    ax = fig.add_subplot(1, 1, 1)
    for level in levels_pct:
        line, = ax.plot(t, _step_kw(model, level, step_pct, n),
                        label=f"from {level:g} {units.input}")
        band = _band([_step_kw(m, level, step_pct, n) for m in draws.models])
        if band is not None:
            ax.fill_between(t, *band, color=line.get_color(), alpha=0.2, lw=0)
    ax.set_xlabel("time after the step [s]")
    ax.set_ylabel(f"output change [{units.output}]")
    ax.set_title(f"response to a {step_pct:g} {units.input} step of the input; {draws.note}",
                 fontsize=9)
    ax.legend(loc="best")
    save_figure(fig, path)
    return path


def bode_figure(path: Path, model: HammersteinModel, levels_pct: Sequence[float],
                draws: ModelDraws) -> Path:
    """Magnitude and phase of the linearization at each level, up to the Nyquist frequency."""
    units = model.effective_units
    nyquist = np.pi / model.ts_s
    omega = np.logspace(np.log10(nyquist) - 4.0, np.log10(nyquist), 400)
    fig = new_figure((9.0, 6.0))
    ax_m, ax_p = fig.add_subplot(2, 1, 1), fig.add_subplot(2, 1, 2, sharex=None)
    for level in levels_pct:
        g = linearize(model, level).frequency_response(omega)
        line, = ax_m.loglog(omega, np.abs(g), label=f"at {level:g} {units.input}")
        ax_p.semilogx(omega, np.degrees(np.unwrap(np.angle(g))), color=line.get_color())
        responses = [linearize(m, level).frequency_response(omega) for m in draws.models]
        mag = _band([np.abs(r) for r in responses])
        phase = _band([np.degrees(np.unwrap(np.angle(r))) for r in responses])
        if mag is not None and phase is not None:
            ax_m.fill_between(omega, *mag, color=line.get_color(), alpha=0.2, lw=0)
            ax_p.fill_between(omega, *phase, color=line.get_color(), alpha=0.2, lw=0)
    ax_m.set_ylabel(f"|G| [{units.output}/{units.input}]")
    ax_m.set_title(f"linearized at each level; Nyquist {nyquist:.3g} rad/s; {draws.note}",
                   fontsize=9)
    ax_m.legend(loc="best")
    ax_p.set_ylabel("phase [deg]")
    ax_p.set_xlabel("angular frequency [rad/s]")
    save_figure(fig, path)
    return path


def pole_zero_figure(path: Path, model: HammersteinModel, draws: ModelDraws) -> Path:
    """Poles and zeros of ``G(z)`` in the z-plane, the drawn models as a cloud.

    The poles are the roots of ``A`` and, for each sample of delay, one at ``z = 0``;
    the zeros are the roots of ``B``.
    """
    fig = new_figure((6.0, 6.0))
    ax = fig.add_subplot(1, 1, 1)
    circle = np.exp(1j * np.linspace(0.0, 2.0 * np.pi, 361))
    ax.plot(circle.real, circle.imag, color="0.5", lw=0.8)
    for m in draws.models:
        lin = linearize(m, m.operating_point.triac_pct)
        p, z = np.roots(lin.den_z), np.roots(lin.num_z)
        ax.plot(p.real, p.imag, "x", color="tab:blue", alpha=0.08, ms=4)
        ax.plot(z.real, z.imag, "o", mfc="none", color="tab:orange", alpha=0.08, ms=4)
    lin = linearize(model, model.operating_point.triac_pct)
    p, z = np.roots(lin.den_z), np.roots(lin.num_z)
    ax.plot(p.real, p.imag, "x", color="tab:blue", ms=10, mew=2,
            label="poles (of A; the delay's at z = 0)")
    ax.plot(z.real, z.imag, "o", mfc="none", color="tab:orange", ms=10, mew=2,
            label="zeros (of B)")
    ax.set_aspect("equal")
    ax.set_xlabel("Re z")
    ax.set_ylabel("Im z")
    ax.set_title(draws.note, fontsize=8)
    ax.legend(loc="lower left", fontsize=8)
    save_figure(fig, path)
    return path
