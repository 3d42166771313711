"""run_closed_loop -> ClosedLoopResult: the only place the order of one sample lives.

One sample ``k`` (time ``t_k = k * ts_s``):

1. the measured power ``y_k`` gets the sensor faults (NaN while missing, plus any
   spike) and goes with the setpoint ``r_k`` to ``controller.step`` (timed with
   `time.perf_counter`); if the scenario says so, also the setpoints of the next
   ``Scenario.preview_steps`` samples (``setpoint_preview_kw``, fewer at the run's end)
   and the grid voltage factor measured over the last sample (``grid_voltage_factor``:
   the plant's own ``grid_voltage_factor`` if it has one, else the scenario's, plus
   sensor noise of `VOLTAGE_SENSOR_NOISE_STD`);
2. the returned input ``s_k`` goes to ``plant.step`` with sample ``k``'s `Exogenous`
   value, acting over ``[t_k, t_{k+1})``; it returns ``y_{k+1}``;
3. the runner records ``t_k``, ``r_k``, the measurement as delivered, the true power at
   ``t_k``, ``s_k``, the step time and the controller's ``last_step`` (if any).

One seed is split (`numpy.random.SeedSequence.spawn`) into independent plant-noise and
sensor-fault streams, so adding a fault does not change the noise; the voltage sensor's
noise is drawn from the fault stream after the faults, so it changes neither.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sim.disturbances import ExogenousProfile, exogenous_profile, fault_profile
from sim.errors import ScenarioError, SimError
from sim.protocols import NOMINAL, Controller, Exogenous, Plant
from sim.scenario import Scenario
from sysid._typing import FloatArray
from sysid.atomic import atomic_write_text
from sysid.errors import SamplingTimeError

#: CSV columns of `ClosedLoopResult.to_csv` (then ``disturbance_estimate_kw`` and the
#: `STATUS_COLUMNS` the diagnostics carry).
CSV_COLUMNS = (
    "time_s", "setpoint_kw", "power_measured_kw", "power_true_kw", "triac_pct", "step_time_s",
)
#: Per-sample controller status columns of `ClosedLoopResult.to_csv`, where every step's
#: diagnostics carry them (as `czmpc.controller.StepDiagnostics` does).
STATUS_COLUMNS = ("mode", "status", "solver_status", "fallback")

ProgressCallback = Callable[[int, int], None]

#: Standard deviation [-] of the measured grid voltage factor's noise: 0.1 % of nominal,
#: the repeatability of a thyristor power unit's line-voltage reading (its 0.5-1 %
#: accuracy class is mostly a steady bias, which the controller's disturbance removes).
VOLTAGE_SENSOR_NOISE_STD = 1e-4


def _readonly(values: object, name: str, n: int) -> FloatArray:
    arr = np.array(values, dtype=float, copy=True)
    if arr.shape != (n,):
        raise ScenarioError(f"ClosedLoopResult.{name}: expected shape ({n},) (the scenario's n_steps); "
                            f"got {arr.shape}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False, kw_only=True)
class ClosedLoopResult:
    """What one closed-loop run recorded, one row per sample (read-only arrays).

    Parameters
    ----------
    scenario :
        The scenario that was run.
    seed :
        The int seed of the noise and fault streams (the fresh entropy when none was
        given); None when a `numpy.random.Generator` was passed.
    time_s :
        Sample times ``k * ts_s`` [s], shape ``(n_steps,)``.
    setpoint_kw :
        Setpoint given to the controller [kW].
    power_measured_kw :
        Measured power as delivered to the controller, faults included [kW].
    power_true_kw :
        The plant's true (noise-free) power at the same sample [kW].
    triac_pct :
        TRIAC input the controller returned [%] (applied over the next sample).
    step_time_s :
        Wall-clock time of each ``controller.step`` call [s].
    diagnostics :
        The controller's ``last_step`` after every step, or None if it has none.

    Raises
    ------
    ScenarioError
        A signal whose length is not the scenario's ``n_steps``.
    """

    scenario: Scenario
    seed: int | None
    time_s: FloatArray = field(repr=False)
    setpoint_kw: FloatArray = field(repr=False)
    power_measured_kw: FloatArray = field(repr=False)
    power_true_kw: FloatArray = field(repr=False)
    triac_pct: FloatArray = field(repr=False)
    step_time_s: FloatArray = field(repr=False)
    diagnostics: tuple[object, ...] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        n = self.scenario.n_steps
        for name in ("time_s", "setpoint_kw", "power_measured_kw", "power_true_kw",
                     "triac_pct", "step_time_s"):
            object.__setattr__(self, name, _readonly(getattr(self, name), name, n))
        if self.diagnostics is not None:
            diagnostics = tuple(self.diagnostics)
            if len(diagnostics) != n:
                raise ScenarioError(
                    f"ClosedLoopResult.diagnostics: expected {n} entries; got {len(diagnostics)}")
            object.__setattr__(self, "diagnostics", diagnostics)

    @property
    def n_steps(self) -> int:
        """Number of samples recorded."""
        return self.scenario.n_steps

    @property
    def ts_s(self) -> float:
        """Sampling time [s]."""
        return self.scenario.ts_s

    @property
    def disturbance_estimate_kw(self) -> FloatArray | None:
        """Each ``last_step.disturbance_estimate`` [kW]; None if the diagnostics have none."""
        diags = self.diagnostics
        if not diags or not all(hasattr(d, "disturbance_estimate") for d in diags):
            return None
        arr = np.array([float(d.disturbance_estimate) for d in diags])  # type: ignore[attr-defined]
        arr.setflags(write=False)
        return arr

    def to_csv(self, path: str | os.PathLike[str]) -> None:
        """Write the run as CSV (`CSV_COLUMNS`, then `STATUS_COLUMNS` as text), atomically.

        Written by `sysid.atomic` (a reader never sees half a file); NaN as ``nan``,
        numbers in Python's shortest round-trip form.

        Parameters
        ----------
        path :
            Output file.
        """
        columns: list[tuple[str, list[float] | list[str]]] = [
            (name, getattr(self, name).tolist()) for name in CSV_COLUMNS
        ]
        estimate = self.disturbance_estimate_kw
        if estimate is not None:
            columns.append(("disturbance_estimate_kw", estimate.tolist()))
        diags = self.diagnostics
        columns += [(name, [str(getattr(getattr(d, name), "value", getattr(d, name)))
                            for d in diags])
                    for name in STATUS_COLUMNS if diags and all(hasattr(d, name) for d in diags)]
        header = ",".join(name for name, _ in columns)
        rows = (",".join(v if isinstance(v, str) else repr(v) for v in row)
                for row in zip(*(vals for _, vals in columns), strict=True))
        atomic_write_text(path, header + "\n" + "\n".join(rows) + "\n")


def _check_sampling_times(plant: Plant, controller: Controller, scenario: Scenario) -> None:
    for what, ts_s in (("plant", plant.ts_s), ("controller", controller.ts_s)):
        if not math.isclose(ts_s, scenario.ts_s, rel_tol=1e-9, abs_tol=1e-12):
            raise SamplingTimeError(f"run_closed_loop: expected the {what}'s ts_s to equal scenario "
                                    f"'{scenario.name}''s {scenario.ts_s:g} s; got {ts_s:g} s")


def spawn_streams(
    rng: np.random.Generator | int | None,
) -> tuple[int | None, np.random.Generator, np.random.Generator]:
    """Split ``rng`` into independent plant-noise and sensor-fault generators.

    Parameters
    ----------
    rng :
        An int seed, a generator (spawned from), or None (fresh entropy).

    Returns
    -------
    seed, noise_rng, fault_rng
        ``seed`` is the int seed (the fresh entropy for None) or None for a generator.
    """
    if isinstance(rng, np.random.Generator):
        noise_rng, fault_rng = rng.spawn(2)
        return None, noise_rng, fault_rng
    if rng is None:
        seq = np.random.SeedSequence()
    elif isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and rng >= 0:
        seq = np.random.SeedSequence(int(rng))
    else:
        raise TypeError(f"rng: expected a numpy Generator, an int >= 0 or None; got {rng!r}")
    entropy = seq.entropy
    noise_seq, fault_seq = seq.spawn(2)
    seed = int(entropy) if isinstance(entropy, (int, np.integer)) else None
    return seed, np.random.default_rng(noise_seq), np.random.default_rng(fault_seq)


def _exogenous_per_sample(profile: ExogenousProfile) -> list[Exogenous]:
    """One `Exogenous` per sample, reusing the object while the values do not change."""
    out: list[Exogenous] = []
    last = NOMINAL
    for volt, offset in zip(profile.grid_voltage_factor.tolist(),
                            profile.power_offset_kw.tolist(), strict=True):
        if volt != last.grid_voltage_factor or offset != last.power_offset_kw:
            last = Exogenous(grid_voltage_factor=volt, power_offset_kw=offset)
        out.append(last)
    return out


def run_closed_loop(
    plant: Plant,
    controller: Controller,
    scenario: Scenario,
    *,
    rng: np.random.Generator | int | None = None,
    progress: ProgressCallback | None = None,
    voltage_noise_std: float = VOLTAGE_SENSOR_NOISE_STD,
) -> ClosedLoopResult:
    """Run ``controller`` on ``plant`` through ``scenario`` and record every sample.

    Both are reset first, so two runs with the same int seed are identical.

    Parameters
    ----------
    plant :
        Any `Plant`; it sets the initial state (see `ModelPlant.for_scenario`).
    controller :
        Any `Controller`; if it has a ``last_step`` attribute it is recorded each step.
    scenario :
        Setpoints, disturbances, faults and duration.
    rng :
        Seed of the run: split into independent plant-noise and fault streams.
    progress :
        Called as ``progress(samples_done, n_steps)`` about every 1 % and at the end.
    voltage_noise_std :
        Noise of the measured voltage factor [-] when the scenario's
        ``measured_voltage`` is on (0 for a noise-free run).

    Returns
    -------
    ClosedLoopResult
        The recorded run.

    Raises
    ------
    SamplingTimeError
        The plant's or controller's ``ts_s`` differs from the scenario's.
    SimError
        The controller returned a non-finite input.
    """
    _check_sampling_times(plant, controller, scenario)
    seed, noise_rng, fault_rng = spawn_streams(rng)
    n = scenario.n_steps
    ts_s = scenario.ts_s
    setpoints = scenario.setpoint_profile_kw().tolist()
    exogenous = _exogenous_per_sample(exogenous_profile(scenario.disturbances, n_steps=n, ts_s=ts_s))
    faults = fault_profile(scenario.faults, n_steps=n, ts_s=ts_s, rng=fault_rng)
    missing = faults.missing.tolist()
    spikes = faults.spike_kw.tolist()
    has_diagnostics = hasattr(controller, "last_step")
    preview_n = scenario.preview_steps
    setpoint_arr = np.asarray(setpoints)
    voltage_noise: list[float] = []
    if scenario.measured_voltage:
        if not (math.isfinite(voltage_noise_std) and voltage_noise_std >= 0):
            raise SimError(f"run_closed_loop: voltage_noise_std must be finite and >= 0; "
                           f"got {voltage_noise_std!r}")
        voltage_noise = (fault_rng.standard_normal(n) * voltage_noise_std).tolist()
    plant_voltage = isinstance(getattr(type(plant), "grid_voltage_factor", None), property)

    measured_rec = [math.nan] * n
    true_rec = [math.nan] * n
    triac_rec = [math.nan] * n
    time_rec = [math.nan] * n
    diagnostics: list[object] = []
    every = max(1, n // 100)

    controller.reset()
    y = plant.reset(noise_rng)
    controller_step = controller.step
    plant_step = plant.step
    clock = time.perf_counter
    isfinite = math.isfinite
    nan = math.nan
    for k in range(n):
        measured = nan if missing[k] else y + spikes[k]
        if preview_n or voltage_noise:
            extra: dict[str, object] = {}
            if preview_n:
                extra["setpoint_preview_kw"] = setpoint_arr[k + 1 : k + 1 + preview_n]
            if voltage_noise:
                volt = (plant.grid_voltage_factor if plant_voltage  # type: ignore[attr-defined]
                        else exogenous[k - 1].grid_voltage_factor if k else 1.0)
                extra["grid_voltage_factor"] = volt + voltage_noise[k]
            t0 = clock()
            triac = controller_step(measured, setpoints[k], **extra)
        else:
            t0 = clock()
            triac = controller_step(measured, setpoints[k])
        t1 = clock()
        if not isfinite(triac):
            raise SimError(f"run_closed_loop: expected a finite TRIAC input [%] from the controller; "
                           f"got {triac!r} at sample {k} (t = {k * ts_s:g} s)")
        measured_rec[k] = measured
        true_rec[k] = plant.true_power_kw
        triac_rec[k] = triac
        time_rec[k] = t1 - t0
        if has_diagnostics:
            diagnostics.append(controller.last_step)  # type: ignore[attr-defined]
        y = plant_step(triac, exogenous[k])
        if progress is not None and ((k + 1) % every == 0 or k + 1 == n):
            progress(k + 1, n)

    return ClosedLoopResult(scenario=scenario, seed=seed, time_s=scenario.time_s(),
                            setpoint_kw=np.array(setpoints), power_measured_kw=np.array(measured_rec),
                            power_true_kw=np.array(true_rec), triac_pct=np.array(triac_rec),
                            step_time_s=np.array(time_rec),
                            diagnostics=tuple(diagnostics) if has_diagnostics else None)


__all__ = ["CSV_COLUMNS", "STATUS_COLUMNS", "VOLTAGE_SENSOR_NOISE_STD", "ClosedLoopResult",
           "ProgressCallback", "run_closed_loop", "spawn_streams"]
