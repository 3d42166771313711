"""Regression suites for your own controller: record what "good" is, check it again.

  czmpc regress record SUITE.toml --out GOLDEN_DIR [--force] [--executor ...]
  czmpc regress check GOLDEN_DIR [--junit FILE] [--out REPORT_DIR] [--executor ...]
  czmpc regress audit GOLDEN_DIR [--mutation NAME ...] [--executor ...]

A suite (TOML) names your model files, MPC settings files, scenarios (shipped names or
your own scenario files, e.g. a recipe's setpoint schedule), plants (model, heater,
perturbed, sampled), seeds and the metrics to hold. A minimal suite (paths relative to it):

    scenarios = ["recipe_a.toml", "staircase"]   # your scenario files or shipped names
    seeds = [3]
    [[controllers]]
    kind = "mpc"              # or nmpc, linear_mpc, pi_gs, pi, pi_table, open_loop
    model = "my_model.json"
    settings = "my_settings.toml"
    [[controllers]]
    kind = "c_step"           # the MPC step as C that 'czmpc codegen ... --out step/' wrote,
    directory = "step/"       # built with the system's C compiler; its model and settings
    [[plants]]
    kind = "model"            # or "heater", or "perturbed" with gain_factors = [...]

Optional keys: name, time_scale (shortens scenarios), metrics = [...] (default: IAE,
ISE, overshoot, steady-state error, input total variation, violation counts, solver
failures) and a [tolerances] table (metric = absolute value or "2%"); every key is
described in the module czmpc.campaigns.regression. The project's own golden set is the
shipped suite regress_project_golden.toml.

`record` runs every case twice (default and tight solver tolerances) and writes
GOLDEN_DIR: the metrics with derived tolerances, a compact trajectory per case, the
czmpc version, the SHA-256 of every model, settings and scenario file, and a copy of
the suite. It refuses to replace an existing GOLDEN_DIR without --force. A c_step (whose
compiled solver tolerances are fixed) is re-run as the Python MPC of its model and
settings at the tight tolerances, so it gets the tolerances an mpc of those gets; its
generated C is an input file like the model (regenerated C is named as a likely cause).

`check` re-runs every case with your files as they are now and prints, for each failing
case, the metric, golden value, tolerance, new value and the first time the trajectory
leaves the golden band; a changed model or settings file (which keys) or czmpc version
is named as the likely cause. --out writes REPORT_DIR/report.md and a figure per failing
case (golden band and new trajectory on shared axes); --junit writes JUnit XML for CI.

`audit` re-runs the MPC cases with the controller mutated (move_weight x2, horizon
-20%, rate limit off, other disturbance model) and reports which mutations the suite
catches.

Exit codes: 0 every case holds (record: written; audit: at least one mutation caught);
1 a case fails (check), a case cannot run (record), the suite catches no mutation
(audit); 2 bad input (a suite or file that cannot be read, an existing GOLDEN_DIR).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from czmpc.cli import _argtypes

NAME = "regress"
HELP = "record a regression suite of your controller, check it after a change, audit it"


def _executor_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--executor", choices=("serial", "processes", "dask"), default="serial",
                   help="where cases run (default: serial, this process)")
    p.add_argument("--workers", metavar="N", type=_argtypes.integer(1, "a whole number"),
                   default=2, help="worker processes of 'processes' and '--dask local' (default: 2)")
    p.add_argument("--dask", metavar="local|ADDRESS", default="local",
                   help="'local': a LocalCluster on 127.0.0.1; or a scheduler address "
                        "(default: local)")


def _golden_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("golden", metavar="GOLDEN_DIR", type=Path,
                   help="a golden directory written by 'czmpc regress record'")
    p.add_argument("--suite-dir", metavar="DIR", type=Path, default=None,
                   help="folder the suite's relative file names are taken from (default: where "
                        "the suite was when recorded, relative to GOLDEN_DIR)")
    _executor_options(p)


def register(parser: argparse.ArgumentParser) -> None:
    """Add the ``record``, ``check`` and ``audit`` sub-commands."""
    sub = parser.add_subparsers(dest="regress_command", metavar="{record,check,audit}",
                                required=True)
    rec = sub.add_parser(
        "record", help="run a suite and write its golden directory",
        description="Run every case of SUITE (default and tight solver tolerances) and write "
                    "GOLDEN_DIR: metrics with tolerances, trajectories, provenance, the suite.")
    rec.add_argument("suite", metavar="SUITE.toml",
                     help="suite file, or a shipped suite name (regress_project_golden.toml)")
    rec.add_argument("--out", metavar="GOLDEN_DIR", type=Path, required=True,
                     help="golden directory to write (refused if it exists, unless --force)")
    rec.add_argument("--force", action="store_true", help="replace an existing golden directory")
    _executor_options(rec)
    chk = sub.add_parser(
        "check", help="re-run a golden directory's cases; exit 1 if one does not hold",
        description="Re-run every case and compare it with GOLDEN_DIR; print a table of every "
                    "failing metric (golden, tolerance, new) and its first divergence.")
    _golden_options(chk)
    chk.add_argument("--junit", metavar="FILE", type=Path, default=None,
                     help="write JUnit XML (one testcase per case) for CI systems")
    chk.add_argument("--out", metavar="REPORT_DIR", type=Path, default=None,
                     help="write REPORT_DIR/report.md and REPORT_DIR/figures/<case>.png")
    aud = sub.add_parser(
        "audit", help="mutate the recorded controller; report which mutations the suite catches",
        description="Re-run the MPC cases with the controller mutated; exit 1 if the suite "
                    "catches none.")
    _golden_options(aud)
    aud.add_argument("--mutation", metavar="NAME", action="append", default=None,
                     help="a mutation to try (repeatable): 'move_weight x2', 'horizon -20%%', "
                          "'rate limit off', 'disturbance model' (default: all)")


def _record(args: argparse.Namespace) -> int:
    from czmpc.campaigns.regression import RegressRunError, load_suite, record_suite
    from czmpc.cli._progress import Progress

    path = _argtypes.file_or_shipped(args.suite, "suite")
    suite = load_suite(path)
    progress = Progress()
    n = len(suite.expand())
    progress(f"suite '{suite.name}': {n} case(s), each at default and tight solver tolerances")
    try:
        out = record_suite(path, args.out, force=args.force, executor=args.executor,
                           workers=args.workers, dask_address=args.dask,
                           progress=lambda d, t: progress.fraction(d, t, what="runs"))
    except RegressRunError as exc:
        print(f"czmpc: error: {exc}", file=sys.stderr)
        return 1
    print(f"recorded {n} case(s) of suite '{suite.name}' in {out.parent} "
          f"({progress.elapsed_s:.1f} s)")
    return 0


def _check(args: argparse.Namespace) -> int:
    from czmpc.campaigns.regression import check_golden
    from czmpc.campaigns.regression_report import check_table, junit_xml, write_report
    from czmpc.cli._progress import Progress
    from sysid.atomic import atomic_write_text

    progress = Progress()
    report = check_golden(args.golden, suite_dir=args.suite_dir, executor=args.executor,
                          workers=args.workers, dask_address=args.dask,
                          progress=lambda d, t: progress.fraction(d, t, what="cases"))
    print(check_table(report), end="")
    if args.junit is not None:
        args.junit.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.junit, junit_xml(report))
        progress(f"wrote JUnit XML {args.junit}")
    if args.out is not None:
        paths = write_report(report, args.out)
        progress(f"wrote {paths[0]}" + (f" and {len(paths) - 1} figure(s)" if len(paths) > 1 else ""))
    return 0 if report.passed else 1


def _audit(args: argparse.Namespace) -> int:
    from czmpc.campaigns.regression import audit_golden
    from czmpc.campaigns.regression_report import audit_table
    from czmpc.cli._progress import Progress

    progress = Progress()
    report = audit_golden(args.golden, mutations=args.mutation, suite_dir=args.suite_dir,
                          executor=args.executor, workers=args.workers, dask_address=args.dask,
                          progress=progress)
    print(audit_table(report), end="")
    return 0 if report.catches_any else 1


def run(args: argparse.Namespace) -> int:
    """Run the sub-command."""
    return {"record": _record, "check": _check, "audit": _audit}[args.regress_command](args)
