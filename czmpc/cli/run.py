"""Run the offset-free MPC in real time against a plant's OPC UA server.

CONFIG.toml names the server's endpoint, the node ids (any server's: they are strings
such as "ns=2;s=Heater.Power"), the model, the setpoint (a node, a fixed value or a
recipe CSV with columns time_s,setpoint_kw) and the log; see the example
examples/plant_link/run.toml and the README section "Plant link".

Every Ts (monotonic schedule, no drift) the loop reads the power, steps the controller
and writes the TRIAC command and a heartbeat. Bad/Uncertain status codes and stale
source timestamps are missing samples (soft sensor, then shed). It starts bumplessly
from the plant's applied input; on a lost connection it keeps predicting and
reconnects with backoff. SIGINT/SIGTERM stop it with the configured safe action
([safety] action = "hold" or "ramp" to safe_triac_pct at the rate limit), exit 0.

The log (CSV, one row per step, flushed per row) has: k, time_s [s], wall_time_s
[s since epoch], power_kw [kW], quality, setpoint_kw [kW], triac_pct [%],
applied_triac_pct [%], status, verdict, mode, connected, written, lateness_s [s],
step_latency_s [s], skipped (periods skipped after an overrun).

Exit codes: 0 done or stopped by a signal; 2 bad config, model or settings; 1 the
plant could not be reached at the start.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from czmpc.cli import _argtypes

NAME = "run"
HELP = "run the MPC in real time against a plant's OPC UA server (config file)"
ORDER = 80


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("config", metavar="CONFIG.toml", type=Path,
                        help="run configuration: [plant], [nodes], [controller], [run], [safety]")
    parser.add_argument("--duration-s", metavar="S", type=_argtypes.number(above=0.0, unit="s"),
                        default=None, help="plant time to run [s] (overrides [run].duration_s)")
    parser.add_argument("--log", metavar="RUN.csv", type=Path, default=None,
                        help="step log (overrides [run].log)")


def run(args: argparse.Namespace) -> int:
    """Load the config and the model, build the controller, run the loop."""
    import dataclasses

    from czmpc.controller import OffsetFreeMPC
    from czmpc.errors import SettingsError
    from czmpc.runtime.config import load_run_config
    from czmpc.runtime.loop import ControlLoop, tty_status
    from czmpc.settings import MPCSettings
    from czmpc.settings_file import load_settings
    from sysid.modelfile import load_model

    config = load_run_config(args.config)
    changes: dict[str, object] = {}
    if args.duration_s is not None:
        changes["duration_s"] = float(args.duration_s)
    if args.log is not None:
        changes["log_path"] = args.log
    config = dataclasses.replace(config, **changes)  # type: ignore[arg-type]
    print(f"czmpc run: plant link {config.endpoint}: {config.security.describe()}", file=sys.stderr)
    model = load_model(config.model_path)
    if abs(model.ts_s - config.ts_s) > 1e-9 * config.ts_s:
        raise SettingsError(f"plant.ts_s: expected the model's sampling time {model.ts_s:g} s; "
                            f"got {config.ts_s:g} s")
    if config.settings_path is None:
        settings = MPCSettings.default_for(model)
    else:
        settings = load_settings(config.settings_path, model)
    controller = OffsetFreeMPC(model, settings)
    loop = ControlLoop(config, controller, status=tty_status())
    try:
        summary = asyncio.run(loop.run())
    except ConnectionError as exc:
        print(f"czmpc: error: {exc}", file=sys.stderr)
        return 1
    if sys.stderr.isatty():
        sys.stderr.write("\n")
    print(f"run: {summary.n_steps} steps, {summary.n_writes} writes, {summary.n_missing} missing "
          f"samples, {summary.n_overruns} overruns, {summary.n_reconnects} reconnects; "
          f"stopped by {summary.stopped_by}; log {config.log_path}")
    return 0
