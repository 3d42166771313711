"""Run the offset-free MPC in real time against a plant's OPC UA server.

CONFIG.toml names the endpoint, the node ids, the model, the setpoint (a node, a value
or a time_s,setpoint_kw recipe CSV) and the log (example: examples/plant_link/run.toml;
keys: docs/reference/run_config.rst). Every Ts the loop reads the power [kW], steps the
controller and writes the TRIAC command [%] and a heartbeat, starting bumplessly from
the applied input; SIGINT/SIGTERM stop it with the [safety] action. The log (CSV, one
row per step; columns in docs/guides/plant_link.rst) never overwrites an earlier one
without --append or --replace-log. A model 'czmpc check-model' judged not ready runs
in PREDICT only unless --force. --test plays an open-loop identification test and
--dither-pct runs a closed-loop one, both guarded by [test] (docs/guides/commission.rst);
--check only checks the nodes. Guides: docs/guides/plant_link.rst (typed nodes, refused
writes, lost links), docs/guides/service.rst (events, log files, one writer per plant).

--controller c:DIR runs the MPC step 'czmpc codegen' wrote as C into DIR instead of the
Python MPC: built with the system's C compiler (a missing compiler is an error, exit 2)
and loaded with ctypes. [controller] model must be the model DIR was generated from
(DIR/model.json; the health monitor and a shadow candidate use it), and [controller]
settings, if given, the settings compiled into it (DIR/settings.toml); otherwise the run
is refused with what to generate. The switch-on rule, modes, log columns and state nodes
are the Python MPC's; the log's meta file records DIR and the SHA-256 of its C and
library (docs/guides/codegen.rst).

Exit codes: 0 done or stopped by a signal; 2 bad config, model or settings, or a node
the server will not accept as configured; 1 the plant could not be reached at the
start, a test or run was aborted, or the controller meant to write and the plant
accepted none of its commands.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from czmpc.cli import _argtypes
from czmpc.cli._logging import add_logging_options, configure_logging, log_to_syslog

if TYPE_CHECKING:
    from czmpc.runtime.config import RunConfig
    from czmpc.runtime.link import CheckReport
    from czmpc.runtime.loop import RunSummary

#: The command's own records (start-up notes, the verdict); stderr via `configure_logging`.
_log = logging.getLogger("czmpc.cli.run")

NAME = "run"
HELP = "run the MPC in real time against a plant's OPC UA server (config file)"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    parser.add_argument("config", metavar="CONFIG.toml", type=Path,
                        help="run configuration: [plant], [nodes], [controller], [run], [safety], "
                             "[test]")
    parser.add_argument("--duration-s", metavar="S", type=_argtypes.seconds,
                        default=None, help="plant time to run [s] (overrides [run].duration_s)")
    parser.add_argument("--log", metavar="RUN.csv", type=Path, default=None,
                        help="step log (overrides [run].log)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--test", metavar="TEST.csv", type=Path, default=None,
                      help="open-loop identification test: play this time_s,triac_pct schedule "
                           "(czmpc design-test) instead of the MPC; needs [test] in the config")
    mode.add_argument("--dither-pct", metavar="A", default=None,
                      type=_argtypes.number(above=0.0, at_most=10.0, unit="%"),
                      help="closed-loop test: add a +-A %% GBN dither to the MPC's input "
                           "(0 < A <= 10)")
    parser.add_argument("--dither-seed", metavar="N", type=_argtypes.non_negative_int, default=0,
                        help="seed of the dither's switching (default: 0)")
    add_logging_options(parser)
    parser.add_argument("--check", action="store_true",
                        help="pre-flight check only: connect with the configured security, check "
                             "every node (exists, type carries its value after scaling, access, "
                             "timestamps), print one table; exit 0 (all usable) or 2")
    logs = parser.add_mutually_exclusive_group()
    logs.add_argument("--append", action="store_true",
                      help="the log file exists: continue it (its meta file keeps every run's "
                           "provenance); without this or --replace-log a start refuses")
    logs.add_argument("--replace-log", action="store_true",
                      help="the log file exists: replace it (the earlier run's evidence is lost)")
    parser.add_argument("--force", action="store_true",
                        help="switch ON even with a model 'czmpc check-model' judged not ready "
                             "(said on stderr at the start and in the run summary)")
    parser.add_argument("--controller", metavar="c:DIR", default=None,
                        help="run the MPC step 'czmpc codegen' wrote as C into DIR (built with "
                             "the system's C compiler, loaded with ctypes) instead of the Python "
                             "MPC; DIR/model.json must be [controller] model, and [controller] "
                             "settings, if given, its compiled settings (default: the Python MPC)")


def run(args: argparse.Namespace) -> int:
    """Load the config and the model, build the controller, run the loop."""
    import dataclasses

    from czmpc.controller import OffsetFreeMPC
    from czmpc.errors import SettingsError
    from czmpc.runtime.c_step import c_step_directory
    from czmpc.runtime.config import load_run_config
    from czmpc.runtime.loop import tty_status
    from czmpc.runtime.session import open_run

    c_step = None if args.controller is None else c_step_directory(args.controller)
    if c_step is not None and (args.test is not None or args.dither_pct is not None):
        other = ("--test plays its schedule without a controller" if args.test is not None
                 else "--dither-pct dithers the Python MPC")
        raise SettingsError(f"run: --controller {args.controller} runs the C step in closed "
                            f"loop; {other}: drop one of them")
    config = load_run_config(args.config)
    changes: dict[str, object] = {}
    if args.duration_s is not None:
        changes["duration_s"] = float(args.duration_s)
    if args.log is not None:
        changes["log_path"] = args.log
    if args.test is None and args.dither_pct is None:
        changes["test_limits"] = None   # [test] limits guard tests only (--test, --dither-pct)
    config = dataclasses.replace(config, **changes)  # type: ignore[arg-type]
    configure_logging(args.log_level, args.log_format)
    if config.syslog is not None:
        log_to_syslog(config.syslog, config.syslog_facility)
    _log.info("plant link %s: %s", config.endpoint, config.security.describe())
    if args.check:
        return _check(config)
    forced = False
    if args.test is not None:
        from czmpc.commissioning.test_run import load_input_schedule, make_test_loop

        schedule = load_input_schedule(args.test)
        loop = make_test_loop(config, schedule, status=tty_status())
    else:
        opened = open_run(config, force=args.force, log=_log, c_step=c_step)
        forced = opened.switch_on.forced
        if args.dither_pct is None:
            loop = opened.loop(provenance={"kind": "MPC run", "closed_loop": True},
                               status=tty_status())
        else:
            from czmpc.commissioning.dither import DitheredMPC, dominant_time_constant_s

            if not isinstance(opened.mpc, OffsetFreeMPC):   # refused above
                raise SettingsError("run: --dither-pct dithers the Python MPC only")
            dithered = DitheredMPC(opened.mpc, amplitude_pct=args.dither_pct,
                                   switch_time_s=dominant_time_constant_s(opened.mpc.model),
                                   rng=args.dither_seed)
            _log.info("closed-loop test: +-%g %% GBN dither on the MPC's input, mean switching "
                      "time %.0f s; the log is closed-loop data", args.dither_pct,
                      dithered.switch_time_s)
            loop = opened.loop(dithered, provenance=dithered.provenance(args.dither_seed),
                               status=tty_status())
    loop.log_policy = "append" if args.append else "force" if args.replace_log else "new"
    try:
        summary = asyncio.run(loop.run())
    except ConnectionError as exc:
        print(f"czmpc: error: {exc}", file=sys.stderr)
        return 1
    if sys.stderr.isatty():
        sys.stderr.write("\n")
    print(f"run: {summary.closing_line()}; log {config.log_path}")
    if forced:
        print("run: forced (--force): the model was judged not ready by check-model")
    if summary.stale_alarm_at_s is not None:
        print(f"run: STALE-MODEL ALARM at {summary.stale_alarm_at_s:g} s of plant time: "
              f"{summary.stale_alarm_reason}")
    if config.candidate_path is not None:
        print(f"run: candidate {config.candidate_path}: RMS one-step error "
              f"{summary.candidate_rms_kw:.4g} kW against {summary.active_rms_kw:.4g} kW for the "
              "active model"
              + ("" if summary.candidate_stale_alarm_at_s is None else
                 f"; its stale alarm at {summary.candidate_stale_alarm_at_s:g} s"))
    is_test = args.test is not None or args.dither_pct is not None
    return _verdict(summary, loop.check, config, "test" if is_test else "run")


def _check(config: RunConfig) -> int:
    """``--check``: the node table on stdout; 0 when every node is usable, else 2."""
    from czmpc.runtime.link import preflight

    try:
        report = asyncio.run(preflight(config))
    except ConnectionError as exc:
        print(f"czmpc: error: {exc}", file=sys.stderr)
        return 1
    print(report.table())
    if report.ok:
        print(f"check: every node of {config.endpoint} is usable as configured")
        return 0
    for c in report.problems:
        print(f"czmpc: error: [nodes] {c.key} ({c.node}): {c.problem}", file=sys.stderr)
    return 2


def _verdict(summary: RunSummary, check: CheckReport | None, config: RunConfig,
             what: str) -> int:
    """Say why a run (or a ``what = "test"``) failed, as error records; its exit code."""
    if summary.configuration_error is not None:
        if check is not None and not check.ok:
            _log.error("the nodes as the server has them:\n%s", check.table())
        _log.error("%s; nothing more was written", summary.configuration_error)
    elif summary.abort_reason is not None:
        safe = ("hold" if config.safe_triac_pct is None else f"TRIAC to {config.safe_triac_pct:g} %")
        _log.error("%s aborted: %s; the safe action (%s) was taken where the plant accepted it; "
                   "see the log's event column", what, summary.abort_reason, safe)
    elif summary.moved_nothing:
        _log.error("the controller meant to write %d commands and the plant accepted none of "
                   "them: see the refused writes and link losses above and the log's event "
                   "column", summary.n_commands_meant)
    return summary.exit_code
