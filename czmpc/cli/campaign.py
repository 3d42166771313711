"""Run a campaign spec (controllers x plants x scenarios x seeds) and summarise it.

  czmpc campaign run SPEC.toml --out DIR [--executor serial|processes|dask] [--workers N]
                     [--dask local|ADDRESS] [--worst N] [--samples N] [--time-scale X]
                     [--controllers A,B]
  czmpc campaign report DIR

`run` writes DIR/results.parquet (one row of metrics per run: IAE [kW s], ISE
[kW^2 s], overshoot [kW], settling time [s], steady error [kW], input total variation
[%], limit and rate violations, solver failures, controller step times [ms], status,
and the robustness measures against the reachable setpoint). An interrupted campaign
resumes where it stopped when run again with the same SPEC and DIR. Shipped specs
(package data) can be named without a path: campaign_smoke.toml,
campaign_montecarlo.toml (MPC, gain-scheduled PI and linear MPC on plants sampled from
the model's parameter covariance), campaign_robustness.toml (the MPC on the model
perturbed in gain, time constant and delay, and on the virtual heater),
campaign_bench.toml (the six controllers of the tracking benchmark, the NMPC included),
campaign_throughput.toml. --samples, --time-scale and --controllers change a spec for
one run (e.g. a quick look at the Monte Carlo: --samples 5 --time-scale 0.05).

The MPC step as C (czmpc codegen) is a controller like the others: kind = "c_step" with
directory = "step/" (relative to the spec); it runs the model and settings the directory
was generated from and is built once, before the runs, with the system's C compiler (a
missing compiler is an error, exit 2). A scenario whose limits would change its compiled
settings is refused in its runs.

`report` writes DIR/report.md, DIR/iae_distribution.png, DIR/iae_heatmap.png (perturbed
plants: IAE ratio to the nominal plant per gain, time constant and delay, offset-free
failures marked), DIR/montecarlo_iae.png (sampled plants: offset-free and within-limits
shares per controller in the report) and, with trajectories saved by `run --worst N`,
DIR/worst_runs.png.

Exit codes: 0 done; 1 some run crashed or violated an input limit; 2 bad input.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from czmpc.cli import _argtypes

NAME = "campaign"
HELP = "run a campaign spec on serial, process or Dask executors; summarise its results"


_workers = _argtypes.integer(1, "a whole number")


def _split_names(text: str) -> list[str]:
    """The names of a comma-separated list, without blanks and empty items."""
    return [name.strip() for name in text.split(",") if name.strip()]


#: --controllers: at least one name.
_names = _argtypes.checked(_split_names, bool, "comma-separated controller names")
#: --time-scale: 0 < X <= 1.
_time_scale = _argtypes.checked(float, lambda value: 0.0 < value <= 1.0, "a number in (0, 1]")


def _add_overrides(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--samples", metavar="N", type=_workers, default=None,
                        help="override n of the spec's sampled plants (plants drawn from the "
                             "model's parameter covariance)")
    parser.add_argument("--time-scale", metavar="X", type=_time_scale, default=None,
                        help="override the spec's time_scale: scenario times x X, 0 < X <= 1")
    parser.add_argument("--controllers", metavar="A,B", type=_names, default=None,
                        help="run only these controllers of the spec (their names)")


def register(parser: argparse.ArgumentParser) -> None:
    """Add the ``run`` and ``report`` sub-commands."""
    sub = parser.add_subparsers(dest="campaign_command", metavar="{run,report}", required=True)
    run_p = sub.add_parser("run", help="run (or resume) a campaign into DIR",
                           description="Run the runs of SPEC not yet in DIR; write DIR/results.parquet.")
    run_p.add_argument("spec", metavar="SPEC.toml",
                       help="campaign spec file, or the name of a shipped spec (campaign_smoke.toml)")
    run_p.add_argument("--out", metavar="DIR", type=Path, required=True,
                       help="campaign directory (created; resumed if it holds the same spec)")
    run_p.add_argument("--executor", choices=("serial", "processes", "dask"), default="serial",
                       help="where runs execute (default: serial, this process)")
    run_p.add_argument("--workers", metavar="N", type=_workers, default=2,
                       help="worker processes of 'processes' and of '--dask local' (default: 2)")
    run_p.add_argument("--dask", metavar="local|ADDRESS", default="local",
                       help="'local': a LocalCluster on 127.0.0.1; or a scheduler address, "
                            "e.g. tcp://10.0.0.5:8786 (default: local)")
    run_p.add_argument("--worst", metavar="N", type=_workers, default=None,
                       help="save the trajectories of the N highest-IAE runs of each controller, "
                            "N >= 1 (re-run at the end; default: none)")
    _add_overrides(run_p)
    rep_p = sub.add_parser("report", help="summary Markdown and figures of a finished campaign",
                           description="Write DIR/report.md and figures from DIR/results.parquet.")
    rep_p.add_argument("dir", metavar="DIR", type=Path, help="a finished campaign directory")


def _run(args: argparse.Namespace) -> int:
    import sys

    from czmpc.campaigns.campaign import build_c_steps, load_spec
    from czmpc.campaigns.runner import run_campaign, save_trajectories, worst_runs
    from czmpc.cli._progress import Progress

    spec = load_spec(_argtypes.file_or_shipped(args.spec, "campaign spec"), samples=args.samples,
                     time_scale=args.time_scale, controllers=args.controllers)
    build_c_steps(spec)   # a missing C compiler: one error now, not one per run
    for message in spec.warnings:
        print(f"czmpc: warning: {message}", file=sys.stderr)
    progress = Progress()
    n_runs = len(spec.expand())
    where = args.executor if args.executor == "serial" else f"{args.executor} x{args.workers}"
    progress(f"campaign '{spec.name}': {n_runs} runs on {where} into {args.out}")
    outcome = run_campaign(
        spec, args.out, executor=args.executor, workers=args.workers, dask_address=args.dask,
        progress=lambda done, total: progress.fraction(done, total, what="runs"))
    if outcome.n_skipped:
        progress(f"resumed: {outcome.n_skipped} runs were already done")
    if args.worst is not None:
        chosen = worst_runs(spec, outcome.rows, args.worst)
        progress(f"saving the trajectories of {len(chosen)} worst runs")
        save_trajectories(chosen, Path(args.out))
    violations = sum(1 for r in outcome.rows if r["status"] == "ok"
                     and (r["n_limit_violations"] > 0 or r["n_rate_violations"] > 0))
    print(f"{len(outcome.rows)} runs ({outcome.n_run} run now, {outcome.n_skipped} resumed), "
          f"{outcome.n_errors} crashed, {violations} with input-limit violations; "
          f"results: {outcome.results_path}")
    return 1 if outcome.n_errors or violations else 0


def _report(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from czmpc.campaigns.measure import OFFSET_FREE_THRESHOLD_KW
    from czmpc.campaigns.runner import CAMPAIGN_FILE, TRAJECTORY_DIR, read_results
    from czmpc.reports.campaign_report import (
        format_summary_markdown,
        plot_iae_distribution,
        plot_perturbation_heatmaps,
        plot_trajectories,
    )
    from czmpc.reports.montecarlo_report import format_montecarlo_markdown, is_sampled, plot_iae_ecdf

    rows = read_results(args.dir)
    record = json.loads((args.dir / CAMPAIGN_FILE).read_text(encoding="utf-8"))
    name = record["name"]
    figures = ["iae_distribution.png"]
    plot_iae_distribution(rows, args.dir / figures[0])
    if plot_perturbation_heatmaps(rows, args.dir / "iae_heatmap.png") is not None:
        figures.append("iae_heatmap.png")
    saved = sorted((args.dir / TRAJECTORY_DIR).glob("*.npz"))
    if saved:
        trajectories = []
        for path in saved:
            with np.load(path) as data:
                trajectories.append({**{k: data[k] for k in data.files}, "run_id": str(data["run_id"])})
        plot_trajectories(trajectories, args.dir / "worst_runs.png")
        figures.append("worst_runs.png")
    text = format_summary_markdown(rows, title=name, figures=figures)
    if any(is_sampled(r) for r in rows):
        plot_iae_ecdf(rows, args.dir / "montecarlo_iae.png")
        figures.append("montecarlo_iae.png")
        text += "\n" + format_montecarlo_markdown(
            rows, offset_free_threshold_kw=OFFSET_FREE_THRESHOLD_KW, figure="montecarlo_iae.png",
            warnings=record.get("warnings", []))
    report = args.dir / "report.md"
    report.write_text(text, encoding="utf-8")
    print(f"wrote {report} and {', '.join(figures)}")
    return 0


def run(args: argparse.Namespace) -> int:
    """Dispatch to ``run`` or ``report`` (``czmpc.cli`` pins BLAS to one thread on import)."""
    if args.campaign_command == "run":
        return _run(args)
    return _report(args)
