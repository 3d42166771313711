"""Run the paper's identification experiment on the virtual heater and write it as CSV.

Simulates the experiment of the paper's Fig. 2 on the grey-box virtual CZ heater
(`sim.heater`): about 24,000 s at 2 s sampling, a staircase of the TRIAC input up to
45 %, a steady stretch over t in [8700, 10300] s, the four +5 % steps of Table 3 and
the two grid events of sec. 5.2. Writes FILE.csv (header time_s,triac_pct,power_kw)
and prints a summary with the measured step gains beside the paper's Table 3. The
default seed reproduces the shipped data/cz_heater_experiment.csv byte for byte.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sim.experiment import Table3Row

from czmpc.cli import _argtypes
from czmpc.reports.tables import format_table

NAME = "experiment"
HELP = "simulate the paper's identification experiment on the virtual heater; write CSV"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.add_argument(
        "--seed", metavar="N", type=_argtypes.seed, default=None,
        help="seed of the sensor noise and grid wander (default: the seed of the shipped "
             "data/cz_heater_experiment.csv)",
    )
    parser.add_argument(
        "--out", metavar="FILE.csv", type=Path, required=True,
        help="file to write (overwritten; its directory must exist)",
    )


def format_table3_comparison(rows: Sequence[Table3Row]) -> str:
    """Render `sim.experiment.table3_comparison` rows beside the paper's values."""
    lines = [
        "Instantaneous gains of the steps after t = 1e4 s (paper Table 3), deviations from "
        "(45 %, 45 kW),",
        "levels after subtracting the 0.15 kW level shift from t = 20714 s as the paper did:",
        format_table(
            ["time [s]", "ds [%]", "dP paper [kW]", "dP here [kW]", "r paper [kW/%]", "r here [kW/%]"],
            [[f"{row.time_s:.0f}", f"{row.ds_before_pct:5.2f} -> {row.ds_after_pct:5.2f}",
              f"{row.paper_dp_before_kw:6.2f} -> {row.paper_dp_after_kw:6.2f}",
              f"{row.dp_before_kw:6.2f} -> {row.dp_after_kw:6.2f}",
              f"{row.paper_gain_kw_per_pct:.2f}", f"{row.gain_kw_per_pct:.3f}"] for row in rows],
            align="rrrrrr"),
    ]
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    """Simulate, write the CSV and print the summary."""
    from sim.experiment import DEFAULT_SEED, identification_experiment, table3_comparison
    from sysid.data import write_csv

    seed = DEFAULT_SEED if args.seed is None else args.seed
    data = identification_experiment(rng=seed)
    write_csv(data, args.out)
    print(
        f"wrote {args.out}: {data.n_samples} samples, {data.duration_s:g} s at "
        f"{data.ts_s:g} s (seed {seed})\n"
        f"input {data.triac_pct.min():g} to {data.triac_pct.max():g} %, power "
        f"{data.power_kw.min():g} to {data.power_kw.max():g} kW"
    )
    print(format_table3_comparison(table3_comparison(data)), end="")
    return 0
