"""An open-loop identification test through the plant link (`czmpc run --test`).

`InputSchedule` is a designed TRIAC schedule (``time_s,triac_pct``, as written by
`czmpc design-test`); `ScheduleDriver` plays it as a `czmpc.runtime.step.LoopController`,
so the test runs in the same loop as the MPC (timing, heartbeat, quality handling,
watchdog, safe action), and the config's ``[test]`` limits abort it
(`czmpc.runtime.config.ExperimentLimits`).

Start (bumpless): the first command is the input the plant applies now, held for
`LEAD_IN_HOLD_SAMPLES` samples so that the loop aligns its reads to the plant's period
before any input moves (`czmpc.runtime.alignment`; unaligned, a lead-in move a sample
late left a +-5 kW residual that failed check-model's whiteness). The driver then ramps
to the schedule's first value at `InputSchedule.max_step_pct` per sample, plays the
schedule (zero-order hold) and finishes after its last row. An operator who switches
the plant's mode away from ON aborts the test.
"""

from __future__ import annotations

import csv
import hashlib
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from czmpc.errors import CzmpcError
from czmpc.modes import Mode
from czmpc.runtime import alignment
from czmpc.runtime.config import RunConfig
from czmpc.runtime.loop import ControlLoop, RunSummary
from sysid._typing import FloatArray

_log = logging.getLogger(__name__)

#: Ramp rate [%/sample] into a schedule whose value never changes (its largest step is 0).
CONSTANT_SCHEDULE_RAMP_PCT = 1.0
#: Samples the applied input is held at the start, before the lead-in ramp (module
#: docstring): the loop's read phase is estimated from `alignment.WINDOW` good samples
#: and applied on the next; two more for a sample missed on the way.
LEAD_IN_HOLD_SAMPLES = alignment.WINDOW + 2


class ScheduleError(CzmpcError, ValueError):
    """A test schedule file that cannot be used."""


@dataclass(frozen=True, eq=False, kw_only=True)
class InputSchedule:
    """A designed TRIAC input schedule.

    Parameters
    ----------
    time_s :
        Times [s] from the start of the test, strictly increasing, the first 0.
    triac_pct :
        TRIAC input [%] from each time on (zero-order hold), inside 0..100.
    source :
        File it was read from, or a description.
    sha256 :
        SHA-256 of the file's bytes (provenance of the test), or None.
    """

    time_s: FloatArray
    triac_pct: FloatArray
    source: str = "<memory>"
    sha256: str | None = None

    def __post_init__(self) -> None:
        t = np.array(self.time_s, dtype=float)
        u = np.array(self.triac_pct, dtype=float)
        if t.ndim != 1 or t.shape != u.shape or t.size < 2:
            raise ScheduleError(f"{self.source}: expected two equal 1-D columns of at least 2 rows; "
                                f"got shapes {t.shape} and {u.shape}")
        if not (np.isfinite(t).all() and np.isfinite(u).all()):
            raise ScheduleError(f"{self.source}: expected finite times and inputs")
        if t[0] != 0.0 or (np.diff(t) <= 0).any():
            raise ScheduleError(f"{self.source}: expected time_s to start at 0 and increase; "
                                f"got {t[0]:g} first")
        if u.min() < 0.0 or u.max() > 100.0:
            raise ScheduleError(f"{self.source}: expected triac_pct inside 0..100 %; got "
                                f"{u.min():g} .. {u.max():g} %")
        t.flags.writeable = False
        u.flags.writeable = False
        object.__setattr__(self, "time_s", t)
        object.__setattr__(self, "triac_pct", u)

    @property
    def duration_s(self) -> float:
        """Time of the last row [s]."""
        return float(self.time_s[-1])

    @property
    def max_step_pct(self) -> float:
        """Largest designed jump between two consecutive rows [%]."""
        return float(np.abs(np.diff(self.triac_pct)).max())

    @property
    def ramp_pct_per_sample(self) -> float:
        """Rate of the lead-in and of an abort's safe ramp [%/sample]: `max_step_pct`
        (or `CONSTANT_SCHEDULE_RAMP_PCT` for a constant schedule)."""
        step = self.max_step_pct
        return step if step > 0.0 else CONSTANT_SCHEDULE_RAMP_PCT

    def triac_at(self, time_s: float) -> float:
        """Input [%] in force at test time ``time_s`` [s] (zero-order hold)."""
        i = int(np.searchsorted(self.time_s, time_s, side="right")) - 1
        return float(self.triac_pct[max(0, i)])


def load_input_schedule(path: str | Path) -> InputSchedule:
    """Read a test schedule CSV with the header ``time_s,triac_pct``.

    Raises
    ------
    ScheduleError
        A missing column, a non-number (message with the line), times that do not
        start at 0 and increase, inputs outside 0..100 %.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ScheduleError(f"{path}: cannot read the test schedule: {exc.strerror}") from exc
    rows = list(csv.DictReader(raw.decode("utf-8-sig").splitlines()))
    times: list[float] = []
    inputs: list[float] = []
    for i, row in enumerate(rows, start=2):
        try:
            times.append(float(row["time_s"]))
            inputs.append(float(row["triac_pct"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise ScheduleError(
                f"{path} line {i}: expected columns time_s [s], triac_pct [%] with numbers "
                f"(as czmpc design-test writes them); got {row!r}") from exc
    return InputSchedule(time_s=np.asarray(times), triac_pct=np.asarray(inputs), source=str(path),
                         sha256=hashlib.sha256(raw).hexdigest())


class ScheduleDriver:
    """Plays an `InputSchedule` as the loop's controller (module docstring).

    Parameters
    ----------
    schedule :
        The designed schedule.
    ts_s :
        Sampling time of the loop [s].
    hold_samples :
        Samples the applied input is held before the lead-in ramp, >= 0.
    """

    def __init__(self, schedule: InputSchedule, ts_s: float, *,
                 hold_samples: int = LEAD_IN_HOLD_SAMPLES) -> None:
        if isinstance(hold_samples, bool) or not isinstance(hold_samples, int) or hold_samples < 0:
            raise ScheduleError(f"hold_samples must be an integer >= 0; got {hold_samples!r}")
        self.schedule = schedule
        self.ts_s = float(ts_s)
        self._hold_left = hold_samples
        self._mode = Mode.ON
        self._u = math.nan
        self._k_test: int | None = None   # samples since the schedule started
        self._abort: str | None = None
        self._phase = "LEAD_IN"
        #: Samples spent holding and ramping into the schedule (the last is its time 0).
        self.lead_in_samples = 0

    @property
    def mode(self) -> Mode:
        """ON until the operator takes the heater (then the test is aborted)."""
        return self._mode

    def request_mode(self, mode: Mode) -> object:
        """Any mode but ON from the plant aborts the test (the operator took over)."""
        if mode is not Mode.ON:
            self._mode = mode
            self._abort = f"the plant's mode was switched to {mode.name} during the test"
        return None

    @property
    def rate_limit_pct_per_step(self) -> float:
        """`InputSchedule.ramp_pct_per_sample`."""
        return self.schedule.ramp_pct_per_sample

    def step(self, power_kw: float, setpoint_kw: float, *,
             applied_triac_pct: float | None = None) -> float:
        """The schedule's input now (the lead-in hold and ramp first); measurements are not used.

        Parameters
        ----------
        power_kw, setpoint_kw :
            Ignored (the loop checks the test band).
        applied_triac_pct :
            The plant's applied input; the first one known is where the lead-in starts.
        """
        self._phase = "LEAD_IN" if self._k_test is None else "TEST"
        if not math.isfinite(self._u):
            known = applied_triac_pct is not None and math.isfinite(applied_triac_pct)
            self._u = float(applied_triac_pct) if known else self.schedule.triac_at(0.0)  # type: ignore[arg-type]
        if self._hold_left > 0:
            self._hold_left -= 1
            self.lead_in_samples += 1
            return self._u
        if self._k_test is None:
            target = self.schedule.triac_at(0.0)
            rate = self.rate_limit_pct_per_step
            self._u = self._u + max(-rate, min(rate, target - self._u))
            self.lead_in_samples += 1
            if abs(self._u - target) <= 1e-9:
                self._u = target
                self._k_test = 0
            return self._u
        self._k_test += 1
        self._u = self.schedule.triac_at(self._k_test * self.ts_s)
        return self._u

    def status_words(self) -> tuple[str, str]:
        """``("LEAD_IN" | "TEST", "")``: the phase of the last step."""
        return self._phase, ""

    def skipped(self, n_periods: int) -> None:
        """Keep the schedule on plant time: the skipped periods count as played (the
        plant held the last command through them)."""
        if self._k_test is not None:
            self._k_test += n_periods

    def finished(self) -> str | None:
        """``"end of schedule"`` once the last row's time has been applied."""
        if self._k_test is not None and self._k_test * self.ts_s >= self.schedule.duration_s:
            return "end of schedule"
        return None

    def abort_reason(self) -> str | None:
        """Why the test stopped as failed (operator mode change), or None."""
        return self._abort


def schedule_provenance(schedule: InputSchedule) -> dict[str, object]:
    """The provenance of an open-loop test for the run log's ``<log>.meta.json``."""
    return {"kind": "open-loop test", "closed_loop": False, "schedule": schedule.source,
            "schedule_sha256": schedule.sha256, "schedule_duration_s": schedule.duration_s,
            "schedule_max_step_pct": schedule.max_step_pct}


def make_test_loop(config: RunConfig, schedule: InputSchedule, **loop_options: object) -> ControlLoop:
    """The runtime loop playing ``schedule`` until its end (``duration_s`` is ignored).

    Raises
    ------
    ScheduleError
        If ``config`` has no ``[test]`` section (a test needs its safety band).
    """
    import dataclasses

    limits = config.test_limits
    if limits is None:
        raise ScheduleError(
            "a test needs a [test] section in the run config: power_band_kw = [LO, HI] (kW) and "
            "max_bad_quality_s (s); see czmpc run --help")
    _log.info("open-loop test %s: %g s of plant time, largest step %g %%; band %g..%g kW, "
              "at most %g s without a usable sample; abort -> %g %%", schedule.source,
              schedule.duration_s, schedule.max_step_pct, limits.power_band_kw[0],
              limits.power_band_kw[1], limits.max_bad_quality_s, config.safe_triac_pct)
    config = dataclasses.replace(config, duration_s=None)
    return ControlLoop(config, ScheduleDriver(schedule, config.ts_s),
                       provenance=schedule_provenance(schedule), **loop_options)  # type: ignore[arg-type]


__all__ = ["CONSTANT_SCHEDULE_RAMP_PCT", "LEAD_IN_HOLD_SAMPLES", "InputSchedule", "RunSummary",
           "ScheduleDriver", "ScheduleError", "load_input_schedule", "make_test_loop", "schedule_provenance"]
