"""`czmpc plant history`: read the plant server's power and applied-input history into a run log.

CONFIG.toml is the run configuration of 'czmpc run' ([plant], [plant.security], [nodes]
power_kw and applied_triac_pct or triac_pct); the server must historize those tags.
--from and --to are ISO 8601 times (UTC without a zone), both included. The output is a
run log with LOG.meta.json beside it, one row per sample period, that 'czmpc identify'
reads directly; it is never replaced without --force. Guide: docs/guides/history.rst.

Exit codes: 0 written; 2 a bad config or time range, a node without history, no power
sample in the range, an existing output without --force; 1 the server could not be
reached or stopped answering.
"""

from __future__ import annotations

import argparse
import asyncio
import datetime as dt
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from czmpc.cli import _argtypes
from czmpc.cli._exit import ExitCode
from czmpc.errors import CzmpcError

if TYPE_CHECKING:
    from czmpc.cli._progress import Progress
    from czmpc.runtime.config import RunConfig
    from czmpc.runtime.history import NodeHistory

class HistoryRangeError(CzmpcError, ValueError):
    """A --from/--to time that cannot be read, or a range that is empty."""


def utc_time(text: str) -> dt.datetime:
    """An ISO 8601 time as an aware UTC datetime; a time without a zone is UTC."""
    try:
        value = dt.datetime.fromisoformat(text.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected an ISO 8601 time in UTC such as 2026-11-26T06:00:00Z; got {text!r}"
        ) from None
    return value.replace(tzinfo=dt.UTC) if value.tzinfo is None else value.astimezone(dt.UTC)


def register(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``czmpc plant history``."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("config", metavar="CONFIG.toml", type=Path,
                        help="run configuration ([plant], [nodes]; the rest is not used)")
    parser.add_argument("--from", dest="start", metavar="T0", type=utc_time, required=True,
                        help="start of the range, ISO 8601 UTC (no zone: UTC)")
    parser.add_argument("--to", dest="end", metavar="T1", type=utc_time, required=True,
                        help="end of the range, ISO 8601 UTC (no zone: UTC)")
    parser.add_argument("--out", metavar="LOG.csv", type=Path, required=True,
                        help="the run log to write (and LOG.meta.json beside it)")
    parser.add_argument("--force", action="store_true",
                        help="replace an existing LOG.csv and LOG.meta.json")
    parser.add_argument("--page-values", metavar="N", type=_argtypes.positive_int, default=None,
                        help="most values per HistoryRead request (NumValuesPerNode; default: "
                             "1000)")
    parser.add_argument("--timeout-s", metavar="S", type=_argtypes.seconds,
                        default=None, help="hard deadline of each OPC UA call [s] (default: "
                                           "four [plant] connect_timeout_s)")
    parser.add_argument("--closed-loop", action="store_true",
                        help="a controller drove the input in this range: 'identify' then "
                             "says the data are closed-loop")


def _input_key(config: RunConfig) -> str:
    return "applied_triac_pct" if config.nodes.applied_triac_pct is not None else "triac_pct"


async def _read(config: RunConfig, *, start: dt.datetime, end: dt.datetime, page_values: int,
                deadline_s: float, progress: Progress) -> dict[str, NodeHistory]:
    """Connect with the configured security, read the power's and the input's history."""
    from czmpc.runtime.history import read_node_history
    from czmpc.runtime.link import close_client, within
    from czmpc.runtime.secure_client import connect

    specs = config.nodes.specs()
    client = await within(connect(config.endpoint, config.security,
                                  timeout_s=config.connect_timeout_s),
                          deadline_s + 4.0 * config.connect_timeout_s,
                          f"connecting to {config.endpoint}")
    try:
        return {key: await read_node_history(client, key, specs[key], start=start, end=end,
                                             page_values=page_values, deadline_s=deadline_s,
                                             bounds=key != "power_kw", progress=progress)
                for key in ("power_kw", _input_key(config))}
    finally:
        await close_client(client, deadline_s)


def run(args: argparse.Namespace) -> int:
    """Read the history, put it on the Ts grid, write the run log and its provenance."""
    from czmpc.cli._progress import Progress
    from czmpc.runtime.config import load_run_config
    from czmpc.runtime.history import DEFAULT_PAGE_VALUES, align_history, refuse_existing, write_history_log
    from czmpc.runtime.link import CallDeadlineError
    from czmpc.runtime.secure_client import PlantUnreachableError
    from sysid.atomic import file_sha256

    if not args.start < args.end:
        raise HistoryRangeError(f"--from must be before --to; got --from {args.start.isoformat()} "
                                f"--to {args.end.isoformat()}")
    config = load_run_config(args.config)
    if not args.force:
        refuse_existing(args.out)
    page_values = args.page_values or DEFAULT_PAGE_VALUES
    deadline_s = args.timeout_s or 4.0 * config.connect_timeout_s
    progress = Progress(stream=sys.stderr)
    progress(f"reading history from {config.endpoint}: {args.start.isoformat()} .. "
             f"{args.end.isoformat()}")
    try:
        histories = asyncio.run(_read(config, start=args.start, end=args.end,
                                      page_values=page_values, deadline_s=deadline_s,
                                      progress=progress))
    except (PlantUnreachableError, CallDeadlineError) as exc:
        print(f"czmpc: error: {exc}", file=sys.stderr)
        return ExitCode.RUN_FAILED
    power = histories["power_kw"]
    if power.n_values == 0:
        raise HistoryRangeError(
            f"the server holds no value of nodes.power_kw = {power.node_id!r} between "
            f"{args.start.isoformat()} and {args.end.isoformat()} (times are UTC)")
    key = _input_key(config)
    aligned = align_history(power, histories[key] if key == "applied_triac_pct" else None,
                            histories[key] if key == "triac_pct" else None,
                            period_s=config.period_s)
    specs = config.nodes.specs()
    meta: dict[str, object] = {
        "closed_loop": bool(args.closed_loop),
        "config": str(config.source_path), "config_sha256": file_sha256(args.config),
        "endpoint": config.endpoint, "security": config.security.describe(),
        "nodes": {k: specs[k].describe() for k in histories},
        "from_utc": args.start.isoformat(), "to_utc": args.end.isoformat(),
        "start_utc": dt.datetime.fromtimestamp(float(aligned.epoch_s[0]), dt.UTC).isoformat(),
        "time_scale": config.time_scale, "period_s": config.period_s,
        "rows": aligned.n_rows, **{f"rows_{w}": aligned.count(w)
                                   for w in ("good", "bad", "uncertain", "missing")},
        "samples_moved_back": aligned.n_moved,
        "values": {k: h.n_values for k, h in histories.items()},
        "requests": {k: h.n_requests for k, h in histories.items()},
        "continuation_points": {k: h.n_continuations for k, h in histories.items()},
        "resumed_requests": {k: h.n_resumed for k, h in histories.items()},
        "page_values": page_values,
        "command": (f"czmpc plant history {args.config} --from {args.start.isoformat()} --to "
                    f"{args.end.isoformat()} --out {args.out} --page-values {page_values}"),
    }
    meta_file = write_history_log(args.out, aligned, ts_s=config.ts_s, meta=meta,
                                  overwrite=args.force)
    gaps = aligned.n_rows - aligned.count("good")
    print(f"wrote {args.out}: {aligned.n_rows} samples ({aligned.count('good')} good, {gaps} "
          f"gaps: {aligned.count('bad')} bad, {aligned.count('uncertain')} uncertain, "
          f"{aligned.count('missing')} missing) from {meta['start_utc']}; {power.n_values} "
          f"power and {histories[key].n_values} {key} values in "
          f"{sum(h.n_requests for h in histories.values())} requests; provenance {meta_file}")
    return ExitCode.OK
