"""The structure choice in the identification report: the delay's evidence and each search's runners-up.

As MATLAB's ``delayest`` and ``selstruc`` do, it shows how sharply the data single out a
structure, for the two searches of ``czmpc identify --orders auto``:

* `sysid.structure.select_structure`: the delay from an ARX fit's ``B`` coefficients
  (`sysid.structure.DelayEstimate`), then the Hammerstein-OE structures scored on
  validation data;
* `sysid.rest_oe.search_oe_from_rest`: the linear OE structures scored by their
  simulation from rest, with the structures the record does not tell apart
  (`sysid.rest_oe.RestOESearch.near`).

`structure_section` writes the Markdown, `plot_structure_choice` the figure (plain arrays in).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from czmpc.reports.figure_style import FigureError, legend_above, save_figure, stacked_axes, vector
from czmpc.reports.tables import format_table

if TYPE_CHECKING:
    from sysid.rest_oe import RestOESearch
    from sysid.structure import CandidateScore, StructureChoice

#: Rows of the order grid's table: the best by validation V (the chosen and the paper's
#: structure are always shown).
GRID_ROWS = 8


def _grid_notes(score: CandidateScore, choice: StructureChoice) -> str:
    """Why a grid candidate is, or is not, the choice (the exclusion rules of `select_structure`)."""
    from sysid.structure import MAX_GAIN_RSD, MIN_POLE_ZERO_SHARE

    notes = []
    if score.orders == choice.chosen.orders:
        notes.append("**chosen**")
    if choice.paper is not None and score.orders == choice.paper.orders:
        notes.append("the paper's")
    if score.slowest_tau_samples > choice.estimation_samples:
        notes.append("time constant longer than the estimation record")
    if not score.static_gain_rsd <= MAX_GAIN_RSD:
        notes.append(f"static gain undetermined (relative std {100 * score.static_gain_rsd:.0f} %)")
    if score.pole_zero_share < MIN_POLE_ZERO_SHARE:
        notes.append("a zero nearly cancels a pole")
    if not score.converged:
        notes.append("search not converged")
    return "; ".join(notes)


def _delay_text(choice: StructureChoice, gain_unit: str) -> str:
    d = choice.delay
    n_shown = min(d.lags.size, max(d.delay_steps + 3, 6))
    rows = [[f"{int(lag)}", f"{b:.4g}", f"{s:.3g}",
             f"{abs(b) / s:.1f}" if s > 0 else "inf"]
            for lag, b, s in zip(d.lags[:n_shown], d.coefficients[:n_shown],
                                 d.std_errors[:n_shown], strict=True)]
    return (f"**Delay: {d.delay_steps} sample(s).** An ARX model with {d.lags.size} input "
            "coefficients and no delay estimates the first samples of the impulse response; "
            f"the delay is the first lag whose coefficient exceeds {d.threshold_sigma:g} standard "
            "errors and a tenth of the largest, 0 where none does (no evidence of a delay). "
            "The grid below tries the delays next to it and the paper's.\n\n"
            + format_table(["lag [samples]", f"coefficient [{gain_unit}]", "standard error",
                            "coefficient / error [-]"], rows, align="rrrr", markdown=True))


def _grid_text(choice: StructureChoice, v_unit: str) -> str:
    chosen_v = choice.v(choice.chosen)
    shown = sorted(choice.candidates, key=choice.v)[:GRID_ROWS]
    for extra in (choice.chosen, choice.paper):
        if extra is not None and extra not in shown:
            shown.append(extra)
    rows = [[f"{s.degree}, {s.nb}, {s.nf}, {s.nk}", str(s.n_parameters),
             f"{s.estimation_v_kw2:.4g}", f"{choice.v(s):.4g}",
             f"{choice.v(s) / chosen_v:.3g}" if chosen_v > 0 else "-",
             _grid_notes(s, choice)] for s in shown]
    how = ("the last third of each segment validates what the rest estimates"
           if choice.validation == "holdout" else
           "a short log: each half of the record estimates, the other validates")
    column = ("validation V" if choice.criterion == "validation"
              else "validation V, each block's initial state fitted")
    return (f"**Orders on validation data** ({how}): {len(choice.candidates)} Hammerstein-OE "
            f"structures, the {len(shown)} best by {column} shown. Chosen: "
            f"{choice.chosen.label()}. {choice.reason[:1].upper()}{choice.reason[1:]}. "
            "Held-out fit of the chosen: "
            f"{choice.validation_fit_percent:.1f} %.\n\n"
            + format_table(["degree, nb, nf, nk", "parameters", f"estimation V [{v_unit}]",
                            f"{column} [{v_unit}]", "V / chosen", "note"], rows,
                           align="lrrrrl", markdown=True))


def _rest_text(search: RestOESearch, v_unit: str, gain_unit: str) -> str:
    from sysid.rest_oe import NEAR_V_SHARE, PARSIMONY_RTOL, REST_GAIN_SPAN_FACTOR

    near = search.near()
    lowest = near[0].v_rest
    c = search.chosen
    rows = [[f"{f.nb}, {f.nf}, {f.nk}", str(f.n_parameters), f"{f.v_rest:.4g}",
             f"{f.v_rest / lowest:.3f}",
             "**chosen**" if (f.nb, f.nf, f.nk) == (c.nb, c.nf, c.nk) else ""] for f in near]
    if len(near) > 1:
        verdict = (f"{len(near)} of the {len(search.candidates)} structures lie within "
                   f"{100 * NEAR_V_SHARE:.0f} % of the lowest V from rest: the record does not single "
                   "out one structure, and adding or removing samples at its ends can move the "
                   "choice among these (their models predict alike). The chosen has the fewest "
                   f"parameters within {100 * PARSIMONY_RTOL:.0f} % of the lowest.")
    else:
        verdict = (f"Only the chosen of the {len(search.candidates)} structures lies within "
                   f"{100 * NEAR_V_SHARE:.0f} % of the lowest V from rest: the record singles it out.")
    left_out = len(search.candidates) - len(search.admissible)
    if left_out:
        verdict += (f" {left_out} structure(s) with a static gain above {search.max_abs_gain:.4g} "
                    f"{gain_unit} ({REST_GAIN_SPAN_FACTOR:g} times the recorded output span over "
                    "the input span) are not chosen and not listed: a pole next to z = 1 that "
                    "the record cannot tell from an integrator, whatever its V.")
    return (f"**Linear OE from rest** (nb, nf, nk: OE({c.nb}, {c.nf}, {c.nk}) chosen, V from "
            f"rest after a burn-in of {c.burn_in_steps} samples). {verdict}\n\n"
            + format_table(["nb, nf, nk", "parameters", f"V from rest [{v_unit}]",
                            "V / lowest", "note"], rows, align="lrrrl", markdown=True))


def structure_section(choice: StructureChoice | None, search: RestOESearch | None, *,
                      v_unit: str, gain_unit: str) -> str:
    """The report's ``## Structure selection`` section, or ``""`` with neither search run.

    Parameters
    ----------
    choice :
        The Hammerstein-OE structure search (`sysid.pipeline.PipelineResult.structure`).
    search :
        The OE-from-rest search (`sysid.pipeline.PipelineResult.rest_search`).
    v_unit :
        Unit of V, the output unit squared (``kW^2``).
    gain_unit :
        Unit of a gain, output per input unit (``kW/%``).
    """
    if choice is None and search is None:
        return ""
    parts = ["## Structure selection",
             "How sharply the record singles out a structure (as MATLAB's `delayest` and "
             "`selstruc` show it)."]
    if choice is not None:
        parts += [_delay_text(choice, gain_unit), _grid_text(choice, v_unit)]
    if search is not None:
        parts.append(_rest_text(search, v_unit, gain_unit))
    return "\n\n".join(parts)


def plot_structure_choice(
    lags_steps: Sequence[float] | np.ndarray,
    coefficients: Sequence[float] | np.ndarray,
    std_errors: Sequence[float] | np.ndarray,
    threshold_sigma: float,
    delay_steps: int,
    structures: Sequence[tuple[str, Sequence[float] | np.ndarray, Sequence[float] | np.ndarray,
                               int]],
    path: str | os.PathLike[str],
    *,
    gain_unit: str,
    v_unit: str,
    title: str = "Structure selection",
) -> Figure:
    """The delay's evidence (upper) and each search's V against its number of parameters (lower).

    Parameters
    ----------
    lags_steps, coefficients, std_errors :
        The delay ARX's input coefficients [output per input unit] and their standard
        errors at those lags [samples], shape ``(m,)`` each.
    threshold_sigma :
        Significance threshold [standard errors], drawn as a band ``+-threshold * error``.
    delay_steps :
        The estimated delay [samples], marked.
    structures :
        Per search ``(name, n_parameters, v, chosen_index)``: each structure's number of
        parameters and V [`v_unit`], and which one was chosen.
    path :
        PNG file to write.
    gain_unit, v_unit :
        Units of the coefficients and of V, for the axes.
    title :
        Figure title.

    Returns
    -------
    Figure

    Raises
    ------
    FigureError
        Arrays of different lengths, an empty search, or a chosen index out of range.
    """
    lags = vector(lags_steps, "lags_steps")
    coef = vector(coefficients, "coefficients", lags.size)
    err = vector(std_errors, "std_errors", lags.size)
    fig, (ax_d, ax_v) = stacked_axes(2, sharex=False)
    ax_d.bar(lags, coef, width=0.6, color="tab:blue", label="ARX input coefficient")
    ax_d.fill_between(lags, -threshold_sigma * err, threshold_sigma * err, step="mid",
                      color="tab:gray", alpha=0.3, label=f"+-{threshold_sigma:g} standard errors")
    ax_d.axvline(delay_steps, color="tab:red", linestyle="--",
                 label=f"estimated delay {delay_steps} sample(s)")
    ax_d.set_xlabel("lag [samples]")
    ax_d.set_ylabel(f"coefficient [{gain_unit}]")
    legend_above(ax_d)
    for i, (name, n_par, v, chosen) in enumerate(structures):
        p = vector(n_par, f"{name} n_parameters")
        vv = vector(v, f"{name} v", p.size)
        if not 0 <= chosen < p.size:
            raise FigureError(f"plot_structure_choice: chosen index {chosen} of {name} is "
                              f"outside its {p.size} structures")
        offset = 0.12 * (i - (len(structures) - 1) / 2)     # side by side at each count
        ax_v.scatter(p + offset, vv, s=14, color=f"C{i}", alpha=0.7, label=name)
        ax_v.scatter([p[chosen] + offset], [vv[chosen]], s=90, facecolors="none",
                     edgecolors=f"C{i}", linewidths=1.8, label=f"{name}: chosen")
    ax_v.set_yscale("log")
    ax_v.set_xlabel("parameters [-]")
    ax_v.set_ylabel(f"V [{v_unit}]")
    legend_above(ax_v)
    fig.suptitle(title)
    return save_figure(fig, path)


def draw_structure_choice(choice: StructureChoice, search: RestOESearch | None,
                          path: str | os.PathLike[str], *, gain_unit: str, v_unit: str,
                          title: str = "Structure selection") -> Figure:
    """`plot_structure_choice` of the searches' results: the delay ARX, then the grid's
    V on its choice's criterion (`StructureChoice.v`) and, if run, the OE-from-rest V."""
    grid = list(choice.candidates)
    name = ("Hammerstein-OE, validation V" if choice.criterion == "validation"
            else "Hammerstein-OE, validation V (initial states fitted)")
    structures: list[tuple[str, list[float], list[float], int]] = [
        (name, [float(s.n_parameters) for s in grid], [choice.v(s) for s in grid],
         grid.index(choice.chosen))]
    if search is not None:
        fits = list(search.candidates)
        structures.append(("linear OE, V from rest", [float(f.n_parameters) for f in fits],
                           [f.v_rest for f in fits], fits.index(search.chosen)))
    d = choice.delay
    return plot_structure_choice(d.lags, d.coefficients, d.std_errors, d.threshold_sigma,
                                 d.delay_steps, structures, path, gain_unit=gain_unit,
                                 v_unit=v_unit, title=title)


__all__ = ["GRID_ROWS", "draw_structure_choice", "plot_structure_choice", "structure_section"]
