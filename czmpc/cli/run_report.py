"""Draw a run log of 'czmpc run' for an operator: one figure and a short summary.

Writes into DIR:

  run.png    five panels on the plant-time axis [s]: power [kW] (measured, the model's
             one-step prediction, setpoint); TRIAC input [%] (command, applied, the
             samples written); status and link (GOOD/PREDICTED/CLAMPED/HELD/SHED, samples
             not good, the stretches without a link shaded on every panel);
             timing [ms wall] (lateness, step latency, overruns); model health [-]
             (the stale-model test's figure, alarm limit 1, and the alarm)
  report.md  steps, modes, bad samples, writes, overruns, timing, tracking error,
             largest health figure and the stale-model alarm, link losses and
             reconnections counted apart, and a table of what happened (link lost, shed,
             mode changes, refused writes, aborts) with times and durations

RUN.csv may be a directory or a quoted glob: the parts of a rotated log, or the runs of
a log directory ([run] log = "logs/"), are drawn as one record, run after run.

Logs of older versions without the health columns draw without that panel's curve.

Exit codes: 0 written; 2 bad input (not a run log, unreadable file).
"""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "run-report"
HELP = "draw a 'czmpc run' log: power, input, quality, timing, model health and alarms"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
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
    print(f"wrote {', '.join(str(f) for f in files)}")
    return 0
