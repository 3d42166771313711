"""Throughput of one campaign spec on the serial, process and Dask executors, one session.

    python -m benchmarks.campaign_throughput [SPEC.toml] [--workers N] [--samples N]
                                             [--time-scale X] [--controllers A,B] [--record]

The spec defaults to the shipped campaign_throughput.toml; --record writes the table
into BENCHMARKS.md, section 'Campaign executors' (that spec) or 'Campaign executors:
spec NAME'.

Per executor: runs per second (wall clock of the whole campaign, start-up of the pool
or cluster included), scaling efficiency (runs/s over ``workers`` x the serial runs/s),
scheduler overhead per run (``workers x wall - sum of the runs' own wall times``, over
the number of runs: what the executor adds to every run) and the peak resident memory of
the worker processes (`resource.getrusage` of the reaped children: the largest worker
seen so far in this process, in MiB). The machine's 1-minute load average is read before
and after each executor (`os.getloadavg`): on a shared machine it says how much of the
cores the campaign had.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from benchmarks._md import BENCHMARKS_MD, benchmark_parser, machine_info, run_main, write_benchmarks_section
from czmpc.campaigns.campaign import CampaignSpec, load_spec
from czmpc.campaigns.runner import ExecutorName, run_campaign


@dataclass(frozen=True, kw_only=True)
class ExecutorTiming:
    """One executor's measurement (definitions: module docstring)."""

    executor: str
    workers: int
    n_runs: int
    n_errors: int
    wall_s: float
    runs_per_s: float
    efficiency: float
    overhead_per_run_ms: float
    worker_peak_rss_mib: float | None
    load_average_start: float = float("nan")
    load_average_end: float = float("nan")


def benchmark_executors(spec: CampaignSpec, *, workers: int = 2,
                        progress: Callable[[str], None] | None = None) -> list[ExecutorTiming]:
    """Run ``spec`` on serial, processes x ``workers`` and Dask LocalCluster x ``workers``."""
    out: list[ExecutorTiming] = []
    serial_rate = float("nan")
    plan: list[tuple[ExecutorName, int]] = [("serial", 1), ("processes", workers), ("dask", workers)]
    for executor, n in plan:
        if progress is not None:
            progress(f"{executor} x{n}: {len(spec.expand())} runs")
        load_start = os.getloadavg()[0]
        with tempfile.TemporaryDirectory(prefix="czmpc-bench-campaign-") as tmp:
            t0 = time.perf_counter()
            outcome = run_campaign(spec, Path(tmp), executor=executor, workers=n)
            wall = time.perf_counter() - t0
        load_end = os.getloadavg()[0]
        rows = outcome.rows
        rate = len(rows) / wall
        if executor == "serial":
            serial_rate = rate
        busy = sum(float(r["wall_time_s"]) for r in rows)
        rss = None
        if executor != "serial":
            scale = 1024.0 if sys.platform != "darwin" else 1024.0 * 1024.0
            rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / scale
        out.append(ExecutorTiming(
            executor=executor, workers=n, n_runs=len(rows), n_errors=outcome.n_errors, wall_s=wall,
            runs_per_s=rate, efficiency=rate / (n * serial_rate),
            overhead_per_run_ms=1e3 * (n * wall - busy) / len(rows), worker_peak_rss_mib=rss,
            load_average_start=load_start, load_average_end=load_end))
        if progress is not None:
            progress(f"{executor} x{n}: {rate:.2f} runs/s, load average {load_start:.1f} -> "
                     f"{load_end:.1f}")
    return out


def format_benchmark_markdown(timings: list[ExecutorTiming], *, spec: CampaignSpec,
                              command: str, machine: str) -> str:
    """The BENCHMARKS.md section body: command, machine, one table row per executor."""
    from czmpc.reports.tables import format_table

    table = format_table(
        ["executor", "workers", "runs", "wall [s]", "runs/s", "efficiency [-]",
         "overhead per run [ms]", "worker peak RSS [MiB]", "load average (1 min) start / end"],
        [[t.executor, str(t.workers), str(t.n_runs), f"{t.wall_s:.1f}", f"{t.runs_per_s:.2f}",
          f"{t.efficiency:.2f}", f"{t.overhead_per_run_ms:.1f}",
          "-" if t.worker_peak_rss_mib is None else f"{t.worker_peak_rss_mib:.0f}",
          f"{t.load_average_start:.1f} / {t.load_average_end:.1f}"] for t in timings],
        markdown=True)
    return "\n".join([
        f"Command: `{command}`", "",
        f"Machine: {machine}", "",
        f"Spec `{spec.name}` ({spec.source}): {len(spec.expand())} runs, time scale "
        f"{spec.time_scale:g}. Efficiency: runs/s over workers x serial runs/s (goal >= 0.8). "
        "Overhead per run: (workers x wall - sum of run times) / runs, pool or cluster start-up "
        "included. Worker RSS: largest worker process of the session. Load average: the "
        f"machine's ({os.cpu_count()} cores) 1-minute load before and after the executor ran "
        "(the machine is shared; a load above the core count means the campaign had less "
        "than the whole machine).", "", table])


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.campaign_throughput``."""
    parser = benchmark_parser("campaign_throughput", __doc__)
    parser.add_argument("spec", metavar="SPEC.toml", nargs="?", default="campaign_throughput.toml",
                        help="campaign spec file or shipped spec name (default: %(default)s)")
    parser.add_argument("--workers", metavar="N", type=int, default=2,
                        help="workers of the parallel executors (default: 2)")
    parser.add_argument("--samples", metavar="N", type=int, default=None,
                        help="override n of the spec's sampled plants")
    parser.add_argument("--time-scale", metavar="X", type=float, default=None,
                        help="override the spec's time_scale")
    parser.add_argument("--controllers", metavar="A,B", default=None,
                        help="run only these controllers of the spec")
    parser.add_argument("--record", action="store_true",
                        help="write the table into BENCHMARKS.md of this repository")
    return parser


def _run(args: argparse.Namespace) -> int:
    from czmpc.cli._argtypes import file_or_shipped
    from czmpc.cli._progress import Progress

    names = None if args.controllers is None else [n.strip() for n in args.controllers.split(",")]
    spec = load_spec(file_or_shipped(args.spec, "campaign spec"), samples=args.samples,
                     time_scale=args.time_scale, controllers=names)
    for message in spec.warnings:
        print(f"warning: {message}", file=sys.stderr)
    machine = machine_info().describe()
    timings = benchmark_executors(spec, workers=args.workers, progress=Progress())
    body = format_benchmark_markdown(timings, spec=spec, command=args.command_line,
                                     machine=machine)
    print(body)
    if args.record:
        suffix = "" if spec.name == "throughput" else f": spec '{spec.name}'"
        write_benchmarks_section(BENCHMARKS_MD, body, heading=f"## Campaign executors{suffix}")
    return 1 if any(t.n_errors for t in timings) else 0


def main(argv: Sequence[str] | None = None) -> int:
    """Measure, print, optionally record in BENCHMARKS.md; return the exit code."""
    return run_main(build_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())

