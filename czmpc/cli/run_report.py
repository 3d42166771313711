"""Draw a run log of 'czmpc run' for an operator: one figure and a short summary.

Writes into DIR run.png (power [kW], TRIAC input [%], status and link, timing [ms],
model health [-] on the plant-time axis [s]) and report.md (counts, timing, tracking
error, the stale-model alarm and a table of events). RUN.csv may be a directory or a
quoted glob: the parts of a rotated log or the runs of a log directory are drawn as one
record. Panels and summary: czmpc.reports.run_report; guide: docs/guides/commission.rst.

Exit codes: 0 written; 2 bad input (not a run log, unreadable file).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from czmpc.cli._progress import print_written

NAME = "run-report"
HELP = "draw a 'czmpc run' log: power, input, quality, timing, model health and alarms"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.add_argument("log", metavar="RUN.csv",
                        help="the run log 'czmpc run' wrote, or a directory or quoted glob of "
                             "its parts")
    parser.add_argument("--out", metavar="DIR", type=Path, required=True,
                        help="output directory for run.png and report.md (created; files of "
                             "those names are replaced)")


def run(args: argparse.Namespace) -> int:
    """Read the log, draw it, write the summary."""
    from czmpc.reports.run_report import write_run_report
    from czmpc.runtime.runlog import read_run_record

    files = write_run_report(read_run_record(args.log), args.out)
    print_written(files)
    return 0
