"""The main job end to end: experiment -> identification -> offset-free MPC on two plants.

1. Generate the paper's identification experiment on the virtual heater (seed 2010)
   and print its step gains beside the paper's Table 3.
2. Identify the paper's models from it (`czmpc identify`) and print the paper's
   findings as measured on these data.
3. Run the offset-free MPC on the staircase scenario (45 -> 65 kW) against the plant
   built from the identified model and against the virtual heater (model mismatch), and
   print the tracking metrics.

Everything is written under ``--out``; ``make demo`` runs this with ``--out out/demo``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from czmpc.cli._progress import Progress, print_written
from czmpc.shipped import EXPERIMENT_CSV, shipped_path

NAME = "demo"
HELP = "run the whole job: experiment, identification, MPC on the staircase (both plants)"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.formatter_class = argparse.HelpFormatter  # its description is re-wrapped
    parser.add_argument("--out", type=Path, default=Path("out/demo"),
                        help="output directory (default: out/demo)")
    parser.add_argument("--scenario", default="staircase",
                        help="closed-loop scenario name or TOML file (default: staircase)")


def run(args: argparse.Namespace) -> int:
    """Run the three stages and print a summary."""
    from czmpc.campaigns.simulation import run_simulation, write_outputs
    from czmpc.cli.experiment import format_table3_comparison
    from czmpc.cli.identify import identify_to_directory
    from sim.experiment import DEFAULT_SEED, identification_experiment, table3_comparison
    from sim.scenario import load_scenario
    from sysid.data import format_csv, write_csv
    from sysid.modelfile import load_model

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    stage = Progress(n_stages=4).stage

    stage("identification experiment on the virtual CZ heater (paper Fig. 2)")
    data = identification_experiment(rng=DEFAULT_SEED)
    experiment_csv = out / "experiment.csv"
    write_csv(data, experiment_csv)
    shipped = shipped_path(EXPERIMENT_CSV)
    same = shipped.is_file() and shipped.read_text(encoding="utf-8") == format_csv(data)
    print(f"{experiment_csv}: {data.n_samples} samples at Ts = {data.ts_s:g} s, seed {DEFAULT_SEED}"
          + (f"; identical to the shipped {EXPERIMENT_CSV}" if same else ""))
    print(format_table3_comparison(table3_comparison(data)), end="")

    stage("identification: the paper's pipeline (secs. 5-7)")
    outcome = identify_to_directory(experiment_csv, out / "identify",
                                    command=f"czmpc demo --out {out}")
    model = load_model(outcome.model_path)
    crit = model.criteria
    print(f"model for control: {outcome.model_path} (noise-model Hammerstein, eq. 30): "
          f"V = {crit.ballistic_mse_kw2:.4g} kW^2, W = {crit.one_step_mse_kw2:.3g} kW^2")
    for finding in outcome.findings:
        print(f"  [{'x' if finding.verdict == 'shown' else ' '}] {finding.claim}: {finding.ours}")
    print(f"report: {outcome.report_path}")
    if outcome.unconverged:
        print(f"NOTE: fits that did not converge: {', '.join(outcome.unconverged)}")

    scenario = load_scenario(args.scenario)
    for plant in ("model", "heater"):
        label = "plant built from the identified model" if plant == "model" else \
            "virtual CZ heater (model mismatch)"
        stage(f"offset-free MPC, scenario '{scenario.name}', {label}")
        sim_outcome = run_simulation(model, scenario, plant=plant, seed=1)
        files = write_outputs(sim_outcome, out / f"simulate-{plant}", model_path=outcome.model_path)
        print(sim_outcome.metrics_table())
        print_written(files)
    print(f"\nall outputs under {out}/", file=sys.stderr)
    return 0 if not outcome.unconverged else 1
