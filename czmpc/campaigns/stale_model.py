"""Stale-model trials: the model-health monitor on plants that stay or drift away from the model.

A trial runs the offset-free MPC of a model in closed loop on the model's own plant
(`sim.drift.vary_model_plant`), optionally drifting at a plant time, through an
operating profile that moves the power (a setpoint staircase: every
``step_every_s`` the setpoint steps by a random ``step_kw`` range amount, up or down,
inside a band), and runs the `czmpc.health.ModelHealthMonitor` on the recorded
trajectory, sample by sample as `czmpc run` does. It reports whether and when the stale
alarm came. `false_alarm_trial` runs the unchanged plant open loop through an input
staircase of the same kind (43,200 samples in seconds rather than the closed loop's
minute), which is honest for the false-alarm figure: the monitor sees only the input and
the measured power, and its residuals under a correct model are white whatever the
input (regressors are past data, as in closed loop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from czmpc.campaigns.simulation import controller_settings
from czmpc.controller import OffsetFreeMPC
from czmpc.health import HealthSettings, ModelHealthMonitor
from sim.drift import PlantVariation, vary_model_plant
from sim.loop import run_closed_loop
from sim.model_plant import steady_state_triac_pct
from sim.scenario import Scenario, SetpointStep
from sysid._typing import FloatArray
from sysid.model import HammersteinModel


@dataclass(frozen=True, slots=True, kw_only=True)
class OperatingProfile:
    """The setpoint staircase a trial runs (or, open loop, the input staircase).

    Parameters
    ----------
    start_kw :
        Setpoint at the start [kW].
    band_kw :
        Setpoints stay inside ``[lo, hi]`` [kW].
    step_every_s :
        Time between setpoint steps [s].
    step_kw :
        Range ``(lo, hi)`` of the step size [kW], drawn uniformly, sign random.
    """

    start_kw: float = 45.0
    band_kw: tuple[float, float] = (35.0, 55.0)
    step_every_s: float = 300.0
    step_kw: tuple[float, float] = (3.0, 6.0)

    def scenario(self, duration_s: float, seed: int, ts_s: float) -> Scenario:
        """The closed-loop scenario: the staircase over ``duration_s`` [s], seeded."""
        rng = np.random.default_rng(seed)
        level = self.start_kw
        steps = []
        for t in np.arange(self.step_every_s, duration_s, self.step_every_s):
            move = float(rng.choice([-1.0, 1.0]) * rng.uniform(*self.step_kw))
            if not self.band_kw[0] <= level + move <= self.band_kw[1]:
                move = -move
            level = float(np.clip(level + move, *self.band_kw))
            steps.append(SetpointStep(at_s=float(t), power_kw=level))
        return Scenario(name="stale-model profile", duration_s=duration_s, ts_s=ts_s,
                        initial_setpoint_kw=self.start_kw, setpoints=tuple(steps))


@dataclass(frozen=True, eq=False, kw_only=True)
class HealthTrial:
    """What the monitor said on one trajectory.

    Parameters
    ----------
    variation :
        The plant's variation (drifts included).
    drift_at_s :
        Plant time of the first drift [s]; None for an unchanged plant.
    alarm_at_s :
        Plant time of the stale alarm [s]; None if it never came.
    duration_s :
        Plant time simulated [s].
    seed :
        Seed of the plant noise and the profile.
    health :
        (n,) the monitor's ``health`` figure per sample [-].
    max_health_before_drift :
        Largest ``health`` before the drift (the whole run if none) [-].
    """

    variation: PlantVariation
    drift_at_s: float | None
    alarm_at_s: float | None
    duration_s: float
    seed: int
    health: FloatArray = field(repr=False)
    max_health_before_drift: float

    @property
    def detection_delay_s(self) -> float | None:
        """Alarm time after the drift [s]; None without drift or alarm."""
        if self.drift_at_s is None or self.alarm_at_s is None:
            return None
        return self.alarm_at_s - self.drift_at_s

    @property
    def false_alarm(self) -> bool:
        """An alarm before any drift."""
        return self.alarm_at_s is not None and (self.drift_at_s is None
                                                or self.alarm_at_s < self.drift_at_s)


def monitor_record(model: HammersteinModel, power_kw: FloatArray, triac_pct: FloatArray, *,
                   initial_triac_pct: float, disturbance_kw: FloatArray | None = None,
                   settings: HealthSettings | None = None) -> tuple[FloatArray, int | None]:
    """Run the monitor over a record as the runtime loop does.

    Parameters
    ----------
    power_kw :
        (n,) measured power at sample ``k`` [kW] (NaN: missing).
    triac_pct :
        (n,) input decided at ``k``, applied over ``(t_k, t_{k+1}]`` [%].
    initial_triac_pct :
        Input applied before the first sample [%].
    disturbance_kw :
        (n,) the controller's disturbance estimate [kW], or None.

    Returns
    -------
    health, alarm_k
        (n,) the ``health`` figure per sample, and the sample of the alarm (None).
    """
    monitor = ModelHealthMonitor(model, settings)
    n = len(power_kw)
    health = np.empty(n)
    previous = float(initial_triac_pct)
    for k in range(n):
        d = math.nan if disturbance_kw is None else float(disturbance_kw[k])
        health[k] = monitor.update(float(power_kw[k]), previous, d).health
        previous = float(triac_pct[k])
    return health, monitor.alarm_k


def _trial(variation: PlantVariation, health: FloatArray, alarm_k: int | None, *, ts_s: float,
           seed: int) -> HealthTrial:
    drift_at = variation.drifts[0].at_s if variation.drifts else None
    before = health if drift_at is None else health[: int(round(drift_at / ts_s))]
    return HealthTrial(variation=variation, drift_at_s=drift_at,
                       alarm_at_s=None if alarm_k is None else alarm_k * ts_s,
                       duration_s=len(health) * ts_s, seed=seed, health=health,
                       max_health_before_drift=float(np.max(before)) if before.size else 0.0)


def closed_loop_trial(model: HammersteinModel, variation: PlantVariation, *, duration_s: float,
                      seed: int, profile: OperatingProfile | None = None,
                      settings: HealthSettings | None = None) -> HealthTrial:
    """The MPC of ``model`` on the varied model plant; the monitor on its trajectory.

    Parameters
    ----------
    model :
        The controller's (and the monitor's) model; the plant before any variation.
    variation :
        How the plant differs and drifts.
    duration_s :
        Plant time [s].
    seed :
        Seed of the plant noise and of the staircase.
    profile :
        The setpoint staircase; None: `OperatingProfile()`.
    settings :
        Monitor settings; None: `HealthSettings()`.

    Returns
    -------
    HealthTrial
    """
    profile = OperatingProfile() if profile is None else profile
    scenario = profile.scenario(duration_s, seed, model.ts_s)
    s0 = steady_state_triac_pct(model, profile.start_kw)
    plant = vary_model_plant(model, variation, noise=True, initial_triac_pct=s0)
    mpc = OffsetFreeMPC(model, controller_settings(model, scenario, initial_triac_pct=s0))
    run = run_closed_loop(plant, mpc, scenario, rng=seed)
    dist = (None if run.diagnostics is None
            else np.array([getattr(d, "disturbance_power_kw", math.nan)
                           for d in run.diagnostics]))
    health, alarm_k = monitor_record(model, run.power_measured_kw, run.triac_pct,
                                     initial_triac_pct=s0, disturbance_kw=dist,
                                     settings=settings)
    return _trial(variation, health, alarm_k, ts_s=model.ts_s, seed=seed)


def false_alarm_trial(model: HammersteinModel, *, duration_s: float, seed: int,
                      step_every_s: float = 300.0, step_pct: tuple[float, float] = (2.0, 4.0),
                      band_pct: tuple[float, float] | None = None,
                      settings: HealthSettings | None = None) -> HealthTrial:
    """The unchanged model plant, open loop through an input staircase; the monitor on it.

    Parameters
    ----------
    duration_s :
        Plant time [s].
    seed :
        Seed of the plant noise and the staircase.
    step_every_s :
        Time between input steps [s].
    step_pct :
        Range of the input step size [%], sign random.
    band_pct :
        The input stays inside this band [%]; None: the model's input range.

    Returns
    -------
    HealthTrial
    """
    rng = np.random.default_rng(seed)
    lo, hi = model.input_range_pct if band_pct is None else band_pct
    n = int(round(duration_s / model.ts_s))
    every = max(1, int(round(step_every_s / model.ts_s)))
    s0 = 0.5 * (lo + hi)
    triac = np.empty(n)
    level = s0
    for start in range(0, n, every):
        move = float(rng.choice([-1.0, 1.0]) * rng.uniform(*step_pct))
        if not lo <= level + move <= hi:
            move = -move
        level = float(np.clip(level + move, lo, hi))
        triac[start:start + every] = level
    plant = vary_model_plant(model, PlantVariation(), noise=True, initial_triac_pct=s0)
    power = np.empty(n)
    power[0] = plant.reset(seed)
    for k in range(n - 1):
        power[k + 1] = plant.step(float(triac[k]))
    health, alarm_k = monitor_record(model, power, triac, initial_triac_pct=s0,
                                     settings=settings)
    return _trial(PlantVariation(), health, alarm_k, ts_s=model.ts_s, seed=seed)


__all__ = ["HealthTrial", "OperatingProfile", "closed_loop_trial", "false_alarm_trial",
           "monitor_record"]
