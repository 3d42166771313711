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

With --plant-link the journey runs as a user runs it: the heater is served over OPC UA
on 127.0.0.1 by `czmpc plant serve` in its own process (with --log: its true power),
`czmpc commission --switch-on` tests, identifies, checks and switches the MPC on for the
staircase (a recipe file), and the reference model runs through the link too; both runs
are scored on the served plant's true power. One seed takes (test + 2 runs) / time
scale of wall time: 7,200 s + 2 x 6,000 s at --time-scale 20 is 16 min.

Exit codes: 0 done (whatever the numbers); 2 bad options.
"""

from __future__ import annotations

import argparse
import shlex
import sys
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
    parser.add_argument("--plant-link", action="store_true",
                        help="run `czmpc commission --switch-on` against the heater served over "
                             "OPC UA on loopback, with the reference through the link too (the "
                             "--case options do not apply; the test is --test-s of multilevel)")
    parser.add_argument("--time-scale", metavar="X", type=_argtypes.number(at_least=1.0),
                        default=20.0, help="with --plant-link: plant samples per Ts of wall "
                                           "time (default: 20, 100 ms periods)")
    parser.add_argument("--test-s", metavar="S", type=_argtypes.number(above=0.0, unit="s"),
                        default=7200.0, help="with --plant-link: length of the multilevel test "
                                             "[plant s] (default: 7200, the issue's 2 h)")
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

    if args.plant_link:
        return _run_plant_link(args)
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


def _run_plant_link(args: argparse.Namespace) -> int:
    """The study through the plant link (`czmpc.commissioning.link_study`)."""
    from czmpc.cli._progress import Progress
    from czmpc.commissioning.link_study import BENCHMARK_HEADING, format_link_study, run_seed
    from czmpc.reports.benchmarks_md import machine_info, write_benchmarks_section

    if args.case:
        print("czmpc: error: --case does not apply with --plant-link (its test is --test-s of "
              "the multilevel design)", file=sys.stderr)
        return 2
    words = ["czmpc", NAME, "--plant-link", "--seeds", str(args.seeds), "--time-scale",
             f"{args.time_scale:g}", "--test-s", f"{args.test_s:g}"]
    progress = Progress()
    runs = [run_seed(seed, out_dir=args.out / "plant_link", time_scale=args.time_scale,
                     test_s=args.test_s, progress=progress) for seed in range(args.seeds)]
    text = format_link_study(runs, command=" ".join(shlex.quote(w) for w in words),
                             machine=machine_info().describe(), time_scale=args.time_scale)
    print(text, end="")
    if args.record_benchmarks:
        target = args.benchmarks_md or _argtypes.default_benchmarks_md()
        write_benchmarks_section(target, text, heading=BENCHMARK_HEADING)
        progress(f"wrote the table to {target}")
    return 0
