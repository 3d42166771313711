"""Setpoint-tracking benchmark: every controller on every scenario and both plants.

Runs the offset-free MPC (OSQP), the CasADi/IPOPT NMPC on the same Hammerstein, the
linear offset-free MPC on the ARMAX(1,2,1), a PI with and without gain scheduling and
the open-loop inversion on every shipped scenario (or --scenarios), on the model plant
and the virtual heater (or --plants), with one fixed seed, and writes DIR/bench.md
(metrics table and goals), DIR/bench.csv (one row per run: IAE, ISE, overshoot,
settling time, steady-state error, input total variation, violations, failures, step
time median/p95/max) and DIR/figures/<scenario>.png (power and input of every
controller on shared axes). Progress (which run, elapsed, ETA) goes to stderr.

The goals (MPC IAE within 2 % of the NMPC's, its median step time at least 100x lower,
MPC beats the linear MPC on large_step and meltdown_ramp and the gain-scheduled PI
everywhere) are printed with the measured ratios; unless --no-record, the report goes
under '## Setpoint-tracking benchmark' in BENCHMARKS.md with this command line and the
machine. --short FACTOR shortens every scenario (times x FACTOR) for a quick look.

--update-golden is deprecated (since 0.2.0, removed in 0.3.0): the project's golden set
is the shipped regression suite regress_project_golden.toml, recorded with
`czmpc regress record regress_project_golden.toml --out tests/golden --force`, which
--update-golden now runs (with a warning) instead of the benchmark.

Exit codes: 0 done (goals met or not, unless --strict); 1 a goal missed with --strict;
2 bad input.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from czmpc.cli import _argtypes
from czmpc.cli._progress import Progress

NAME = "bench"
HELP = "benchmark MPC, NMPC, linear MPC, PI and open loop on every scenario and plant"
ORDER = 82



def _csv_names(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"expected comma-separated names; got {text!r}")
    return names


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--scenarios", metavar="A,B", type=_csv_names, default=None,
                        help="shipped scenario names or TOML files (default: all shipped)")
    parser.add_argument("--controllers", metavar="A,B", type=_csv_names, default=None,
                        help="mpc, nmpc, linear_mpc, pi_gs, pi, open_loop (default: all)")
    parser.add_argument("--plants", metavar="A,B", type=_csv_names, default=None,
                        help="model, heater (default: both)")
    parser.add_argument("--short", metavar="FACTOR", type=_argtypes.shortening_factor, default=None,
                        help="shorten every scenario: times x FACTOR, 0 < FACTOR <= 1")
    parser.add_argument("--model", metavar="MODEL.json", type=Path, default=None,
                        help="Hammerstein model (default: data/cz_heater_model.json)")
    parser.add_argument("--linear-model", metavar="MODEL.json", type=Path, default=None,
                        help="linear model of the linear MPC (default: "
                             "data/cz_heater_armax_model.json)")
    parser.add_argument("--out", metavar="DIR", type=Path, default=None,
                        help="write DIR/bench.md, DIR/bench.csv, DIR/figures/*.png "
                             "(required unless --update-golden)")
    parser.add_argument("--benchmarks-md", metavar="FILE", type=Path, default=None,
                        help="Markdown file for the '## Setpoint-tracking benchmark' section "
                             "(default: BENCHMARKS.md at the project root)")
    parser.add_argument("--no-record", action="store_true",
                        help="do not write the section into BENCHMARKS.md")
    parser.add_argument("--update-golden", action="store_true",
                        help="DEPRECATED, use 'czmpc regress record "
                             "regress_project_golden.toml --out tests/golden --force' (which this "
                             "runs, with a warning)")
    parser.add_argument("--golden-dir", metavar="DIR", type=Path, default=None,
                        help="where --update-golden writes (default: tests/golden)")
    parser.add_argument("--strict", action="store_true", help="exit 1 if a goal is missed")
    parser.add_argument("--settings", metavar="SETTINGS.toml", type=Path, default=None,
                        help="controller settings file for mpc, nmpc and linear_mpc (keys it "
                             "leaves out come from each model's defaults; see 'czmpc settings "
                             "--show'); default: each model's defaults")


def _command_line(args: argparse.Namespace) -> str:
    return "czmpc bench " + shlex.join(sys.argv[2:]) if len(sys.argv) > 1 else "czmpc bench"


_SHIPPED_SUITE = "regress_project_golden.toml"


def _update_golden(args: argparse.Namespace, progress: Progress) -> int:
    """Deprecated --update-golden: `czmpc regress record` of the shipped suite."""
    from czmpc.campaigns.golden import GOLDEN_DIR
    from czmpc.shipped import shipped_path
    from czmpc.testing.regress import RegressRunError, record_suite

    out = args.golden_dir or GOLDEN_DIR
    print(f"czmpc: warning: 'czmpc bench --update-golden' is deprecated (since 0.2.0) and will be "
          f"removed in 0.3.0; use: czmpc regress record {_SHIPPED_SUITE} --out {out} --force",
          file=sys.stderr)
    unused = [o for o, v in (("--scenarios", args.scenarios), ("--model", args.model),
                             ("--linear-model", args.linear_model)) if v is not None]
    if unused:
        print(f"czmpc: error: {', '.join(unused)} cannot be combined with --update-golden any more; "
              f"write a regression suite naming them and run 'czmpc regress record SUITE.toml'",
              file=sys.stderr)
        return 2
    try:
        path = record_suite(shipped_path(_SHIPPED_SUITE), out, force=True,
                            progress=lambda d, t: progress.fraction(d, t, what="runs"))
    except RegressRunError as exc:
        print(f"czmpc: error: {exc}", file=sys.stderr)
        return 1
    progress(f"recorded the project's golden set in {path.parent}")
    return 0


def run(args: argparse.Namespace) -> int:
    """Run the benchmark (or, deprecated, record the project's golden set)."""
    from benchmarks._md import machine_info
    from czmpc.campaigns.bench import (
        BenchModels,
        check_goals,
        run_bench,
        section_text,
        write_benchmarks_section,
        write_outputs,
    )
    from sim.scenario import list_scenarios, load_scenario
    from sysid.modelfile import load_model

    progress = Progress()
    if args.update_golden:
        return _update_golden(args, progress)

    shipped = BenchModels.shipped() if args.model is None or args.linear_model is None else None
    models = BenchModels(
        hammerstein=load_model(args.model) if args.model is not None else shipped.hammerstein,  # type: ignore[union-attr]
        linear=(load_model(args.linear_model) if args.linear_model is not None
                else shipped.linear),  # type: ignore[union-attr]
    )
    if args.out is None:
        print("czmpc: error: --out DIR is required (unless --update-golden)", file=sys.stderr)
        return 2
    names = args.scenarios if args.scenarios is not None else list(list_scenarios())
    scenarios = [load_scenario(n) for n in names]
    if args.short is not None:
        scenarios = [s.shortened(args.short) for s in scenarios]
    machine = machine_info()
    kwargs = {}
    if args.controllers is not None:
        kwargs["controllers"] = args.controllers
    if args.plants is not None:
        kwargs["plants"] = args.plants
    settings_doc = None
    if args.settings is not None:
        from czmpc.settings_file import load_settings_doc, settings_from_dict

        settings_doc = load_settings_doc(args.settings)
        # Refuse a bad file before the first run, not in the middle of the bench.
        settings_from_dict(settings_doc, models.hammerstein, source=str(args.settings))
    runs = run_bench(scenarios, models=models, progress=progress, settings_doc=settings_doc,
                     **kwargs)
    wall_s = progress.elapsed_s
    goals = check_goals(runs)
    text = section_text(runs, goals, command=_command_line(args), machine=machine.describe(),
                        wall_time_s=wall_s, short_factor=args.short)
    print(text, end="")
    write_outputs(runs, goals, args.out, header=text)
    progress(f"wrote {args.out / 'bench.md'}, {args.out / 'bench.csv'} and figures")
    if not args.no_record:
        target = args.benchmarks_md if args.benchmarks_md is not None else _argtypes.default_benchmarks_md()
        write_benchmarks_section(target, text)
        progress(f"recorded the section in {target}")
    if args.strict and not all(g.met for g in goals):
        return 1
    return 0
