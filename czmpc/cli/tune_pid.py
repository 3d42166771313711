"""Tune a gain-scheduled PI or PID from an identified model, for the plant's own PID block.

The model is linearised at breakpoints of the TRIAC input, each gets a PI/PID by the
chosen rule on the sampled loop, and breakpoints are added where the schedule does not
hold between them. A block runs the ISA numbers through its own difference equation:
--discretization says which (forward, backward or trapezoidal integration, or the worst
case of the three, the default), and each vendor form holds for its vendor's. Writes
into DIR: pid_table.csv (one row per breakpoint, ideal ISA form in engineering units,
its sampling time and discretization in header comments), characterizer.csv (an f^-1
X-Y table), sampled_integral.csv where the rule asks for Ti below the sampling time (an
integral-dominant loop: the integral-only law), vendor_FORM.csv per --form (needs
--pv-range-kw and --out-range-pct), report.md and its figures. Columns, rules and forms:
docs/guides/pid.rst. Run the table in closed loop with 'czmpc simulate --controller
DIR/pid_table.csv'.

Exit codes: 0 written (warnings, if any, on stderr); 2 bad input (model file, options,
a vendor form without spans, a rule the model cannot be reduced for).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from czmpc.cli import _argtypes
from czmpc.cli._progress import print_written

NAME = "tune-pid"
HELP = "tune a gain-scheduled PI/PID from a model; write pid_table.csv, vendor forms, report"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    from czmpc.pid.design import RULES
    from czmpc.pid.discretization import DEFAULT_DISCRETIZATION, DISCRETIZATIONS
    from czmpc.pid.vendor import FORMS

    parser.add_argument("model", metavar="MODEL.json", type=Path,
                        help="identified model file (format czmpc-model/1)")
    parser.add_argument("--out", metavar="DIR", type=Path, required=True,
                        help="output directory (created; files of the same names are replaced)")
    parser.add_argument("--rule", choices=RULES, default="simc",
                        help="tuning rule (default: simc)")
    knob = parser.add_mutually_exclusive_group()
    knob.add_argument("--tau-c-s", metavar="T", type=_argtypes.positive_float, default=None,
                      help="SIMC's tau_c or lambda's closed-loop time constant [s] "
                           "(default: the effective dead time)")
    knob.add_argument("--ms", metavar="M", type=_argtypes.number(above=1.0), default=None,
                      help="Ms bound [-] the knob is chosen for (simc, lambda) or the ms rule "
                           "optimises under (default for ms: 1.4)")
    parser.add_argument("--type", choices=("pi", "pid"), default="pi", dest="controller",
                        help="controller type (default: pi)")
    parser.add_argument("--breakpoints-pct", metavar="S", type=_argtypes.finite_float,
                        nargs="+", default=None,
                        help="TRIAC breakpoints [%%] to start from (default: the range's ends "
                             "and the operating point); more are added where needed")
    parser.add_argument("--keep-breakpoints", action="store_true",
                        help="add no breakpoint; only warn where the schedule does not hold")
    parser.add_argument("--triac-range-pct", metavar=("LO", "HI"), nargs=2,
                        type=_argtypes.finite_float, default=None,
                        help="TRIAC range the schedule covers [%%] (default: the model's "
                             "identified range widened by 5 %%, within 0..100, as the MPC's)")
    parser.add_argument("--discretization", choices=DISCRETIZATIONS,
                        default=DEFAULT_DISCRETIZATION,
                        help="how the block integrates, which pid_table.csv's numbers and "
                             "margins hold for: forward (e_{k-1}), backward (e_k) or tustin "
                             "(trapezoidal) Euler, or worst: all three, every margin the "
                             f"worst of them (default: {DEFAULT_DISCRETIZATION})")
    parser.add_argument("--form", choices=FORMS, action="append", default=[],
                        help="also write the tuning in this vendor's form (repeatable; it "
                             "holds for the vendor's own discretization)")
    parser.add_argument("--pv-range-kw", metavar=("LO", "HI"), nargs=2,
                        type=_argtypes.finite_float, default=None,
                        help="the PID block's PV (power) range [kW] (needed by --form)")
    parser.add_argument("--out-range-pct", metavar=("LO", "HI"), nargs=2,
                        type=_argtypes.finite_float, default=None,
                        help="the PID block's output (TRIAC) range [%%] (needed by --form)")


def run(args: argparse.Namespace) -> int:
    """Tune the schedule, write the files, print the rows and any warning."""
    from czmpc.inversion import allowed_triac_range
    from czmpc.pid.design import DesignSpec
    from czmpc.pid.discretization import covering
    from czmpc.pid.report import write_outputs
    from czmpc.pid.schedule import tune_schedule
    from czmpc.pid.table import integral_dominant_note, row_values
    from czmpc.pid.vendor import VENDOR_DISCRETIZATION, Spans
    from czmpc.settings import MPCSettings
    from sysid.modelfile import load_model

    spans = None
    if args.pv_range_kw is not None or args.out_range_pct is not None:
        if args.pv_range_kw is None or args.out_range_pct is None:
            raise _bad_input("give both --pv-range-kw LO HI and --out-range-pct LO HI")
        spans = Spans(pv_range_kw=tuple(args.pv_range_kw), out_range_pct=tuple(args.out_range_pct))
    if args.form and spans is None:
        raise _bad_input(
            f"--form {' '.join(args.form)} needs the spans the block scales with: give "
            "--pv-range-kw LO HI (the PV's range in kW) and --out-range-pct LO HI (the "
            "output's range in %); they are not assumed")
    model = load_model(args.model)
    # the design holds for the table's discretization and every vendor form's
    design = covering(args.discretization, *(VENDOR_DISCRETIZATION[f] for f in args.form))
    spec = DesignSpec(rule=args.rule, controller=args.controller, tau_c_s=args.tau_c_s,
                      ms=args.ms, discretization=design)
    if args.triac_range_pct is None:
        triac_range = allowed_triac_range(
            model, triac_min_pct=0.0, triac_max_pct=100.0,
            validity_margin_pct=MPCSettings().validity_margin_pct)
    else:
        triac_range = (args.triac_range_pct[0], args.triac_range_pct[1])
    schedule = tune_schedule(model, spec, triac_range_pct=triac_range,
                             breakpoints_pct=None if args.breakpoints_pct is None
                             else tuple(args.breakpoints_pct),
                             add_breakpoints=not args.keep_breakpoints)
    command = "czmpc " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    files = write_outputs(schedule, model, args.out, forms=args.form, spans=spans,
                          command=command, model_source=str(args.model),
                          discretization=args.discretization)
    shown = ("triac_pct", "kc_pct_per_kw", "ti_s", "td_s", "ms", "phase_margin_deg",
             "worst_ms_to_next")
    print(f"{spec.describe()} on {args.model} (Ts = {model.ts_s:g} s), "
          f"{len(schedule.rows)} rows over {triac_range[0]:g}..{triac_range[1]:g} %")
    if design != args.discretization:
        print(f"pid_table.csv states {args.discretization} integration; designed for "
              f"{design} so that the vendor forms' numbers hold too")
    print("  ".join(f"{c:>16}" for c in shown))
    for row in schedule.rows:
        values = row_values(row, args.discretization)
        print("  ".join(f"{values[c]:>16.4g}" for c in shown))
    if schedule.added_breakpoints_pct:
        print("added breakpoints [%]: "
              + ", ".join(f"{p:g}" for p in schedule.added_breakpoints_pct))
    note = integral_dominant_note(schedule)
    if note is not None:
        print(note)
    for warning in schedule.warnings:
        print(f"czmpc: warning: {warning}", file=sys.stderr)
    print_written(files)
    return 0


def _bad_input(message: str) -> Exception:
    from czmpc.pid.errors import PIDTuningError
    return PIDTuningError(f"tune-pid: {message}")
