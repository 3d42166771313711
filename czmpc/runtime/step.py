"""One loop step's decisions, without I/O: judge a read, step the controller, name what changed.

`czmpc.runtime.loop.ControlLoop` reads the plant, hands the values to `judge` and
`decide`, and writes what they decided; so every rule of a step (usable samples, refused
mode requests, the applied input, writes, shedding, aborts on refused commands) is tested
with DataValues built in memory and no server.
"""

from __future__ import annotations

import datetime as dt
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from czmpc.modes import Mode
from czmpc.runtime.measurement import age_s, measurement, sample_time
from czmpc.runtime.node_types import NodeSpec, NodeValueError, decode


class LoopController(Protocol):
    """What the loop drives: the MPC, an open-loop test schedule, a dithered MPC."""

    @property
    def mode(self) -> Mode:
        """OFF / PREDICT / ON; the loop writes the command in ON only."""

    def request_mode(self, mode: Mode) -> object:
        """The operator asks for another mode (the plant's mode node)."""

    def step(self, power_kw: float, setpoint_kw: float, *,
             applied_triac_pct: float | None = None) -> float:
        """Return the TRIAC input [%] to apply now (see `OffsetFreeMPC.step`).

        A controller that also takes ``setpoint_preview_kw`` and ``grid_voltage_factor``
        (as `OffsetFreeMPC.step` does) is given them when the run has them (`decide`).
        """

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


def mode_of(value: Any) -> Mode | None:
    """The operator's mode from the mode node: text, an integer 0/1/2 (OFF/PREDICT/ON) or a
    bool (True: ON, False: OFF, a PLC's enable bit); None for anything else."""
    if isinstance(value, bool):
        return Mode.ON if value else Mode.OFF
    if isinstance(value, str) and value.strip().upper() in Mode.__members__:
        return Mode[value.strip().upper()]
    if isinstance(value, int):
        modes = list(Mode)
        if 0 <= value < len(modes):
            return modes[value]
    return None


@dataclass(frozen=True, slots=True, kw_only=True)
class Sample:
    """One read of the plant, judged (`judge`).

    Attributes
    ----------
    power_kw :
        Measured power [kW]; NaN unless ``quality`` is ``"good"``.
    quality :
        ``"good"``, ``"bad"``, ``"uncertain"``, ``"stale"``, ``"repeated"`` or
        ``"disconnected"`` (`czmpc.runtime.measurement.measurement`).
    time :
        The power's sample time (the previous one when this read carried none).
    age_s :
        Age of a good sample [wall s] (for the read alignment), else None.
    setpoint_kw, mode :
        A Good setpoint node's value [kW] and the operator's mode; None when absent.
    applied_triac_pct :
        The input the plant reports applied [%] (the value read at a (re)connect first),
        None when unknown.
    grid_voltage_factor :
        The grid voltage relative to nominal [-] over the last sample; NaN when the node
        is configured but its value is not usable (judged as the power is: Bad,
        Uncertain, stale, not a number, or no link), None when no node is configured.
    setpoint_preview_kw :
        The array node's setpoints of the coming samples [kW] (element 0 the next
        sample); None when no node is configured or its value is not usable.
    preview_quality :
        ``"good"`` or why the array node's value is not usable (``"bad"``,
        ``"uncertain"``, ``"stale"``, ``"not an array of numbers"``, ``"disconnected"``);
        ``""`` when no node is configured.
    """

    power_kw: float
    quality: str
    time: dt.datetime | None = None
    age_s: float | None = None
    setpoint_kw: float | None = None
    mode: Mode | None = None
    applied_triac_pct: float | None = None
    grid_voltage_factor: float | None = None
    setpoint_preview_kw: tuple[float, ...] | None = None
    preview_quality: str = ""


def judge(values: Mapping[str, Any] | None, specs: Mapping[str, NodeSpec], *, max_age_s: float,
          previous_time: dt.datetime | None, reject_repeated: bool = True,
          connect_applied_pct: float = math.nan) -> Sample:
    """Make a `Sample` of one read's DataValues.

    Parameters
    ----------
    values :
        DataValues by node key (``power_kw`` and any of ``setpoint_kw``, ``mode``,
        ``applied_triac_pct``); None when there was no link or the read failed.
    specs :
        The nodes' specs (their raw-to-value scales).
    max_age_s :
        Oldest usable power sample [wall s].
    previous_time :
        The previous read's sample time (a sample not later is ``"repeated"``).
    reject_repeated :
        False: a repeated sample is used again (``[plant] reject_repeated_samples``).
    connect_applied_pct :
        The applied input read at a (re)connect [%], NaN if none: it wins over the node.
    """
    voltage = math.nan if "grid_voltage_factor" in specs else None
    if values is None:
        return Sample(power_kw=math.nan, quality="disconnected", time=previous_time,
                      grid_voltage_factor=voltage,
                      preview_quality="disconnected" if "setpoint_preview_kw" in specs else "")
    dv = values["power_kw"]
    power, quality = measurement(dv, max_age_s, previous_time if reject_repeated else None,
                                 specs["power_kw"].scale)

    def good(key: str) -> float | None:
        if key not in values:
            return None
        value, q = measurement(values[key], math.inf, None, specs[key].scale)
        return value if q == "good" else None

    if "grid_voltage_factor" in values:
        voltage, _ = measurement(values["grid_voltage_factor"], max_age_s, None,
                                 specs["grid_voltage_factor"].scale)
    preview, preview_quality = (None, "")
    if "setpoint_preview_kw" in values:
        preview, preview_quality = preview_of(values["setpoint_preview_kw"], max_age_s,
                                              specs["setpoint_preview_kw"])
    mode_dv = values.get("mode")
    return Sample(power_kw=power, quality=quality, time=sample_time(dv)[0] or previous_time,
                  age_s=age_s(dv) if quality == "good" else None, setpoint_kw=good("setpoint_kw"),
                  mode=None if mode_dv is None or mode_dv.Value is None
                  else mode_of(mode_dv.Value.Value),
                  applied_triac_pct=good("applied_triac_pct") if math.isnan(connect_applied_pct)
                  else connect_applied_pct,
                  grid_voltage_factor=voltage, setpoint_preview_kw=preview,
                  preview_quality=preview_quality)


def preview_of(dv: Any, max_age_s: float, spec: NodeSpec,
               ) -> tuple[tuple[float, ...] | None, str]:
    """The coming setpoints [kW] an array node's DataValue holds, and a quality word.

    The array is judged as the power is (Bad, Uncertain, older than ``max_age_s``: not
    usable, None); each element is scaled as the node's spec says. An array element
    that is not finite stays in (the controller cuts the preview there); an element that
    is not a number, or a value that is not an array, makes the whole value unusable.
    """
    status = dv.StatusCode
    if status is not None and not status.is_good():
        return None, "uncertain" if status.is_uncertain() else "bad"
    age = age_s(dv)
    if age is not None and age > max_age_s:
        return None, "stale"
    raw = None if dv.Value is None else dv.Value.Value
    if not isinstance(raw, list | tuple):
        return None, "not an array of numbers"
    try:
        return tuple(decode(x, spec.scale) for x in raw), "good"
    except NodeValueError:
        return None, "not an array of numbers"


@dataclass(frozen=True, slots=True, kw_only=True)
class Decision:
    """What one step decided (`decide`).

    Attributes
    ----------
    command_pct :
        The controller's input [%] (written in ON only).
    write :
        True when the command is meant for the plant (mode ON, a finite command).
    applied_triac_pct :
        The input the controller was told is applied [%], None when not known.
    applied_before_pct :
        The input acting over the period that ends now [%] (the monitors' input).
    status, verdict, mode :
        The controller's words for the log, and its mode after the step.
    """

    command_pct: float
    write: bool
    applied_triac_pct: float | None
    applied_before_pct: float
    status: str
    verdict: str
    mode: Mode


def decide(ctrl: LoopController, sample: Sample, *, setpoint_kw: float, last_command_pct: float,
           allow_on: bool, setpoint_preview_kw: Sequence[float] | None = None,
           grid_voltage_factor: float | None = None) -> Decision:
    """Pass the operator's mode request, step the controller, decide whether to write.

    Outside ON, where the operator drives the TRIAC, an applied input the plant does not
    report is taken as the last command.

    Parameters
    ----------
    ctrl :
        The controller (stepped once).
    sample :
        This step's judged read.
    setpoint_kw :
        The setpoint in force [kW].
    last_command_pct :
        The last command accepted by the plant, or the last input outside ON [%]; NaN: none.
    allow_on :
        False: a request for ON is refused (the switch-on rule, `czmpc.runtime.session`).
    setpoint_preview_kw :
        The setpoints of the coming samples [kW] (element 0 the next sample); None: no
        preview. Passed to the controller only when given.
    grid_voltage_factor :
        The measured grid voltage relative to nominal [-] (NaN: configured but not
        usable); None: not measured. Passed to the controller only when given.
    """
    mode = sample.mode
    if mode is not None and mode is not ctrl.mode and (mode is not Mode.ON or allow_on):
        ctrl.request_mode(mode)
    applied = sample.applied_triac_pct
    if ctrl.mode is not Mode.ON and applied is None and math.isfinite(last_command_pct):
        applied = last_command_pct
    extra: dict[str, Any] = {}
    if setpoint_preview_kw is not None:
        extra["setpoint_preview_kw"] = setpoint_preview_kw
    if grid_voltage_factor is not None:
        extra["grid_voltage_factor"] = grid_voltage_factor
    command = float(ctrl.step(sample.power_kw, setpoint_kw, applied_triac_pct=applied, **extra))
    status, verdict = ctrl.status_words()
    return Decision(command_pct=command, write=ctrl.mode is Mode.ON and math.isfinite(command),
                    applied_triac_pct=applied,
                    applied_before_pct=last_command_pct if applied is None else applied,
                    status=status, verdict=verdict, mode=ctrl.mode)


@dataclass(frozen=True, slots=True, kw_only=True)
class Transitions:
    """Where shedding and the mode stood after the last step (`transitions`).

    Attributes
    ----------
    shed_at_k, mode :
        Sample shedding began at (None: not shedding); the last step's mode (None before).
    """

    shed_at_k: int | None = None
    mode: Mode | None = None


def transitions(before: Transitions, k: int, ts_s: float, decision: Decision,
                ) -> tuple[Transitions, tuple[tuple[int, str], ...]]:
    """The step's shedding and mode changes: the new state and its events (level, text)."""
    t = k * ts_s
    events: list[tuple[int, str]] = []
    shed_at = before.shed_at_k
    if decision.status == "SHED" and shed_at is None:
        shed_at = k
        events.append((logging.WARNING, f"shedding at t={t:.0f}s: no usable measurement for too "
                                        "long; the controller holds its input"))
    elif decision.status not in ("SHED", "") and shed_at is not None:
        events.append((logging.INFO, f"resumed at t={t:.0f}s after {(k - shed_at) * ts_s:.0f} s "
                                     "shed"))
        shed_at = None
    if before.mode is not None and decision.mode is not before.mode:
        events.append((logging.INFO, f"mode {before.mode.name} -> {decision.mode.name} at "
                                     f"t={t:.0f}s"))
    return Transitions(shed_at_k=shed_at, mode=decision.mode), tuple(events)


def refused_in_row(code: str | None, in_row: int, max_refused: int) -> tuple[int, str | None]:
    """Count a command write's outcome: (refused in a row now, why the run aborts or None).

    Parameters
    ----------
    code :
        The write's refusal code (a status code name), None when the plant accepted it.
    in_row :
        Command writes refused in a row before this one.
    max_refused :
        ``[plant] max_refused_writes``: this many in a row abort the run.
    """
    if code is None:
        return 0, None
    in_row += 1
    if in_row < max_refused:
        return in_row, None
    return in_row, (f"{in_row} command writes in a row refused (last {code}; "
                    f"[plant] max_refused_writes = {max_refused})")


__all__ = ["Decision", "LoopController", "Sample", "Transitions", "decide", "judge", "mode_of",
           "preview_of", "refused_in_row", "transitions"]
