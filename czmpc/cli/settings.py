"""Print the effective controller settings for a model, as a settings file.

The output is a complete settings TOML file: every key with its value (defaults as they
follow from the model) and, as a comment, its meaning and unit; pass it back with
--settings or [controller].settings (docs/reference/settings_file.rst). The settings are
checked completely, including that a controller can be built from them and the model.

Exit codes: 0 printed; 2 names what is wrong.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from czmpc.cli import _argtypes

NAME = "settings"
HELP = "show (and check) the effective MPC settings for a model, as a settings TOML file"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.add_argument("--show", action="store_true",
                        help="print the effective settings as TOML (the default action)")
    parser.add_argument("--model", metavar="MODEL.json", type=Path, default=None,
                        help="the model the settings are for (default: the shipped CZ "
                             "heater model)")
    _argtypes.add_settings_options(parser)
    parser.add_argument("--no-comments", action="store_true",
                        help="values only, without the meaning and unit of each key")


def run(args: argparse.Namespace) -> int:
    """Build the settings, check them against the model, print them."""
    from czmpc.controller import OffsetFreeMPC
    from czmpc.settings_file import settings_to_toml
    from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
    from sysid.modelfile import load_model

    model_path = args.model if args.model is not None else shipped_path(HAMMERSTEIN_MODEL_JSON)
    model = load_model(model_path)
    settings = _argtypes.settings_for(args, model)
    OffsetFreeMPC(model, settings)  # raises DesignError (exit 2) if no controller can be built
    source = (f"file {args.settings}" if args.settings is not None
              else f"preset {args.preset!r}")
    print(f"# czmpc MPC settings for {model_path} (Ts = {model.ts_s:g} s), from {source}.\n"
          f"# Optional settings are switched off with \"off\".")
    print(settings_to_toml(settings, comments=not args.no_comments), end="")
    return 0
