"""Run the offset-free MPC against plants whose gain, slow time constant or delay differ from its model.

The controller is built from MODEL.json; the plants are that model with its gain
scaled (-30 % .. +30 %), its slow time constant scaled (x0.5 .. x2, instantaneous
response and static gain held) and its delay lengthened by one sample, plus the
virtual CZ heater. Each runs the scenario once (same seed; noise-free plants unless
--noise). Writes DIR/robustness.csv (one row per plant), DIR/robustness.md (settings,
definitions, table, verdicts) and DIR/robustness_heatmap.png (IAE ratio over gain x
time constant, one panel per delay, crosses where offset-free tracking fails).
Progress goes to stderr, the summary to stdout.

Exit codes: 0 done; 1 some plant saw an input outside the controller's limits (a
broken guarantee); 2 bad input.
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path
from typing import TYPE_CHECKING

from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path

if TYPE_CHECKING:
    from czmpc.campaigns.robustness import PlantVariant

from czmpc.cli import _argtypes
from czmpc.cli._progress import Progress

NAME = "robustness"
HELP = "MPC against plants with other gain, time constant and delay (table, heat map)"
ORDER = 30

#: The model the command uses without --model: the shipped one (package data).
DEFAULT_MODEL = shipped_path(HAMMERSTEIN_MODEL_JSON)
CSV_NAME = "robustness.csv"
REPORT_NAME = "robustness.md"
FIGURE_NAME = "robustness_heatmap.png"


def _threshold(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number [kW]; got {text!r}") from None
    if not 0.0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0 [kW]; got {text!r}")
    return value


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("--model", metavar="MODEL.json", type=Path, default=DEFAULT_MODEL,
                        help=f"model the controller is built from (default: {DEFAULT_MODEL})")
    parser.add_argument("--scenario", metavar="NAME", default="staircase",
                        help="shipped scenario name or TOML file (default: staircase)")
    parser.add_argument("--seed", metavar="N", type=_argtypes.seed, default=1,
                        help="seed of every run (default: 1)")
    parser.add_argument("--grid", choices=("quick", "full"), default="quick",
                        help="quick: 5 gains x 3 time constants x 2 delays (about 10 s); "
                             "full: 13 x 9 x 2 (default: quick)")
    parser.add_argument("--preset", choices=("default", "aggressive", "smooth"),
                        default="default", help="controller tuning preset (default: default)")
    parser.add_argument("--threshold-kw", metavar="KW", type=_threshold, default=None,
                        help="offset-free threshold on |steady-state error| [kW] "
                             "(default: 0.05)")
    parser.add_argument("--noise", action="store_true",
                        help="noisy plants (the scenario's setting); default: noise-free, "
                             "so the numbers measure model mismatch alone")
    parser.add_argument("--out", metavar="DIR", type=Path, required=True,
                        help="output directory (created if missing; files overwritten)")


def _command_line(args: argparse.Namespace) -> str:
    words = ["czmpc", "robustness", "--model", str(args.model), "--scenario", args.scenario,
             "--seed", str(args.seed), "--grid", args.grid]
    if args.preset != "default":
        words += ["--preset", args.preset]
    if args.threshold_kw is not None:
        words += ["--threshold-kw", f"{args.threshold_kw:g}"]
    if args.noise:
        words.append("--noise")
    return shlex.join([*words, "--out", str(args.out)])


def run(args: argparse.Namespace) -> int:
    """Run the campaign, write the three files, print the summary."""
    from czmpc.campaigns.robustness import (
        DEFAULT_SSE_THRESHOLD_KW,
        draw_heatmap,
        format_csv,
        format_markdown,
        run_robustness,
        summary_lines,
    )
    from czmpc.settings import MPCSettings
    from sim.scenario import load_scenario
    from sysid.atomic import atomic_path, atomic_write_text
    from sysid.modelfile import load_model

    model = load_model(args.model)
    scenario = load_scenario(args.scenario)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    printer = Progress()

    def progress(i: int, n: int, variant: PlantVariant) -> None:
        printer(f"[{i}/{n}] {variant.label}")

    report = run_robustness(
        model, scenario, grid=args.grid, settings=MPCSettings.preset(args.preset, model),
        seed=args.seed,
        sse_threshold_kw=DEFAULT_SSE_THRESHOLD_KW if args.threshold_kw is None
        else args.threshold_kw,
        noise=args.noise, model_source=str(args.model), progress=progress,
    )
    csv_path, md_path, fig_path = out / CSV_NAME, out / REPORT_NAME, out / FIGURE_NAME
    figure = draw_heatmap(report)
    with atomic_path(fig_path) as tmp:
        figure.savefig(tmp, format="png")
    atomic_write_text(csv_path, format_csv(report))
    atomic_write_text(md_path, format_markdown(report, command=_command_line(args),
                                               figure_name=FIGURE_NAME))
    for line in summary_lines(report):
        print(line)
    print(f"wrote {csv_path}, {md_path}, {fig_path}")
    violations = sum(r.n_input_violations for r in report.results)
    return 1 if violations else 0
