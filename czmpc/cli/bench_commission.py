"""How long must a commissioning test be? Test length against the MPC's tracking.

For each test (a designed signal of a kind and length, or the paper's 24,000 s
experiment): apply it open loop to the virtual heater made to differ from the shipped
model (gain x0.8, slow time constant 600 s, two samples more delay), identify a model
as `czmpc commission` does, run the MPC on it through setpoints 36 -> 40 -> 45 -> 50 kW
on the same plant, and compare its IAE with the MPC on the model from the paper's
experiment. Prints a table (test length, orders, fit, IAE, IAE ratio, offset-free) and
draws the IAE ratio against the test length; with --record-benchmarks it also puts
the table into BENCHMARKS.md. Each test runs --seeds times (seeds 0..N-1, fixed: the same command gives the
same numbers); a ratio compares runs of the same seed.

A run takes a few minutes (each identification takes 10 s to 1 min).

Exit codes: 0 done (whatever the numbers); 2 bad options.
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from czmpc.cli import _argtypes

NAME = "bench-commission"
HELP = "test length against closed-loop tracking for a heater unlike the shipped model"
ORDER = 84


def _case(text: str) -> tuple[str, float | None]:
    """``KIND:SECONDS``, ``KIND`` (its shortest design) or ``paper`` (argparse type)."""
    kind, colon, seconds = text.partition(":")
    if kind not in (*_argtypes.TEST_SIGNAL_KINDS, "paper") or (kind == "paper" and colon):
        raise argparse.ArgumentTypeError(
            f"expected KIND:SECONDS or KIND with KIND one of "
            f"{', '.join(_argtypes.TEST_SIGNAL_KINDS)}, or 'paper'; got {text!r}")
    return kind, _argtypes.number(above=0.0, unit="s")(seconds) if colon else None


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--case", metavar="KIND[:S]|paper", type=_case, action="append",
                        default=None,
                        help="a test: a design kind and its length in plant seconds "
                             "(multilevel:7200), a kind alone for its shortest design "
                             "(mixed), or 'paper' for the paper's experiment; repeatable "
                             "(default: multilevel:4800, multilevel:6000, multilevel:7200, "
                             "gbn:12000, mixed, paper)")
    parser.add_argument("--seeds", metavar="N", type=_argtypes.positive_int, default=3,
                        help="runs of every test, seeds 0..N-1 (design, test noise, "
                             "closed-loop noise) (default: 3)")
    parser.add_argument("--out", metavar="DIR", type=Path, default=Path("out/bench/commission"),
                        help="where the figure goes (default: out/bench/commission)")
    parser.add_argument("--record-benchmarks", action="store_true",
                        help="also put the table into BENCHMARKS.md")
    parser.add_argument("--benchmarks-md", metavar="FILE", type=Path, default=None,
                        help="the Markdown file for --record-benchmarks (default: "
                             "BENCHMARKS.md at the project root)")


def run(args: argparse.Namespace) -> int:
    """Run the study, print the table, draw the figure, record when asked."""
    from czmpc.cli._progress import Progress
    from czmpc.commissioning.length_study import (
        BENCHMARK_HEADING,
        DEFAULT_CASES,
        MAX_IAE_RATIO,
        MAX_TEST_S,
        LengthCase,
        format_study,
        iae_ratio,
        run_length_study,
    )
    from czmpc.reports.benchmarks_md import machine_info, write_benchmarks_section
    from czmpc.reports.commissioning import length_study_figure

    cases = DEFAULT_CASES if args.case is None else tuple(
        LengthCase(kind=k, duration_s=s) for k, s in args.case)
    words = ["czmpc", NAME, "--seeds", str(args.seeds)]
    for c in args.case or ():
        words += ["--case", c[0] if c[1] is None else f"{c[0]}:{c[1]:g}"]
    progress = Progress()
    rows = run_length_study(cases, seeds=range(args.seeds), progress=progress)
    text = format_study(rows, command=" ".join(shlex.quote(w) for w in words),
                        machine=machine_info().describe())
    print(text, end="")
    args.out.mkdir(parents=True, exist_ok=True)
    fig = length_study_figure(
        args.out / "test_length.png",
        [(r.case.kind, r.test_s, iae_ratio(r, rows)) for r in rows if r.failure is None],
        goal_ratio=MAX_IAE_RATIO, max_test_s=MAX_TEST_S)
    progress(f"wrote {fig}")
    if args.record_benchmarks:
        target = args.benchmarks_md or _argtypes.default_benchmarks_md()
        write_benchmarks_section(target, text, heading=BENCHMARK_HEADING)
        progress(f"wrote the table to {target}")
    return 0
