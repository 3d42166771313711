"""Identify the heater's Hammerstein model from a logged CSV file, the paper's whole route.

Reads DATA (CSV or Parquet; header time_s,triac_pct,power_kw or other names mapped
with --columns; time in seconds or ISO-8601 stamps; NaN, gaps and jittered stamps under
the stated --gaps/--resample policies, see sysid.historian) and runs
Komperod et al.'s pipeline: operating point (sec. 5.1), outlier candidates from an
ARX(10,10) model and their repair (sec. 5.2), the linear ARX/ARMAX/OE models of
Table 2, the input-step gains of Table 3, the Hammerstein route of sec. 7.4-7.5
(eq. 21 initial values, ARX- and OE-reidentified, final PEM from those values and
from zeros) and the Hammerstein model with a noise model (eq. 30, sec. 7.6).

It writes into DIR:

  model.json      the MPC's prediction model (czmpc-model/1; read it with 'czmpc
                  show-model DIR/model.json'): the noise-model Hammerstein (eq. 30),
                  unless it simulates from rest more than 1.1 times worse than the
                  best linear OE from rest, which is then written (stderr says which)
  models/*.json   every intermediate model, one czmpc-model/1 file each
  report.md       data, preprocessing, Table 2 and Table 3 analogues, the
                  Hammerstein route beside the paper's values, the final model's
                  parameters with standard errors, and a checklist of the paper's
                  findings, with the figures (figures/*.png) linked

Before and after the fit, the data and the model are judged for identifiability
(sysid.identifiability): a log that cannot support a model (an input that does not
move, too few input levels or samples for the orders, an output that does not depend
on the input) is refused with exit 1, every reason on stderr, and nothing written
(--accept-unidentifiable writes the files anyway); an unusual model (a gain that is not
significant or not positive, a pole at z = 1, a long delay), a log that does not start
at rest (sysid.criteria.start_at_rest), an output that clips (output_clipping) or one
that a sensor or logger holds for several samples (output_held) is a warning on stderr,
in report.md and in model.json's provenance ("identifiability"), with exit 0.

A log may carry an optional column grid_voltage_factor (grid voltage / nominal, finite,
within 0.5..1.5; a column of another name is mapped with --columns ...,
grid_voltage_factor=NAME). The heater's drive goes with the square of the voltage, so
the Hammerstein PEM fits (OE block and noise model) then regress on the effective input
w_eff = v^2 f(ds) + (v^2 - 1) W0, W0 = P_nom / G1 (G1 = B(1)/A(1)), refitting until W0
moves by less than 1e-6 relative (10 refits at most); model.json's provenance
("grid_voltage") says whether its model compensated the voltage, and the W0 used. The
linear models, the structure selection and the OE from rest take no voltage (said in
their provenance and the report). Without the column nothing changes.

Every prediction-error search stops when V falls by less than 1e-6 relative over ten
iterations (its budget follows progress), with a cap of 1000 iterations stated in the
report. An intermediate model whose search hit the cap is reported (stderr and the
report) and does not fail the run.

Progress (stage names with elapsed seconds) goes to stderr. Exit codes: 0 success;
1 the search of model.json's own model did not converge (the files are still written;
the message names the model and the optimizer's reason; pass --allow-unconverged to
accept it), or the data cannot support a model; 2 bad input (file, options, numbers
that cannot be represented).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sysid.errors import IdentificationError

if TYPE_CHECKING:
    from czmpc.reports.identification import Finding
    from sysid.data import Dataset
    from sysid.identifiability import IdentifiabilityAssessment

from czmpc.cli import _argtypes
from czmpc.cli._progress import Progress

NAME = "identify"
HELP = "identify the Hammerstein heater model from logged data and write model, report, figures"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.add_argument(
        "data", metavar="DATA",
        help="logged data, CSV or Parquet: header time_s,triac_pct,power_kw (time [s], "
             "TRIAC input s [%%], heater power P [kW]), optionally grid_voltage_factor "
             "(grid voltage / nominal, compensated in the fits), or other names with "
             "--columns; time "
             "in seconds or ISO-8601 stamps; NaN, gaps and jitter under --gaps/--resample",
    )
    parser.add_argument(
        "--out", metavar="DIR", required=True, type=Path,
        help="output directory (created if missing; files in it are overwritten)",
    )
    parser.add_argument(
        "--operating-point", metavar=("TRIAC_PCT", "POWER_KW"), nargs=2, type=_argtypes.finite_float,
        default=None,
        help="steady operating point s_nom [%%] and P_nom [kW] to take deviations about; "
             "default: the longest steady window of the data (paper sec. 5.1), or the "
             "sample means if there is none",
    )
    parser.add_argument(
        "--level-shift", metavar=("TIME_S", "KW"), nargs=2, type=_argtypes.finite_float, default=None,
        help="correct a level shift of the measured power: subtract KW [kW] from P at and "
             "after TIME_S [s] (the paper subtracts 0.15 kW from t = 20714 s); default: "
             "repair the level shifts the outlier search finds, with the size it estimates, "
             "if that estimate is at least 5 standard errors from zero and at most 5 %% of the "
             "output's span (a smaller one is not established, a larger one is the process "
             "moving: said, not repaired)",
    )
    _argtypes.add_log_options(parser)
    parser.add_argument(
        "--orders", metavar="auto|paper|NB,NF,NK[,NC]", type=_orders, default="auto",
        help="structure of the Hammerstein model: 'auto' (default) estimates the delay and "
             "chooses the input-polynomial degree (1..3) and orders nb (B coefficients), nf "
             "(poles), nk (delay, samples) on validation data held out from the log, keeping "
             "the paper's structure unless another beats it by more than 5 %%; 'paper' uses "
             "degree 2, nb 2, nf 1, nk 1; NB,NF,NK[,NC] fixes them (NC: order of the noise "
             "model C, default NF). The paper's orders are always fitted beside an auto choice",
    )
    parser.add_argument(
        "--initial-state", choices=("estimate", "held", "zero"), default="estimate",
        help="initial state of each PEM fit: 'estimate' (default) fits it per segment, as "
             "MATLAB's 'estimate'; 'held' holds the past at the first sample; 'zero' assumes "
             "the log starts at rest at the operating point",
    )
    parser.add_argument(
        "--accept-unidentifiable", action="store_true",
        help="write the model even if the data cannot support one (an input that does not "
             "move, too few levels or samples, an output that does not depend on the "
             "input); the refusals are then printed as warnings and recorded in the report "
             "and the model's provenance, and the exit code is 0 (default: exit 1 and "
             "write nothing)",
    )
    parser.add_argument(
        "--reference", choices=("paper", "none"), default=None,
        help="'paper' adds the paper's values (Komperod et al.: Tables 2-3, the route's V "
             "and W) beside ours in the report; 'none' leaves them out. Default: 'paper' "
             "for data in %% and kW (a CZ puller's log), else 'none'",
    )
    parser.add_argument(
        "--allow-unconverged", action="store_true",
        help="exit 0 even if the search of model.json's own model did not converge; the "
             "report then flags it (default: exit 1; an intermediate model that did not "
             "converge is reported and never fails the run)",
    )


@dataclass(frozen=True, kw_only=True)
class IdentifyOutcome:
    """What `identify_to_directory` wrote and whether every fit converged.

    Parameters
    ----------
    model_path, model_files, report_path, figure_files :
        model.json (the noise-model Hammerstein, eq. 30), every intermediate model
        file, report.md and the report's PNG figures.
    unconverged :
        ``"name (n iterations)"`` of each intermediate fit that did not converge;
        model.json's own fit is never among them.
    final_unconverged :
        Why model.json's own fit did not converge (``"name: optimizer message"``), or
        None: the only non-convergence that fails the command.
    warnings :
        Every warning raised while identifying, as ``"Category: message"``.
    notes :
        What the run changed or left out that a user must know (the segments used, a
        model kind other than the Hammerstein with noise model), as printed.
    findings :
        The paper's findings checked on these data, as in the report
        (`czmpc.reports.identification.findings_checklist`).
    identifiability :
        Every identifiability check on the data and the final model
        (`sysid.identifiability`), or None.
    """

    model_path: Path
    model_files: tuple[Path, ...]
    report_path: Path
    figure_files: tuple[Path, ...]
    unconverged: tuple[str, ...]
    final_unconverged: str | None = None
    warnings: tuple[str, ...] = ()
    findings: tuple[Finding, ...] = ()
    identifiability: IdentifiabilityAssessment | None = None
    notes: tuple[str, ...] = ()


def _order_values(text: str) -> str | tuple[int, ...]:
    """``auto`` or ``paper`` as given, else the integers of NB,NF,NK[,NC] (ValueError if not)."""
    if text in ("auto", "paper"):
        return text
    return tuple(int(part) for part in text.split(","))


def _usable_orders(orders: str | tuple[int, ...]) -> bool:
    """A name, or three or four orders with NB >= 1 and NF, NK, NC >= 0."""
    return isinstance(orders, str) or (len(orders) in (3, 4) and orders[0] >= 1
                                       and min(orders) >= 0)


#: --orders: ``auto``, ``paper`` or ``(nb, nf, nk[, nc])``.
_orders = _argtypes.checked(
    _order_values, _usable_orders,
    "'auto', 'paper' or NB,NF,NK[,NC] with NB >= 1 and NF, NK, NC >= 0 (for example 2,1,1)")


def identify_to_directory(
    data_path: str | Path | Dataset,
    out_dir: str | Path,
    *,
    operating_point: tuple[float, float] | None = None,
    level_shift: tuple[float, float] | None = None,
    progress: Callable[[str], None] | None = None,
    command: str | None = None,
    orders: str | tuple[int, ...] = "paper",
    initial_state: str = "estimate",
    accept_unidentifiable: bool = False,
    reference: str | None = None,
    min_nk: int = 0,
) -> IdentifyOutcome:
    """Read a log, run the paper's pipeline and write model.json, models/, report.md.

    Parameters
    ----------
    data_path :
        CSV file in the data contract, or a `sysid.data.Dataset` already read (for
        example with a column mapping).
    out_dir :
        Output directory (created if missing).
    operating_point :
        ``(s_nom [%], P_nom [kW])``, or None to find a steady window.
    level_shift :
        ``(from_time_s [s], shift_kw [kW])`` to subtract from the power, or None to
        correct the level shifts the outlier search finds.
    progress :
        Called with a stage name as each stage starts.
    command :
        The command line, recorded in the report.
    orders :
        ``"auto"``, ``"paper"`` or ``(nb, nf, nk[, nc])`` (see ``czmpc identify --help``).
    initial_state :
        ``"estimate"``, ``"held"`` or ``"zero"``: initial state of the PEM fits.
    accept_unidentifiable :
        Write the files even when the identifiability checks refuse the data.
    reference :
        ``"paper"`` to show the paper's values beside ours, ``"none"`` to leave them
        out; None: ``"paper"`` for data in % and kW, else ``"none"``.
    min_nk :
        Smallest delay ``orders="auto"`` may choose [samples]: 1 for a `czmpc run` log
        (its loop reads the power before it writes the input).

    Returns
    -------
    IdentifyOutcome

    Raises
    ------
    DataFileError
        The file breaks the data contract.
    IdentificationError
        Options the pipeline refuses, or data that support no model.
    UnidentifiableDataError
        An identifiability check refuses the data (before the fit, or with the fitted
        model's orders) and `accept_unidentifiable` is False; nothing is written.
    OSError
        A file cannot be read or written.
    """
    if progress is not None:
        progress("loading the numerical libraries")
    from czmpc.reports.identification import findings_checklist, write_report
    from sysid.atomic import atomic_write_text
    from sysid.data import Dataset, read_csv
    from sysid.model import OperatingPoint, Units
    from sysid.modelfile import save_model
    from sysid.pipeline import run_paper_pipeline

    if isinstance(data_path, Dataset):
        data = data_path
    else:
        if progress is not None:
            progress(f"reading {data_path}")
        data = read_csv(data_path)
    notes: list[str] = []
    if data.n_segments > 1:
        notes.append(segments_note(data))
    if data.grid_voltage_factor is not None:
        notes.append(voltage_read_note(data.grid_voltage_factor))
    from sysid.criteria import output_clipping, output_held, start_at_rest
    from sysid.identifiability import (
        IdentifiabilityAssessment,
        UnidentifiableDataError,
        assess_data,
        assess_model,
        structure_before_fit,
    )
    from sysid.scale import check_representable
    check_representable(data, where=f"identify {data.source or 'data'}")
    degree, nb, n_par, what = structure_before_fit(orders)
    before = assess_data(data, degree=degree, nb=nb, n_parameters=n_par, what=what)
    if before.refusals and not accept_unidentifiable:
        raise UnidentifiableDataError(before)
    op = None if operating_point is None else OperatingPoint(
        triac_pct=operating_point[0], power_kw=operating_point[1])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        order_kw: dict[str, Any] = (  # NB,NF,NK[,NC] fix the paper's structure's orders
            {"orders": "paper", **dict(zip(("nb", "nf", "nk", "nc"), orders, strict=False))}
            if isinstance(orders, tuple) else {"orders": orders, "min_nk": min_nk})
        result = run_paper_pipeline(
            data, operating_point=op, level_shift="auto" if level_shift is None else level_shift,
            progress=progress, initial_state=initial_state,  # type: ignore[arg-type]
            **order_kw)
    messages = tuple(dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught))
    if result.final is None:  # pragma: no cover - the pipeline raises instead
        raise IdentificationError("identify: the pipeline returned no model")
    judged = before + assess_model(result.final.model, result.data) + \
        IdentifiabilityAssessment(checks=(start_at_rest(data), output_clipping(data),
                                          output_held(data)))
    if judged.refusals and not accept_unidentifiable:
        raise UnidentifiableDataError(judged)
    out = Path(out_dir)
    models_dir = out / "models"
    models_dir.mkdir(parents=True, exist_ok=True)
    if progress is not None:
        progress(f"writing {len(result.models)} model files and the report")
    units = Units(input=data.input_unit, output=data.output_unit)
    model_files = []
    for named in result.models:
        path = models_dir / f"{named.name}.json"
        save_model(named.model.with_updates(units=units), path)
        model_files.append(path)
    model_path = out / "model.json"
    final = result.final.model
    provenance = replace(final.provenance, extra={
        **final.provenance.extra, "identifiability": judged.as_dicts(),
        **({"accepted_unidentifiable": True} if judged.refusals else {})})
    save_model(final.with_updates(units=units, provenance=provenance), model_path)
    if reference is None:
        reference = "paper" if (data.input_unit, data.output_unit) == ("%", "kW") else "none"
    notes += model_kind_notes(result) + structure_notes(result)
    files = write_report(
        result, out, model_file="model.json",
        model_files=[p.relative_to(out).as_posix() for p in model_files], command=command,
        reference=reference == "paper", notes=notes)
    atomic_write_text(files.report_path, files.report_path.read_text(encoding="utf-8")
                      + "\n" + judged.markdown())
    unconverged = tuple(f"{m.name} ({m.n_iterations} iterations)" for m in result.models
                        if not m.converged and m.name != result.final.name)
    final_unconverged = None if result.final.converged else (
        f"{result.final.name} after {result.final.n_iterations} iterations: "
        f"{result.final.message}")
    return IdentifyOutcome(model_path=model_path, model_files=tuple(model_files),
                           report_path=files.report_path, figure_files=files.figure_files,
                           unconverged=unconverged, final_unconverged=final_unconverged,
                           warnings=messages,
                           findings=findings_checklist(result), identifiability=judged,
                           notes=(*notes, *(f"skipped: {x}" for x in result.skipped)))


def voltage_read_note(v: Any) -> str:
    """A sentence saying the log carries the grid voltage ``v`` (an array), its range,
    and what is done with it."""
    return (f"the log carries grid_voltage_factor ({float(v.min()):.4g} .. {float(v.max()):.4g},"
            f" mean {float(v.mean()):.4g}): the Hammerstein PEM fits compensate it (w_eff = "
            "v^2 f(ds) + (v^2 - 1) W0); model.json's provenance 'grid_voltage' says whether "
            "its model did, and the W0 used")


def segments_note(data: Dataset) -> str:
    """A sentence saying that every segment of a split log is used, and which they are.

    The pipeline (`sysid.pipeline.run_paper_pipeline`) uses all segments, each with its
    own initial state; nothing is left out.
    """
    bounds = data.segment_bounds()
    parts = [f"{data.time_s[a]:g}..{data.time_s[b - 1]:g} s ({b - a} samples)"
             for a, b in bounds]
    return (f"the log holds {len(bounds)} segments; all are used, each with its own initial "
            f"state ({data.n_samples} samples: " + "; ".join(parts) + ")")


def structure_notes(result: Any) -> list[str]:
    """A sentence when model.json is the OE from rest and the log does not single out its
    structure: other structures lie within `sysid.rest_oe.NEAR_V_SHARE` of its V."""
    from sysid.rest_oe import NEAR_V_SHARE

    search = result.rest_search
    if search is None or result.final is None or result.final.name != "oe_rest":
        return []
    near = search.near()
    if len(near) < 2:
        return []
    c = search.chosen
    return [f"model.json's structure (nb, nf, nk = {c.nb}, {c.nf}, {c.nk}) is one of "
            f"{len(near)} of the {len(search.candidates)} OE structures within "
            f"{100 * NEAR_V_SHARE:.0f} % of the lowest V from rest: the log does not single "
            "out one, and a few samples more or fewer at its ends can change it while the "
            "model predicts alike (report.md: Structure selection)"]


def model_kind_notes(result: Any) -> list[str]:
    """Sentences for the terminal and the report when model.json is not the Hammerstein.

    The pipeline writes the noise-model Hammerstein (eq. 30); if that was not fitted it
    falls back to the OE Hammerstein, then to the best linear model on W; with orders
    "auto" the OE simulated from rest replaces it when it simulates much better from
    rest (`sysid.pipeline.REST_V_RATIO`). Each fallback is said with the reasons the
    pipeline recorded.
    """
    final = result.final
    if final is None or final.name == "hammerstein_armax":
        return []
    reasons = [s for s in result.skipped if "Hammerstein" in s or "hammerstein" in s
               or "eq. 21" in s or "input polynomial" in s]
    if final.name == "hammerstein_oe":
        kind = "the OE Hammerstein (eq. 27, no noise model)"
    elif final.name == "oe_rest":
        kind = f"the linear model {final.label} (the best simulation from rest)"
        reasons = [s for s in result.skipped if "not used as the final model" in s] or reasons
    else:
        kind = f"the linear model {final.label} (best W)"
    why = "; ".join(reasons) if reasons else "the noise-model Hammerstein was not fitted"
    return [f"model.json holds {kind} instead of the Hammerstein with a noise model "
            f"(eq. 30): {why}"]


def command_words(args: argparse.Namespace) -> list[str]:
    """The command line that reproduces this run exactly (every option that matters)."""
    words = ["czmpc", NAME, str(args.data), "--out", str(args.out)]
    if args.operating_point is not None:
        words += ["--operating-point", *(_argtypes.exact(v) for v in args.operating_point)]
    if args.level_shift is not None:
        words += ["--level-shift", *(_argtypes.exact(v) for v in args.level_shift)]
    words += _argtypes.log_option_words(args)
    orders_text = args.orders if isinstance(args.orders, str) else ",".join(
        str(v) for v in args.orders)
    words += ["--orders", orders_text, "--initial-state", args.initial_state]
    if args.reference is not None:
        words += ["--reference", args.reference]
    if args.allow_unconverged:
        words.append("--allow-unconverged")
    if args.accept_unidentifiable:
        words.append("--accept-unidentifiable")
    return words


def run(args: argparse.Namespace) -> int:
    """Run the pipeline and write model.json, models/*.json and report.md into --out."""
    progress = Progress()
    command = " ".join(shlex.quote(w) for w in command_words(args))
    progress(f"reading {args.data}")
    from czmpc.runtime.runlog import is_run_log
    from sysid.identifiability import UnidentifiableDataError

    try:
        outcome = identify_to_directory(
            _argtypes.read_log(args.data, args),
            args.out,
            operating_point=None if args.operating_point is None else tuple(args.operating_point),
            level_shift=None if args.level_shift is None else tuple(args.level_shift),
            progress=progress,
            command=command,
            orders=args.orders,
            initial_state=args.initial_state,
            accept_unidentifiable=args.accept_unidentifiable,
            reference=args.reference,
            min_nk=1 if args.columns is None and is_run_log(args.data) else 0,
        )
    except UnidentifiableDataError as exc:
        refusals = exc.assessment.refusals
        print(f"czmpc: error: {args.data}: the data cannot support a model "
              f"({len(refusals)} check(s) refused); nothing was written:", file=sys.stderr)
        for check in refusals:
            print(f"czmpc: error:   {check.message}", file=sys.stderr)
        print("czmpc: error: pass --accept-unidentifiable to write the model anyway",
              file=sys.stderr)
        return 1
    progress(f"wrote {outcome.model_path}, {len(outcome.model_files)} model files in "
             f"{outcome.model_path.parent / 'models'}, {outcome.report_path} and "
             f"{len(outcome.figure_files)} figures")
    for note in outcome.notes:
        print(f"czmpc: note: {note}", file=sys.stderr)
    for message in outcome.warnings:
        print(f"czmpc: warning: {message}", file=sys.stderr)
    judged = outcome.identifiability
    if judged is not None:
        for check in judged.refusals:
            print(f"czmpc: WARNING: refusal overridden (--accept-unidentifiable): "
                  f"{check.message}", file=sys.stderr)
        for check in judged.warnings:
            print(f"czmpc: WARNING: {check.message}", file=sys.stderr)
    if outcome.unconverged:
        print(f"czmpc: note: intermediate fit(s) not converged, reported in "
              f"{outcome.report_path}: {', '.join(outcome.unconverged)}; model.json is not "
              "among them", file=sys.stderr)
    if outcome.final_unconverged is not None:
        if args.allow_unconverged:
            print(f"czmpc: warning: model.json not converged ({outcome.final_unconverged}); "
                  "accepted (--allow-unconverged)", file=sys.stderr)
            return 0
        print(f"czmpc: error: model.json not converged ({outcome.final_unconverged}). The "
              "files are written and the report flags it; check the data, or pass "
              "--allow-unconverged to accept the last iterate.", file=sys.stderr)
        return 1
    return 0
