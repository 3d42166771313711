"""Print the effective controller settings for a model, as a settings file.

The output is a complete settings TOML file: every key with its value (defaults as they
follow from the model) and, as a comment, its meaning and unit; pass it back with
--settings or [controller].settings (docs/reference/settings_file.rst). The settings are
checked completely, including that a controller can be built from them and the model.

Before the keys, comments state the defaults that protect the CZ heater (a rate limit,
the validity band), whether the model's defaults set them and why, and what each costs:
the IAE it adds on a named scenario, measured (`PROTECTION_COSTS`).

Exit codes: 0 printed; 2 names what is wrong.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from czmpc.cli import _argtypes

if TYPE_CHECKING:
    from sysid.model import HammersteinModel

NAME = "settings"
HELP = "show (and check) the effective MPC settings for a model, as a settings TOML file"


@dataclass(frozen=True, kw_only=True)
class ProtectionCost:
    """What one protecting default costs, measured on one closed loop.

    Parameters
    ----------
    setting :
        The `MPCSettings` field.
    model :
        The model file the run's controller was built from (repository path).
    scenario, plant :
        The scenario (shipped name or repository path) and `czmpc simulate --plant`.
    iae_with, iae_without :
        IAE of the run (seed 0, default noise) with the model's default and with the
        protection off (no rate limit; a margin of 100 %, i.e. the whole 0..100 %) [output
        unit times s].
    unit :
        The output's unit.
    note :
        Why the cost is what it is, or "".
    """

    setting: str
    model: str
    scenario: str
    plant: str
    iae_with: float
    iae_without: float
    unit: str
    note: str = ""

    def sentence(self) -> str:
        """The cost in words: IAE with and without, and the increase in percent."""
        extra_pct = 100.0 * (self.iae_with / self.iae_without - 1.0)
        return (f"scenario '{self.scenario}' on the {self.plant} plant ({self.model}, seed 0): "
                f"IAE {self.iae_with:.1f} {self.unit} s, {self.iae_without:.1f} without "
                f"({extra_pct:+.0f} %)" + (f"; {self.note}" if self.note else ""))


#: Measured costs of the protecting defaults (re-measured by
#: tests/czmpc/test_default_settings_other_plant.py to 1 %).
PROTECTION_COSTS: tuple[ProtectionCost, ...] = (
    ProtectionCost(setting="max_move_pct_per_step", model="czmpc/data/cz_heater_model.json",
                   scenario="staircase", plant="heater", iae_with=128.90, iae_without=100.98,
                   unit="kW"),
    ProtectionCost(setting="validity_margin_pct", model="czmpc/data/cz_heater_model.json",
                   scenario="large_step", plant="heater", iae_with=31034.0, iae_without=1516.0,
                   unit="kW", note="its 80 kW lies beyond the band's reach (none on 'staircase')"),
    ProtectionCost(setting="validity_margin_pct", model="tests/data/models/thermal_model.json",
                   scenario="tests/data/scenarios/thermal_steps.toml", plant="thermal",
                   iae_with=8495.0, iae_without=6045.0, unit="degC"),
)


def protection_lines(model: HammersteinModel) -> list[str]:
    """Comment lines: the protecting defaults for ``model``, why, and their measured cost."""
    from czmpc.inversion import allowed_triac_range
    from czmpc.settings import RATE_LIMIT_MIN_IMMEDIATE_FRACTION, MPCSettings, immediate_fraction

    default = MPCSettings.default_for(model)
    fraction = immediate_fraction(model)
    lo, hi = allowed_triac_range(model, triac_min_pct=default.triac_min_pct,
                                 triac_max_pct=default.triac_max_pct,
                                 validity_margin_pct=default.validity_margin_pct)
    if default.max_move_pct_per_step is not None:
        rate = (f"max_move_pct_per_step = {default.max_move_pct_per_step:g} by default: a move "
                f"reaches this model's output at once ({fraction:.2f} of its largest effect, "
                f">= {RATE_LIMIT_MIN_IMMEDIATE_FRACTION:g}), and an element must not be slammed; "
                f"it costs")
    else:
        rate = (f"max_move_pct_per_step: no rate limit by default: a move reaches this model's "
                f"output only through its lags ({fraction:.2g} of its largest effect at once, "
                f"< {RATE_LIMIT_MIN_IMMEDIATE_FRACTION:g}); where it is set, it costs")
    band = (f"validity_margin_pct = {default.validity_margin_pct:g} by default: the input stays "
            f"within {lo:.4g}..{hi:.4g} % (the identified range and the margin), where the "
            f"model was seen; it costs")
    lines = ["Defaults that protect the CZ heater and what they cost (IAE with and without them):"]
    for setting, text in (("max_move_pct_per_step", rate), ("validity_margin_pct", band)):
        lines += [text, *(f"  {c.sentence()}" for c in PROTECTION_COSTS if c.setting == setting)]
    return [f"# {line}" for line in lines]


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
    if not args.no_comments:
        print("\n".join(protection_lines(model)))
    print(settings_to_toml(settings, comments=not args.no_comments), end="")
    return 0
