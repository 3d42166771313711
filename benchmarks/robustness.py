"""Robustness benchmark: the shipped spec campaign_robustness.toml, its table in BENCHMARKS.md.

The campaign engine runs the offset-free MPC on the model perturbed in gain, slow time
constant and delay and on the virtual heater (staircase, noise-free, seed 1); the rows
carry the measures against the reachable setpoint (`czmpc.campaigns.measure`). This
module writes the section '## Robustness campaign' of BENCHMARKS.md: one table row per
plant (offset-free, largest steady error, IAE and its ratio to the nominal plant's,
overshoot, input violations, solver failures) and a summary. ``--full`` runs the full
grid (gain x0.70 .. x1.30 in steps of 0.05, time constant x0.5 .. x2 in factors of
2^(1/4), delay +0/+1). ``czmpc campaign report DIR`` draws the heat map of the IAE ratios.

    python -m benchmarks.robustness [--full] [--time-scale X] [--out DIR]
                                    [--executor serial|processes] [--workers N]
                                    [--benchmarks-md FILE] [--no-record]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from benchmarks._md import (
    add_campaign_run_options,
    benchmark_parser,
    machine_info,
    run_main,
    write_benchmarks_section,
)
from czmpc.campaigns.campaign import spec_from_dict
from czmpc.campaigns.measure import OFFSET_FREE_THRESHOLD_KW
from czmpc.campaigns.runner import run_campaign
from czmpc.shipped import shipped_path

Row = Mapping[str, Any]
SECTION_HEADING = "## Robustness campaign"
#: The full grid of ``--full``.
FULL_GRID: dict[str, list[float]] = {
    "gain_factors": [round(0.7 + 0.05 * k, 2) for k in range(13)],
    "time_constant_factors": [0.5, 0.59, 0.71, 0.84, 1.0, 1.19, 1.41, 1.68, 2.0],
    "extra_delays_steps": [0, 1],
}


def iae_ratios(rows: Sequence[Row]) -> dict[str, float]:
    """Per run id: its reachable-setpoint IAE over the nominal plant's (same controller,
    scenario and seed; the heater's over the nominal model plant's)."""
    nominal = {(r["controller"], r["scenario"], r["seed"]): float(r["iae_changes_reachable_kw_s"])
               for r in rows if r["plant"] == "perturbed g1 m1 d+0" and r["status"] == "ok"}
    return {str(r["run_id"]): float(r["iae_changes_reachable_kw_s"])
            / nominal.get((r["controller"], r["scenario"], r["seed"]), math.nan)
            for r in rows if r["status"] == "ok"}


def section_text(rows: Sequence[Row], *, command: str, machine: str, wall_time_s: float,
                 n_resumed: int = 0) -> str:
    """The BENCHMARKS.md section body: command, machine, the table, the summary."""
    ratios = iae_ratios(rows)
    ok = [r for r in rows if r["status"] == "ok"]
    lines = [
        f"Command: `{command}`", "", f"Machine: {machine}", "",
        f"{len(rows)} runs in {wall_time_s:.1f} s wall time"
        + (f" ({n_resumed} resumed from an earlier run)" if n_resumed else "")
        + ". Errors are taken against the "
        "reachable setpoint (the setpoint clipped to the powers that plant holds with the "
        "allowed input); offset-free: |mean measured error over the last quarter of each "
        f"step| < {OFFSET_FREE_THRESHOLD_KW:g} kW.", "",
        "| controller | plant | scenario | offset-free | max abs SSE [kW] | IAE [kW s] | "
        "IAE ratio | max overshoot [kW] | max overshoot [%] | input violations | "
        "solver failures |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if r["status"] != "ok":
            lines.append(f"| {r['controller']} | {r['plant']} | {r['scenario']} | "
                         f"error: {r['error']} | | | | | | | |")
            continue
        unreachable = int(r["n_unreachable_changes"])
        verdict = ("yes" if r["offset_free"] else "**NO**") + (
            f" ({unreachable} unreachable)" if unreachable else "")
        lines.append(
            f"| {r['controller']} | {r['plant']} | {r['scenario']} | {verdict} | "
            f"{r['max_abs_steady_state_error_reachable_kw']:.4f} | "
            f"{r['iae_changes_reachable_kw_s']:.1f} | {ratios[str(r['run_id'])]:.2f} | "
            f"{r['max_overshoot_reachable_kw']:.3f} | {r['max_overshoot_reachable_pct']:.1f} | "
            f"{r['n_allowed_range_violations']} | {r['n_solver_failures']} |")
    worst = max(ok, key=lambda r: ratios[str(r["run_id"])], default=None)
    lines += ["", f"Offset-free on {sum(bool(r['offset_free']) for r in ok)} of {len(rows)} "
              f"plants; {sum(int(r['n_allowed_range_violations']) for r in ok)} input "
              f"violations" + ("" if worst is None else
                               f"; worst IAE ratio {ratios[str(worst['run_id'])]:.2f} "
                               f"({worst['plant']})") + "."]
    return "\n".join(lines) + "\n"


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.robustness``."""
    parser = benchmark_parser("robustness", __doc__)
    parser.add_argument("--full", action="store_true", help="the full grid (module notes)")
    parser.add_argument("--time-scale", metavar="X", type=float, default=None,
                        help="shorten the scenario: times x X, 0 < X <= 1")
    add_campaign_run_options(parser)
    return parser


def _run(args: argparse.Namespace) -> int:
    path = shipped_path("campaign_robustness.toml")
    doc = tomllib.loads(path.read_text(encoding="utf-8"))
    if args.full:
        doc["plants"] = [{"kind": "perturbed", **FULL_GRID}, {"kind": "heater"}]
    if args.time_scale is not None:
        doc["time_scale"] = args.time_scale
    spec = spec_from_dict(doc, source=str(path), base_dir=path.parent)
    machine = machine_info().describe()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        outcome = run_campaign(spec, args.out or Path(tmp) / "robustness",
                               executor=args.executor, workers=args.workers)
    body = section_text(outcome.rows, command=args.command_line, machine=machine,
                        wall_time_s=time.perf_counter() - t0, n_resumed=outcome.n_skipped)
    print(body, end="")
    if not args.no_record:
        write_benchmarks_section(args.benchmarks_md, body, heading=SECTION_HEADING)
    return 1 if outcome.n_errors else 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print its section, record it in BENCHMARKS.md; return the exit code."""
    return run_main(build_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())
