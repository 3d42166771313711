"""Run the offset-free MPC in closed loop through a scenario and write trajectory, metrics, figure.

Builds the controller (OffsetFreeMPC) from an identified model file, runs it
against one of two plants through a scenario (setpoints, grid disturbances, sensor
faults; a shipped name or a TOML file), and writes into DIR:

  trajectory.csv  one row per 2 s sample: time_s [s], setpoint_kw, power_measured_kw,
                  power_true_kw [kW], triac_pct [%], step_time_s [s] (controller wall
                  time), disturbance_estimate_kw (the controller's d), and the MPC's
                  status of the step: mode (on, predict, off), status (good; predicted:
                  no usable measurement; clamped: the input on a limit; held; shed),
                  solver_status (the QP's: solved, solved inaccurate, ..., or skipped)
                  and fallback (none, shifted_plan, target)
  metrics.json    the run's settings (scenario, plant, seed, controller tuning), the czmpc
                  version and the model file's SHA-256, and its metrics: per setpoint
                  change IAE [kW s], overshoot [kW, %], 2 % settling time [s],
                  steady-state error [kW]; overall IAE, ISE, input moves, limit/rate
                  violations, solver fallbacks, step-time statistics [ms]
  figure.png      power with setpoint (and soft limits) [kW], TRIAC input with its
                  allowed range [%], disturbance estimate [kW], on one time axis

and prints the metrics table. Errors are those of the plant's true power (without
sensor noise, spikes, missing samples); the steady-state errors of the measured power
are given beside them (metrics_measured in metrics.json): on the model plant they
are the ones to judge offsets by, since its noise C/A e is a slow disturbance the
controller rightly rejects, which moves the noise-free power.

Plants: 'model' runs the model's own difference equation (no model mismatch) from the
scenario's initial input; 'heater' runs the virtual CZ heater (grey-box physics: model
mismatch) from the input whose steady power is the initial setpoint; 'thermal' runs a
furnace zone (sim.thermal_plant: lags of 20 s and 140 s, a 0.1 degC sensor; its output,
a temperature, takes the power's place) from the input whose steady temperature is the
initial setpoint, for a model identified from it (tools/regenerate_thermal_model.py).

Shipped scenarios: staircase, level_shift, voltage_sag, large_step, meltdown_ramp,
missing_samples, combined.

A tuned PID table (czmpc tune-pid): --controller DIR/pid_table.csv runs three controllers
with the same limits, start and seed: the table's scheduled PI (pi_table), the MPC (mpc)
and the table's row at the operating point as a fixed-gain PI (pi_fixed). DIR then holds
one sub-directory per controller with the three files above, and comparison.csv: per
controller the IAE [kW s], the largest IAE of one setpoint change [kW s], the largest
overshoot [% of the step] and the input travel [%], with the ratio of IAE, overshoot and
travel to the MPC's [-].

What only an MPC can use: a scenario with setpoint_preview_s = 60 tells the MPC the
setpoints of the coming 60 s (a recipe), and measured_voltage = true gives every
controller the grid voltage measured over the last sample (the PIs divide their drive by
v^2 through the model's characterizer, as a DCS would). See docs/theory.rst, C8 and C9.

The generated C step (czmpc codegen): --controller c:DIR builds DIR with the system's C
compiler and runs it beside the Python MPC of the model and settings DIR was generated
from (give DIR/model.json as --model); DIR then holds c_step/ and mpc/ with the three
files above, and the command prints both runs' metrics and the largest difference of
their inputs [%], the samples where they are bit-equal and where mode, status or
fallback differ.

A plant that differs from the model: --gain-factor, --tau-s, --extra-delay-samples and
--drift as for 'czmpc plant serve' (see sim.drift); the plant then starts at the nominal
plant's input for the initial setpoint.

Exit codes: 0 done; 2 bad input (unknown scenario, bad TOML, bad model file, model and
scenario with different sampling times, unusable settings).
"""

from __future__ import annotations

import argparse
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

from czmpc.cli import _argtypes, _variation
from czmpc.cli._progress import Progress, print_written
from czmpc.errors import SettingsError

if TYPE_CHECKING:
    from czmpc.settings import MPCSettings
    from sim.scenario import Scenario
    from sysid.model import HammersteinModel

NAME = "simulate"
HELP = "run the offset-free MPC through a scenario on a plant; write trajectory, metrics, figure"

#: A run reports its progress on stderr once it has taken this long [s].
PROGRESS_AFTER_S = 1.0
#: ``--controller c:DIR``: a directory written by ``czmpc codegen``.
C_STEP_PREFIX = "c:"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.add_argument(
        "--model", metavar="MODEL.json", type=Path, required=True,
        help="identified model file (format czmpc-model/1, e.g. data/cz_heater_model.json "
             "or the model.json 'czmpc identify' writes); Ts must equal the scenario's",
    )
    parser.add_argument(
        "--scenario", metavar="NAME|FILE.toml", required=True,
        help="shipped scenario name (see above) or a scenario TOML file",
    )
    parser.add_argument(
        "--plant", choices=("model", "heater", "thermal"), default="model",
        help="'model': the model's own equation (no mismatch); 'heater': the virtual CZ "
             "heater (model mismatch); 'thermal': a furnace zone, a plant of another kind "
             "(setpoints in degC; its model: tests/data/models/thermal_model.json) "
             "(default: model)",
    )
    parser.add_argument(
        "--seed", metavar="N", type=_argtypes.seed, default=0,
        help="seed of the plant noise and sensor faults; the same seed gives the same run "
             "bit for bit (default: 0)",
    )
    _argtypes.add_settings_options(parser)
    parser.add_argument(
        "--noise", action=argparse.BooleanOptionalAction, default=None,
        help="plant noise on or off: the model's innovations (noise_std_kw [kW]) through "
             "its noise model, or the heater's sensor noise and grid-voltage wander "
             "(default: as the scenario's plant_noise says)",
    )
    parser.add_argument(
        "--short", metavar="FACTOR", type=_argtypes.shortening_factor, default=None,
        help="multiply every time of the scenario (duration, events) by FACTOR in (0, 1] "
             "for a quick run; Ts is kept, so responses may not settle (default: 1)",
    )
    parser.add_argument(
        "--out", metavar="DIR", type=Path, required=True,
        help="output directory for trajectory.csv, metrics.json, figure.png (created; "
             "files of those names are replaced)",
    )
    parser.add_argument(
        "--controller", metavar="pid_table.csv|c:DIR", type=Path, default=None,
        help="pid_table.csv: run this PID table (czmpc tune-pid) beside the MPC and a "
             "fixed-gain PI at the operating point, and compare them; c:DIR: run the C step "
             "'czmpc codegen' wrote into DIR (built with the system's C compiler) beside the "
             "Python MPC of DIR/model.json and DIR/settings.toml, and say how far their inputs "
             "are apart (default: the MPC alone)",
    )
    _variation.add_variation_options(parser)


def run(args: argparse.Namespace) -> int:
    """Load model and scenario, run the closed loop, write the files, print the metrics."""
    from czmpc.campaigns.simulation import run_simulation, write_outputs
    from sim.scenario import load_scenario
    from sysid.modelfile import load_model

    model = load_model(args.model)
    scenario = load_scenario(args.scenario)
    if args.short is not None and args.short < 1.0:
        scenario = scenario.shortened(args.short)
    noise = scenario.plant_noise if args.noise is None else bool(args.noise)
    settings = _argtypes.settings_for(args, model)
    if args.controller is not None and str(args.controller).startswith(C_STEP_PREFIX):
        return _compare_generated(args, model, scenario, noise,
                                  Path(str(args.controller)[len(C_STEP_PREFIX):]))
    if args.controller is not None:
        return _compare(args, model, scenario, noise, settings)
    outcome = run_simulation(model, scenario, plant=args.plant, seed=args.seed,
                             settings=settings, noise=noise,
                             variation=_variation.variation(args),
                             progress=partial(Progress(quiet_for_s=PROGRESS_AFTER_S).fraction,
                                              what="simulating"))
    files = write_outputs(outcome, args.out, model_path=args.model)
    print(outcome.metrics_table())
    print_written(files)
    return 0


def _compare(args: argparse.Namespace, model: HammersteinModel, scenario: Scenario,
             noise: bool, settings: MPCSettings) -> int:
    """Run the PID table, the MPC and the fixed PI; write each run and comparison.csv."""
    from czmpc.campaigns.pid_comparison import compare_pid_table, comparison_csv, comparison_table
    from czmpc.campaigns.simulation import write_outputs
    from czmpc.pid.table import read_pid_table
    from sysid.atomic import atomic_write_text

    if not _variation.variation(args).is_nominal:
        raise SettingsError("simulate: --controller compares on the nominal plant; drop the "
                            "plant-variation options (--gain-factor, --tau-s, ...)")
    table = read_pid_table(args.controller)
    summaries = compare_pid_table(model, table.schedule, scenario, plant=args.plant,
                                  seed=args.seed, noise=noise, settings=settings)
    files: list[Path] = []
    for s in summaries:
        files += write_outputs(s.outcome, args.out / s.name, model_path=args.model)
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out / "comparison.csv", comparison_csv(summaries))
    files.append(args.out / "comparison.csv")
    print(comparison_table(summaries, title=(
        f"scenario '{scenario.name}', plant '{args.plant}', seed {args.seed}, noise "
        f"{'on' if noise else 'off'}, setpoint preview {scenario.setpoint_preview_s:g} s, "
        f"voltage {'measured' if scenario.measured_voltage else 'not measured'}; "
        f"table {args.controller}")))
    print_written(files)
    return 0


def _compare_generated(args: argparse.Namespace, model: HammersteinModel, scenario: Scenario,
                       noise: bool, directory: Path) -> int:
    """Run the generated C step and the Python MPC; write each run and print how they differ."""
    from czmpc.campaigns.generated_comparison import COMPARED, compare_generated
    from czmpc.campaigns.simulation import write_outputs

    if args.settings is not None or args.preset != "default":
        raise SettingsError(f"simulate: --controller c:{directory} runs the settings compiled into "
                            f"the C step ({directory}/settings.toml); drop --settings/--preset")
    if not _variation.variation(args).is_nominal:
        raise SettingsError("simulate: --controller compares on the nominal plant; drop the "
                            "plant-variation options (--gain-factor, --tau-s, ...)")
    comparison = compare_generated(
        model, directory, scenario, plant=args.plant, seed=args.seed, noise=noise,
        progress=partial(Progress(quiet_for_s=PROGRESS_AFTER_S).fraction, what="simulating"))
    files: list[Path] = []
    for name, outcome in zip(COMPARED, (comparison.c_step, comparison.mpc), strict=True):
        files += write_outputs(outcome, args.out / name, model_path=args.model)
    print(f"scenario '{scenario.name}', plant '{args.plant}', seed {args.seed}, noise "
          f"{'on' if noise else 'off'}; C step {directory}")
    print(comparison.table())
    print_written(files)
    return 0
