"""Benchmark the MPC: controller step time at N = 50 and a 24 h closed-loop simulation.

1. Step time: runs the offset-free MPC (default tuning, horizon N = 50 samples) on
   the shipped staircase scenario (3,900 samples of 2 s) against the plant built
   from the model, --repeats times, and prints the median, p95, p99 and maximum of
   the wall time of one controller step [ms] per run. Goal: median <= 0.3 ms and
   p99 <= 2 ms (medians over the runs).
2. 24 h simulation: 43,200 samples (24 h of plant time) of a day-long scenario
   (staircase up and down, grid level shift, voltage sag, noise) with the MPC in the
   loop, on the model plant and on the virtual heater; prints the wall time [s].
   Goal: under 30 s.

Prints the numbers with the machine (cores, CPU model, Python, numpy/scipy/osqp
versions, load average at start) and whether each goal is met, and writes them, with
this command line, under '## Controller step time and 24 h simulation' in
BENCHMARKS.md (other sections are kept).

Exit codes: 0 done (goals met or not, unless --strict); 1 a goal missed with
--strict; 2 bad input (model file).
"""

from __future__ import annotations

import argparse
import contextlib
import shlex
import sys
from pathlib import Path

from czmpc.cli import _argtypes
from czmpc.cli._progress import Progress
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path

NAME = "bench-mpc"
HELP = "time the MPC step (N = 50) and a 24 h closed-loop simulation; record in BENCHMARKS.md"
ORDER = 81

_SHIPPED_MODEL = shipped_path(HAMMERSTEIN_MODEL_JSON)


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument(
        "--model", metavar="MODEL.json", type=Path, default=None,
        help="identified model file for the controller and the model plant (default: the "
             "shipped data/cz_heater_model.json)",
    )
    parser.add_argument(
        "--repeats", metavar="N", type=_argtypes.positive_int, default=5,
        help="step-time runs of the staircase (3,900 steps each) (default: 5)",
    )
    parser.add_argument(
        "--benchmarks-md", metavar="FILE", type=Path, default=None,
        help="Markdown file to put the section in (default: BENCHMARKS.md at the project "
             "root)",
    )
    parser.add_argument(
        "--no-record", action="store_true",
        help="only print the numbers; do not write them into BENCHMARKS.md",
    )
    parser.add_argument(
        "--strict", action="store_true",
        help="exit 1 if a goal (step median <= 0.3 ms and p99 <= 2 ms; 24 h under 30 s) "
             "is missed",
    )


def _command_line(args: argparse.Namespace) -> str:
    words = ["czmpc", NAME]
    if args.model is not None:
        words += ["--model", str(args.model)]
    words += ["--repeats", str(args.repeats)]
    return " ".join(shlex.quote(w) for w in words)


def run(args: argparse.Namespace) -> int:
    """Run the benchmark, print it, and record it."""
    from czmpc.campaigns.bench_mpc import format_report, run_benchmark, write_benchmarks_section
    from sysid.modelfile import load_model

    path = args.model if args.model is not None else _SHIPPED_MODEL
    model = load_model(path)
    label = str(path)
    if args.model is None:
        with contextlib.suppress(ValueError):  # show the shipped file relative to here if below
            label = str(_SHIPPED_MODEL.relative_to(Path.cwd()))
    progress = Progress()

    bench = run_benchmark(model, model_label=f"`{label}`", repeats=args.repeats,
                          command=_command_line(args), progress=progress)
    text = format_report(bench)
    print(text, end="")
    if not args.no_record:
        target = args.benchmarks_md if args.benchmarks_md is not None else _argtypes.default_benchmarks_md()
        write_benchmarks_section(target, text)
        progress(f"wrote the numbers to {target}")
    if args.strict and not (bench.step_goal_met and bench.day_goal_met):
        print("czmpc: error: a benchmark goal was missed (see above)", file=sys.stderr)
        return 1
    return 0
