"""The soft real-time MPC loop over OPC UA (`czmpc run`).

Each period (``ts_s / time_scale`` wall seconds, on a monotonic-clock schedule
``t0 + k * period``, so no drift accumulates):

1. read the measured power (with its status code and source timestamp), and the
   optional setpoint, mode and applied-input nodes;
2. step the controller; a Bad or Uncertain status, a source timestamp older than
   ``max_sample_age_s``, one not later than the previous read's (``repeated``: the
   plant's step was late and the previous sample was read again; ``[plant]
   reject_repeated_samples``), or no connection is a missing sample (NaN): the
   controller predicts (soft sensor), then sheds, as in simulation;
3. write the command (mode ON only: in OFF/PREDICT the operator drives the TRIAC) and
   the heartbeat; record the row in the log (flushed per row).

Model health (`czmpc.health`): every sample also goes to the model-health monitor (the
model's own one-step residual and the stale-model test); its figure is logged
(``health``, ``stale_alarm``), written to the optional ``model_health`` node and shown in
the live status, and the alarm is said once when it is raised (`RunSummary`).

Reads are kept just after the plant publishes its sample (`czmpc.runtime.alignment`,
``[plant] align_to_plant``): from the power's source timestamps the loop estimates
where in the plant's period it reads and, when that is late in the period (so that a
write could land on either side of the plant's next step), delays its schedule once
by less than a period.

A step that ends past its deadline is an overrun: the periods it covered are skipped
(recorded in ``skipped``), never caught up, so there is at most one write per period.
Lost connection: the controller keeps predicting; reconnects are tried with a doubling
backoff (up to `MAX_BACKOFF_S`); on return the applied input is read and handed to the
controller, so the next move starts from it within the rate limit (bumpless). A stop
(SIGINT/SIGTERM, or the duration) writes the safe action: ``hold`` leaves the last
command, ``ramp`` moves to ``safe_triac_pct`` at the rate limit, one move per period.

The loop drives any `LoopController`: the MPC (`MPCDriver`), or an open-loop test
schedule or a dithered MPC (`czmpc.commissioning`). With a ``[test]`` section in the
config (`ExperimentLimits`) every sample is checked against the power band and the
longest tolerated stretch of unusable samples; leaving either aborts the run: the
reason goes into the log (column ``event``) and the summary, and the input moves to
``safe_triac_pct`` at the controller's rate limit whatever ``[safety] action`` says.
A controller may also end the run itself (`LoopController.finished`, e.g. at the end
of a test schedule). Beside the log, ``<log>.meta.json`` records where the run came
from (config file and its SHA-256, start time, what drove the input).
"""

from __future__ import annotations

import asyncio
import datetime as dt
import logging
import math
import signal
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from czmpc.controller import OffsetFreeMPC
from czmpc.health import RUNTIME_HEALTH, HealthSettings, ModelHealth, ModelHealthMonitor
from czmpc.modes import Mode
from czmpc.runtime import alignment, refusals
from czmpc.runtime.config import RunConfig
from czmpc.runtime.link import HEALTH_TOP, CheckReport, LinkLostError, PlantLink
from czmpc.runtime.logfiles import (
    LOG_COLUMNS,
    RunLog,
    open_run_log,
    refuse_overwrite,
    sha256_or_none,
)
from czmpc.runtime.measurement import age_s, measurement, sample_time
from czmpc.runtime.node_types import NodeValueError, decode
from czmpc.runtime.ownership import PlantBusyError, PlantLock, WriterWatch, identity, moved
from czmpc.runtime.secure_client import SecurityRejectedError
from sysid.modelfile import load_model

#: The run's events (link lost and restored, refused writes, aborts, alarms): the CLI
#: sends them to stderr with UTC times; they also go into the log's event column.
_log = logging.getLogger("czmpc.runtime.loop")

#: Longest wait between reconnect attempts [s wall] (also at most `MAX_BACKOFF_PERIODS`
#: loop periods; the first wait is one period).
MAX_BACKOFF_S = 5.0
#: Longest wait between reconnect attempts in loop periods.
MAX_BACKOFF_PERIODS = 25
#: How long the start waits for the server [s wall] before giving up (exit 1).
STARTUP_WAIT_S = 15.0
#: Deadline of a connection attempt outside a step (the start, the safe action), in
#: connect timeouts: discovery and the session each get up to two (`secure_client`).
STARTUP_CONNECT_FACTOR = 4.0
#: Integer codes of the ``status`` and ``mode_in_effect`` nodes when they are INT tags.
STATUS_CODES = {"GOOD": 0, "PREDICTED": 1, "CLAMPED": 2, "HELD": 3, "SHED": 4, "LEAD_IN": 5,
                "TEST": 6, "OFF": 7}
MODE_CODES = {mode.name: i for i, mode in enumerate(Mode)}
#: An owner lease renewed within this many loop periods is held (`_check_not_driven`).
LEASE_PERIODS = 3.0
#: Overruns are summarised on stderr at most once per this long [wall s].
OVERRUN_REPORT_S = 60.0
class LoopController(Protocol):
    """What the loop drives: the MPC, an open-loop test schedule, a dithered MPC."""

    @property
    def mode(self) -> Mode:
        """OFF / PREDICT / ON; the loop writes the command in ON only."""

    def request_mode(self, mode: Mode) -> object:
        """The operator asks for another mode (the plant's mode node)."""

    def step(self, power_kw: float, setpoint_kw: float, *,
             applied_triac_pct: float | None = None) -> float:
        """Return the TRIAC input [%] to apply now (see `OffsetFreeMPC.step`)."""

    def status_words(self) -> tuple[str, str]:
        """``(status, verdict)`` of the last step, for the log."""

    @property
    def rate_limit_pct_per_step(self) -> float | None:
        """Largest move per sample [%] (the safe ramp's rate); None: no limit."""

    def skipped(self, n_periods: int) -> None:
        """The loop skipped ``n_periods`` sample periods after an overrun (plant time went on)."""

    def finished(self) -> str | None:
        """Why the run is complete (it then stops with the safe action, not failed), or None."""

    def abort_reason(self) -> str | None:
        """Why the run must stop as failed (exit 1), or None."""


class MPCDriver:
    """The offset-free MPC as a `LoopController` (it never finishes or aborts by itself)."""

    def __init__(self, mpc: OffsetFreeMPC) -> None:
        self.mpc = mpc

    @property
    def mode(self) -> Mode:
        """The MPC's mode."""
        return self.mpc.mode

    def request_mode(self, mode: Mode) -> object:
        """Pass the request to the MPC."""
        return self.mpc.request_mode(mode)

    def step(self, power_kw: float, setpoint_kw: float, *,
             applied_triac_pct: float | None = None) -> float:
        """One MPC step."""
        return self.mpc.step(power_kw, setpoint_kw, applied_triac_pct=applied_triac_pct)

    def status_words(self) -> tuple[str, str]:
        """Status and measurement verdict of the last step."""
        diag = self.mpc.last_step
        return ("", "") if diag is None else (diag.status.name, diag.verdict.name)

    @property
    def rate_limit_pct_per_step(self) -> float | None:
        """The settings' ``max_move_pct_per_step``."""
        return self.mpc.settings.max_move_pct_per_step

    def skipped(self, n_periods: int) -> None:
        """Nothing: the MPC's estimator predicts from the next measurement on."""

    def finished(self) -> str | None:
        """Never: the MPC runs until the duration or a signal."""
        return None

    def abort_reason(self) -> str | None:
        """Never."""
        return None




@dataclass(slots=True)
class RunSummary:
    """What a run did (numbers for the report and the tests)."""

    n_steps: int = 0
    #: Commands the plant accepted (loop steps and the safe ramp).
    n_writes: int = 0
    n_overruns: int = 0
    n_skipped: int = 0
    #: Links lost (a transport fault, a missed deadline or a session code) and links
    #: restored after one; a link that never came back has more losses than reconnects.
    n_link_losses: int = 0
    n_reconnects: int = 0
    n_missing: int = 0
    #: Reads of a sample already read (sample time not later than the previous
    #: read's: the plant's step was late); also counted in `n_missing`.
    n_repeated: int = 0
    #: Steps in which the controller meant to write a command (mode ON), and how many of
    #: those commands the plant accepted: a run that meant to and moved nothing failed.
    n_commands_meant: int = 0
    n_commands_accepted: int = 0
    #: Refused writes by status code name (every node), e.g. ``{"BadResourceUnavailable": 5}``.
    refused_writes: dict[str, int] = field(default_factory=dict)
    lateness_s: list[float] = field(default_factory=list)
    latency_s: list[float] = field(default_factory=list)
    stopped_by: str = "duration"
    stale_alarm_at_s: float | None = None
    stale_alarm_reason: str = ""
    #: RMS one-step prediction error [kW] of the active model and of the shadow candidate
    #: (`RunConfig.candidate_path`) over the samples where both have a residual (none while
    #: a gap's transient settles, `ModelHealth.residual_kw`); NaN without a candidate.
    active_rms_kw: float = math.nan
    candidate_rms_kw: float = math.nan
    candidate_stale_alarm_at_s: float | None = None
    #: Why the run was aborted (a test limit, refused commands, the controller); None: it
    #: was not (exit 1).
    abort_reason: str | None = None
    #: A node the server will not accept as configured (its check failed, or a write came
    #: back with a code that does not clear by itself): the node, the code and the fix
    #: (exit 2).
    configuration_error: str | None = None
    #: Read phases estimated (`czmpc.runtime.alignment.read_phase`) and the delays
    #: [wall s] the schedule took to read just after the plant publishes.
    read_phases: list[float] = field(default_factory=list)
    alignment_delays_s: list[float] = field(default_factory=list)

    @property
    def moved_nothing(self) -> bool:
        """True when the controller meant to write and the plant accepted none of it."""
        return self.n_commands_meant > 0 and self.n_commands_accepted == 0

    @property
    def failed(self) -> bool:
        """True when the run was aborted, refused as configured, or moved nothing."""
        return (self.abort_reason is not None or self.configuration_error is not None
                or self.moved_nothing)

    @property
    def exit_code(self) -> int:
        """2 for a configuration error, 1 for another failure, 0 for a run that did its job."""
        if self.configuration_error is not None:
            return 2
        return 1 if self.failed else 0

    def closing_line(self) -> str:
        """The run's last line: steps, accepted and refused writes, losses, reconnects."""
        refused = sum(self.refused_writes.values())
        codes = ", ".join(f"{n} {code}" for code, n in sorted(self.refused_writes.items()))
        return (f"{self.n_steps} steps, {self.n_writes} writes accepted, {refused} refused"
                f"{f' ({codes})' if codes else ''}, {self.n_missing} missing samples "
                f"({self.n_repeated} read twice), {self.n_overruns} overruns, "
                f"{self.n_link_losses} link losses, {self.n_reconnects} reconnects; "
                f"stopped by {self.stopped_by}")


def _mode_of(value: Any) -> Mode | None:
    """The operator's mode from the mode node: text, an integer 0/1/2 (OFF/PREDICT/ON) or a
    bool (True: ON, False: OFF, a PLC's enable bit); None for anything else."""
    if isinstance(value, bool):
        return Mode.ON if value else Mode.OFF
    if isinstance(value, str) and value.strip().upper() in Mode.__members__:
        return Mode[value.strip().upper()]
    if isinstance(value, int) and not isinstance(value, bool):
        modes = list(Mode)
        if 0 <= value < len(modes):
            return modes[value]
    return None


class ControlLoop:
    """The runtime (module docstring).

    Parameters
    ----------
    config :
        The run configuration.
    controller :
        The MPC (its ``ts_s`` must equal ``config.ts_s``; wrapped in `MPCDriver`) or any
        `LoopController`.
    status :
        Called with a one-line status after each step (None: silent).
    step_delay_s :
        Testing hook: extra wall time [s] spent in the step at the given sample indices
        (injects overruns).
    health_settings :
        Window, reference and false-alarm rate of the model-health monitor (None:
        `czmpc.health.RUNTIME_HEALTH`, the change test against the run's first 30 min).
    provenance :
        What drives the input and where it came from (for example the test schedule
        and its SHA-256), written with the config's path, its SHA-256 and the start
        time into ``<log>.meta.json``.
    """

    def __init__(self, config: RunConfig, controller: OffsetFreeMPC | LoopController, *,
                 status: Callable[[str], None] | None = None,
                 step_delay_s: dict[int, float] | None = None,
                 health_settings: HealthSettings | None = None,
                 provenance: Mapping[str, object] | None = None) -> None:
        self.config = config
        self.ctrl: LoopController = (MPCDriver(controller) if isinstance(controller, OffsetFreeMPC)
                                     else controller)
        self._provenance = dict(provenance or {})
        self._bad_run = 0
        self.link = PlantLink(config)
        #: The last pre-flight check of the nodes (`PlantLink.connect`), None before.
        self.check: CheckReport | None = None
        self.summary = RunSummary()
        self._status = status
        self._delay = dict(step_delay_s or {})
        self._stop = asyncio.Event()
        self._heartbeat_value: Any = None   # what the heartbeat node holds (our last write)
        self._watchdog_value: Any = None    # the same for czmpc's own watchdog counter
        self._events: list[str] = []          # events of this step, for the log's event column
        self._refused_in_row = 0              # command writes refused in a row
        self._lost_at: float | None = None    # monotonic time the link was lost (None: up)
        self._shed_at_k: int | None = None    # sample the controller began shedding (None: not)
        #: One writer per plant (`czmpc.runtime.ownership`): what czmpc wrote, read back.
        self.watch = WriterWatch()
        self.identity = identity(config.log_path)
        self._other_writer = False            # another writer seen: czmpc writes nothing more
        self._mode_seen: Mode | None = None   # the mode of the previous step
        self._overruns_said = (0, 0, time.monotonic())   # overruns, skipped, when last said
        self._said_timestamps = False
        #: Longest a step may spend on I/O [wall s]: the connect timeout and half a period,
        #: so that no step lasts longer than one period plus the connect timeout.
        self._step_budget_s = config.connect_timeout_s + 0.5 * config.period_s
        self._last_cmd = math.nan
        self._applied = math.nan
        self._backoff_s = config.period_s
        self._max_backoff_s = min(MAX_BACKOFF_S, MAX_BACKOFF_PERIODS * config.period_s)
        self._next_try = 0.0
        self._ages_s: list[float] = []   # good samples' ages since the last phase estimate
        self._last_time: dt.datetime | None = None   # the power's last sample time
        # The MPC inside the controller (a test schedule has none: no health monitor).
        self._mpc: OffsetFreeMPC | None = getattr(self.ctrl, "mpc", None)
        self.health = (None if self._mpc is None
                       else ModelHealthMonitor(self._mpc.model, health_settings or RUNTIME_HEALTH))
        #: The candidate model in shadow (config `[controller] candidate`): its own
        #: one-step predictor and health test, fed the same samples; it never drives.
        self.shadow = (None if self._mpc is None or config.candidate_path is None
                       else ModelHealthMonitor(load_model(config.candidate_path),
                                               health_settings or RUNTIME_HEALTH))
        self._sq_active_kw2 = 0.0      # sums of squared one-step errors where both predicted
        self._sq_candidate_kw2 = 0.0
        self._n_compared = 0
        #: False: the model was judged not ready (check-model); requests for ON are refused.
        self.allow_on = True
        #: How a start treats an existing log file (`czmpc.runtime.logfiles.open_run_log`):
        #: ``"new"`` refuses, ``"append"`` continues it, ``"force"`` replaces it.
        self.log_policy = "new"
        self._setpoint = config.setpoint_kw if config.setpoint_kw is not None else math.nan
        if config.schedule is not None:
            self._setpoint = config.schedule.setpoints_kw[0]

    def request_stop(self, reason: str) -> None:
        """Ask the loop to stop at the next period and apply the safe action."""
        self.summary.stopped_by = reason
        self._stop.set()

    def _event(self, text: str, level: int = logging.WARNING) -> None:
        """A link or run event: a log record now (stderr, UTC time) and the log's event column."""
        _log.log(level, text)
        self._events.append(text)

    def _take_events(self) -> str:
        text, self._events = "; ".join(self._events), []
        return text

    def _configuration_error(self, text: str) -> None:
        """A node the server will not accept as configured: stop now (exit 2)."""
        if self.summary.configuration_error is None:
            self.summary.configuration_error = text
            self._event(f"CONFIGURATION ERROR: {text}", logging.ERROR)
        self.request_stop("configuration error")

    async def _try_connect(self, now: float, deadline_s: float) -> bool:
        """Open a session and check the nodes; False (retry later) on a network fault.

        A failed check is a configuration error: nothing is written, the run stops.
        """
        if now < self._next_try:
            return False
        try:
            report = await self.link.connect(deadline_s)
        except SecurityRejectedError:
            raise   # a configuration error: never retried, never downgraded (exit 2)
        except LinkLostError as exc:
            self._next_try = now + self._backoff_s
            self._backoff_s = min(self._max_backoff_s, 2 * self._backoff_s)
            self._say(f"connect failed ({exc}); retry in {self._backoff_s:g} s")
            return False
        self.check = report
        if not report.ok:
            self._configuration_error("; ".join(
                f"[nodes] {c.key} ({c.node}): {c.problem}" for c in report.problems))
            return False
        self._backoff_s = self.config.period_s
        if not self._said_timestamps and "power_kw" in self.link.types:
            note = next((c.note for c in report.checks if c.key == "power_kw"), "")
            if note:
                self._event(f"power_kw: {note}")
                self._said_timestamps = True
        self._heartbeat_value = self.link.initial.get("heartbeat")
        self._watchdog_value = self.link.initial.get("watchdog")
        self.watch.reset()      # a new session: watch from czmpc's next writes on
        # bumpless: start from the input the plant applies now
        key = "applied_triac_pct" if "applied_triac_pct" in self.link.specs else "triac_pct"
        try:
            self._applied = decode(self.link.initial.get(key), self.link.specs[key].scale)
        except NodeValueError:
            self._applied = math.nan
        if self._lost_at is not None:
            self.summary.n_reconnects += 1
            self._event(f"link restored after {time.monotonic() - self._lost_at:.1f} s",
                        logging.INFO)
            self._lost_at = None
        return True

    def _say(self, text: str) -> None:
        if self._status is not None:
            self._status(text)

    async def run(self) -> RunSummary:
        """Run until the duration (plant time) or a stop request; return the summary."""
        cfg = self.config
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(sig, self.request_stop, sig.name)
            except (NotImplementedError, RuntimeError, ValueError):
                pass
        refuse_overwrite(cfg.log_path, self.log_policy, per_run=cfg.log_per_run)  # first of all
        lock = PlantLock(cfg.endpoint, cfg.nodes.triac_pct, self.identity)
        lock.acquire()     # a second controller for this plant on this machine stops here
        log: RunLog | None = None
        safe_done = False
        try:
            give_up = time.monotonic() + STARTUP_WAIT_S
            while not await self._try_connect(time.monotonic(),
                                              STARTUP_CONNECT_FACTOR * cfg.connect_timeout_s):
                if self._stop.is_set():
                    break
                if time.monotonic() > give_up:
                    raise ConnectionError(
                        f"cannot connect to {cfg.endpoint} within {STARTUP_WAIT_S:g} s; is the "
                        "server running and plant.endpoint right?")
                await asyncio.sleep(max(0.05, self._next_try - time.monotonic()))
            if self.summary.configuration_error is None and self.link.connected:
                await self._check_not_driven()
            log = open_run_log(cfg.log_path, self._meta(), per_run=cfg.log_per_run,
                               policy=self.log_policy, rotate=cfg.rotate,
                               rotate_bytes=cfg.rotate_bytes)
            if self.summary.configuration_error is None:
                _log.info("connected to %s; every node checked; running (log %s)", cfg.endpoint,
                          log.path)
                await self._loop(log)
            await self._safe_action(log)
            safe_done = True
        except (asyncio.CancelledError, KeyboardInterrupt):
            # No signal handler could be installed (Windows) or the caller cancelled the
            # run: the safe action still runs, from here, before the cancellation goes on.
            self.summary.stopped_by = "cancelled"
            if log is not None and not safe_done:
                safe_done = True
                await self._safe_action(log)
            raise
        finally:
            if log is not None:
                log.close()
            await self.link.close(cfg.connect_timeout_s)
            lock.release()
            _log.log(logging.ERROR if self.summary.failed else logging.INFO, "run ended: %s",
                     self.summary.closing_line())
            for sig in (signal.SIGINT, signal.SIGTERM):
                try:
                    loop.remove_signal_handler(sig)
                except (NotImplementedError, RuntimeError, ValueError):
                    pass
        return self.summary

    def _meta(self) -> dict[str, object]:
        """The run's provenance for ``<log>.meta.json``."""
        cfg = self.config
        return {
            "config": None if cfg.source_path is None else str(cfg.source_path),
            "config_sha256": sha256_or_none(cfg.source_path),
            "endpoint": cfg.endpoint, "ts_s": cfg.ts_s, "time_scale": cfg.time_scale,
            "start_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            "model": None if cfg.model_path is None else str(cfg.model_path),
            "controller": self.identity,
            **self._provenance,
        }

    def _watched(self) -> tuple[str, ...]:
        """The nodes czmpc writes and can read back (command, heartbeat, owner lease)."""
        return tuple(key for key in ("triac_pct", "heartbeat", "owner")
                     if key in self.link.types and self.link.types[key].user_readable)

    async def _check_not_driven(self) -> None:
        """Before the first write: refuse a plant whose watched nodes move (exit 2).

        Reads the command, heartbeat and owner lease, waits one period, reads them again;
        any change, or a lease of another controller newer than `LEASE_PERIODS` periods,
        means another writer (`PlantBusyError`).
        """
        keys = self._watched()
        if not keys:
            return
        deadline = STARTUP_CONNECT_FACTOR * self.config.connect_timeout_s
        try:
            first = await self.link.read(keys, deadline)
            await asyncio.sleep(self.config.period_s)
            second = await self.link.read(keys, deadline)
        except LinkLostError:
            return      # the loop reconnects; the read-back watch still guards every step
        values = [{k: dv.Value.Value for k, dv in reads.items()
                   if dv.Value is not None and (dv.StatusCode is None or dv.StatusCode.is_good())}
                  for reads in (first, second)]
        reason = moved(values[0], values[1])
        lease = values[1].get("owner")
        if reason is None and isinstance(lease, str) and lease and lease != self.identity:
            age = age_s(second["owner"])
            if age is None or age < LEASE_PERIODS * self.config.period_s:
                reason = (f"[nodes] owner holds the lease of {lease!r}, renewed "
                          f"{'recently' if age is None else f'{age:.1f} s ago'}: another "
                          "controller drives the plant; stop it first")
        if reason is not None:
            raise PlantBusyError(reason)

    def _another_writer(self, reason: str) -> None:
        """Another writer at the plant: write nothing more, raise the alarm, stop (exit 1)."""
        if self._other_writer:
            return
        self._other_writer = True
        if self.summary.abort_reason is None:
            self.summary.abort_reason = reason
        self._event(f"ANOTHER WRITER: {reason}; czmpc writes nothing more", logging.ERROR)
        self.request_stop("another writer")

    async def _loop(self, log: RunLog) -> None:
        cfg = self.config
        period = cfg.period_s
        n_end = None if cfg.duration_s is None else round(cfg.duration_s / cfg.ts_s)
        t0 = time.monotonic()
        k = 0
        while not self._stop.is_set() and (n_end is None or k < n_end):
            deadline = t0 + k * period
            wait = deadline - time.monotonic()
            if wait > 0:
                try:
                    await asyncio.wait_for(self._stop.wait(), wait)
                    break
                except TimeoutError:
                    pass
            woke = time.monotonic()
            lateness = woke - deadline
            row = await self._one_step(k, lateness)
            end = time.monotonic()
            self.summary.lateness_s.append(lateness)
            self.summary.latency_s.append(end - woke)
            # overrun: skip every period whose start has passed (never catch up)
            next_k = k + 1
            if end > t0 + next_k * period:
                next_k = math.floor((end - t0) / period) + 1
                self.summary.n_overruns += 1
                self.summary.n_skipped += next_k - k - 1
            self._say_overruns()
            row["skipped"] = next_k - k - 1
            if next_k - k - 1 > 0:
                self.ctrl.skipped(next_k - k - 1)
                self._monitors_skipped(next_k - k - 1)
            row["step_latency_s"] = end - woke
            self._check_limits(row, next_k - k)
            t0 += self._align(row)
            log.row(row)
            k = next_k
        self.summary.n_steps = k

    def _align(self, row: dict[str, object]) -> float:
        """Delay [wall s] that moves the reads to just after the plant's publication.

        Once `alignment.WINDOW` good samples' ages are in, their read phase is
        estimated; outside `alignment.BAND` the schedule is delayed (less than a
        period) and the row says so. 0 otherwise (`czmpc.runtime.alignment`).
        """
        if not self.config.align_to_plant or len(self._ages_s) < alignment.WINDOW:
            return 0.0
        period = self.config.period_s
        phase = alignment.read_phase(self._ages_s, period)
        self._ages_s.clear()
        if phase is None:
            return 0.0
        self.summary.read_phases.append(phase)
        delay = alignment.alignment_delay_s(phase, period)
        if delay is None:
            return 0.0
        self.summary.alignment_delays_s.append(delay)
        self._add_event(row, f"reads moved to {alignment.TARGET_PHASE:.2f} of the period after the "
                             f"plant publishes (were at {phase:.2f}; delay {delay * 1e3:.1f} ms)")
        return delay

    def _check_limits(self, row: dict[str, object], n_periods: int) -> None:
        """Stop the run if a test limit is left, the controller aborts or is done."""
        limits = self.config.test_limits
        reason = self.ctrl.abort_reason()
        if reason is None and limits is not None:
            quality = str(row["quality"])
            power = float(row["power_kw"])  # type: ignore[arg-type]
            self._bad_run = 0 if quality == "good" else self._bad_run + n_periods
            reason = limits.violation(power, quality, self._bad_run * self.config.ts_s)
        if reason is not None and self.summary.abort_reason is None:
            self._add_event(row, f"ABORT: {reason}")
            _log.error("ABORT: %s", reason)
            self.summary.abort_reason = reason
            self.request_stop("abort")
            return
        done = self.ctrl.finished()
        if done is not None:
            self._add_event(row, done)
            _log.info("%s", done)
            self.request_stop(done)

    def _transitions(self, k: int, status_word: str) -> None:
        """Say when the controller starts or stops shedding and when its mode changes."""
        t = k * self.config.ts_s
        if status_word == "SHED" and self._shed_at_k is None:
            self._shed_at_k = k
            self._event(f"shedding at t={t:.0f}s: no usable measurement for too long; the "
                        "controller holds its input")
        elif status_word not in ("SHED", "") and self._shed_at_k is not None:
            shed_s = (k - self._shed_at_k) * self.config.ts_s
            self._shed_at_k = None
            self._event(f"resumed at t={t:.0f}s after {shed_s:.0f} s shed", logging.INFO)
        mode = self.ctrl.mode
        if self._mode_seen is not None and mode is not self._mode_seen:
            self._event(f"mode {self._mode_seen.name} -> {mode.name} at t={t:.0f}s", logging.INFO)
        self._mode_seen = mode

    def _say_overruns(self) -> None:
        """Once a minute of wall time at most: how many periods overran since it was last said."""
        n_said, skipped_said, when = self._overruns_said
        now = time.monotonic()
        if now - when < OVERRUN_REPORT_S or self.summary.n_overruns == n_said:
            return
        longest_ms = 1e3 * max(self.summary.latency_s[-200:], default=0.0)
        _log.warning("%d overruns in the last %.0f s (%d periods skipped; longest recent step "
                     "%.0f ms, period %.0f ms)", self.summary.n_overruns - n_said, now - when,
                     self.summary.n_skipped - skipped_said, longest_ms,
                     1e3 * self.config.period_s)
        self._overruns_said = (self.summary.n_overruns, self.summary.n_skipped, now)

    @staticmethod
    def _add_event(row: dict[str, object], text: str) -> None:
        row["event"] = f"{row['event']}; {text}" if row["event"] else text

    async def _one_step(self, k: int, lateness: float) -> dict[str, object]:
        """Read, decide, write and record one sample; never longer than `_step_budget_s`."""
        cfg = self.config
        end = time.monotonic() + self._step_budget_s
        if not self.link.connected:
            await self._try_connect(time.monotonic(), end - time.monotonic())
        power, quality, reported_applied = await self._read(end)
        if cfg.schedule is not None:
            self._setpoint = cfg.schedule.setpoint_at(k * cfg.ts_s)
        if not math.isfinite(power):
            self.summary.n_missing += 1
        if k in self._delay:
            await asyncio.sleep(self._delay[k])
        if self.ctrl.mode is not Mode.ON and reported_applied is None:
            reported_applied = self._last_cmd if math.isfinite(self._last_cmd) else None
        applied_before = reported_applied if reported_applied is not None else self._last_cmd
        command = self.ctrl.step(power, self._setpoint, applied_triac_pct=reported_applied)
        status_word, verdict_word = self.ctrl.status_words()
        self._transitions(k, status_word)
        health = self._health(k, power, applied_before)
        meant = self.ctrl.mode is Mode.ON and math.isfinite(command)
        if meant:
            self.summary.n_commands_meant += 1
        written = await self._write(command if meant else None, health, end)
        if self.ctrl.mode is not Mode.ON:
            self._last_cmd = float(command)
        row: dict[str, object] = {
            "k": k, "time_s": k * cfg.ts_s, "wall_time_s": time.time(), "power_kw": power,
            "quality": quality, "setpoint_kw": self._setpoint, "triac_pct": float(command),
            "applied_triac_pct": math.nan if reported_applied is None else reported_applied,
            "status": status_word, "verdict": verdict_word,
            "mode": self.ctrl.mode.name, "connected": int(self.link.connected),
            "written": int(written), "lateness_s": lateness, "step_latency_s": 0.0,
            "skipped": 0, "predicted_kw": math.nan if health is None else health.predicted_kw,
            "health": math.nan if health is None else health.health,
            "stale_alarm": "" if health is None else int(health.stale_alarm),
            "event": self._take_events(),
            **self._shadow_columns(k, power, applied_before, health),
        }
        self._say(f"k={k} t={k * cfg.ts_s:.0f}s P={power:.2f}kW ({quality}) "
                  f"SP={self._setpoint:.2f}kW u={command:.2f}% {row['status']} "
                  f"{self.ctrl.mode.name} late={lateness * 1e3:.1f}ms "
                  f"{'' if health is None else health.status()}")
        return row

    def _state_values(self, command: float | None, health: ModelHealth | None) -> dict[str, Any]:
        """The controller's state for the optional state nodes (HMI, historian), as Variants.

        ``status`` and ``mode_in_effect`` are text on a String node and `STATUS_CODES` /
        `MODE_CODES` on an integer one; ``predicted_power_kw`` is the model's prediction
        of the next sample with this step's input acting; ``target_triac_pct`` the MPC's
        steady-state target input.
        """
        link, out = self.link, {}
        present = link.types
        if "status" in present:
            out["status"] = link.word("status", self.ctrl.status_words()[0] or "OFF", STATUS_CODES)
        if "mode_in_effect" in present:
            out["mode_in_effect"] = link.word("mode_in_effect", self.ctrl.mode.name, MODE_CODES)
        if "stale_alarm" in present:
            alarm = health is not None and health.stale_alarm
            out["stale_alarm"] = link.word("stale_alarm", "ON" if alarm else "OFF",
                                           {"OFF": 0, "ON": 1})
        acting = command if command is not None else self._last_cmd
        if "predicted_power_kw" in present and self.health is not None:
            predicted = self.health.predict_next_kw(acting)
            if math.isfinite(predicted):
                out["predicted_power_kw"] = link.variant("predicted_power_kw", max(0.0, predicted))
        diag = None if self._mpc is None else self._mpc.last_step
        target = math.nan if diag is None else float(diag.target_triac_pct)
        if "target_triac_pct" in present and math.isfinite(target):
            out["target_triac_pct"] = link.variant("target_triac_pct", target)
        if "watchdog" in present:
            out["watchdog"] = link.next_count("watchdog", self._watchdog_value)
        return out

    async def _read(self, end: float) -> tuple[float, str, float | None]:
        """One Read of the power and the optional nodes: (power [kW], quality, applied [%]).

        Updates the setpoint and the mode from their nodes; NaN and ``"disconnected"``
        without a link.
        """
        cfg = self.config
        if not self.link.connected:
            return math.nan, "disconnected", None
        keys = tuple(k for k in ("power_kw", "setpoint_kw", "mode", "applied_triac_pct")
                     if k in self.link.specs)
        watched = tuple(k for k in self._watched() if k not in keys)
        try:
            dvs = await self.link.read(keys + watched, end - time.monotonic())
        except LinkLostError as exc:
            self._lost(exc)
            return math.nan, "disconnected", None
        reason = self.watch.other_writer(
            {k: dvs[k].Value.Value for k in watched
             if dvs[k].Value is not None and (dvs[k].StatusCode is None
                                              or dvs[k].StatusCode.is_good())})
        if reason is not None:
            self._another_writer(reason)
        specs = self.link.specs
        dv = dvs["power_kw"]
        power, quality = measurement(
            dv, cfg.max_sample_age_s,
            self._last_time if cfg.reject_repeated_samples else None, specs["power_kw"].scale)
        self._last_time = sample_time(dv)[0] or self._last_time
        if quality == "repeated":
            self.summary.n_repeated += 1
        age = age_s(dv)
        if quality == "good" and age is not None:
            self._ages_s.append(age)
        if "setpoint_kw" in dvs:
            sp, q = measurement(dvs["setpoint_kw"], math.inf, None, specs["setpoint_kw"].scale)
            if q == "good":
                self._setpoint = sp
        if "mode" in dvs:
            dv = dvs["mode"]
            mode = _mode_of(dv.Value.Value if dv.Value is not None else None)
            if mode is Mode.ON and not self.allow_on:
                mode = None   # a 'not ready' model stays in PREDICT (czmpc run --force)
            if mode is not None and mode is not self.ctrl.mode:
                self.ctrl.request_mode(mode)
        reported_applied: float | None = None
        if "applied_triac_pct" in dvs:
            applied, q = measurement(dvs["applied_triac_pct"], math.inf, None,
                                     specs["applied_triac_pct"].scale)
            if q == "good":
                reported_applied = applied
        if math.isfinite(self._applied):  # fresh from a (re)connect
            reported_applied = self._applied
            self._applied = math.nan
        return power, quality, reported_applied

    async def _write(self, command: float | None, health: ModelHealth | None,
                     end: float) -> bool:
        """One Write of the command (None: none meant), heartbeat and model health.

        Returns True when the plant accepted the command. A refusal is counted and said
        with its code; a code that does not clear by itself is a configuration error
        (`czmpc.runtime.refusals`), ``max_refused_writes`` refused commands in a row abort
        the run.
        """
        if not self.link.connected or self._other_writer:
            return False
        values: dict[str, Any] = {}
        try:
            if "owner" in self.link.types:
                values["owner"] = self.link.variant("owner", self.identity)
            if command is not None:
                values["triac_pct"] = self.link.variant("triac_pct", float(command))
            if "heartbeat" in self.link.specs:
                values["heartbeat"] = self.link.next_count("heartbeat", self._heartbeat_value)
            if "model_health" in self.link.specs and health is not None:
                values["model_health"] = self.link.variant(
                    "model_health", min(HEALTH_TOP, max(0.0, health.health)))
            values |= self._state_values(command, health)
        except NodeValueError as exc:
            self._configuration_error(f"a value cannot be written: {exc}")
            return False
        try:
            results = await self.link.write(values, end - time.monotonic())
        except LinkLostError as exc:
            self._lost(exc)
            return False
        for key, code in results.items():
            if code is None:
                continue
            self.summary.refused_writes[code] = self.summary.refused_writes.get(code, 0) + 1
            spec = self.link.specs[key]
            if refusals.kind_of(code) == "configuration":
                info = self.link.types.get(key)
                self._configuration_error(
                    f"[nodes] {key} ({spec.describe()}): write refused with {code}: "
                    + refusals.fix_for(code, key=key, node=spec.describe(), user=self.link.user,
                                       type_name=None if info is None else info.type_name))
            else:
                self._event(f"write refused: [nodes] {key} ({spec.node_id}) {code}")
        for key, variant in values.items():
            if results.get(key) is None and key in ("triac_pct", "heartbeat", "owner"):
                self.watch.wrote(key, variant.Value, self.link.types[key].type_name)
        if "heartbeat" in values and results.get("heartbeat") is None:
            self._heartbeat_value = values["heartbeat"].Value
        if "watchdog" in values and results.get("watchdog") is None:
            self._watchdog_value = values["watchdog"].Value
        if command is None:
            self.watch.forget("triac_pct")   # the operator may drive the TRIAC outside ON
            return False
        code = results.get("triac_pct")
        if code is None:
            self.summary.n_writes += 1
            self.summary.n_commands_accepted += 1
            self._last_cmd = float(command)
            self._refused_in_row = 0
            return True
        self._refused_in_row += 1
        if (self._refused_in_row >= self.config.max_refused_writes
                and self.summary.abort_reason is None
                and self.summary.configuration_error is None):
            self.summary.abort_reason = (
                f"{self._refused_in_row} command writes in a row refused (last {code}; "
                f"[plant] max_refused_writes = {self.config.max_refused_writes})")
            self._event(f"ABORT: {self.summary.abort_reason}", logging.ERROR)
            self.request_stop("abort")
        return False

    def _health(self, k: int, power: float, applied_before: float) -> ModelHealth | None:
        """Feed the model-health monitor; say the stale alarm once when it comes."""
        if self.health is None or self._mpc is None:
            return None
        diag = self._mpc.last_step
        d = float(getattr(diag, "disturbance_power_kw", math.nan)) if diag is not None else math.nan
        health = self.health.update(power, applied_before, d)
        if health.stale_alarm and self.summary.stale_alarm_at_s is None:
            self.summary.stale_alarm_at_s = k * self.config.ts_s
            self.summary.stale_alarm_reason = health.alarm_reason
            self._event(f"STALE-MODEL ALARM at t={k * self.config.ts_s:.0f}s: {health.alarm_reason}")
        return health

    def _monitors_skipped(self, n_periods: int) -> None:
        """Carry the one-step predictors over skipped periods as missing samples.

        Without this the next sample, ``n_periods + 1`` periods after the last one, would be
        scored against a prediction one period ahead. The command is taken as held over
        the skipped periods; when the late write really landed is not known, so no
        residual counts until the gap's transient has settled (`ModelHealth.residual_kw`).
        """
        for monitor in (self.health, self.shadow):
            if monitor is None:
                continue
            for _ in range(n_periods):
                monitor.update(math.nan, self._last_cmd)

    def _shadow_columns(self, k: int, power: float, applied_before: float,
                        health: ModelHealth | None) -> dict[str, object]:
        """Feed the shadow candidate; its log columns; the RMS errors of both models."""
        if self.shadow is None or health is None:
            return {"candidate_predicted_kw": math.nan, "candidate_health": math.nan,
                    "candidate_stale_alarm": ""}
        cand = self.shadow.update(power, applied_before)
        # one-step residuals: none for a missing sample or while a gap's transient settles
        if math.isfinite(health.residual_kw) and math.isfinite(cand.residual_kw):
            self._sq_active_kw2 += health.residual_kw ** 2
            self._sq_candidate_kw2 += cand.residual_kw ** 2
            self._n_compared += 1
            self.summary.active_rms_kw = math.sqrt(self._sq_active_kw2 / self._n_compared)
            self.summary.candidate_rms_kw = math.sqrt(self._sq_candidate_kw2 / self._n_compared)
        if cand.stale_alarm and self.summary.candidate_stale_alarm_at_s is None:
            self.summary.candidate_stale_alarm_at_s = k * self.config.ts_s
            self._event(f"candidate model: stale alarm at t={k * self.config.ts_s:.0f}s: "
                        f"{cand.alarm_reason}")
        return {"candidate_predicted_kw": cand.predicted_kw, "candidate_health": cand.health,
                "candidate_stale_alarm": int(cand.stale_alarm)}

    def _lost(self, exc: BaseException) -> None:
        """The link failed (already closed by `PlantLink`): predict on, reconnect with backoff."""
        self.link.abort()
        self._next_try = time.monotonic() + self._backoff_s
        if self._lost_at is None:
            self._lost_at = time.monotonic()
            self.summary.n_link_losses += 1
            self._event(f"link lost ({exc}); predicting, reconnecting")

    async def _safe_action(self, log: RunLog | None) -> None:
        cfg = self.config
        if self._other_writer:
            _log.error("stopped (%s): no safe action: another writer drives the plant",
                       self.summary.stopped_by)
            return
        ramp = cfg.safe_action == "ramp" or self.summary.abort_reason is not None
        if not ramp or cfg.safe_triac_pct is None:
            _log.info("stopped (%s): holding the last command", self.summary.stopped_by)
            return
        rate = self.ctrl.rate_limit_pct_per_step
        step = math.inf if rate is None else float(rate)
        u = self._last_cmd
        target = cfg.safe_triac_pct
        if not self.link.connected and self.summary.configuration_error is None:
            await self._try_connect(0.0, STARTUP_CONNECT_FACTOR * cfg.connect_timeout_s)
        if "triac_pct" not in self.link.types:
            _log.error("stopped (%s): the safe ramp cannot be written (no usable link to %s)",
                       self.summary.stopped_by, cfg.nodes.triac_pct)
            return
        if not math.isfinite(u):
            u = target
        while self.link.connected:
            u = u + max(-step, min(step, target - u))
            end = time.monotonic() + self._step_budget_s
            values: dict[str, Any] = {"triac_pct": self.link.variant("triac_pct", u)}
            if "heartbeat" in self.link.types:  # the plant's watchdog still sees us
                values["heartbeat"] = self.link.next_count("heartbeat", self._heartbeat_value)
            try:
                results = await self.link.write(values, end - time.monotonic())
            except LinkLostError as exc:
                self._lost(exc)
                break
            if results.get("heartbeat") is None and "heartbeat" in values:
                self._heartbeat_value = values["heartbeat"].Value
            code = results["triac_pct"]
            if code is not None:
                self.summary.refused_writes[code] = self.summary.refused_writes.get(code, 0) + 1
                _log.error("safe ramp: command write refused with %s; the TRIAC stays where the "
                           "plant holds it", code)
                break
            self.summary.n_writes += 1
            self._last_cmd = u
            if log is not None:
                log.row({c: "" for c in LOG_COLUMNS} | {"triac_pct": u, "status": "SAFE_RAMP",
                                                       "written": 1, "wall_time_s": time.time(),
                                                       "event": self._take_events()})
            if u == target:
                break
            await asyncio.sleep(cfg.period_s)
        _log.info("stopped (%s): TRIAC ramped to %g %%", self.summary.stopped_by, u)


def tty_status() -> Callable[[str], None] | None:
    """A one-line live status on stderr when it is a terminal, else None."""
    if not sys.stderr.isatty():
        return None

    def show(text: str) -> None:
        sys.stderr.write("\r\033[K" + text)
        sys.stderr.flush()

    return show


__all__ = ["MODE_CODES", "STATUS_CODES", "ControlLoop", "LoopController", "MPCDriver",
           "RunSummary", "tty_status"]
