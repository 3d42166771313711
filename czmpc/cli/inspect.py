"""Check a logged data file before identifying: size, sampling, ranges and input steps.

Reads FILE.csv (header time_s,triac_pct,power_kw, optionally grid_voltage_factor, or
other names through --columns) and prints the number of samples, the duration, the
sampling time, the ranges of the input and the output with their units (and of the grid
voltage factor if the log carries it), and every input step with the output's
immediate response and the instantaneous gain r (paper sec. 7.3, Table 3). A file that
breaks the data contract is refused with its file name, line and column (exit code 2).
"""

from __future__ import annotations

import argparse

from czmpc.cli import _argtypes

NAME = "inspect"
HELP = "check a logged data file: samples, sampling time, ranges, input steps and gains"

def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.add_argument("file", metavar="FILE.csv", help="logged data file")
    _argtypes.add_log_options(parser)
    parser.add_argument(
        "--min-step", metavar="X", type=_argtypes.non_negative_float, default=None,
        help="smallest input change counted as a step [input unit]; default: 5 %% of the "
             "input's range, and at least 5 noise standard deviations",
    )
    parser.add_argument(
        "--delay-steps", metavar="N", type=_argtypes.non_negative_int, default=1,
        help="delay from input to output in samples (default 1)",
    )


def run(args: argparse.Namespace) -> int:
    """Read, check and summarize the file; print the summary to stdout."""
    from czmpc.reports.tables import format_table
    from sysid.steps import default_step_threshold, detect_steps

    data = _argtypes.read_log(args.file, args)
    threshold = (
        default_step_threshold(data.triac_pct) if args.min_step is None else args.min_step
    )
    steps = detect_steps(data, min_step=threshold, delay_steps=args.delay_steps)
    u_unit, y_unit = data.input_unit, data.output_unit
    names = args.columns or {name: name for name in _argtypes.CONTRACT_COLUMNS}
    lines = [
        f"file:           {data.source}",
        f"sha256:         {data.sha256}",
        f"columns:        time {names['time_s']!r}, input {names['triac_pct']!r}, "
        f"output {names['power_kw']!r}",
        f"samples:        {data.n_samples}",
        f"duration:       {data.duration_s:g} s ({data.time_s[0]:g} s to {data.time_s[-1]:g} s)",
        f"sampling time:  {data.ts_s:g} s (every interval within {100 * data.sampling_rtol:g} %)",
        f"input range:    {data.triac_pct.min():g} to {data.triac_pct.max():g} {u_unit}",
        f"output range:   {data.power_kw.min():g} to {data.power_kw.max():g} {y_unit}",
        *([] if data.grid_voltage_factor is None else [
            f"grid voltage:   {data.grid_voltage_factor.min():.4g} to "
            f"{data.grid_voltage_factor.max():.4g} x nominal (column "
            f"{names.get('grid_voltage_factor', 'grid_voltage_factor')!r}; compensated by "
            "identify)"]),
        f"input steps:    {len(steps)} larger than {threshold:g} {u_unit} "
        f"(output read {args.delay_steps} sample(s) after the step)",
    ]
    print("\n".join(lines))
    if steps:
        print(format_table(
            ["k", "time [s]", f"input [{u_unit}]", f"output [{y_unit}]", f"r [{y_unit}/{u_unit}]"],
            [[str(s.k), f"{s.time_s:.1f}", f"{s.triac_before_pct:7.2f} -> {s.triac_after_pct:7.2f}",
              f"{s.power_before_kw:8.3f} -> {s.power_after_kw:8.3f}", f"{s.gain_kw_per_pct:.4f}"]
             for s in steps]))
    else:
        print("no input steps found")
    return 0
