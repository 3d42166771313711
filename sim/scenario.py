"""Scenario: duration, setpoint profile, disturbances and faults of one closed-loop run.

A scenario is plant- and controller-independent: setpoints are absolute powers [kW],
times are seconds from the start of the run. Scenarios ship as TOML files in
``sim/scenarios/`` (`list_scenarios`, `load_scenario`); the file format is::

    name = "staircase"                 # required, string
    description = "..."                # string
    duration_s = 7200                  # required, > 0, a whole number of samples
    ts_s = 2.0                         # sampling time [s], default 2
    plant_noise = true                 # recommended plant noise on/off, default true
    initial_setpoint_kw = 45.0         # required: setpoint before the first change
    initial_triac_pct = 45.0           # optional: plant starts in steady state here
                                       # (absent: at the input that gives the setpoint)
    setpoint_preview_s = 0.0           # how far ahead the controller is told the
                                       # setpoint [s], default 0 (no preview)
    measured_voltage = false           # the controller is given the grid voltage
                                       # factor each sample, default false
    [limits]                           # limits the metrics check the input against
    triac_min_pct = 0.0                # default 0
    triac_max_pct = 100.0              # default 100
    max_move_pct_per_step = 5.0        # default: no rate limit

    [[setpoint]]   kind = "step",  at_s, power_kw
    [[setpoint]]   kind = "ramp",  start_s, end_s, power_kw (reached at end_s)
    [[disturbance]] kind = "voltage_step", at_s, factor, duration_s (optional)
    [[disturbance]] kind = "voltage_ramp", start_s, end_s, factor
    [[disturbance]] kind = "power_shift",  at_s, offset_kw, duration_s (optional)
    [[fault]]      kind = "spike",           at_s, spike_kw
    [[fault]]      kind = "random_spikes",   probability_per_sample, spike_kw,
                                             start_s (optional), end_s (optional)
    [[fault]]      kind = "missing_samples", at_s, duration_s

Bounds (what the machine can hold, checked before anything is allocated): a run has at
most ``MAX_N_STEPS`` samples (23 days of 2-s samples, longer than a crystal growth),
every time is at most ``MAX_TIME_S`` and every power at most ``MAX_ABS_POWER_KW`` in
magnitude (the constants say why). Other numbers need only be finite floats (TOML
integers too large for a float are refused).

Every key carries its unit in its name. Unknown keys, wrong types, negative times,
inverted limits and overlapping setpoint changes are refused with a `ScenarioError`
that names the file and the key (array entries are numbered from 1, e.g.
``setpoint[2].at_s``).
"""

from __future__ import annotations

import difflib
import math
import os
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np

from sim.disturbances import (
    TIME_RTOL,
    Disturbance,
    Fault,
    MeasurementSpike,
    MissingSamples,
    PowerShift,
    RandomSpikes,
    VoltageRamp,
    VoltageStep,
    sample_times_s,
    scaled_times,
)
from sim.errors import ScenarioError
from sysid._typing import FloatArray


# --- setpoint changes ----------------------------------------------------------------
@dataclass(frozen=True, slots=True, kw_only=True)
class SetpointStep:
    """The setpoint jumps to ``power_kw`` at ``at_s``.

    Parameters
    ----------
    at_s :
        Time of the step [s], >= 0.
    power_kw :
        New setpoint [kW].
    """

    at_s: float
    power_kw: float

    @property
    def start_s(self) -> float:
        """When the change begins [s]."""
        return self.at_s

    @property
    def end_s(self) -> float:
        """When the setpoint reaches its new value [s]."""
        return self.at_s


@dataclass(frozen=True, slots=True, kw_only=True)
class SetpointRamp:
    """The setpoint moves linearly from its current value to ``power_kw`` over ``[start_s, end_s]``.

    Parameters
    ----------
    start_s, end_s :
        Start and end of the ramp [s], ``0 <= start_s < end_s``.
    power_kw :
        Setpoint reached at ``end_s`` [kW].
    """

    start_s: float
    end_s: float
    power_kw: float


SetpointChange = SetpointStep | SetpointRamp


@dataclass(frozen=True, slots=True, kw_only=True)
class SetpointSegment:
    """One stretch of a run between setpoint changes, on the sample grid.

    Parameters
    ----------
    kind :
        ``"initial"`` (before any change), ``"step"`` or ``"ramp"``.
    start_k :
        First sample of the segment (the change begins here).
    settled_k :
        First sample at which the setpoint has its final value (``start_k`` for a step).
    stop_k :
        One past the last sample (the next change's ``start_k`` or the run's end).
    from_kw, to_kw :
        Setpoint before and after the change [kW] (equal for ``"initial"``).
    """

    kind: Literal["initial", "step", "ramp"]
    start_k: int
    settled_k: int
    stop_k: int
    from_kw: float
    to_kw: float

    @property
    def step_kw(self) -> float:
        """Size of the change ``to_kw - from_kw`` [kW]."""
        return self.to_kw - self.from_kw


def _first_sample_at(time_s: float, ts_s: float) -> int:
    """Index of the first sample with ``k * ts_s >= time_s`` (rounding-tolerant)."""
    return max(0, math.ceil(time_s / ts_s - TIME_RTOL))


# --- the scenario ----------------------------------------------------------------------
#: Memory a closed-loop run holds per sample [byte] (arrays, diagnostics, step result),
#: measured; `tests/sim/test_scenario.py` checks it stays an upper bound.
BYTES_PER_STEP = 4_000
#: Most samples in one run: ``MAX_N_STEPS * BYTES_PER_STEP`` = 4 GB, a share of a small machine.
MAX_N_STEPS = 1_000_000
#: Largest power magnitude in a scenario [kW]: ``(2 * MAX_ABS_POWER_KW)**2 * MAX_N_STEPS *
#: 60 s`` (the integrated squared error) is far below the float range (1.8e308).
MAX_ABS_POWER_KW = 1e100
#: Largest time in a scenario [s]: ``MAX_N_STEPS`` samples of 60 s (about 2 years).
MAX_TIME_S = MAX_N_STEPS * 60.0


def _bounded_time(value: float, where: str) -> None:
    if value > MAX_TIME_S:
        raise ScenarioError(f"{where}: expected a time <= {MAX_TIME_S:g} s (MAX_TIME_S: a run holds at most "
                            f"MAX_N_STEPS = {MAX_N_STEPS} samples in memory); got {value:g} s")


def _bounded_power(value: float, where: str) -> None:
    if abs(value) > MAX_ABS_POWER_KW:
        raise ScenarioError(
            f"{where}: expected a power of magnitude <= {MAX_ABS_POWER_KW:g} kW "
            f"(MAX_ABS_POWER_KW: the metrics' squared errors must stay finite); got {value:g}")


def _finite(value: Any, where: str, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ScenarioError(f"{where}: expected a finite number; got {value!r}")
    if positive and value <= 0:
        raise ScenarioError(f"{where}: expected a number > 0; got {value!r}")
    if nonneg and value < 0:
        raise ScenarioError(f"{where}: expected a number >= 0; got {value!r}")
    return float(value)


@dataclass(frozen=True, kw_only=True)
class Scenario:
    """What happens during one closed-loop run (independent of plant and controller).

    Parameters
    ----------
    name :
        Short identifier (the TOML file's stem for shipped scenarios).
    description :
        What the scenario exercises.
    duration_s :
        Length of the run [s], > 0, a whole number of samples.
    ts_s :
        Sampling time [s], > 0.
    initial_setpoint_kw :
        Setpoint before the first change [kW].
    initial_triac_pct :
        TRIAC input the plant should start in steady state at [%]; None: the input
        whose steady-state power is ``initial_setpoint_kw`` (plant-dependent).
    setpoints :
        Setpoint changes in time order, not overlapping.
    disturbances :
        Process disturbances (`sim.disturbances`).
    faults :
        Sensor faults (`sim.disturbances`).
    plant_noise :
        Whether the plant's noise is recommended on.
    triac_limits_pct :
        ``(min, max)`` TRIAC input the metrics check against [%].
    max_move_pct_per_step :
        Largest input move per sample the metrics check against [%]; None: no limit.
    setpoint_preview_s :
        How far ahead [s] the controller is told the setpoint (`sim.loop`): the
        setpoints of the next ``round(setpoint_preview_s / ts_s)`` samples; 0: none.
    measured_voltage :
        Whether the controller is given the grid voltage factor measured over each
        sample (`sim.loop`).
    source :
        File it was read from, or ``"<memory>"``.

    Raises
    ------
    ScenarioError
        Non-positive duration or sampling time, a duration that is not a whole number of
        samples, events outside the run, overlapping setpoint changes, inverted limits.
    """

    name: str
    description: str = ""
    duration_s: float
    ts_s: float = 2.0
    initial_setpoint_kw: float
    initial_triac_pct: float | None = None
    setpoints: tuple[SetpointChange, ...] = ()
    disturbances: tuple[Disturbance, ...] = ()
    faults: tuple[Fault, ...] = ()
    plant_noise: bool = True
    triac_limits_pct: tuple[float, float] = (0.0, 100.0)
    max_move_pct_per_step: float | None = None
    setpoint_preview_s: float = 0.0
    measured_voltage: bool = False
    source: str = field(default="<memory>", compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ScenarioError(f"Scenario.name: expected a non-empty string; got {self.name!r}")
        ts_s = _finite(self.ts_s, "Scenario.ts_s", positive=True)
        duration_s = _finite(self.duration_s, "Scenario.duration_s", positive=True)
        object.__setattr__(self, "ts_s", ts_s)
        object.__setattr__(self, "duration_s", duration_s)
        _bounded_time(duration_s, "Scenario.duration_s")
        n = duration_s / ts_s
        if n > MAX_N_STEPS + 0.5:
            raise ScenarioError(f"Scenario.duration_s: expected at most MAX_N_STEPS = {MAX_N_STEPS} samples "
                                f"(duration_s / ts_s; about {BYTES_PER_STEP} bytes of memory each); got "
                                f"{duration_s:g} s / {ts_s:g} s = {n:.4g} samples")
        if not math.isfinite(n) or round(n) < 1 or abs(n - round(n)) > 1e-6 * max(1.0, n):
            raise ScenarioError(
                f"Scenario.duration_s: expected a whole number (>= 1) of samples of {ts_s:g} s; "
                f"got {duration_s:g} s")
        object.__setattr__(self, "initial_setpoint_kw",
                           _finite(self.initial_setpoint_kw, "Scenario.initial_setpoint_kw"))
        _bounded_power(self.initial_setpoint_kw, "Scenario.initial_setpoint_kw")
        if self.initial_triac_pct is not None:
            object.__setattr__(self, "initial_triac_pct",
                               _finite(self.initial_triac_pct, "Scenario.initial_triac_pct"))
        for name in ("setpoints", "disturbances", "faults"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        lo, hi = (_finite(v, "Scenario.triac_limits_pct") for v in self.triac_limits_pct)
        if not lo < hi:
            raise ScenarioError(f"Scenario.triac_limits_pct: expected min < max [%]; got ({lo:g}, {hi:g})")
        object.__setattr__(self, "triac_limits_pct", (lo, hi))
        if self.max_move_pct_per_step is not None:
            object.__setattr__(
                self, "max_move_pct_per_step",
                _finite(self.max_move_pct_per_step, "Scenario.max_move_pct_per_step",
                        positive=True),
            )
        preview_s = _finite(self.setpoint_preview_s, "Scenario.setpoint_preview_s")
        if preview_s < 0:
            raise ScenarioError(f"Scenario.setpoint_preview_s: expected a time >= 0 [s]; got {preview_s:g}")
        _bounded_time(preview_s, "Scenario.setpoint_preview_s")
        object.__setattr__(self, "setpoint_preview_s", preview_s)
        if not isinstance(self.measured_voltage, bool):
            raise ScenarioError(f"Scenario.measured_voltage: expected true or false; got "
                                f"{self.measured_voltage!r}")
        self._check_setpoints()
        for event in (*self.disturbances, *self.faults):
            for key, bounded in (("at_s", _bounded_time), ("start_s", _bounded_time),
                                 ("end_s", _bounded_time), ("duration_s", _bounded_time),
                                 ("offset_kw", _bounded_power), ("spike_kw", _bounded_power)):
                value = getattr(event, key, None)
                if isinstance(value, float):
                    bounded(value, f"Scenario: {type(event).__name__}.{key}")
            start = event.start_s if isinstance(event, (VoltageRamp, RandomSpikes)) else event.at_s
            if start >= duration_s:
                raise ScenarioError(
                    f"Scenario: {type(event).__name__} starts at {start:g} s; expected a time "
                    f"before the end of the run ({duration_s:g} s)")

    def _check_setpoints(self) -> None:
        previous_end = -math.inf
        for i, change in enumerate(self.setpoints, start=1):
            if not isinstance(change, (SetpointStep, SetpointRamp)):
                raise ScenarioError(f"Scenario.setpoints[{i}]: expected a SetpointStep or SetpointRamp; "
                                    f"got {change!r}")
            key = "at_s" if isinstance(change, SetpointStep) else "start_s"
            start = _finite(change.start_s, f"Scenario.setpoints[{i}].{key}", nonneg=True)
            end = _finite(change.end_s, f"Scenario.setpoints[{i}].end_s", nonneg=True)
            _finite(change.power_kw, f"Scenario.setpoints[{i}].power_kw")
            _bounded_power(change.power_kw, f"Scenario.setpoints[{i}].power_kw")
            if end < start or (isinstance(change, SetpointRamp) and end == start):
                raise ScenarioError(
                    f"Scenario.setpoints[{i}].end_s: expected a time > start_s = {start:g} s; "
                    f"got {end:g}")
            if start <= previous_end:
                raise ScenarioError(f"Scenario.setpoints[{i}].{key}: expected a time after the previous "
                                    f"change ends ({previous_end:g} s); got {start:g}")
            if end >= self.duration_s:
                raise ScenarioError(f"Scenario.setpoints[{i}]: expected the change to end before the run "
                                    f"ends ({self.duration_s:g} s); got {end:g} s")
            previous_end = end

    # --- derived ----------------------------------------------------------------------
    @property
    def n_steps(self) -> int:
        """Number of samples in the run."""
        return round(self.duration_s / self.ts_s)

    @property
    def preview_steps(self) -> int:
        """Samples ahead the controller is told the setpoint: ``round(setpoint_preview_s / ts_s)``."""
        return round(self.setpoint_preview_s / self.ts_s)

    def time_s(self) -> FloatArray:
        """Sample times ``k * ts_s`` [s], shape ``(n_steps,)``."""
        return sample_times_s(self.n_steps, self.ts_s)

    def setpoint_profile_kw(self) -> FloatArray:
        """Setpoint at every sample [kW], shape ``(n_steps,)``, read-only."""
        t = self.time_s()
        out = np.full(t.size, self.initial_setpoint_kw)
        level = self.initial_setpoint_kw
        tol = TIME_RTOL * self.ts_s
        for change in self.setpoints:
            after = t >= change.start_s - tol
            if isinstance(change, SetpointStep):
                out[after] = change.power_kw
            else:
                frac = np.clip((t[after] - change.start_s) / (change.end_s - change.start_s), 0, 1)
                out[after] = level + frac * (change.power_kw - level)
            level = change.power_kw
        out.setflags(write=False)
        return out

    def segments(self) -> tuple[SetpointSegment, ...]:
        """The run cut at every setpoint change, on the sample grid (first: ``"initial"``).

        A change that falls on the same sample as the next one (possible only in a
        heavily `shortened` scenario) yields an empty segment, which is dropped.
        """
        starts = [_first_sample_at(c.start_s, self.ts_s) for c in self.setpoints]
        bounds = [*starts, self.n_steps]
        segs = [SetpointSegment(kind="initial", start_k=0, settled_k=0, stop_k=bounds[0],
                                from_kw=self.initial_setpoint_kw,
                                to_kw=self.initial_setpoint_kw)]
        level = self.initial_setpoint_kw
        for i, change in enumerate(self.setpoints):
            settled = _first_sample_at(change.end_s, self.ts_s)
            segs.append(SetpointSegment(kind="step" if isinstance(change, SetpointStep) else "ramp",
                                        start_k=starts[i], settled_k=min(settled, bounds[i + 1]),
                                        stop_k=bounds[i + 1], from_kw=level, to_kw=change.power_kw))
            level = change.power_kw
        return tuple(s for s in segs if s.stop_k > s.start_k)

    def shortened(self, factor: float) -> Scenario:
        """Return the scenario with every time (duration, events) multiplied by ``factor``.

        For fast tests (0.1: 2 h -> 12 min). The duration is rounded up to whole samples;
        ``ts_s`` and so the plant's dynamics do not scale: responses may not settle.

        Parameters
        ----------
        factor :
            Time scale, ``0 < factor <= 1``.
        """
        if isinstance(factor, bool) or not isinstance(factor, (int, float)) or not (
            0 < factor <= 1
        ):
            raise ScenarioError(f"Scenario.shortened: expected 0 < factor <= 1; got {factor!r}")
        n = max(1, math.ceil(self.n_steps * factor - 1e-9))
        return replace(self, name=f"{self.name}-short",
                       description=f"{self.description} (times x {factor:g})", duration_s=n * self.ts_s,
                       setpoints=tuple(scaled_times(c, factor) for c in self.setpoints),
                       disturbances=tuple(scaled_times(d, factor) for d in self.disturbances),
                       faults=tuple(scaled_times(f, factor) for f in self.faults))


# --- TOML files ------------------------------------------------------------------------
_NUM = "number"
#: Largest integer a float can hold (TOML integers are unbounded in tomllib; beyond this
#: ``float(value)`` overflows).
_MAX_INT_FLOAT = int(np.finfo(float).max)
_TOP_KEYS: dict[str, str] = {
    "name": "string", "description": "string", "duration_s": _NUM, "ts_s": _NUM,
    "plant_noise": "boolean", "initial_setpoint_kw": _NUM, "initial_triac_pct": _NUM,
    "limits": "table", "setpoint": "array of tables", "disturbance": "array of tables",
    "fault": "array of tables", "setpoint_preview_s": _NUM, "measured_voltage": "boolean",
}
_TOP_REQUIRED = ("name", "duration_s", "initial_setpoint_kw")
_LIMIT_KEYS = ("triac_min_pct", "triac_max_pct", "max_move_pct_per_step")
#: A `Scenario` error about one field, and the file key of the fields named otherwise: the
#: file's errors are the Scenario's own, renamed, so each rule is checked in one place.
_FIELD_ERROR = re.compile(r"Scenario\.((?:setpoints\[\d+\])?(?:\.?\w+)?): (.*)", re.S)
_FILE_KEYS = {"triac_limits_pct": "limits.triac_max_pct",
              "max_move_pct_per_step": "limits.max_move_pct_per_step"}

# kind -> (class, required keys, optional keys)
_KINDS: dict[str, dict[str, tuple[type, tuple[str, ...], tuple[str, ...]]]] = {
    "setpoint": {
        "step": (SetpointStep, ("at_s", "power_kw"), ()),
        "ramp": (SetpointRamp, ("start_s", "end_s", "power_kw"), ()),
    },
    "disturbance": {
        "voltage_step": (VoltageStep, ("at_s", "factor"), ("duration_s",)),
        "voltage_ramp": (VoltageRamp, ("start_s", "end_s", "factor"), ()),
        "power_shift": (PowerShift, ("at_s", "offset_kw"), ("duration_s",)),
    },
    "fault": {
        "spike": (MeasurementSpike, ("at_s", "spike_kw"), ()),
        "random_spikes": (RandomSpikes, ("probability_per_sample", "spike_kw"),
                          ("start_s", "end_s")),
        "missing_samples": (MissingSamples, ("at_s", "duration_s"), ()),
    },
}


def _hint(key: str, allowed: list[str]) -> str:
    close = difflib.get_close_matches(key, allowed, n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _check_keys(table: Mapping[str, Any], allowed: list[str], where: str, src: str) -> None:
    for key in table:
        if key not in allowed:
            raise ScenarioError(
                f"{src}: key '{where}{key}': unknown key{_hint(key, allowed)}; expected one of "
                f"{', '.join(sorted(allowed))}")


def _typed(value: Any, kind: str, key: str, src: str) -> Any:
    ok = {
        "string": isinstance(value, str),
        "boolean": isinstance(value, bool),
        _NUM: isinstance(value, (int, float)) and not isinstance(value, bool),
        "table": isinstance(value, dict),
        "array of tables": isinstance(value, list) and all(isinstance(v, dict) for v in value),
    }[kind]
    if not ok:
        raise ScenarioError(f"{src}: key '{key}': expected a {kind}; got {value!r}")
    if kind == _NUM:
        if (isinstance(value, int) and not -_MAX_INT_FLOAT <= value <= _MAX_INT_FLOAT
                or not math.isfinite(value)):
            raise ScenarioError(f"{src}: key '{key}': expected a finite number; got {value!r}")
        return float(value)
    return value


def _events(doc: Mapping[str, Any], group: str, src: str) -> list[Any]:
    out = []
    for i, table in enumerate(doc.get(group, []), start=1):
        where = f"{group}[{i}]"
        kinds = _KINDS[group]
        kind = table.get("kind")
        if kind is None:
            raise ScenarioError(f"{src}: key '{where}.kind': missing; expected one of {', '.join(kinds)}")
        if not isinstance(kind, str) or kind not in kinds:
            raise ScenarioError(f"{src}: key '{where}.kind': expected one of {', '.join(kinds)}"
                                f"{_hint(str(kind), list(kinds))}; got {kind!r}")
        cls, required, optional = kinds[kind]
        _check_keys(table, ["kind", *required, *optional], f"{where}.", src)
        for key in required:
            if key not in table:
                raise ScenarioError(f"{src}: key '{where}.{key}': missing (required for {kind})")
        values = {k: _typed(table[k], _NUM, f"{where}.{k}", src) for k in table if k != "kind"}
        try:
            out.append(cls(**values))
        except ScenarioError as exc:
            raise ScenarioError(f"{src}: {where} ({kind}): {exc}") from None
    return out


def scenario_from_dict(doc: Mapping[str, Any], *, source: str = "<memory>") -> Scenario:
    """Build a `Scenario` from a parsed TOML document, validating every key.

    Parameters
    ----------
    doc :
        The parsed document (see the module docstring for its keys).
    source :
        File name used in error messages.

    Raises
    ------
    ScenarioError
        Unknown or missing keys, wrong types, negative times, inverted limits, or an
        inconsistent scenario; the message names ``source`` and the key.
    """
    src = source
    _check_keys(doc, list(_TOP_KEYS), "", src)
    for key in _TOP_REQUIRED:
        if key not in doc:
            raise ScenarioError(f"{src}: key '{key}': missing (required)")
    top = {key: _typed(value, _TOP_KEYS[key], key, src) for key, value in doc.items()}
    limits = top.get("limits", {})
    _check_keys(limits, list(_LIMIT_KEYS), "limits.", src)
    lim = {k: _typed(v, _NUM, f"limits.{k}", src) for k, v in limits.items()}
    setpoints = _events(doc, "setpoint", src)
    try:
        return Scenario(name=top["name"], description=top.get("description", ""),
                        duration_s=top["duration_s"], ts_s=top.get("ts_s", 2.0),
                        initial_setpoint_kw=top["initial_setpoint_kw"],
                        initial_triac_pct=top.get("initial_triac_pct"), setpoints=tuple(setpoints),
                        disturbances=tuple(_events(doc, "disturbance", src)),
                        faults=tuple(_events(doc, "fault", src)), plant_noise=top.get("plant_noise", True),
                        triac_limits_pct=(lim.get("triac_min_pct", 0.0), lim.get("triac_max_pct", 100.0)),
                        max_move_pct_per_step=lim.get("max_move_pct_per_step"),
                        setpoint_preview_s=top.get("setpoint_preview_s", 0.0),
                        measured_voltage=top.get("measured_voltage", False), source=src)
    except ScenarioError as exc:
        message = str(exc)
        if message.startswith(src):
            raise
        field_error = _FIELD_ERROR.match(message)
        if field_error is None:
            raise ScenarioError(f"{src}: {message}") from None
        name, rest = field_error.groups()
        key = _FILE_KEYS.get(name, name.replace("setpoints[", "setpoint["))
        raise ScenarioError(f"{src}: key '{key}': {rest}") from None


def list_scenarios() -> tuple[str, ...]:
    """Names of the scenarios shipped in ``sim/scenarios/``, sorted."""
    folder = resources.files("sim.scenarios")
    return tuple(sorted(
        p.name.removesuffix(".toml") for p in folder.iterdir() if p.name.endswith(".toml")
    ))


def load_scenario(name_or_path: str | os.PathLike[str]) -> Scenario:
    """Read a scenario by shipped name (``"staircase"``) or from a TOML file path.

    Parameters
    ----------
    name_or_path :
        A name from `list_scenarios`, or a path to a ``.toml`` file.

    Raises
    ------
    ScenarioError
        Unknown name, unreadable file, invalid TOML, or any invalid key (the message
        names the file and the key).
    """
    text_name = os.fspath(name_or_path)
    is_path = (
        isinstance(name_or_path, os.PathLike) or text_name.endswith(".toml")
        or os.sep in text_name or "/" in text_name
    )
    if is_path:
        path = Path(text_name)
        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise ScenarioError(f"{path}: cannot read scenario file: {exc.strerror}") from None
        src = str(path)
    else:
        names = list_scenarios()
        if text_name not in names:
            raise ScenarioError(f"load_scenario: expected a shipped scenario name ({', '.join(names)}) or a "
                                f".toml path; got {text_name!r}{_hint(text_name, list(names))}")
        raw = resources.files("sim.scenarios").joinpath(f"{text_name}.toml").read_bytes()
        src = f"{text_name}.toml"
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{src}: not a valid TOML file: {exc}") from None
    return scenario_from_dict(doc, source=src)


__all__ = ["BYTES_PER_STEP", "MAX_ABS_POWER_KW", "MAX_N_STEPS", "MAX_TIME_S", "Scenario", "SetpointChange",
           "SetpointRamp", "SetpointSegment", "SetpointStep", "list_scenarios", "load_scenario",
           "scenario_from_dict"]
