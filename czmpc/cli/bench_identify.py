"""Benchmark the identification pipeline: wall time per stage, total, machine, optional SIPPY peer.

Runs the whole paper pipeline (the one 'czmpc identify' runs, without writing
files or figures) on the shipped 12,000-sample experiment, or on --data, N times;
prints the median wall time of every stage and of the whole pipeline with the
machine (cores, CPU model, Python, numpy/scipy/casadi versions), says whether the
goal (whole pipeline under 2 s) is met, and writes the same numbers, with this
command line, under '## Identification pipeline' in BENCHMARKS.md (other sections
are kept).

With --with-sippy it also fits SIPPY's ARX(1,2), ARMAX(1,2,1) and OE(2,1)
(sippy-unipi, the 'bench' extra) on the same preprocessed data and prints time
ratios and both criteria (V, eq. 9; W, eq. 10) beside ours; if SIPPY is missing or
fails, the output says so.

With --real-logs DIR it also runs the pipeline as 'czmpc identify' does by default
(orders auto) on each real log of another rig found in DIR (data/real/ of the
repository) and prints model.json's simulation error from rest beside the best linear
OE of a multistart search (issue 29's goal: within 1.10 on every log).

Exit codes: 0 done (goal met or not, unless --strict); 1 goal missed with --strict;
2 bad input.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shlex
import sys
from pathlib import Path

from czmpc.cli import _argtypes
from czmpc.cli._progress import Progress
from czmpc.shipped import EXPERIMENT_CSV, shipped_path

NAME = "bench-identify"
HELP = "time the whole identification pipeline per stage and record it in BENCHMARKS.md"
ORDER = 80

_SHIPPED = shipped_path(EXPERIMENT_CSV)


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument(
        "--data", metavar="FILE", type=Path, default=None,
        help=f"logged data CSV (time_s [s], triac_pct [%%], power_kw [kW]); default: the "
             f"shipped experiment {EXPERIMENT_CSV}",
    )
    parser.add_argument(
        "--repeats", metavar="N", type=_argtypes.positive_int, default=5,
        help="whole-pipeline runs to take the median over (default: 5)",
    )
    parser.add_argument(
        "--out", metavar="DIR", type=Path, default=None,
        help="also write the numbers to DIR/bench_identify.json and DIR/bench_identify.md",
    )
    parser.add_argument(
        "--benchmarks-md", metavar="FILE", type=Path, default=None,
        help="Markdown file to put the '## Identification pipeline' section in (default: "
             "BENCHMARKS.md at the project root)",
    )
    parser.add_argument(
        "--with-sippy", action="store_true",
        help="also fit SIPPY's ARX/ARMAX/OE on the same data and compare times and V, W",
    )
    parser.add_argument(
        "--real-logs", metavar="DIR", type=Path, default=None,
        help="also tabulate identify's model.json against a multistart OE reference on each "
             "real log in DIR (data/real/ of the repository)",
    )
    parser.add_argument(
        "--strict", action="store_true",
        help="exit 1 if the whole pipeline's median time misses the 2 s goal",
    )


def _command_line(args: argparse.Namespace) -> str:
    words = ["czmpc", NAME]
    if args.data is not None:
        words += ["--data", str(args.data)]
    words += ["--repeats", str(args.repeats)]
    if args.out is not None:
        words += ["--out", str(args.out)]
    if args.with_sippy:
        words.append("--with-sippy")
    if args.real_logs is not None:
        words += ["--real-logs", str(args.real_logs)]
    return " ".join(shlex.quote(w) for w in words)


def run(args: argparse.Namespace) -> int:
    """Run the benchmark, print it, and record it."""
    from czmpc.campaigns.bench_identify import (
        PIPELINE_GOAL_S,
        format_report,
        result_to_dict,
        run_benchmark,
        write_benchmarks_section,
    )
    from sysid.atomic import atomic_write_text

    data = args.data if args.data is not None else _SHIPPED
    if args.data is None:
        with contextlib.suppress(ValueError):  # show the shipped file relative to here if below
            data = _SHIPPED.relative_to(Path.cwd())
    if args.data is None and not _SHIPPED.is_file():
        print(f"czmpc: error: the shipped experiment {_SHIPPED} is not there; pass --data FILE",
              file=sys.stderr)
        return 2
    progress = Progress()

    result = run_benchmark(data, repeats=args.repeats, with_sippy=args.with_sippy,
                           command=_command_line(args), progress=progress)
    text = format_report(result)
    if args.real_logs is not None:
        from czmpc.campaigns.bench_reallogs import format_real_logs, run_real_logs
        text += "\n" + format_real_logs(run_real_logs(args.real_logs, progress=progress))
    print(text, end="")
    target = args.benchmarks_md if args.benchmarks_md is not None else _argtypes.default_benchmarks_md()
    write_benchmarks_section(target, text)
    progress(f"wrote the numbers to {target}")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out / "bench_identify.md", text)
        atomic_write_text(args.out / "bench_identify.json",
                          json.dumps(result_to_dict(result), indent=2) + "\n")
        progress(f"wrote {args.out / 'bench_identify.json'} and bench_identify.md")
    if args.strict and not result.goal_met:
        print(f"czmpc: error: the whole pipeline took {result.total.median_s:.3f} s (median), "
              f"above the {PIPELINE_GOAL_S:g} s goal", file=sys.stderr)
        return 1
    return 0
