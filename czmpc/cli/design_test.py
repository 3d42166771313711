"""Design an open-loop identification test signal and write it as TEST.csv.

The signal (see `sysid.design`) is a staircase across the band plus generalized binary
noise whose mean switching time equals the plant time constant.  The time constant comes
from ``--tau-s`` or from the dominant pole of a prior model (``--prior MODEL.json``).

With --plot FILE.png it also draws what the signal shows the identification: the
signal [%] against time [s], every level's hold time in time constants, and the
spectrum [%^2 s] against frequency [rad/s] with the expected bandwidth 1/tau.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from czmpc.cli import _argtypes as t

NAME = "design-test"
HELP = "design an identification test signal (staircase + GBN) and write TEST.csv (time_s,triac_pct)"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.formatter_class = argparse.HelpFormatter  # its description is re-wrapped
    parser.add_argument("--ts-s", type=t.seconds, required=True,
                        help="sampling time of the test [s]")
    parser.add_argument("--range-pct", type=t.percent, nargs=2,
                        metavar=("LO", "HI"), required=True, help="band of triac set-points to visit [%%]")
    prior = parser.add_mutually_exclusive_group(required=True)
    prior.add_argument("--tau-s", type=t.seconds,
                       help="prior guess of the dominant plant time constant [s]")
    prior.add_argument("--prior", metavar="MODEL.json",
                       help="prior model; its slowest real pole gives the time constant")
    parser.add_argument("--duration-s", type=t.seconds, required=True,
                        help="length of the test [s]")
    parser.add_argument("--max-step-pct", type=t.percent_step, default=100.0,
                        help="largest jump between consecutive samples [%%] (default: no limit)")
    parser.add_argument("--kind", choices=t.TEST_SIGNAL_KINDS, default="mixed",
                        help="staircase, generalized binary noise, both (default mixed), or "
                             "multilevel noise: the short test for a slow plant (2 rounds of "
                             "degree + 2 levels at one tau each)")
    parser.add_argument("--seed", type=t.signal_seed, default=0,
                        help="seed of the GBN or multilevel random switching (default 0)")
    parser.add_argument("--out", metavar="TEST.csv", required=True,
                        help="output CSV with header time_s,triac_pct")
    parser.add_argument("--plot", metavar="FILE.png", type=Path, default=None,
                        help="also draw the signal, hold times vs tau and the spectrum vs the "
                             "expected bandwidth (PNG)")


def _tau_from_model(path: str) -> tuple[float, int]:
    from sysid.errors import ModelFileError
    from sysid.modelfile import load_model
    from sysid.polynomials import slowest_time_constant_samples

    model = load_model(path)
    tau_s = model.ts_s * slowest_time_constant_samples(model.a)   # a model's A is stable
    if tau_s == 0.0:
        raise ModelFileError(f"{path}: the model has no stable pole to give a time constant; use --tau-s")
    return tau_s, model.input_degree


def run(args: argparse.Namespace) -> int:
    """Design the signal, print what it shows, write the CSV."""
    import numpy as np

    from sysid.design import ExcitationSpec, design_test_signal

    degree = 3
    if args.prior is not None:
        tau_s, degree = _tau_from_model(args.prior)
    else:
        tau_s = args.tau_s
    lo, hi = args.range_pct
    spec = ExcitationSpec(ts_s=args.ts_s, lo_pct=lo, hi_pct=hi, tau_s=tau_s, duration_s=args.duration_s,
                          max_step_pct=args.max_step_pct, kind=args.kind, degree=degree)
    signal = design_test_signal(spec, np.random.default_rng(args.seed))
    table = np.column_stack((signal.time_s, signal.triac_pct))
    np.savetxt(args.out, table, delimiter=",", header="time_s,triac_pct", comments="", fmt="%.6g")
    print(signal.summary())
    print(f"wrote {args.out}")
    if args.plot is not None:
        from czmpc.reports.design_figure import plot_test_signal

        plot_test_signal(signal, args.plot)
        print(f"wrote {args.plot}")
    return 0
