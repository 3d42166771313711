"""Go/no-go before switch-on: judge a model 'ready', 'ready with conditions' or 'not ready'.

Checks the model's stability, its steady-state gain over its input range and, with
--data (a held-out record), the simulation fit [%], the residuals, the gain's
uncertainty and a closed-loop Monte Carlo of the MPC against --mc-runs plants drawn from
the parameter covariance (docs/guides/commission.rst, czmpc.commissioning.check). Every
reason is printed; the verdict is written beside the model as MODEL.check.json, where
'czmpc run' reads it.

Exit codes: 0 ready; 1 ready with conditions or not ready; 2 bad input (model or data
file, sampling times that differ).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from czmpc.cli import _argtypes

NAME = "check-model"
HELP = "go/no-go before switch-on: ready / ready with conditions / not ready, with every reason"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.add_argument("model", metavar="MODEL.json", type=Path, help="model file to check")
    parser.add_argument("--data", metavar="VALIDATION.csv", type=Path, default=None,
                        help="held-out record (time_s,triac_pct,power_kw, optionally "
                             "grid_voltage_factor, which drives a voltage-compensated model; "
                             "the model's Ts) for the fit and residual checks (default: none, "
                             "a condition)")
    _argtypes.add_log_options(parser)
    _argtypes.add_settings_options(parser)
    parser.add_argument("--mc-runs", metavar="N", type=_argtypes.non_negative_int, default=10,
                        help="plants of the closed-loop Monte Carlo, 0 skips it (about 1-3 s "
                             "each) (default: 10)")
    parser.add_argument("--seed", metavar="N", type=_argtypes.non_negative_int, default=0,
                        help="seed of the Monte Carlo draws (default: 0)")
    parser.add_argument("--no-write", action="store_true",
                        help="print the verdict only; do not write MODEL.check.json")


def run(args: argparse.Namespace) -> int:
    """Check, print every reason, write the verdict beside the model."""
    from czmpc.commissioning.check import check_model, write_check
    from sysid.atomic import file_sha256
    from sysid.modelfile import load_model

    model = load_model(args.model)
    data = None if args.data is None else _argtypes.read_log(args.data, args)
    settings = _argtypes.settings_for(args, model)
    check = check_model(model, data, settings, mc_runs=args.mc_runs, seed=args.seed,
                        model_sha256=file_sha256(args.model))
    print(check.format_text(), end="")
    if not args.no_write:
        path = write_check(check, args.model)
        print(f"wrote {path}")
    return check.exit_code
