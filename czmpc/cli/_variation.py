"""Options of a plant that differs from its model and drifts (plant serve, simulate)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from czmpc.cli import _argtypes

if TYPE_CHECKING:
    from sim.drift import PlantVariation

def add_variation_options(p: argparse.ArgumentParser) -> None:
    """The plant's deviation from its model and its drift in time (sim.drift)."""
    g = p.add_argument_group("plant variation (a plant that differs from its model)")
    g.add_argument("--gain-factor", metavar="F", type=_argtypes.positive_float, default=1.0,
                   help="multiply every gain of the plant by F from the start (default: 1)")
    g.add_argument("--tau-s", metavar="T", type=_argtypes.seconds,
                   default=None, help="time constant of the plant's slow mode [s] (the "
                                      "heater's power sag; default: the plant's own)")
    g.add_argument("--extra-delay-samples", metavar="N", type=_argtypes.non_negative_int, default=0,
                   help="samples of input delay added to the plant's own (default: 0)")
    g.add_argument("--drift", metavar="Q=V@T", action="append", default=[],
                   help="at plant time T [s] the gain factor (Q=gain, V a factor) or the "
                        "time constant (Q=tau, V in s) moves to V, e.g. gain=0.75@3600; "
                        "repeatable")


def variation(args: argparse.Namespace) -> PlantVariation:
    """The `PlantVariation` the options ask for (PlantError for a bad --drift)."""
    from sim.drift import PlantVariation, parse_drift

    return PlantVariation(gain_factor=args.gain_factor, tau_s=args.tau_s,
                          extra_delay_samples=args.extra_delay_samples,
                          drifts=tuple(parse_drift(text) for text in args.drift))
