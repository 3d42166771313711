"""Disturbance and sensor-fault signals: pure functions of the sample time (and an rng).

Two families act on a closed loop:

* **process disturbances** reach the plant as `sim.protocols.Exogenous` values:
  `VoltageStep` and `VoltageRamp` (grid voltage factor, multiplied) and `PowerShift`
  (power offset [kW], added);
* **sensor faults** corrupt only the measurement: `MeasurementSpike` (one sample),
  `RandomSpikes` (seeded) and `MissingSamples` (NaN).

Sample ``k`` is at ``t_k = k * ts_s``; an event "at ``at_s``" acts on every sample with
``t_k >= at_s`` (before ``at_s + duration_s`` if a duration is given), a window
``[start_s, end_s]`` likewise. Each class validates itself, raising `ScenarioError`
that names the class and field.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
import numpy.typing as npt

from sim.errors import ScenarioError
from sim.protocols import Exogenous
from sysid._typing import FloatArray

#: Tolerance [relative to ts_s] comparing sample with event times (600 s hits sample 300 at 2 s).
TIME_RTOL = 1e-9

BoolArray = npt.NDArray[np.bool_]
if TYPE_CHECKING:
    from _typeshed import DataclassInstance
_Event = TypeVar("_Event", bound="DataclassInstance")


def _is_finite_number(value: object) -> bool:
    """True for a finite int or float (a bool is not a number here)."""
    return (not isinstance(value, bool) and isinstance(value, (int, float))
            and math.isfinite(value))


def _check_time(obj: object, name: str, *, allow_none: bool = False, positive: bool = False) -> None:
    value = getattr(obj, name)
    where = f"{type(obj).__name__}.{name}"
    if value is None and allow_none:
        return
    if not _is_finite_number(value):
        raise ScenarioError(f"{where}: expected a finite number [s]; got {value!r}")
    if positive and value <= 0:
        raise ScenarioError(f"{where}: expected a duration > 0 [s]; got {value!r}")
    if value < 0:
        raise ScenarioError(f"{where}: expected a time >= 0 [s]; got {value!r}")
    object.__setattr__(obj, name, float(value))


def _check_number(obj: object, name: str, *, lo: float = -math.inf, lo_open: bool = False,
                  hi: float = math.inf, unit: str = "") -> None:
    value = getattr(obj, name)
    where = f"{type(obj).__name__}.{name}"
    if not _is_finite_number(value) or value < lo or (lo_open and value == lo) or value > hi:
        bound = []
        if lo > -math.inf:
            bound.append(f"{'>' if lo_open else '>='} {lo:g}")
        if hi < math.inf:
            bound.append(f"<= {hi:g}")
        rng_txt = (" " + " and ".join(bound)) if bound else ""
        raise ScenarioError(f"{where}: expected a finite number{rng_txt}{unit}; got {value!r}")
    object.__setattr__(obj, name, float(value))


def _check_held_event(obj: object, value_name: str, **bounds: Any) -> None:
    """Check ``at_s``, the held ``value_name`` (``bounds`` of `_check_number`), ``duration_s``."""
    _check_time(obj, "at_s")
    _check_number(obj, value_name, **bounds)
    _check_time(obj, "duration_s", allow_none=True, positive=True)


def _check_end_after_start(obj: VoltageRamp | RandomSpikes) -> None:
    """Refuse a window whose ``end_s`` (if given) is not after its ``start_s``."""
    if obj.end_s is not None and obj.end_s <= obj.start_s:
        raise ScenarioError(f"{type(obj).__name__}.end_s: expected a time > start_s = "
                            f"{obj.start_s:g} s; got {obj.end_s:g}")


def _active(time_s: FloatArray, start_s: float, end_s: float | None, ts_s: float) -> BoolArray:
    """Boolean mask of ``start_s <= t < end_s`` with a rounding tolerance of ``TIME_RTOL*ts_s``."""
    tol = TIME_RTOL * ts_s
    mask = time_s >= start_s - tol
    if end_s is not None:
        mask &= time_s < end_s - tol
    return mask


def _during(time_s: FloatArray, at_s: float, duration_s: float | None, ts_s: float) -> BoolArray:
    """Boolean mask of an event from ``at_s`` for ``duration_s`` [s] (None: to the end)."""
    return _active(time_s, at_s, None if duration_s is None else at_s + duration_s, ts_s)


def _held_profile(time_s: FloatArray, ts_s: float, event: VoltageStep | PowerShift,
                  value: float, idle: float) -> FloatArray:
    """``value`` at the sample times ``time_s`` [s] where ``event`` is active, else ``idle``."""
    t = np.asarray(time_s, dtype=float)
    return np.where(_during(t, event.at_s, event.duration_s, ts_s), value, idle)


# --- process disturbances ------------------------------------------------------------
@dataclass(frozen=True, slots=True, kw_only=True)
class VoltageStep:
    """Grid voltage jumps to ``factor`` x nominal at ``at_s`` (for ``duration_s``, or for good).

    Parameters
    ----------
    at_s :
        Time the step happens [s].
    factor :
        Grid voltage relative to nominal while active [-], in (0, 2] (0.97 is a 3 % sag).
    duration_s :
        How long it lasts [s], > 0; None keeps it to the end of the run.
    """

    at_s: float
    factor: float
    duration_s: float | None = None

    def __post_init__(self) -> None:
        _check_held_event(self, "factor", lo=0.0, lo_open=True, hi=2.0)

    def voltage_factor(self, time_s: FloatArray, ts_s: float) -> FloatArray:
        """Voltage factor [-] at the sample times ``time_s`` [s] (1 where inactive)."""
        return _held_profile(time_s, ts_s, self, self.factor, 1.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class VoltageRamp:
    """Grid voltage moves linearly from nominal to ``factor`` over ``[start_s, end_s]``, then holds.

    Parameters
    ----------
    start_s, end_s :
        Start and end of the ramp [s], ``start_s < end_s``.
    factor :
        Voltage relative to nominal at and after ``end_s`` [-], in (0, 2].
    """

    start_s: float
    end_s: float
    factor: float

    def __post_init__(self) -> None:
        _check_time(self, "start_s")
        _check_time(self, "end_s")
        _check_number(self, "factor", lo=0.0, lo_open=True, hi=2.0)
        _check_end_after_start(self)

    def voltage_factor(self, time_s: FloatArray, ts_s: float) -> FloatArray:
        """Voltage factor [-] at the sample times ``time_s`` [s]."""
        t = np.asarray(time_s, dtype=float)
        frac = np.clip((t - self.start_s) / (self.end_s - self.start_s), 0.0, 1.0)
        return 1.0 + frac * (self.factor - 1.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class PowerShift:
    """The true heater power shifts by ``offset_kw`` from ``at_s`` (for ``duration_s``, or for good).

    The paper's grid event (sec. 5.2) is ``PowerShift(at_s=..., offset_kw=0.15)``.

    Parameters
    ----------
    at_s :
        Time of the shift [s].
    offset_kw :
        Added to the true power while active [kW].
    duration_s :
        How long it lasts [s], > 0; None keeps it to the end of the run.
    """

    at_s: float
    offset_kw: float
    duration_s: float | None = None

    def __post_init__(self) -> None:
        _check_held_event(self, "offset_kw", unit=" [kW]")

    def power_offset_kw(self, time_s: FloatArray, ts_s: float) -> FloatArray:
        """Power offset [kW] at the sample times ``time_s`` [s] (0 where inactive)."""
        return _held_profile(time_s, ts_s, self, self.offset_kw, 0.0)


Disturbance = VoltageStep | VoltageRamp | PowerShift


# --- sensor faults -------------------------------------------------------------------
@dataclass(frozen=True, slots=True, kw_only=True)
class MeasurementSpike:
    """One measured sample (the first with ``t_k >= at_s``) is off by ``spike_kw``.

    Parameters
    ----------
    at_s :
        Time of the spike [s].
    spike_kw :
        Added to that one measurement [kW].
    """

    at_s: float
    spike_kw: float

    def __post_init__(self) -> None:
        _check_time(self, "at_s")
        _check_number(self, "spike_kw", unit=" [kW]")

    def spike_profile_kw(self, time_s: FloatArray, ts_s: float) -> FloatArray:
        """Additive measurement error [kW] at the sample times ``time_s`` [s]."""
        t = np.asarray(time_s, dtype=float)
        k_spike = math.ceil(self.at_s / ts_s - TIME_RTOL)
        k = np.rint(t / ts_s)
        return np.where(k == k_spike, self.spike_kw, 0.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class RandomSpikes:
    """Each sample in ``[start_s, end_s)`` is hit with probability ``probability_per_sample``.

    A hit adds ``+spike_kw`` or ``-spike_kw`` (equally likely) to that measurement, drawn
    from the run's fault stream (reproducible by seed).

    Parameters
    ----------
    probability_per_sample :
        Chance of a spike at each sample, in ``[0, 1]``.
    spike_kw :
        Spike magnitude [kW].
    start_s, end_s :
        Window the spikes may occur in [s]; ``end_s`` None means to the end of the run.
    """

    probability_per_sample: float
    spike_kw: float
    start_s: float = 0.0
    end_s: float | None = None

    def __post_init__(self) -> None:
        _check_number(self, "probability_per_sample", lo=0.0, hi=1.0)
        _check_number(self, "spike_kw", unit=" [kW]")
        _check_time(self, "start_s")
        _check_time(self, "end_s", allow_none=True)
        _check_end_after_start(self)

    def spike_profile_kw(
        self, time_s: FloatArray, ts_s: float, rng: np.random.Generator
    ) -> FloatArray:
        """Additive error [kW] at ``time_s`` [s]; draws ``2 * len(time_s)`` uniforms whatever the window."""
        t = np.asarray(time_s, dtype=float)
        hit = rng.random(t.size) < self.probability_per_sample
        sign = np.where(rng.random(t.size) < 0.5, -1.0, 1.0)
        mask = _active(t, self.start_s, self.end_s, ts_s) & hit
        return np.where(mask, sign * self.spike_kw, 0.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class MissingSamples:
    """Power samples in ``[at_s, at_s + duration_s)`` are missing (NaN to the controller).

    Parameters
    ----------
    at_s :
        Time the outage starts [s].
    duration_s :
        Outage length [s], > 0; ``ceil(duration_s / ts_s)`` samples when ``at_s`` is on
        the sample grid (30 samples for 60 s at 2 s).
    """

    at_s: float
    duration_s: float

    def __post_init__(self) -> None:
        _check_time(self, "at_s")
        _check_time(self, "duration_s", positive=True)

    def missing_mask(self, time_s: FloatArray, ts_s: float) -> BoolArray:
        """True at the sample times ``time_s`` [s] whose measurement is missing."""
        return _during(np.asarray(time_s, dtype=float), self.at_s, self.duration_s, ts_s)


Fault = MeasurementSpike | RandomSpikes | MissingSamples


# --- per-run profiles ----------------------------------------------------------------
@dataclass(frozen=True, eq=False, kw_only=True)
class ExogenousProfile:
    """Per-sample process disturbances of one run (read-only arrays of length ``n_steps``).

    Parameters
    ----------
    grid_voltage_factor :
        Product of all voltage disturbances at each sample [-].
    power_offset_kw :
        Sum of all power shifts at each sample [kW].
    """

    grid_voltage_factor: FloatArray
    power_offset_kw: FloatArray


@dataclass(frozen=True, eq=False, kw_only=True)
class FaultProfile:
    """Per-sample sensor faults of one run (read-only arrays of length ``n_steps``).

    Parameters
    ----------
    spike_kw :
        Sum of all spikes added to each measurement [kW].
    missing :
        True where the measurement is missing (delivered as NaN).
    """

    spike_kw: FloatArray
    missing: BoolArray


def sample_times_s(n_steps: int, ts_s: float) -> FloatArray:
    """Sample times ``k * ts_s`` [s] for ``k = 0 .. n_steps - 1``."""
    return np.arange(n_steps, dtype=float) * ts_s


def _combined(disturbances: Sequence[Disturbance], time_s: FloatArray,
              ts_s: float) -> tuple[FloatArray, FloatArray]:
    """Voltage factors multiplied and power shifts added, at the sample times ``time_s``."""
    volt = np.ones(time_s.size)
    offset = np.zeros(time_s.size)
    for dist in disturbances:
        if isinstance(dist, PowerShift):
            offset += dist.power_offset_kw(time_s, ts_s)
        else:
            volt *= dist.voltage_factor(time_s, ts_s)
    return volt, offset


def exogenous_profile(
    disturbances: Sequence[Disturbance], *, n_steps: int, ts_s: float
) -> ExogenousProfile:
    """Evaluate process disturbances at every sample of a run.

    Parameters
    ----------
    disturbances :
        Voltage steps/ramps (multiplied) and power shifts (added).
    n_steps :
        Number of samples.
    ts_s :
        Sampling time [s].
    """
    volt, offset = _combined(disturbances, sample_times_s(n_steps, ts_s), ts_s)
    volt.setflags(write=False)
    offset.setflags(write=False)
    return ExogenousProfile(grid_voltage_factor=volt, power_offset_kw=offset)


def exogenous_at(disturbances: Sequence[Disturbance], k: int, ts_s: float) -> Exogenous:
    """The `Exogenous` value of sample ``k`` (one sample of `exogenous_profile`).

    Parameters
    ----------
    disturbances :
        Voltage steps/ramps (multiplied) and power shifts (added).
    k :
        Sample index (time ``k * ts_s``).
    ts_s :
        Sampling time [s].
    """
    volt, offset = _combined(disturbances, np.array([k * ts_s]), ts_s)
    return Exogenous(grid_voltage_factor=float(volt[0]), power_offset_kw=float(offset[0]))


def fault_profile(
    faults: Sequence[Fault], *, n_steps: int, ts_s: float, rng: np.random.Generator
) -> FaultProfile:
    """Evaluate sensor faults at every sample of a run.

    Parameters
    ----------
    faults :
        Spikes (added) and missing-sample windows (or-ed).
    n_steps :
        Number of samples.
    ts_s :
        Sampling time [s].
    rng :
        The run's fault stream; random faults draw from it in list order.
    """
    t = sample_times_s(n_steps, ts_s)
    spike = np.zeros(n_steps)
    missing = np.zeros(n_steps, dtype=bool)
    for fault in faults:
        if isinstance(fault, MissingSamples):
            missing |= fault.missing_mask(t, ts_s)
        elif isinstance(fault, RandomSpikes):
            spike += fault.spike_profile_kw(t, ts_s, rng)
        else:
            spike += fault.spike_profile_kw(t, ts_s)
    spike.setflags(write=False)
    missing.setflags(write=False)
    return FaultProfile(spike_kw=spike, missing=missing)


def scaled_times(event: _Event, factor: float) -> _Event:
    """Return a copy of ``event`` (a disturbance, fault or setpoint change) with every time
    field (``*_s``) multiplied by ``factor``."""
    return replace(event, **{f.name: getattr(event, f.name) * factor for f in fields(event)
                             if f.name.endswith("_s") and getattr(event, f.name) is not None})


__all__ = ["Disturbance", "ExogenousProfile", "Fault", "FaultProfile", "MeasurementSpike", "MissingSamples",
           "PowerShift", "RandomSpikes", "VoltageRamp", "VoltageStep", "exogenous_at", "exogenous_profile",
           "fault_profile", "sample_times_s", "scaled_times"]
