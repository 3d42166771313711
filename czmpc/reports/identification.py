"""Assemble the identification report (report.md and its figures) from a pipeline result.

`write_report` draws the paper's figures from a `sysid.pipeline.PipelineResult` with
`czmpc.reports.identification_figures`, then writes report.md: the data, the preprocessing
and repairs, the analogues of Tables 2 and 3, the Hammerstein route, the final model and a
checklist of the paper's findings (`findings_checklist`, also for tools that read the
verdicts), each with the paper's value (the ``PAPER_*`` constants, Komperød et al.) beside ours.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from czmpc.reports import identification_figures as figs
from czmpc.reports.structure_report import draw_structure_choice, structure_section
from czmpc.reports.tables import format_table
from sim.experiment import PAPER_TABLE3, PAPER_TRIAC_NOM_PCT
from sysid._version import SOFTWARE
from sysid.atomic import atomic_write_text
from sysid.optimize import DEFAULT_PROGRESS_RTOL, MAX_ITERATIONS, PROGRESS_WINDOW

if TYPE_CHECKING:
    from sysid.model import HammersteinModel
    from sysid.pipeline import NamedModel, PipelineResult
    from sysid.steps import InputStep

#: Table 2: V [kW^2] of the linear models, by pipeline model name.
PAPER_TABLE2_V: dict[str, float] = {
    "arx_1_2": 0.106, "arx_2_3": 0.109, "armax_1_2_1": 0.108, "armax_2_3_2": 0.110,
    "oe_2_1": 0.043, "oe_3_2": 0.042,
}
#: Secs. 7.4-7.6: V [kW^2] of every step of the Hammerstein route.
PAPER_ROUTE_V: dict[str, float] = {
    "hammerstein_eq21": 0.045,               # Fig. 12
    "hammerstein_arx_reidentified": 0.024,   # Fig. 13
    "hammerstein_oe_reidentified": 0.008,    # Fig. 13
    "hammerstein_oe": 0.007,                 # Figs. 15-16, eq. 27
    "hammerstein_oe_from_zeros": 0.007,      # sec. 7.5: the same parameters
    "hammerstein_armax": 0.032,              # sec. 7.6, eq. 30
}
#: Sec. 7.5: iterations of the final PEM from good initial values and from zeros.
PAPER_ITERATIONS = {"hammerstein_oe": 3, "hammerstein_oe_from_zeros": 17}
#: Sec. 7.6, Fig. 18: W [kW^2] of ARMAX(1,2,1) and of the noise-model Hammerstein.
PAPER_W = {"armax_1_2_1": 3.1e-4, "hammerstein_armax": 1.8e-4}
#: Sec. 7.6: the noise-model Hammerstein's W is 42 % below the ARMAX model's.
PAPER_W_REDUCTION = 0.42
#: Sec. 7.5: V of OE(2,1) over V of the final Hammerstein ("a factor of six").
PAPER_V_RATIO = 0.043 / 0.007

#: Thresholds of the findings checklist (issue 3).
HIGHER_ORDER_MAX_IMPROVEMENT = 0.10
HAMMERSTEIN_MIN_V_RATIO = 3.0
NOISE_MODEL_MIN_W_REDUCTION = 0.25
FROM_ZEROS_MAX_RELATIVE_DIFFERENCE = 1e-4

#: Half width of the outlier zoom figures (paper figs. 4-5) [s].
ZOOM_HALF_WIDTH_S = 60.0
#: Most outlier candidates drawn zoomed, those of largest peak residual (the paper draws
#: two; a logger that holds samples gave 75 candidates, and 449 figures took 150 s).
MAX_ZOOM_FIGURES = 6

Verdict = Literal["shown", "not shown", "not measured"]


@dataclass(frozen=True, kw_only=True)
class Finding:
    """One of the paper's findings, checked on our data.

    Parameters
    ----------
    claim :
        The finding in words, with its threshold.
    paper :
        What the paper reports for it.
    ours :
        What our data give, with the numbers.
    verdict :
        ``"shown"``, ``"not shown"`` or ``"not measured"`` (a model it needs is missing).
    """

    claim: str
    paper: str
    ours: str
    verdict: Verdict


@dataclass(frozen=True, kw_only=True)
class ReportFiles:
    """What `write_report` wrote.

    Parameters
    ----------
    report_path :
        The Markdown report.
    figure_files :
        Every PNG, in the order the report shows them.
    """

    report_path: Path
    figure_files: tuple[Path, ...]


# --- how the report speaks of the data --------------------------------------------------

#: Units of the paper's experiment: data in these units get the paper's names and,
#: unless told otherwise, its values beside ours.
PAPER_UNITS = ("%", "kW")


@dataclass(frozen=True, kw_only=True)
class _Style:
    """Names, units and symbols of the data, and whether the paper's values are shown."""

    paper: bool
    in_name: str
    out_name: str
    in_unit: str
    out_unit: str
    in_sym: str
    out_sym: str

    @property
    def labels(self) -> dict[str, str]:
        if (self.in_name, self.out_name, self.in_unit, self.out_unit) == (
                "TRIAC input s", "heater power P", *PAPER_UNITS):
            return dict(figs.AXIS_LABELS)
        return figs.axis_labels(input_name=self.in_name, input_unit=self.in_unit,
                                output_name=self.out_name, output_unit=self.out_unit,
                                input_symbol=self.in_sym, output_symbol=self.out_sym)

    @property
    def v_unit(self) -> str:
        return f"{self.out_unit}^2"

    @property
    def gain_unit(self) -> str:
        return f"{self.out_unit}/{self.in_unit}"

    def title(self, text: str, paper_part: str) -> str:
        """A figure title or section heading, with the paper's part named only when the paper is shown."""
        return f"{text} ({paper_part})" if self.paper else text

    def paper_note(self, text: str) -> str:
        """``text`` (what the paper found) when the paper is shown, else nothing."""
        return text if self.paper else ""


def load_record(result: PipelineResult) -> Mapping[str, Any] | None:
    """The ``load_log`` entry of the raw data's preprocessing (how the log was read), if any."""
    return next((step for step in result.raw_data.preprocessing
                 if step.get("what") == "load_log"), None)


def _style(result: PipelineResult, reference: bool | None) -> _Style:
    raw = result.raw_data
    units = (raw.input_unit, raw.output_unit)
    puller = units == PAPER_UNITS
    record = load_record(result)
    columns = {} if record is None else dict(record.get("columns") or {})
    in_col = columns.get("triac_pct", "triac_pct")
    out_col = columns.get("power_kw", "power_kw")
    if puller and in_col == "triac_pct" and out_col == "power_kw":
        in_name, out_name = "TRIAC input s", "heater power P"
    else:
        in_name, out_name = f"input {in_col}", f"output {out_col}"
    return _Style(paper=puller if reference is None else reference, in_name=in_name,
                  out_name=out_name, in_unit=raw.input_unit, out_unit=raw.output_unit,
                  in_sym="ds" if puller else "du", out_sym="dP" if puller else "dy")


# --- small helpers ---------------------------------------------------------------------

def _models(result: PipelineResult) -> dict[str, NamedModel]:
    return {m.name: m for m in result.models}


def _num(value: float | None, spec: str = ".4g") -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return format(value, spec)


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]], align: str | None = None) -> str:
    return format_table(header, rows, align=align, markdown=True)


def _lagged_sum(coefs: Sequence[float] | np.ndarray, term: Callable[[str], str]) -> str:
    """``sum_i coefs[i] term(k-i)`` as text, e.g. ``dP_k - 0.99 dP_{k-1}``."""
    parts: list[str] = []
    for lag, c in enumerate(coefs):
        if c == 0.0:
            continue
        sym = term("k" if lag == 0 else f"{{k-{lag}}}")
        mag = abs(float(c))
        body = sym if mag == 1.0 else f"{mag:.6g} {sym}"
        if not parts:
            parts.append(body if c > 0 else f"-{body}")
        else:
            parts.append(("- " if c < 0 else "+ ") + body)
    return " ".join(parts) if parts else "0"


def model_equation(model: HammersteinModel, *, input_symbol: str = "ds",
                   output_symbol: str = "dP", output_unit: str | None = None) -> str:
    """The model's difference equation in the paper's notation (eqs. 27, 30), as text.

    Parameters
    ----------
    model :
        A `sysid.model.HammersteinModel`.
    input_symbol, output_symbol :
        Names of the input and output deviations (``ds``, ``dP`` for the puller).
    output_unit :
        Unit of ``f``; default the model's output unit.

    Returns
    -------
    str
        Two lines: the difference equation in ``dP``, ``f(ds)`` and the error, and ``f``.
    """
    lhs = _lagged_sum(model.a, lambda k: f"{output_symbol}_{k}")
    rhs = _lagged_sum(model.b, lambda k: f"f({input_symbol}_{k})")
    if model.linear_block == "oe":
        noise = "eps_k   (output error: no noise model)"
    elif model.linear_block == "arx":
        noise = "e_k"
    else:
        noise = _lagged_sum(model.c, lambda k: f"e_{k}")
    f_terms = ""
    for power, p in enumerate(model.input_poly, start=1):
        term = input_symbol if power == 1 else f"{input_symbol}^{power}"
        sign = ("-" if p < 0 else "") if not f_terms else (" - " if p < 0 else " + ")
        f_terms += f"{sign}{abs(float(p)):.6g} {term}"
    unit = model.effective_units.output if output_unit is None else output_unit
    return f"{lhs} = {rhs} + {noise}\nf({input_symbol}) = {f_terms}   [{unit}]"


# --- findings --------------------------------------------------------------------------

def findings_checklist(result: PipelineResult) -> tuple[Finding, ...]:
    """The issue's five findings of the paper, each checked on the pipeline's models.

    Parameters
    ----------
    result :
        A `sysid.pipeline.PipelineResult` run with the paper's base orders
        (``nb = 2``, ``nf = 1``, ``nk = 1``).

    Returns
    -------
    tuple of Finding
        In order: OE beats ARX/ARMAX on V (Table 2); one order more improves each
        family's own criterion by at most 10 % (Table 2,
        `sysid.pipeline.OrderComparison`); final Hammerstein V at least 3x below
        OE(2,1) with one more parameter (sec. 7.5); noise-model Hammerstein W at least 25 % below
        ARMAX(1,2,1) (sec. 7.6); PEM from zeros reaches the same parameters (max
        relative difference < 1e-4, sec. 7.5).
    """
    m = _models(result)
    out: list[Finding] = []
    u2 = f"{result.raw_data.output_unit}^2"

    def add(claim: str, paper: str, measured: str | tuple[str, bool]) -> None:
        """Record a finding: ``(ours, shown)``, or why it was not measured."""
        if isinstance(measured, str):
            out.append(Finding(claim=claim, paper=paper, ours=measured, verdict="not measured"))
        else:
            out.append(Finding(claim=claim, paper=paper, ours=measured[0],
                               verdict="shown" if measured[1] else "not shown"))

    arx, armax, oe = m.get("arx_1_2"), m.get("armax_1_2_1"), m.get("oe_2_1")
    add("OE(2,1) has a lower V than ARX(1,2) and ARMAX(1,2,1) (Table 2)",
        "V: OE 0.043 vs ARX 0.106, ARMAX 0.108",
        "a model is missing" if arx is None or armax is None or oe is None else (
            f"V: OE {oe.ballistic_mse_kw2:.4g} vs ARX {arx.ballistic_mse_kw2:.4g}, "
            f"ARMAX {armax.ballistic_mse_kw2:.4g} {u2}",
            oe.ballistic_mse_kw2 < min(arx.ballistic_mse_kw2, armax.ballistic_mse_kw2)))

    comparisons = result.findings.higher_order_comparisons
    add(f"one order more improves each family's own criterion (W for ARX and ARMAX, "
        f"V for OE) by at most {100 * HIGHER_ORDER_MAX_IMPROVEMENT:.0f} % "
        "(Table 2: the base orders suffice)",
        "V: ARX 0.106 -> 0.109, ARMAX 0.108 -> 0.110, OE 0.043 -> 0.042 (at most 2 %)",
        "models missing" if not comparisons else (
            ", ".join(f"{c.criterion} {c.family.upper()} {c.base_kw2:.4g} -> {c.high_kw2:.4g} "
                      f"({-100 * c.improvement:+.1f} %)" for c in comparisons) + f" {u2}",
            max(c.improvement for c in comparisons) <= HIGHER_ORDER_MAX_IMPROVEMENT))

    final_oe = m.get("hammerstein_oe")
    ratio = (math.nan if final_oe is None or oe is None
             else oe.ballistic_mse_kw2 / final_oe.ballistic_mse_kw2)
    add(f"the final Hammerstein (eq. 27) has V at least {HAMMERSTEIN_MIN_V_RATIO:g}x below "
        "OE(2,1) with one parameter more (sec. 7.5)",
        f"0.043 / 0.007 = {PAPER_V_RATIO:.1f}x with 4 vs 3 parameters",
        "a model is missing" if final_oe is None or oe is None else (
            f"{oe.ballistic_mse_kw2:.4g} / {final_oe.ballistic_mse_kw2:.4g} = {ratio:.1f}x with "
            f"{final_oe.n_parameters} vs {oe.n_parameters} parameters",
            ratio >= HAMMERSTEIN_MIN_V_RATIO and final_oe.n_parameters == oe.n_parameters + 1))

    noise = m.get("hammerstein_armax")
    red = (math.nan if noise is None or armax is None
           else 1.0 - noise.one_step_mse_kw2 / armax.one_step_mse_kw2)
    add(f"the noise-model Hammerstein (eq. 30) has W at least "
        f"{100 * NOISE_MODEL_MIN_W_REDUCTION:.0f} % below ARMAX(1,2,1) (sec. 7.6, Fig. 18)",
        "W 3.1e-4 -> 1.8e-4 kW^2, 42 % lower",
        "a model is missing" if noise is None or armax is None else (
            f"W {armax.one_step_mse_kw2:.3g} -> {noise.one_step_mse_kw2:.3g} {u2}, "
            f"{100 * red:.0f} % lower", red >= NOISE_MODEL_MIN_W_REDUCTION))

    f = result.findings
    d = f.from_zeros_relative_difference
    add(f"the final PEM from zeros reaches the same parameters as from good initial values "
        f"(max relative difference < {FROM_ZEROS_MAX_RELATIVE_DIFFERENCE:g}; sec. 7.5)",
        "the same parameters; 3 iterations from good values, 17 from zeros",
        "PEM from zeros not run" if d is None else (
            f"max relative difference {d:.2g}; {f.iterations_from_initial_values} iterations "
            f"from good values, {f.iterations_from_zeros} from zeros",
            d < FROM_ZEROS_MAX_RELATIVE_DIFFERENCE))
    return tuple(out)


# --- figures ---------------------------------------------------------------------------

@dataclass(frozen=True, kw_only=True)
class _Figure:
    key: str
    caption: str
    path: Path


def _pred_error(model: HammersteinModel, result: PipelineResult) -> np.ndarray:
    from sysid.simulate import predict_one_step

    return np.asarray(result.data.power_kw) - np.asarray(predict_one_step(model, result.data))


def _draw_figures(result: PipelineResult, fig_dir: Path, st: _Style) -> list[_Figure]:
    """Draw every figure the result supports; return them in report order."""
    from sysid.errors import SysidError
    from sysid.residuals import CorrelationResult, autocorrelation, cross_correlation
    from sysid.simulate import simulate

    m = _models(result)
    raw = result.raw_data
    op = result.operating_point.operating_point
    t = np.asarray(result.data.time_s)
    ds = np.asarray(result.data.triac_pct) - op.triac_pct
    dp = np.asarray(result.data.power_kw) - op.power_kw
    drawn: list[_Figure] = []
    lab = st.labels

    def add(key: str, caption: str, draw: Callable[[Path], object]) -> None:
        path = fig_dir / f"{key}.png"
        draw(path)
        drawn.append(_Figure(key=key, caption=caption, path=path))

    def add_plot(key: str, caption: str, plot: Callable[..., object], *arrays: Any, title: str,
                 paper_part: str, **options: Any) -> None:
        """Draw ``plot(*arrays, path, **options)``: the report's axis labels, `_Style.title`'s title."""
        add(key, caption, lambda p: plot(*arrays, p, labels=lab, title=st.title(title, paper_part),
                                         **options))

    add_plot("fig02_data", f"Fig. 2 analogue: the logged data ({st.in_name} [{st.in_unit}] "
             f"and {st.out_name} [{st.out_unit}]).",
             figs.plot_dataset, raw.time_s, raw.triac_pct, raw.power_kw,
             title="Logged data", paper_part="paper Fig. 2")
    out = result.outliers
    if out is not None:
        add_plot("fig03_residuals_before", "Fig. 3 analogue: one-step residuals of ARX"
                 f"({out.na},{out.nb}) on the raw data; outlier candidates marked.",
                 figs.plot_residuals, raw.time_s,
                 {f"ARX({out.na},{out.nb}) on raw data": out.residuals_kw},
                 marked_time_s=[c.time_s for c in out.candidates],
                 title=f"Residuals of ARX({out.na},{out.nb})", paper_part="paper Fig. 3")
        numbered = list(enumerate(out.candidates, start=1))
        drawn_zooms = sorted(numbered, key=lambda ic: -abs(ic[1].peak_residual_kw))[
            :MAX_ZOOM_FIGURES]
        of_many = (f" (one of the {MAX_ZOOM_FIGURES} of largest peak residual among "
                   f"{len(numbered)})" if len(numbered) > MAX_ZOOM_FIGURES else "")
        for i, cand in sorted(drawn_zooms, key=lambda ic: ic[0]):
            add_plot(f"fig04_zoom_{i}",
                     f"Figs. 4-5 analogue: candidate {i} ({cand.kind}) at t = {cand.time_s:g} s, "
                     f"zoomed{of_many}.",
                     figs.plot_outlier_zoom, raw.time_s, out.residuals_kw,
                     np.asarray(raw.power_kw) - op.power_kw, cand.time_s,
                     half_width_s=ZOOM_HALF_WIDTH_S,
                     title=f"Outlier candidate {i}: {cand.kind} at {cand.time_s:g} s",
                     paper_part="paper Figs. 4-5")
    after = result.outliers_after
    if after is not None:
        add_plot("fig06_residuals_after", "Fig. 6 analogue: residuals of the same ARX model after "
                 "the repairs; remaining candidates marked.",
                 figs.plot_residuals, t,
                 {f"ARX({after.na},{after.nb}) after repairs": after.residuals_kw},
                 marked_time_s=[c.time_s for c in after.candidates],
                 title="Residuals after handling outliers", paper_part="paper Fig. 6")
    repair_times = [float(step.get("time_s", step.get("from_time_s", math.nan)))
                    for step in result.data.preprocessing
                    if "time_s" in step or "from_time_s" in step]
    add_plot("fig07_preprocessed", "Fig. 7 analogue: the preprocessed data as deviations from the "
             "operating point; repairs marked.",
             figs.plot_dataset, t, ds, dp, deviation=True, marked_time_s=repair_times,
             marked_label="repair", title="Preprocessed data", paper_part="paper Fig. 7")

    def sims(pairs: Sequence[tuple[str, str]]) -> dict[str, np.ndarray]:
        """Legend label (with V) -> ballistic simulation [kW, deviation] of each named model."""
        return {f"{short}, V = {m[n].ballistic_mse_kw2:.3g} {st.v_unit}":
                np.asarray(simulate(m[n].model, result.data), dtype=float)
                - float(m[n].model.operating_point.power_kw) for n, short in pairs}

    def add_sims(key: str, caption: str, curves: dict[str, np.ndarray], title: str,
                 paper_fig: str) -> None:
        add_plot(key, caption, figs.plot_simulations, t, dp, curves, input_pct=ds, title=title,
                 paper_part=paper_fig)

    choice = result.structure
    if choice is not None:
        add("structure_choice", "Structure selection: the delay's evidence (the ARX input "
            "coefficients against their significance band) and each search's V against its "
            "number of parameters, the chosen structure ringed.",
            lambda p: draw_structure_choice(choice, result.rest_search, p,
                                            gain_unit=st.gain_unit, v_unit=st.v_unit))
    lin = [(n, s) for n, s in (("arx_1_2", "ARX(1,2)"), ("armax_1_2_1", "ARMAX(1,2,1)"),
                               ("oe_2_1", "OE(2,1)")) if n in m]
    if lin:
        curves8 = sims(lin)
        add_sims("fig08_linear_simulations", "Fig. 8 analogue: ballistic simulations of the "
                 f"linear models against the measured {st.out_name}.", curves8,
                 "Ballistic simulations, linear models", "paper Fig. 8")
        add_plot("fig09_linear_errors", "Fig. 9 analogue: ballistic simulation errors of the "
                 "linear models.", figs.plot_simulation_errors, t,
                 {s: dp - sim for (_, s), sim in zip(lin, curves8.values(), strict=True)},
                 title="Simulation errors, linear models", paper_part="paper Fig. 9")
    if "hammerstein_eq21" in m:
        add_sims("fig12_eq21", "Fig. 12 analogue: the Hammerstein model of eq. 21 (ARX block, f "
                 "from the step gains) against ARX(1,2) and the measurement.",
                 sims([("hammerstein_eq21", "Hammerstein, eq. 21")]
                      + [("arx_1_2", "ARX(1,2)")] * ("arx_1_2" in m)),
                 "Hammerstein from eq. 21 vs ARX", "paper Fig. 12")
    re = [(n, s) for n, s in (("hammerstein_arx_reidentified", "Hammerstein, ARX-reidentified"),
                              ("hammerstein_oe_reidentified", "Hammerstein, OE-reidentified"))
          if n in m]
    if re:
        add_sims("fig13_reidentified", "Fig. 13 analogue: Hammerstein models with f fixed and "
                 "the linear block re-identified by ARX and by OE.", sims(re),
                 "Re-identified Hammerstein models", "paper Fig. 13")
    if "hammerstein_oe" in m:
        final15 = sims([("hammerstein_oe", "final Hammerstein (eq. 27)")])
        add_sims("fig15_final_simulation", "Fig. 15 analogue: ballistic simulation of the final "
                 "Hammerstein model (eq. 27).", final15, "Final Hammerstein model", "paper Fig. 15")
        add_plot("fig16_final_error", "Fig. 16 analogue: its ballistic simulation error.",
                 figs.plot_simulation_errors, t,
                 {"final Hammerstein (eq. 27)": dp - next(iter(final15.values()))},
                 title="Simulation error, final Hammerstein", paper_part="paper Fig. 16")
    if "armax_1_2_1" in m and "hammerstein_armax" in m:
        e_lin = _pred_error(m["armax_1_2_1"].model, result)
        e_ham = _pred_error(m["hammerstein_armax"].model, result)
        add_plot("fig18_one_step_errors", "Fig. 18 analogue: one-step-ahead prediction errors of "
                 "ARMAX(1,2,1) (upper) and the noise-model Hammerstein of eq. 30 (lower).",
                 figs.plot_residuals, t,
                 {"ARMAX(1,2,1)": e_lin, "Hammerstein with noise model (eq. 30)": e_ham},
                 title="One-step-ahead prediction errors", paper_part="paper Fig. 18")
    final = result.final
    if final is not None:
        e = _pred_error(final.model, result)
        tests: tuple[CorrelationResult, CorrelationResult] | None
        try:
            tests = (autocorrelation(e), cross_correlation(e, ds))
        except SysidError:  # a constant residual or input: no test to draw
            tests = None
        if tests is not None:
            auto, cross = tests
            add("residual_tests", f"Residual tests of the model in model.json ({final.label}): "
                f"autocorrelation of its one-step errors and their cross-correlation with {st.in_sym}, "
                "with 99 % bounds.",
                lambda p: figs.plot_correlations(
                    auto.lags, auto.values, auto.bound, cross.lags, cross.values, cross.bound, p,
                    labels=lab, title=f"Residual tests: {final.label}"))
    gain_models = [(n, s) for n, s in (("hammerstein_eq21", "eq. 21 initial"),
                                       ("hammerstein_oe", "final (eq. 27)"),
                                       ("hammerstein_armax", "noise model (eq. 30)")) if n in m]
    if gain_models and result.steps:
        mid = np.array([0.5 * (s.triac_before_pct + s.triac_after_pct) - op.triac_pct
                        for s in result.steps])
        r = np.array([s.gain_kw_per_pct for s in result.steps])
        grid = np.linspace(float(np.min(ds)), float(np.max(ds)), 101)
        curves_g = {f"{s}: b1 f'({st.in_sym})": _instant_gain(m[n].model, grid) for n, s in gain_models}
        add_plot("gain_curve", "Table 3 analogue: the instantaneous gain of each Hammerstein model "
                 "against the measured step gains r (at each step's midpoint, where a quadratic f's "
                 "secant slope equals f').",
                 figs.plot_gain_curve, grid, curves_g, step_ds_pct=mid, step_gain_kw_per_pct=r,
                 title=f"Instantaneous gain f'({st.in_sym}) vs step gains r", paper_part="Table 3")
    return drawn


def _instant_gain(model: HammersteinModel, ds_grid: np.ndarray) -> np.ndarray:
    """Gain of the first output sample after an input step: ``b_nk f'(ds)`` [kW/%]."""
    b_first = float(model.b[model.delay_steps])
    return b_first * np.asarray(model.input_nonlinearity_slope(ds_grid), dtype=float)


# --- the report ------------------------------------------------------------------------

def _data_section(result: PipelineResult, st: _Style) -> str:
    raw = result.raw_data
    src = raw.source or "(in memory)"
    rows = [
        ["file", f"`{src}`"],
        ["samples", f"{raw.n_samples}"],
        ["sampling time Ts", f"{raw.ts_s:g} s"],
        ["time", f"{raw.time_s[0]:g} .. {raw.time_s[-1]:g} s ({raw.duration_s / 3600:.2f} h)"],
        [st.in_name, f"{np.min(raw.triac_pct):.4g} .. {np.max(raw.triac_pct):.4g} {raw.input_unit}"],
        [st.out_name, f"{np.min(raw.power_kw):.4g} .. {np.max(raw.power_kw):.4g} {raw.output_unit}"],
        ["sha256", f"`{raw.sha256 or '-'}`"],
    ]
    if raw.n_segments > 1:
        rows.insert(2, ["segments", f"{raw.n_segments}, all used, each with its own initial "
                                    "state (starting at samples "
                                    + ", ".join(str(k) for k in raw.segment_starts) + ")"])
    record = load_record(result)
    if record is not None:
        rows += _load_rows(record)
    return "## Data\n\n" + _md_table(["", "value"], rows, "ll")


def _load_rows(record: Mapping[str, Any]) -> list[list[str]]:
    """Rows of the data table saying how the log was read (`sysid.historian`)."""
    fmt = str(record.get("format"))
    if fmt == "csv":
        fmt += f", separator {record.get('separator')!r}, decimal {record.get('decimal')!r}"
    columns = record.get("columns") or {}
    rows = [["format", fmt],
            ["columns", ", ".join(f"{k} = `{v}`" for k, v in columns.items())],
            ["time", "seconds" if record.get("time_format") == "seconds"
             else f"time stamps, t = 0 at {record.get('time_origin')}"],
            ["missing data", f"{record.get('n_missing_cells')} empty/NaN cell(s), "
             f"{record.get('n_gap_samples')} missing sampling instant(s); policy "
             f"`--gaps {record.get('gaps')}`"
             + (f" (runs of at most {record.get('fill_max_samples')} filled)"
                if record.get("gaps") == "fill" else "")],
            ["changes", f"{record.get('n_filled')} sample(s) filled, {record.get('n_dropped')} "
             f"dropped, {record.get('n_segments')} segment(s)"],
            ["time stamps", "resampled by linear interpolation onto t0 + k Ts"
             if record.get("resampled") else
             f"{record.get('n_snapped')} snapped onto t0 + k Ts (largest jitter "
             f"{100 * float(record.get('max_jitter_fraction_of_ts') or 0.0):.3g} % of Ts; "
             "`--resample snap`)"]]
    return rows


def _describe_repair(step: Mapping[str, Any], unit: str = "kW") -> tuple[str, str, str]:
    what = str(step.get("what", "?"))
    if what == "interpolate_spike":
        where = f"sample {step.get('sample')} (t = {step.get('time_s')} s)"
        how = (f"{step.get('old_value')} -> {_num(step.get('new_value'), '.6g')} {unit} "
               "(mean of the neighbours)")
    elif what == "correct_level_shift":
        where = f"t >= {step.get('from_time_s')} s (sample {step.get('from_sample')} on)"
        how = (f"{_num(step.get('shift_kw'), '.4g')} {unit} subtracted from "
               f"{step.get('n_samples_changed')} samples")
    elif what == "load_log":
        where, how = "whole log", "read under the policies in the Data table"
    else:
        keys = {k: v for k, v in step.items() if k != "what"}
        where, how = "", ", ".join(f"{k} = {v}" for k, v in keys.items())
    return what, where, how


def _preprocessing_section(result: PipelineResult, st: _Style) -> str:
    choice = result.operating_point
    op = choice.operating_point
    u, y = st.in_unit, st.out_unit
    how = {"given": "given on the command line",
           "means": ("sample means of the record (no steady window found)"
                     if choice.power_offset_kw == 0.0 else
                     f"sample means of the record (no steady window found), the output's moved "
                     f"by {choice.power_offset_kw:+.4g} {y} onto the steady-state curve "
                     "(sysid.offset)"),
           "steady": ("means over the steady window nearest the middle of the input range "
                      "(paper sec. 5.1)")}[choice.method]
    lines = ["## Preprocessing (paper sec. 5)", "",
             f"Operating point: **{st.in_sym[1:]}_nom = {op.triac_pct:.4g} {u}, "
             f"{st.out_sym[1:]}_nom = {op.power_kw:.4g} {y}**, {how}."]
    w = choice.window
    if w is not None:
        lines.append(
            f"Steady window t = {w.start_time_s:g} .. {w.end_time_s:g} s (samples {w.start_sample}.."
            f"{w.stop_sample}); output std {w.output_std_kw:.3g} {y}, drift {w.output_drift_kw:.3g} {y}."
            + st.paper_note(" The paper found t in [8700, 10300] s at (45 %, 45 kW)."))
    out = result.outliers
    lines.append("")
    if out is None:
        lines.append("Outlier search: not run.")
    else:
        lines.append(
            f"Outlier candidates from the one-step residuals of ARX({out.na},{out.nb}) with delay "
            f"{out.nk} (paper Fig. 3): threshold {out.threshold:g} robust scales = "
            f"{out.threshold_kw:.3g} {y} (scale {out.scale_kw:.3g} {y}). {len(out.step_residuals)} "
            "large-residual event(s) right after input steps are model imperfection, not outliers, "
            f"and are excluded. {len(out.candidates)} candidate(s) remain"
            + st.paper_note(" (the paper found two: a one-sample power drop and a 0.15 kW level "
                            "shift at t = 20714 s)") + ":")
        lines.append("")
        if out.candidates:
            rows = [[str(i), f"{c.time_s:g}", str(c.sample), c.kind, f"{c.peak_residual_kw:+.3g}",
                     f"{c.output_jump_kw:+.3g}", f"{c.persisting_change_kw:+.3g}"]
                    for i, c in enumerate(out.candidates, start=1)]
            lines.append(_md_table(["#", "t [s]", "sample", "kind", f"peak residual [{y}]",
                                    f"output jump [{y}]", f"persisting change [{y}]"], rows,
                                   "rrrlrrr"))
        if out.clipped_samples:
            lines.append(f"\n{len(out.clipped_samples)} sample(s) sit in a constant run at the output's "
                         "extreme (possible sensor clipping); reported, not repaired.")
    lines += ["", "Changes made to the data (each is recorded in every model file's provenance):",
              ""]
    repairs = list(result.data.preprocessing)
    if repairs:
        lines.append(_md_table(["what", "where", "how much"],
                               [list(_describe_repair(s, y)) for s in repairs], "lll"))
        if st.paper:
            lines.append("\nThe paper replaced the spike by the mean of its neighbours and "
                         "subtracted 0.15 kW from dP for t >= 20714 s.")
    else:
        lines.append("none.")
    left = [s for s in result.skipped if s.startswith("level shift") and "not corrected" in s]
    if left:
        lines.append("\nNot repaired:\n")
        lines += [f"- {s[0].upper()}{s[1:]}." for s in left]
    after = result.outliers_after
    if after is not None:
        lines.append(f"\nAfter the repairs the same search finds {len(after.candidates)} candidate(s)"
                     + st.paper_note(" (paper Fig. 6: none)") + ".")
    return "\n".join(lines)


def _criteria_cells(nm: NamedModel) -> list[str]:
    """A model's V (marked if its search did not converge), W, parameter and iteration counts."""
    conv = "" if nm.converged else " (not converged)"
    return [f"{nm.ballistic_mse_kw2:.4g}{conv}", f"{nm.one_step_mse_kw2:.3g}",
            str(nm.n_parameters), str(nm.n_iterations)]


def _criteria_table(first_column: str, rows: Sequence[Sequence[str]], st: _Style,
                    paper_columns: Sequence[str]) -> str:
    """Markdown table of rows of a name and its `_criteria_cells`, then ``paper_columns`` if shown."""
    header = [first_column, f"V [{st.v_unit}]", f"W [{st.v_unit}]", "parameters", "iterations"]
    if st.paper:
        header += paper_columns
    return _md_table(header, rows, "l" + "r" * (len(header) - 1))


def _table2_section(result: PipelineResult, st: _Style) -> str:
    rows = [[nm.label, *_criteria_cells(nm)]
            + ([_num(PAPER_TABLE2_V.get(nm.name), ".3f")] if st.paper else [])
            for nm in result.linear]
    nk = result.final.model.delay_steps if result.final is not None else 1
    return (st.title("## Linear models", "paper Table 2")
            + f"\n\nAll with a delay of {nk} sample(s). V: mean squared "
            "ballistic simulation error (eq. 9); W: mean squared one-step-ahead prediction error "
            "(eq. 10); ARX by least squares, ARMAX on W, OE on V.\n\n"
            + (_criteria_table("model", rows, st, ["paper V [kW^2]"]) if rows
               else "No linear model could be fitted."))


def _match_paper_step(step: InputStep) -> tuple[float, float, float, float, float] | None:
    """The paper's Table 3 row of the same absolute input step (the paper's s_nom = 45 %)."""
    before = step.triac_before_pct - PAPER_TRIAC_NOM_PCT
    after = step.triac_after_pct - PAPER_TRIAC_NOM_PCT
    return next((row for row in PAPER_TABLE3
                 if abs(before - row[0]) < 0.5 and abs(after - row[1]) < 0.5), None)


def _table3_section(result: PipelineResult, st: _Style) -> str:
    op = result.operating_point.operating_point
    u, y, ds, dp = st.in_unit, st.out_unit, st.in_sym, st.out_sym
    rows = []
    for step in result.steps:
        paper = _match_paper_step(step)
        row = [
            f"{step.time_s:g}",
            f"{step.triac_before_pct:.4g} -> {step.triac_after_pct:.4g}",
            f"{step.triac_before_pct - op.triac_pct:.2f} -> {step.triac_after_pct - op.triac_pct:.2f}",
            f"{step.power_before_kw - op.power_kw:.2f} -> {step.power_after_kw - op.power_kw:.2f}",
            f"{step.gain_kw_per_pct:.2f}",
        ]
        if st.paper:
            row += ["-" if paper is None else f"{paper[2]:.2f} -> {paper[3]:.2f}",
                    "-" if paper is None else f"{paper[4]:.2f}"]
        rows.append(row)
    header = ["t [s]", f"step {ds[1:]} [{u}]", f"step {ds} [{u}]", f"step {dp} [{y}]",
              f"r [{y}/{u}]"]
    if st.paper:
        header += ["paper step dP [kW]", "paper r [kW/%]"]
    text = (st.title("## Input steps and instantaneous gains", "paper Table 3")
            + f"\n\nr = ({dp} after - {dp} before) / ({ds} after - {ds} before), the first "
            "output sample that shows the step against the last one before it.")
    if st.paper:
        text += (" The paper lists the four steps of +5 % after t = 10^4 s; its rows "
                 "stand beside ours for the same absolute input step (its s_nom = 45 %, "
                 f"P_nom = 45 kW; ours: {op.triac_pct:.4g} %, {op.power_kw:.4g} kW).")
    text += "\n\n" + (_md_table(header, rows, "rlllr" + "lr" * st.paper) if rows
                       else "No input steps found.")
    if st.paper:
        text += ("\n\nThe paper's Table 3 (ds [%]: dP [kW], r [kW/%]): "
                 + "; ".join(f"{a:g} -> {b:g}: {pa:.2f} -> {pb:.2f}, r = {r:.2f}"
                             for a, b, pa, pb, r in PAPER_TABLE3) + ".")
    return text


def _route_section(result: PipelineResult, st: _Style) -> str:
    m = _models(result)
    labels = [("hammerstein_eq21", "eq. 21 initial (ARX block, f from the step gains; Fig. 12)"),
              ("hammerstein_arx_reidentified", "f fixed, ARX-reidentified (Fig. 13)"),
              ("hammerstein_oe_reidentified", "f fixed, OE-reidentified (Fig. 13)"),
              ("hammerstein_oe", "final PEM on V from those values (eq. 27; Figs. 15-16)"),
              ("hammerstein_oe_from_zeros", "final PEM on V from zeros (sec. 7.5)"),
              ("hammerstein_armax", "noise-model Hammerstein, PEM on W (eq. 30)")]
    rows = []
    for name, label in labels:
        paper_it = PAPER_ITERATIONS.get(name)
        paper = [_num(PAPER_ROUTE_V[name], ".3f"), _num(PAPER_W.get(name), ".2g"),
                 "-" if paper_it is None else str(paper_it)] if st.paper else []
        cells = _criteria_cells(m[name]) if name in m else ["skipped", "-", "-", "-"]
        rows.append([label, *cells, *paper])
    text = ("## The Hammerstein route (paper secs. 7.4-7.6)\n\n"
            + _criteria_table("step", rows, st, ["paper V [kW^2]", "paper W [kW^2]", "paper iterations"]))
    arx_like = [n for n in m if n.startswith("armax_")]
    if arx_like and "hammerstein_armax" in m:
        base = m[arx_like[0]]
        w_lin = base.one_step_mse_kw2
        w_ham = m["hammerstein_armax"].one_step_mse_kw2
        text += (f"\n\nOne-step prediction (Fig. 18): W of {base.label} = {w_lin:.3g} {st.v_unit}, "
                 f"of the noise-model Hammerstein = {w_ham:.3g} {st.v_unit}: "
                 f"**{100 * (1 - w_ham / w_lin):.0f} % lower**"
                 + st.paper_note(f" (paper: 3.1e-4 vs 1.8e-4 kW^2, {100 * PAPER_W_REDUCTION:.0f} % "
                                 "lower)") + ".")
    f = result.findings
    if f.iterations_from_zeros is not None:
        text += (f"\n\nFinal PEM: {f.iterations_from_initial_values} iterations from the "
                 f"OE-reidentified values, {f.iterations_from_zeros} from zeros"
                 + st.paper_note(" (paper: 3 and 17)")
                 + "; largest relative parameter difference between the two: "
                 f"{_num(f.from_zeros_relative_difference, '.2g')}.")
    return text


def _final_section(result: PipelineResult, model_file: str, st: _Style) -> str:
    final = result.final
    if final is None:
        return "## Final model\n\nNo model could be identified."
    model = final.model
    u, y = st.in_unit, st.out_unit
    extra = dict(model.provenance.extra)
    lines = [f"## The model for control: `{model_file}`", "",
             f"{final.label}: V = {final.ballistic_mse_kw2:.4g} {st.v_unit}, "
             f"W = {final.one_step_mse_kw2:.3g} {st.v_unit}, noise std {model.noise_std_kw:.3g} "
             f"{y}, valid for {st.in_sym[1:]} in {model.input_range_pct[0]:g} .. "
             f"{model.input_range_pct[1]:g} {u} (the identification data's range). Deviations "
             f"{st.out_sym} = {st.out_sym[1:]} - {model.operating_point.power_kw:.4g} {y}, "
             f"{st.in_sym} = {st.in_sym[1:]} - {model.operating_point.triac_pct:.4g} {u}.",
             "", "```",
             model_equation(model, input_symbol=st.in_sym, output_symbol=st.out_sym,
                            output_unit=y), "```"]
    names = extra.get("parameter_names")
    values = extra.get("parameters")
    ses = extra.get("std_errors")
    if names and values and ses and len(names) == len(values) == len(ses):
        rows = []
        for n, v, se in zip(names, values, ses, strict=True):
            rel = "-" if se is None or v == 0 else f"{100 * abs(se / v):.2g} %"
            rows.append([f"`{n}`", f"{v:.6g}", _num(se, ".3g"), rel])
        lines += ["", "Estimated parameters (b1 = 1 by the normalization of eqs. 22-25; for the "
                  "noise model c1 = a1 + k1, eq. 32):", "",
                  _md_table(["parameter", "estimate", "standard error", "relative"], rows)]
    lines += ["", f"Linear-block static gain B(1)/A(1) = {model.linear_static_gain:.4g}; "
              f"instantaneous gain f'(0) = {float(model.input_nonlinearity_slope(0.0)):.4g} "
              f"{y}/{u}."]
    lines += _voltage_line(extra.get("grid_voltage"), y)
    return "\n".join(lines)


def _voltage_line(entry: Any, unit: str) -> list[str]:
    """The report's line on grid-voltage compensation (none for a log without the column)."""
    if not isinstance(entry, Mapping):
        return []
    if entry.get("compensated") is True:
        return ["", f"Grid voltage compensated: the fit's input is w_eff = v^2 f(ds) + (v^2 - 1) "
                f"W0 with W0 = P_nom / G1 = {_num(entry.get('nominal_drive_kw'), '.6g')} {unit}-"
                f"equivalent ({entry.get('n_refits')} refit(s), W0 "
                f"{'settled' if entry.get('settled') else 'NOT settled'} to "
                f"{_num(entry.get('w0_rtol'), 'g')} relative)."]
    return ["", f"Grid voltage NOT compensated although the log carries it: "
            f"{entry.get('reason', 'no reason recorded')}."]


def _findings_section(findings: Sequence[Finding], paper: bool = True) -> str:
    box = {"shown": "[x]", "not shown": "[ ]", "not measured": "[?]"}
    lines = ["## Findings of the paper, checked on these data", ""]
    for f in findings:
        lines.append(f"- {box[f.verdict]} **{f.verdict}**: {f.claim}. Ours: {f.ours}."
                     + (f" Paper: {f.paper}." if paper else ""))
    return "\n".join(lines)


def _timing_section(result: PipelineResult) -> str:
    rows = [[t.name, f"{t.wall_time_s:.3f}"] for t in result.timings]
    rows.append(["**total**", f"**{result.total_time_s:.3f}**"])
    return "## Wall time per stage\n\n" + _md_table(["stage", "time [s]"], rows)


#: Report section each figure belongs to, by the start of its file name.
_FIGURE_SECTIONS: tuple[tuple[str, str], ...] = (
    ("fig02", "data"), ("structure", "structure"), ("fig03", "preprocessing"), ("fig04", "preprocessing"),
    ("fig06", "preprocessing"), ("fig07", "preprocessing"), ("fig08", "linear"),
    ("fig09", "linear"), ("gain_curve", "steps"), ("fig12", "route"), ("fig13", "route"),
    ("fig15", "route"), ("fig16", "route"), ("fig18", "route"), ("residual_tests", "final"),
)


def _figure_md(caption: str, rel_path: str) -> str:
    """Markdown of one figure of the report: the image, then its caption in italics."""
    return f"![{Path(rel_path).stem}]({rel_path})\n\n*{caption}*"


def _section_of(rel_path: str) -> str | None:
    stem = Path(rel_path).stem
    return next((sec for prefix, sec in _FIGURE_SECTIONS if stem.startswith(prefix)), None)


def render_report(
    result: PipelineResult,
    figures: Sequence[tuple[str, str]],
    *,
    model_file: str = "model.json",
    model_files: Sequence[str] = (),
    command: str | None = None,
    reference: bool | None = None,
    notes: Sequence[str] = (),
) -> str:
    """The Markdown text of report.md.

    Parameters
    ----------
    result :
        A `sysid.pipeline.PipelineResult`.
    figures :
        ``(caption, relative path)`` of each figure, in order.
    model_file :
        Relative path of the model for control.
    model_files :
        Relative paths of the intermediate model files.
    command :
        The command line that produced the report, if known.
    reference :
        Show the paper's values beside ours; default: for data in % and kW only.
    notes :
        What the run changed or left out (the segments used, a model kind other than
        the Hammerstein with noise model), shown under the header.

    Returns
    -------
    str
        The report.
    """
    st = _style(result, reference)
    findings = findings_checklist(result)
    raw = result.raw_data
    intro = ("Komperød et al., *Empirical Modeling of Heating Element Power for the Czochralski "
             "Crystallization Process*, secs. 5-7, rerun on these data.")
    if st.paper:
        intro += (" The paper's values stand beside ours; they come from the authors' log, so "
                  "they are a yardstick, not a target.")
    else:
        intro += (f" Input: {st.in_name} [{raw.input_unit}]; output: {st.out_name} "
                  f"[{raw.output_unit}]. The paper's values (a CZ puller's heater, % and kW) are "
                  "not shown; pass --reference paper to show them.")
    parts = ["# Identification report", intro]
    parts.append(f"Produced by {SOFTWARE}" + (f": `{command}`." if command else "."))
    for note in notes:
        parts.append(f"**Note:** {note}.")
    unconverged = result.unconverged
    if unconverged:
        final = result.final.name if result.final is not None else ""
        which = ("including model.json's own" if final in unconverged
                 else "intermediate models only; model.json's search converged")
        parts.append("**Warning: not converged: " + ", ".join(unconverged)
                     + f" ({which}).** Their numbers are the optimizer's last iterate.")
    parts.append(f"Each prediction-error search stops when V falls by less than "
                 f"{DEFAULT_PROGRESS_RTOL:g} relative over {PROGRESS_WINDOW} iterations, "
                 f"or at the cap of {MAX_ITERATIONS} iterations.")
    if result.skipped:
        parts.append("Skipped: " + "; ".join(result.skipped) + ".")
    parts.append(_findings_section(findings, st.paper))
    sections = (("data", _data_section(result, st)),
                ("preprocessing", _preprocessing_section(result, st)),
                ("structure", structure_section(result.structure, result.rest_search,
                                                v_unit=st.v_unit, gain_unit=st.gain_unit)),
                ("linear", _table2_section(result, st)), ("steps", _table3_section(result, st)),
                ("route", _route_section(result, st)),
                ("final", _final_section(result, model_file, st)))
    placed: set[str] = set()
    for key, text in sections:
        if not text:
            continue
        parts.append(text)
        for caption, rel in figures:
            if _section_of(rel) == key:
                parts.append(_figure_md(caption, rel))
                placed.add(rel)
    rest = [(c, r) for c, r in figures if r not in placed]
    if rest:
        parts.append("## Other figures\n\n" + "\n\n".join(_figure_md(c, r) for c, r in rest))
    if model_files:
        parts.append("## Model files\n\n" + "\n".join(f"- [`{p}`]({p})" for p in model_files))
    parts.append(_timing_section(result))
    return "\n\n".join(parts) + "\n"


def write_report(
    result: PipelineResult,
    out_dir: str | os.PathLike[str],
    *,
    model_file: str = "model.json",
    model_files: Sequence[str] = (),
    command: str | None = None,
    figure_dir: str = "figures",
    reference: bool | None = None,
    notes: Sequence[str] = (),
) -> ReportFiles:
    """Draw the figures into ``out_dir/figures`` and write ``out_dir/report.md``.

    Parameters
    ----------
    result :
        A `sysid.pipeline.PipelineResult`.
    out_dir :
        Output directory (created if missing).
    model_file, model_files, command, reference, notes :
        As in `render_report` (the paths relative to `out_dir`).
    figure_dir :
        Sub-directory of `out_dir` for the PNGs.

    Returns
    -------
    ReportFiles
    """
    out = Path(out_dir)
    fig_dir = out / figure_dir
    fig_dir.mkdir(parents=True, exist_ok=True)
    drawn = _draw_figures(result, fig_dir, _style(result, reference))
    text = render_report(
        result, [(f.caption, f.path.relative_to(out).as_posix()) for f in drawn],
        model_file=model_file, model_files=model_files, command=command, reference=reference,
        notes=notes)
    report = out / "report.md"
    atomic_write_text(report, text)
    return ReportFiles(report_path=report, figure_files=tuple(f.path for f in drawn))


__all__ = ["Finding", "ReportFiles", "findings_checklist", "model_equation", "render_report", "write_report"]
