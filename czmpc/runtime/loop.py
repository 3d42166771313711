"""The soft real-time MPC loop over OPC UA (`czmpc run`).

Each period (``ts_s / time_scale`` wall seconds at ``t0 + k * period``, no drift) the
loop reads the power (status, source timestamp) and the optional setpoint, mode and
applied-input nodes; decides without I/O (`czmpc.runtime.step`: a Bad, Uncertain, stale,
repeated or disconnected sample is missing, the controller predicts, then sheds); writes
the command (mode ON only), the heartbeat and the optional state nodes; records the row
(`czmpc.runtime.logfiles`) and feeds the model-health monitor (`czmpc.health`).

Reads are kept just after the plant publishes (`czmpc.runtime.alignment`). An overrun
skips periods, never catches up. A lost link keeps the controller predicting and
reconnects with a doubling backoff (up to `MAX_BACKOFF_S`), bumpless from the applied
input. A stop writes the ``[safety]`` action; a ``[test]`` limit left aborts the run to
``safe_triac_pct``. The loop drives any `LoopController`: the MPC (`MPCDriver`), a test
schedule or a dithered MPC (`czmpc.commissioning`), or the MPC step generated as C
(`CStepDriver`); docs/guides/plant_link.rst and
docs/guides/service.rst show each case.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import inspect
import logging
import math
import signal
import sys
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from czmpc.controller import OffsetFreeMPC
from czmpc.health import RUNTIME_HEALTH, HealthSettings, ModelHealth, ModelHealthMonitor
from czmpc.modes import Mode, Status
from czmpc.runtime import alignment, refusals
from czmpc.runtime.c_step import CStepMPC
from czmpc.runtime.config import RunConfig
from czmpc.runtime.link import HEALTH_TOP, CheckReport, LinkLostError, PlantLink
from czmpc.runtime.logfiles import (
    LOG_COLUMNS,
    RunLog,
    open_run_log,
    refuse_overwrite,
)
from czmpc.runtime.measurement import age_s
from czmpc.runtime.node_types import NodeValueError, decode
from czmpc.runtime.ownership import PlantBusyError, PlantLock, WriterWatch, identity, moved
from czmpc.runtime.secure_client import SecurityRejectedError
from czmpc.runtime.step import (
    Decision,
    LoopController,
    Sample,
    Transitions,
    decide,
    judge,
    refused_in_row,
    transitions,
)
from czmpc.validation import Verdict
from sysid._version import __version__
from sysid.atomic import file_sha256
from sysid.modelfile import load_model

#: The run's events (link lost and restored, refused writes, aborts, alarms), also in the
#: log's event column.
_log = logging.getLogger("czmpc.runtime.loop")

#: Longest wait between reconnect attempts [s wall] (the first is one period).
MAX_BACKOFF_S = 5.0
#: Longest wait between reconnect attempts in loop periods.
MAX_BACKOFF_PERIODS = 25
#: How long the start waits for the server [s wall] before giving up (exit 1).
STARTUP_WAIT_S = 15.0
#: Deadline of a connection outside a step (start, safe action) in connect timeouts:
#: discovery and the session each get two (`secure_client`).
STARTUP_CONNECT_FACTOR = 4.0
#: Integer codes of the ``status`` and ``mode_in_effect`` nodes when they are INT tags.
STATUS_CODES = {"GOOD": 0, "PREDICTED": 1, "CLAMPED": 2, "HELD": 3, "SHED": 4, "LEAD_IN": 5,
                "TEST": 6, "OFF": 7}
MODE_CODES = {mode.name: i for i, mode in enumerate(Mode)}
#: An owner lease renewed within this many loop periods is held (`_check_not_driven`).
LEASE_PERIODS = 3.0
#: Overruns are summarised on stderr at most once per this long [wall s].
OVERRUN_REPORT_S = 60.0
#: Steps whose latency the overrun note's "longest recent step" looks back over.
RECENT_STEPS = 200
#: Read-phase estimates a run keeps (one per `alignment.WINDOW` good samples).
RECENT_PHASES = 1000
#: The counters czmpc increments each step (the plant's watchdog and its own).
_COUNTERS = ("heartbeat", "watchdog")
#: What the loop tells a controller about the coming samples and the grid, besides the
#: power and the setpoint (keyword arguments of `OffsetFreeMPC.step`).
CONTEXT_ARGS = ("setpoint_preview_kw", "grid_voltage_factor")


def context_args_taken(ctrl: object) -> frozenset[str]:
    """Which of `CONTEXT_ARGS` the controller's ``step`` takes as keyword arguments.

    An open-loop test schedule takes neither (it plays its inputs whatever comes); the
    MPC (`MPCDriver`, `czmpc.commissioning.dither.DitheredMPC`) takes both.
    """
    try:
        params = inspect.signature(ctrl.step).parameters  # type: ignore[attr-defined]
    except (AttributeError, TypeError, ValueError):
        return frozenset()
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return frozenset(CONTEXT_ARGS)
    return frozenset(name for name in CONTEXT_ARGS if name in params)


def _good_values(reads: Mapping[str, Any], keys: tuple[str, ...]) -> dict[str, Any]:
    """The values of the Good DataValues among ``keys``."""
    return {key: dv.Value.Value for key, dv in reads.items() if key in keys
            and dv.Value is not None and (dv.StatusCode is None or dv.StatusCode.is_good())}


def _signal_handlers(loop: asyncio.AbstractEventLoop, handler: Callable[[str], None] | None,
                     ) -> None:
    """Install ``handler`` (None: remove it) for SIGINT and SIGTERM where the platform can."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            if handler is None:
                loop.remove_signal_handler(sig)
            else:
                loop.add_signal_handler(sig, handler, sig.name)
        except (NotImplementedError, RuntimeError, ValueError):
            pass


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
             applied_triac_pct: float | None = None,
             setpoint_preview_kw: Sequence[float] | None = None,
             grid_voltage_factor: float | None = None) -> float:
        """One MPC step, told the coming setpoints and the grid voltage when the run has
        them (`CONTEXT_ARGS`; None: not known)."""
        return self.mpc.step(power_kw, setpoint_kw, applied_triac_pct=applied_triac_pct,
                             setpoint_preview_kw=setpoint_preview_kw,
                             grid_voltage_factor=grid_voltage_factor)

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
class StepTimes:
    """A per-step time [wall s] over a run of any length, in fixed memory.

    Attributes
    ----------
    count :
        Steps seen.
    max_s :
        The longest [s] (0 before the first step).
    recent_s :
        The last `RECENT_STEPS` values, oldest first.
    """

    count: int = 0
    max_s: float = 0.0
    recent_s: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT_STEPS))

    def add(self, value_s: float) -> None:
        """Count one step's time [s]."""
        self.count += 1
        self.max_s = max(self.max_s, value_s)
        self.recent_s.append(value_s)

    @property
    def recent_max_s(self) -> float:
        """The longest of the last `RECENT_STEPS` steps [s] (0 before the first)."""
        return max(self.recent_s, default=0.0)


@dataclass(slots=True)
class RunSummary:
    """What a run did (numbers for the report and the tests)."""

    n_steps: int = 0
    #: Commands the plant accepted (loop steps and the safe ramp).
    n_writes: int = 0
    n_overruns: int = 0
    n_skipped: int = 0
    #: Links lost (a transport fault, a missed deadline or a session code) and restored.
    n_link_losses: int = 0
    n_reconnects: int = 0
    n_missing: int = 0
    #: Reads of a sample already read (the plant's step was late); also in `n_missing`.
    n_repeated: int = 0
    #: Steps meant to write a command (mode ON), and commands the plant accepted.
    n_commands_meant: int = 0
    n_commands_accepted: int = 0
    #: Refused writes by status code name (every node), e.g. ``{"BadResourceUnavailable": 5}``.
    refused_writes: dict[str, int] = field(default_factory=dict)
    #: How late each step woke after its deadline, and how long it took [wall s].
    lateness_s: StepTimes = field(default_factory=StepTimes)
    latency_s: StepTimes = field(default_factory=StepTimes)
    stopped_by: str = "duration"
    stale_alarm_at_s: float | None = None
    stale_alarm_reason: str = ""
    #: RMS one-step prediction error [kW] of the active and the shadow candidate model
    #: (`RunConfig.candidate_path`) where both have a residual; NaN without a candidate.
    active_rms_kw: float = math.nan
    candidate_rms_kw: float = math.nan
    candidate_stale_alarm_at_s: float | None = None
    #: Why the run was aborted (a test limit, refused commands, the controller; exit 1).
    abort_reason: str | None = None
    #: A node the server will not accept as configured: the node, the code, the fix (exit 2).
    configuration_error: str | None = None
    #: The last `RECENT_PHASES` read phases (`czmpc.runtime.alignment.read_phase`) and
    #: schedule shifts [wall s] (positive: later) taken to read just after the plant publishes.
    read_phases: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT_PHASES))
    alignment_shifts_s: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT_PHASES))

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


class CStepDriver(MPCDriver):
    """The generated C step (`czmpc.runtime.c_step.CStepMPC`) as a `LoopController`: the
    MPC's driver, whose step record gives its status and verdict as text."""

    def __init__(self, mpc: CStepMPC) -> None:
        super().__init__(mpc)  # type: ignore[arg-type]   # the same interface, compiled

    def status_words(self) -> tuple[str, str]:
        """Status and measurement verdict of the last step, as the Python MPC's names."""
        record = self.mpc.last_step
        if record is None:
            return ("", "")
        return (Status(str(record.status)).name, Verdict(str(record.verdict)).name)


class ControlLoop:
    """The runtime (module docstring).

    Parameters
    ----------
    config :
        The run configuration.
    controller :
        The MPC (its ``ts_s`` must equal ``config.ts_s``; wrapped in `MPCDriver`), the
        generated C step (wrapped in `CStepDriver`) or any `LoopController`.
    status :
        Called with a one-line status after each step (None: silent).
    step_delay_s :
        Testing hook: extra wall time [s] spent in the step at the given sample indices
        (injects overruns).
    health_settings :
        The model-health monitor's settings (None: `czmpc.health.RUNTIME_HEALTH`).
    provenance :
        What drives the input and where it came from (e.g. the test schedule and its
        SHA-256), for ``<log>.meta.json``.
    """

    def __init__(self, config: RunConfig, controller: OffsetFreeMPC | CStepMPC | LoopController, *,
                 status: Callable[[str], None] | None = None,
                 step_delay_s: dict[int, float] | None = None,
                 health_settings: HealthSettings | None = None,
                 provenance: Mapping[str, object] | None = None) -> None:
        self.config = config
        self.ctrl: LoopController = (
            MPCDriver(controller) if isinstance(controller, OffsetFreeMPC)
            else CStepDriver(controller) if isinstance(controller, CStepMPC) else controller)
        self._provenance = dict(provenance or {})
        self._bad_run = 0
        self.link = PlantLink(config)
        #: The last pre-flight check of the nodes (`PlantLink.connect`), None before.
        self.check: CheckReport | None = None
        self.summary = RunSummary()
        self._status = status
        self._delay = dict(step_delay_s or {})
        self._stop = asyncio.Event()
        self._counts: dict[str, Any] = {}     # what the counter nodes hold (our last writes)
        self._events: list[str] = []          # this step's, for the log's event column
        self._refused_in_row = 0
        self._lost_at: float | None = None    # monotonic time the link was lost (None: up)
        self._transitions = Transitions()
        #: One writer per plant (`czmpc.runtime.ownership`): what czmpc wrote, read back.
        self.watch = WriterWatch()
        self.identity = identity(config.log_path)
        self._other_writer = False            # another writer seen: czmpc writes nothing more
        self._overruns_said = (0, 0, time.monotonic())   # overruns, skipped, when last said
        self._said_timestamps = False
        # no step lasts longer than one period plus the connect timeout
        self._step_budget_s = config.connect_timeout_s + 0.5 * config.period_s
        self._last_cmd = math.nan
        self._applied = math.nan
        self._backoff_s = config.period_s
        self._max_backoff_s = min(MAX_BACKOFF_S, MAX_BACKOFF_PERIODS * config.period_s)
        self._next_try = 0.0
        self._ages_s: list[float] = []   # good samples' ages since the last phase estimate
        self._last_time: dt.datetime | None = None
        # a test schedule has no MPC, so no health monitor
        self._mpc: OffsetFreeMPC | CStepMPC | None = getattr(self.ctrl, "mpc", None)
        self.health = (None if self._mpc is None
                       else ModelHealthMonitor(self._mpc.model, health_settings or RUNTIME_HEALTH))
        #: The candidate model in shadow (config `[controller] candidate`): its own
        #: one-step predictor and health test, fed the same samples; it never drives.
        self.shadow = (None if self._mpc is None or config.candidate_path is None
                       else ModelHealthMonitor(load_model(config.candidate_path),
                                               health_settings or RUNTIME_HEALTH))
        self._sq_active_kw2 = 0.0      # sums of squared one-step errors
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
        #: The `CONTEXT_ARGS` the controller takes; the run's others are not passed (said once).
        self.context_args = context_args_taken(self.ctrl)
        configured = {"setpoint_preview_kw": config.schedule is not None
                      and config.preview_samples > 0 or config.nodes.setpoint_preview_kw is not None,
                      "grid_voltage_factor": config.nodes.grid_voltage_factor is not None}
        for name in CONTEXT_ARGS:
            if configured[name] and name not in self.context_args:
                _log.warning("%s: %s is configured but this controller does not take it; it "
                             "is read and logged only", type(self.ctrl).__name__, name)
        self._preview_said = "good"     # the array node's last quality word said
        self._voltage_said = True       # the voltage node's last value was usable

    def request_stop(self, reason: str) -> None:
        """Ask the loop to stop at the next period and apply the safe action."""
        self.summary.stopped_by = reason
        self._stop.set()

    def _event(self, text: str, level: int = logging.WARNING) -> None:
        """A link or run event: a log record now and the log's event column."""
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
        """Open a session and check the nodes; False (retry later) on a network fault or a
        failed check (a configuration error: the run stops)."""
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
        self._counts = {key: self.link.initial.get(key) for key in _COUNTERS}
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
        _signal_handlers(loop, self.request_stop)
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
            _signal_handlers(loop, None)
        return self.summary

    def _meta(self) -> dict[str, object]:
        """The run's provenance for ``<log>.meta.json``."""
        cfg = self.config
        return {
            "czmpc_version": __version__,
            "config": None if cfg.source_path is None else str(cfg.source_path),
            "config_sha256": None if cfg.source_path is None else file_sha256(cfg.source_path),
            "endpoint": cfg.endpoint, "ts_s": cfg.ts_s, "time_scale": cfg.time_scale,
            "start_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            "model": None if cfg.model_path is None else str(cfg.model_path),
            "model_sha256": None if cfg.model_path is None else file_sha256(cfg.model_path),
            "controller": self.identity,
            **self._provenance,
        }

    def _watched(self) -> tuple[str, ...]:
        """The nodes czmpc writes and can read back (command, heartbeat, owner lease)."""
        return tuple(key for key in ("triac_pct", "heartbeat", "owner")
                     if key in self.link.types and self.link.types[key].user_readable)

    async def _check_not_driven(self) -> None:
        """Before the first write: `PlantBusyError` when the watched nodes change over one
        period, or another controller's lease is newer than `LEASE_PERIODS` periods."""
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
        values = [_good_values(reads, keys) for reads in (first, second)]
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
            self.summary.lateness_s.add(lateness)
            self.summary.latency_s.add(end - woke)
            # overrun: skip every period whose start has passed (never catch up)
            next_k = k + 1
            if end > t0 + next_k * period:
                next_k = math.floor((end - t0) / period) + 1
                self.summary.n_overruns += 1
                self.summary.n_skipped += next_k - k - 1
            self._say_overruns()
            row["skipped"] = skipped = next_k - k - 1
            if skipped > 0:
                self.ctrl.skipped(skipped)
                self._monitors_skipped(skipped)
            row["step_latency_s"] = end - woke
            self._check_limits(row, next_k - k)
            t0 += self._align(row)
            log.row(row)
            k = next_k
        self.summary.n_steps = k

    def _align(self, row: dict[str, object]) -> float:
        """Shift [wall s] of the schedule that moves the reads to just after the plant
        publishes, said in the row; 0 until `alignment.WINDOW` good samples are in, or
        inside `alignment.BAND`."""
        if not self.config.align_to_plant or len(self._ages_s) < alignment.WINDOW:
            return 0.0
        period = self.config.period_s
        phase = alignment.read_phase(self._ages_s, period)
        self._ages_s.clear()
        if phase is None:
            return 0.0
        self.summary.read_phases.append(phase)
        shift = alignment.alignment_shift_s(phase, period)
        if shift is None:
            return 0.0
        self.summary.alignment_shifts_s.append(shift)
        self._add_event(row, f"reads moved to {alignment.TARGET_PHASE:.2f} of the period after the "
                             f"plant publishes (were at {phase:.2f}; {abs(shift) * 1e3:.1f} ms "
                             f"{'later' if shift > 0 else 'earlier'})")
        return shift

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

    def _say_overruns(self) -> None:
        """Once a minute of wall time at most: how many periods overran since it was last said."""
        n_said, skipped_said, when = self._overruns_said
        now = time.monotonic()
        if now - when < OVERRUN_REPORT_S or self.summary.n_overruns == n_said:
            return
        longest_ms = 1e3 * self.summary.latency_s.recent_max_s
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
        end = time.monotonic() + self._step_budget_s
        if not self.link.connected:
            await self._try_connect(time.monotonic(), end - time.monotonic())
        values = await self._read(end)
        if k in self._delay:     # the testing hook: an overrun
            await asyncio.sleep(self._delay[k])
        sample, decision, health = self._decide(k, values)
        written = await self._write(decision.command_pct if decision.write else None, health, end)
        if decision.mode is not Mode.ON:
            self._last_cmd = decision.command_pct
        return self._record(k, lateness, sample, decision, health, written)

    def _decide(self, k: int, values: dict[str, Any] | None,
                ) -> tuple[Sample, Decision, ModelHealth | None]:
        """Judge the read, step the controller and the monitors (no I/O; `czmpc.runtime.step`)."""
        cfg = self.config
        if values is not None:
            reason = self.watch.other_writer(_good_values(values, self._watched()))
            if reason is not None:
                self._another_writer(reason)
        sample = judge(values, self.link.specs, max_age_s=cfg.max_sample_age_s,
                       previous_time=self._last_time,
                       reject_repeated=cfg.reject_repeated_samples,
                       connect_applied_pct=self._applied)
        if values is not None:
            self._applied = math.nan     # the input read at the (re)connect is used
        self._last_time = sample.time
        self.summary.n_repeated += sample.quality == "repeated"
        self.summary.n_missing += not math.isfinite(sample.power_kw)
        if sample.age_s is not None:
            self._ages_s.append(sample.age_s)
        if sample.setpoint_kw is not None:
            self._setpoint = sample.setpoint_kw
        if cfg.schedule is not None:
            self._setpoint = cfg.schedule.setpoint_at(k * cfg.ts_s)
        preview = self._preview(k, sample)
        voltage = self._voltage(k, sample)
        decision = decide(self.ctrl, sample, setpoint_kw=self._setpoint,
                          last_command_pct=self._last_cmd, allow_on=self.allow_on,
                          setpoint_preview_kw=(preview if "setpoint_preview_kw"
                                               in self.context_args else None),
                          grid_voltage_factor=(voltage if "grid_voltage_factor"
                                               in self.context_args else None))
        self._transitions, events = transitions(self._transitions, k, cfg.ts_s, decision)
        for level, text in events:
            self._event(text, level)
        self.summary.n_commands_meant += decision.write
        return sample, decision, self._health(k, sample.power_kw, decision.applied_before_pct)

    def _preview(self, k: int, sample: Sample) -> tuple[float, ...] | None:
        """This step's setpoints of the coming samples [kW] (element 0 the next sample):
        the recipe's on the run's clock, or the array node's cut to ``setpoint_preview_s``
        (0: all of it); None without one. An unusable array node is said once when it
        turns so and once when it is back."""
        cfg = self.config
        n = cfg.preview_samples
        if cfg.schedule is not None:
            return cfg.schedule.setpoints_after(k * cfg.ts_s, cfg.ts_s, n) if n > 0 else None
        if "setpoint_preview_kw" not in self.link.specs:
            return None
        quality = sample.preview_quality
        if quality != self._preview_said:
            t = k * cfg.ts_s
            if quality == "good":
                self._event(f"setpoint preview usable again at t={t:.0f}s", logging.INFO)
            else:
                self._event(f"setpoint preview not usable at t={t:.0f}s ([nodes] "
                            f"setpoint_preview_kw {quality}): the controller steps without one")
            self._preview_said = quality
        ahead = sample.setpoint_preview_kw
        if ahead is None:
            return None
        return ahead[:n] if n > 0 else ahead

    def _voltage(self, k: int, sample: Sample) -> float | None:
        """The measured grid voltage factor [-] (NaN: not usable, the controller then says
        "missing"; None: no node); an unusable node is said once when it turns so."""
        voltage = sample.grid_voltage_factor
        if voltage is None:
            return None
        usable = math.isfinite(voltage)
        if usable != self._voltage_said:
            t = k * self.config.ts_s
            self._event(f"grid voltage usable again at t={t:.0f}s" if usable else
                        f"grid voltage not usable at t={t:.0f}s ([nodes] grid_voltage_factor): "
                        "the controller takes the nominal voltage", logging.INFO if usable
                        else logging.WARNING)
            self._voltage_said = usable
        return voltage

    def _context_columns(self, sample: Sample) -> dict[str, object]:
        """The log's columns of the measured voltage and what the MPC used of it and of
        the preview (blank for a controller without an MPC)."""
        diag = None if self._mpc is None else self._mpc.last_step
        measured = sample.grid_voltage_factor
        return {"grid_voltage_factor": math.nan if measured is None else measured,
                "voltage_factor_used": float(getattr(diag, "voltage_factor_used", math.nan)),
                "voltage_verdict": str(getattr(diag, "voltage_verdict", "")),
                "preview_samples": getattr(diag, "preview_samples", "")}

    def _record(self, k: int, lateness: float, sample: Sample, decision: Decision,
                health: ModelHealth | None, written: bool) -> dict[str, object]:
        """The step's log row (its timing columns filled in by `_loop`) and the status line."""
        cfg = self.config
        applied = decision.applied_triac_pct
        row: dict[str, object] = {
            "k": k, "time_s": k * cfg.ts_s, "wall_time_s": time.time(),
            "power_kw": sample.power_kw, "quality": sample.quality,
            "setpoint_kw": self._setpoint, "triac_pct": decision.command_pct,
            "applied_triac_pct": math.nan if applied is None else applied,
            "status": decision.status, "verdict": decision.verdict,
            "mode": decision.mode.name, "connected": int(self.link.connected),
            "written": int(written), "lateness_s": lateness, "step_latency_s": 0.0,
            "skipped": 0, "predicted_kw": math.nan if health is None else health.predicted_kw,
            "health": math.nan if health is None else health.health,
            "stale_alarm": "" if health is None else int(health.stale_alarm),
            "event": self._take_events(),
            **self._shadow_columns(k, sample.power_kw, decision.applied_before_pct, health),
            **self._context_columns(sample),
        }
        self._say(f"k={k} t={k * cfg.ts_s:.0f}s P={sample.power_kw:.2f}kW ({sample.quality}) "
                  f"SP={self._setpoint:.2f}kW u={decision.command_pct:.2f}% {decision.status} "
                  f"{decision.mode.name} late={lateness * 1e3:.1f}ms "
                  f"{'' if health is None else health.status()}")
        return row

    def _state_values(self, command: float | None, health: ModelHealth | None) -> dict[str, Any]:
        """The controller's state for the optional state nodes (HMI, historian), as Variants.

        ``status`` and ``mode_in_effect``: text, or `STATUS_CODES` / `MODE_CODES` on an
        integer node; ``predicted_power_kw``: the next sample with this step's input acting.
        """
        link, present = self.link, self.link.types
        alarm = health is not None and health.stale_alarm
        words = {"status": (self.ctrl.status_words()[0] or "OFF", STATUS_CODES),
                 "mode_in_effect": (self.ctrl.mode.name, MODE_CODES),
                 "stale_alarm": ("ON" if alarm else "OFF", {"OFF": 0, "ON": 1})}
        out = {key: link.word(key, name, codes) for key, (name, codes) in words.items()
               if key in present}
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
            out["watchdog"] = link.next_count("watchdog", self._counts.get("watchdog"))
        return out

    async def _read(self, end: float) -> dict[str, Any] | None:
        """One Read (I/O only): DataValues of the power, the optional setpoint, mode and
        applied-input nodes and the watched nodes; None without a link."""
        if not self.link.connected:
            return None
        signals = ("power_kw", "setpoint_kw", "mode", "applied_triac_pct", *CONTEXT_ARGS)
        keys = tuple(k for k in signals if k in self.link.specs)
        keys += tuple(k for k in self._watched() if k not in signals)
        try:
            return await self.link.read(keys, end - time.monotonic())
        except LinkLostError as exc:
            self._lost(exc)
            return None

    async def _write(self, command: float | None, health: ModelHealth | None,
                     end: float) -> bool:
        """One Write of the command (None: none meant), heartbeat and model health; True
        when the plant accepted the command. Refusals: `czmpc.runtime.refusals`."""
        if not self.link.connected or self._other_writer:
            return False
        values: dict[str, Any] = {}
        try:
            if "owner" in self.link.types:
                values["owner"] = self.link.variant("owner", self.identity)
            if command is not None:
                values["triac_pct"] = self.link.variant("triac_pct", float(command))
            if "heartbeat" in self.link.specs:
                values["heartbeat"] = self.link.next_count("heartbeat", self._counts.get("heartbeat"))
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
            self._refused(code)
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
        self._counted(values, results)
        if command is None:
            self.watch.forget("triac_pct")   # the operator may drive the TRIAC outside ON
            return False
        code = results.get("triac_pct")
        self._refused_in_row, abort = refused_in_row(code, self._refused_in_row,
                                                     self.config.max_refused_writes)
        if code is None:
            self.summary.n_writes += 1
            self.summary.n_commands_accepted += 1
            self._last_cmd = float(command)
            return True
        if (abort is not None and self.summary.abort_reason is None
                and self.summary.configuration_error is None):
            self.summary.abort_reason = abort
            self._event(f"ABORT: {abort}", logging.ERROR)
            self.request_stop("abort")
        return False

    def _refused(self, code: str) -> None:
        self.summary.refused_writes[code] = self.summary.refused_writes.get(code, 0) + 1

    def _counted(self, values: Mapping[str, Any], results: Mapping[str, str | None]) -> None:
        """Remember the counters the plant accepted."""
        for key in _COUNTERS:
            if key in values and results.get(key) is None:
                self._counts[key] = values[key].Value

    def _health(self, k: int, power: float, applied_before: float) -> ModelHealth | None:
        """Feed the model-health monitor; say the stale alarm once when it comes."""
        if self.health is None or self._mpc is None:
            return None
        d = float(getattr(self._mpc.last_step, "disturbance_power_kw", math.nan))
        health = self.health.update(power, applied_before, d)
        if health.stale_alarm and self.summary.stale_alarm_at_s is None:
            self.summary.stale_alarm_at_s = k * self.config.ts_s
            self.summary.stale_alarm_reason = health.alarm_reason
            self._event(f"STALE-MODEL ALARM at t={k * self.config.ts_s:.0f}s: {health.alarm_reason}")
        return health

    def _monitors_skipped(self, n_periods: int) -> None:
        """Carry the one-step predictors over skipped periods as missing samples, the command
        held (no residual counts until the gap's transient settles, `ModelHealth.residual_kw`)."""
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
        target = cfg.safe_triac_pct
        if not self.link.connected and self.summary.configuration_error is None:
            await self._try_connect(0.0, STARTUP_CONNECT_FACTOR * cfg.connect_timeout_s)
        if "triac_pct" not in self.link.types:
            _log.error("stopped (%s): the safe ramp cannot be written (no usable link to %s)",
                       self.summary.stopped_by, cfg.nodes.triac_pct)
            return
        u = self._last_cmd if math.isfinite(self._last_cmd) else target
        while self.link.connected:
            u = u + max(-step, min(step, target - u))
            end = time.monotonic() + self._step_budget_s
            values: dict[str, Any] = {"triac_pct": self.link.variant("triac_pct", u)}
            if "heartbeat" in self.link.types:  # the plant's watchdog still sees us
                values["heartbeat"] = self.link.next_count("heartbeat", self._counts.get("heartbeat"))
            try:
                results = await self.link.write(values, end - time.monotonic())
            except LinkLostError as exc:
                self._lost(exc)
                break
            self._counted(values, results)
            code = results["triac_pct"]
            if code is not None:
                self._refused(code)
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


__all__ = ["CONTEXT_ARGS", "MODE_CODES", "RECENT_PHASES", "RECENT_STEPS", "STATUS_CODES",
           "ControlLoop", "MPCDriver", "RunSummary", "StepTimes", "context_args_taken",
           "tty_status"]
