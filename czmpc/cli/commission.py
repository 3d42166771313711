"""Commission a heater from nothing: test, identify, check, report, and switch the MPC on.

czmpc commission CONFIG.toml --range-pct LO HI [--tau-s T] --out DIR [--switch-on]
designs an open-loop test over LO..HI % (as 'czmpc design-test', timed from the time
constant T [s]: --tau-s, else the slowest pole of CONFIG.toml's [controller] model),
runs it through the plant link (as 'czmpc run --test': [test] and [safety] are needed),
identifies a model from the log, checks it (as 'czmpc check-model'), writes
DIR/commissioning.md with its figures and, with --switch-on and a 'ready' verdict only,
runs the MPC with the new model (as 'czmpc run'). Guide: docs/guides/commission.rst.

Exit codes: 0 a 'ready' model (and a switched-on run that ended normally); 1 the test
was aborted, or the verdict is not 'ready'; 2 bad input.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from czmpc.cli import _argtypes as t
from czmpc.cli._progress import Progress

NAME = "commission"
HELP = "commission a heater: design and run a test, identify, check, report, switch the MPC on"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.add_argument("config", metavar="CONFIG.toml", type=Path,
                        help="run configuration with [plant], [nodes], [test], [safety] "
                             "(see czmpc run --help)")
    parser.add_argument("--range-pct", type=t.percent, nargs=2,
                        metavar=("LO", "HI"), required=True,
                        help="band of TRIAC inputs the test may visit [%%]")
    parser.add_argument("--tau-s", type=t.seconds, default=None,
                        help="guess of the dominant time constant [s] (default: from the "
                             "config's [controller] model)")
    parser.add_argument("--out", metavar="DIR", type=Path, required=True,
                        help="output directory: test.csv, test_run.csv, model.json, "
                             "identification/, commissioning.md, figures/, run.csv")
    parser.add_argument("--switch-on", action="store_true",
                        help="run the MPC with the new model if the verdict is 'ready'")
    parser.add_argument("--duration-s", type=t.seconds, default=None,
                        help="test length [plant s] (default: the shortest the design accepts)")
    parser.add_argument("--kind", choices=t.TEST_SIGNAL_KINDS, default="mixed",
                        help="test signal (default: mixed = staircase + GBN; multilevel: "
                             "the short test for a slow plant)")
    parser.add_argument("--max-step-pct", type=t.percent_step, default=100.0,
                        help="largest designed move per sample [%%] (default: no limit)")
    parser.add_argument("--seed", type=t.signal_seed, default=0,
                        help="seed of the GBN or multilevel part (default: 0)")
    parser.add_argument("--run-duration-s", type=t.seconds, default=None,
                        help="plant time the MPC runs after switch-on [s] (default: the "
                             "config's [run] duration_s, else until Ctrl-C)")
    parser.add_argument("--mc-runs", type=t.integer(0, "a count"), default=20,
                        help="plants in the check's closed-loop Monte Carlo (default: 20)")


def run(args: argparse.Namespace) -> int:
    """Run the journey and say where it ended."""
    from czmpc.commissioning.dither import dominant_time_constant_s
    from czmpc.commissioning.journey import JourneyError, JourneyPlan, commission
    from czmpc.runtime.config import load_run_config
    from czmpc.runtime.loop import tty_status
    from sysid.modelfile import load_model

    config = load_run_config(args.config)
    lo, hi = args.range_pct
    if not lo < hi:
        raise JourneyError(f"--range-pct: expected LO < HI; got {lo:g} {hi:g}")
    tau_s = args.tau_s
    if tau_s is None:
        if config.model_path is None:
            raise JourneyError("--tau-s: missing; give a guess of the heater's dominant time "
                               "constant [s] (or a prior model in [controller] model)")
        tau_s = dominant_time_constant_s(load_model(config.model_path))
    plan = JourneyPlan(range_pct=(lo, hi), tau_s=tau_s, out_dir=args.out,
                       duration_s=args.duration_s, kind=args.kind, max_step_pct=args.max_step_pct,
                       seed=args.seed, switch_on=args.switch_on,
                       run_duration_s=args.run_duration_s, mc_runs=args.mc_runs)
    words = ["czmpc", NAME, str(args.config), "--range-pct", f"{lo:g}", f"{hi:g}",
             "--tau-s", f"{tau_s:g}", "--out", str(args.out)]
    if args.duration_s is not None:
        words += ["--duration-s", f"{args.duration_s:g}"]
    words += ["--kind", args.kind, "--max-step-pct", f"{args.max_step_pct:g}", "--seed",
              str(args.seed), "--mc-runs", str(args.mc_runs)]
    if args.run_duration_s is not None:
        words += ["--run-duration-s", f"{args.run_duration_s:g}"]
    if args.switch_on:
        words.append("--switch-on")
    progress = Progress()
    result = commission(config, plan, progress=progress, run_status=tty_status(),
                        command=" ".join(shlex.quote(w) for w in words))
    print(f"commissioning report: {result.report_path}")
    for message in result.messages:
        print(f"czmpc: {message}", file=sys.stderr)
    if result.stage == "test aborted":
        print(f"czmpc: error: test aborted: {result.test_summary.abort_reason}; the TRIAC was "
              f"moved to {config.safe_triac_pct:g} %", file=sys.stderr)
        return 1
    check = result.check
    if check is not None:
        print(f"verdict: {check.verdict}; held-out fit {result.fit_pct:.1f} %")
        for reason in check.reasons:
            print(f"  - {reason}")
    if result.run_summary is not None:
        s = result.run_summary
        print(f"MPC run: {s.n_steps} steps, stopped by {s.stopped_by}; log {args.out / 'run.csv'}")
    return 0 if result.ok else 1
