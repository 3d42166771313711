"""Benchmark the model-health monitor: false alarms on the unchanged plant, detection delays after drifts.

1. False alarms: the unchanged model plant (the model's own equation, noise on) for
   24 h of plant time (43,200 samples at Ts = 2 s), --days-open times open loop through
   an input staircase and --days-closed times in closed loop with the MPC through a
   setpoint staircase; counts alarms and the largest health figure.
2. Detection: closed loop with the MPC on the model plant whose gain drops by 25 % or
   whose slow time constant doubles at 1800 s of plant time, --seeds runs each;
   prints how many alarms came within 30 min, the median and largest delay [s].
3. Which reference: 2 x 4 h closed loop on the unchanged virtual heater (which the
   model describes only approximately) with the test against the model and against a
   baseline (what czmpc run uses), and the drifts of 2. with the baseline test.

Prints the numbers with the rule, the false-alarm bound and the machine, and writes
them under '## Model-health monitor (stale-model alarm)' in BENCHMARKS.md (other
sections are kept). Seeds are fixed (1..N): the same command gives the same numbers.

Exit codes: 0 done; 2 bad input (model file).
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from czmpc.cli import _argtypes
from czmpc.cli._progress import Progress
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path

NAME = "bench-health"
HELP = "false alarms and detection delays of the stale-model alarm; record in BENCHMARKS.md"
ORDER = 83


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--model", metavar="MODEL.json", type=Path, default=None,
                        help="model of the controller, the monitor and the plant (default: the "
                             "shipped data/cz_heater_model.json)")
    parser.add_argument("--days-open", metavar="N", type=_argtypes.integer(0), default=3,
                        help="24 h open-loop trials of the unchanged plant (default: 3)")
    parser.add_argument("--days-closed", metavar="N", type=_argtypes.integer(0), default=1,
                        help="24 h closed-loop trials of the unchanged plant (about 1 min "
                             "each) (default: 1)")
    parser.add_argument("--seeds", metavar="N", type=_argtypes.positive_int, default=10,
                        help="closed-loop trials per drift (default: 10)")
    parser.add_argument("--benchmarks-md", metavar="FILE", type=Path, default=None,
                        help="Markdown file to put the section in (default: BENCHMARKS.md at "
                             "the project root)")
    parser.add_argument("--no-record", action="store_true",
                        help="only print the numbers; do not write them into BENCHMARKS.md")


def run(args: argparse.Namespace) -> int:
    """Run the trials, print the table, record it."""
    from czmpc.campaigns.stale_model import (
        BENCHMARK_HEADING,
        format_health_report,
        run_health_benchmark,
    )
    from czmpc.reports.benchmarks_md import machine_info, write_benchmarks_section
    from sysid.modelfile import load_model

    model = load_model(args.model or shipped_path(HAMMERSTEIN_MODEL_JSON))
    words = ["czmpc", NAME, "--days-open", str(args.days_open), "--days-closed",
             str(args.days_closed), "--seeds", str(args.seeds)]
    if args.model is not None:
        words[2:2] = ["--model", str(args.model)]
    progress = Progress()
    bench = run_health_benchmark(model, command=" ".join(shlex.quote(w) for w in words),
                                 machine=machine_info().describe(), n_days_open=args.days_open,
                                 n_days_closed=args.days_closed, n_drift_seeds=args.seeds,
                                 progress=progress)
    text = format_health_report(bench, ts_s=model.ts_s)
    print(text, end="")
    if not args.no_record:
        target = (args.benchmarks_md if args.benchmarks_md is not None
                  else _argtypes.default_benchmarks_md())
        write_benchmarks_section(target, text, heading=BENCHMARK_HEADING)
        progress(f"wrote the numbers to {target}")
    return 0
