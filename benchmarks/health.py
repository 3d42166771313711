"""Benchmark of the model-health monitor: false alarms on the unchanged plant, detection delays.

``python -m benchmarks.health [--days-open N] [--days-closed N] [--seeds N]`` (``--help``)
prints the table and writes it under `BENCHMARK_HEADING` in BENCHMARKS.md. Seeds are
fixed (1..N): the same command gives the same numbers.

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

1. False alarms: the unchanged model plant (the model's own equation, noise on) for
   24 h of plant time (43,200 samples at Ts = 2 s), --days-open times open loop through
   an input staircase and --days-closed times in closed loop with the MPC through a
   setpoint staircase; counts alarms and the largest health figure.
2. Detection: closed loop with the MPC on the model plant whose gain drops by 25 % or
   whose slow time constant doubles at 1800 s of plant time, --seeds runs each;
   prints how many alarms came within 30 min, the median and largest delay [s].
3. Which reference: 2 x 4 h closed loop on the unchanged virtual heater (which the
   model describes only approximately) with the test against the model and against a
   baseline (what czmpc run uses), and the drifts of 2. with the baseline test.

Exit codes: 0 done; 2 bad input (model file).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks._md import BENCHMARKS_MD, benchmark_parser, machine_info, run_main, write_benchmarks_section
from czmpc.campaigns.build import controller_settings
from czmpc.cli import _argtypes
from czmpc.cli._progress import Progress
from czmpc.controller import OffsetFreeMPC
from czmpc.health import RUNTIME_HEALTH, HealthSettings, ModelHealthMonitor
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sim.drift import DriftEvent, PlantVariation, vary_model_plant
from sim.loop import run_closed_loop
from sim.model_plant import steady_state_triac_pct
from sim.scenario import Scenario, SetpointStep
from sysid._typing import FloatArray
from sysid.model import HammersteinModel
from sysid.modelfile import load_model


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


def heater_trials(model: HammersteinModel, *, duration_s: float, seed: int,
                  settings: Sequence[HealthSettings],
                  profile: OperatingProfile | None = None) -> tuple[HealthTrial, ...]:
    """The MPC of ``model`` on the (unchanged) virtual heater; the monitor on its trajectory.

    The heater is the plant the shipped model was identified from, which it describes
    only approximately: this measures what each monitor setting says about a model
    that was fine when switched on. One closed loop, one trial per setting.
    """
    from dataclasses import replace as _replace

    from scipy.optimize import brentq

    from sim.heater import HeaterParams, VirtualHeater, steady_state

    profile = OperatingProfile() if profile is None else profile
    scenario = profile.scenario(duration_s, seed, model.ts_s)
    params = HeaterParams(ts_s=model.ts_s)
    s0 = float(brentq(lambda s: steady_state(s, params)[0] - profile.start_kw, 1.0, 99.0))
    heater = VirtualHeater(_replace(params, initial_triac_pct=s0))
    mpc = OffsetFreeMPC(model, controller_settings(model, scenario, initial_triac_pct=s0))
    run = run_closed_loop(heater, mpc, scenario, rng=seed)
    trials = []
    for st in settings:
        health, alarm_k = monitor_record(model, run.power_measured_kw, run.triac_pct,
                                         initial_triac_pct=s0, settings=st)
        trials.append(_trial(PlantVariation(), health, alarm_k, ts_s=model.ts_s, seed=seed))
    return tuple(trials)


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


#: Heading of this benchmark's section in BENCHMARKS.md.
BENCHMARK_HEADING = "## Model-health monitor (stale-model alarm)"


@dataclass(frozen=True, eq=False, kw_only=True)
class HealthBenchmark:
    """False alarms on the unchanged plant and detection delays after drifts.

    Parameters
    ----------
    command :
        The command line that produced it.
    machine :
        One line describing the machine.
    settings :
        The monitor settings.
    open_loop_days :
        24 h open-loop trials of the unchanged plant.
    closed_loop_days :
        24 h closed-loop trials of the unchanged plant.
    drifts :
        ``(label, trials)`` of the closed-loop drift trials, against the model.
    heater_days :
        ``(reference, trials)`` on the unchanged virtual heater, per monitor setting.
    baseline_drifts :
        ``(label, trials)`` of the drift trials with the runtime's baseline test.
    wall_time_s :
        Wall time of the whole benchmark [s].
    """

    command: str
    machine: str
    settings: HealthSettings
    open_loop_days: tuple[HealthTrial, ...]
    closed_loop_days: tuple[HealthTrial, ...]
    drifts: tuple[tuple[str, tuple[HealthTrial, ...]], ...]
    heater_days: tuple[tuple[str, tuple[HealthTrial, ...]], ...]
    baseline_drifts: tuple[tuple[str, tuple[HealthTrial, ...]], ...]
    wall_time_s: float


def run_health_benchmark(model: HammersteinModel, *, command: str, machine: str,
                         n_days_open: int = 3, n_days_closed: int = 1, n_drift_seeds: int = 10,
                         drift_at_s: float = 1800.0, n_heater_runs: int = 2,
                         heater_hours: float = 4.0,
                         progress: Callable[[str], None] | None = None) -> HealthBenchmark:
    """Run the trials the BENCHMARKS.md section reports (seeds 1.. fixed).

    Parameters
    ----------
    model :
        The model (controller, monitor, and the plant before any drift).
    command, machine :
        Recorded with the numbers.
    n_days_open, n_days_closed :
        24 h trials of the unchanged plant, open and closed loop.
    n_drift_seeds :
        Closed-loop trials per drift (gain x0.75, time constant x2), each run
        ``drift_at_s + 2400`` s (with the baseline test: the drift comes 600 s after
        the baseline).
    n_heater_runs, heater_hours :
        Closed-loop runs on the unchanged virtual heater and their length [h].
    drift_at_s :
        Plant time of the drift [s].
    progress :
        Called with a line of text as trials finish.

    Returns
    -------
    HealthBenchmark
    """
    import time

    say = progress or (lambda _text: None)
    t0 = time.perf_counter()
    day_s = 86_400.0
    open_days = []
    for seed in range(1, n_days_open + 1):
        open_days.append(false_alarm_trial(model, duration_s=day_s, seed=seed))
        say(f"open loop, 24 h, seed {seed}: alarm {open_days[-1].alarm_at_s}")
    closed_days = []
    for seed in range(1, n_days_closed + 1):
        closed_days.append(closed_loop_trial(model, PlantVariation(), duration_s=day_s, seed=seed))
        say(f"closed loop, 24 h, seed {seed}: alarm {closed_days[-1].alarm_at_s}")
    tau_s = slow_time_constant_s(model)
    cases = (("gain x0.75 (-25 %)", DriftEvent(quantity="gain", value=0.75, at_s=drift_at_s)),
             (f"time constant x2 ({tau_s:.0f} -> {2 * tau_s:.0f} s)",
              DriftEvent(quantity="tau", value=2 * tau_s, at_s=drift_at_s)))
    drifts = []
    for label, event in cases:
        trials = []
        for seed in range(1, n_drift_seeds + 1):
            trials.append(closed_loop_trial(model, PlantVariation(drifts=(event,)),
                                            duration_s=drift_at_s + 2400.0, seed=seed))
            say(f"{label}, seed {seed}: delay {trials[-1].detection_delay_s}")
        drifts.append((label, tuple(trials)))
    modes = (("against the model", HealthSettings()), ("against a baseline (czmpc run)",
                                                      RUNTIME_HEALTH))
    heater_runs: list[tuple[HealthTrial, ...]] = []
    for seed in range(1, n_heater_runs + 1):
        heater_runs.append(heater_trials(model, duration_s=heater_hours * 3600.0, seed=seed,
                                         settings=[st for _, st in modes]))
        say(f"virtual heater, {heater_hours:g} h, seed {seed}: alarms "
            f"{[t.alarm_at_s for t in heater_runs[-1]]}")
    heater_days = tuple((label, tuple(run[i] for run in heater_runs))
                        for i, (label, _) in enumerate(modes))
    base_at = RUNTIME_HEALTH.baseline_samples * model.ts_s + 600.0
    baseline_drifts = []
    for label, event in cases:
        event = DriftEvent(quantity=event.quantity, value=event.value, at_s=base_at)
        trials = []
        for seed in range(1, n_drift_seeds + 1):
            trials.append(closed_loop_trial(model, PlantVariation(drifts=(event,)),
                                            duration_s=base_at + 2400.0, seed=seed,
                                            settings=RUNTIME_HEALTH))
            say(f"{label} (baseline test), seed {seed}: delay {trials[-1].detection_delay_s}")
        baseline_drifts.append((label, tuple(trials)))
    return HealthBenchmark(command=command, machine=machine, settings=HealthSettings(),
                           open_loop_days=tuple(open_days), closed_loop_days=tuple(closed_days),
                           drifts=tuple(drifts), heater_days=heater_days,
                           baseline_drifts=tuple(baseline_drifts),
                           wall_time_s=time.perf_counter() - t0)


def slow_time_constant_s(model: HammersteinModel) -> float:
    """Time constant of the model's slow pole [s] (`sim.drift.model_time_constant_s`)."""
    from sim.drift import model_time_constant_s

    return model_time_constant_s(model)


def _drift_rows(drifts: Sequence[tuple[str, Sequence[HealthTrial]]]) -> list[str]:
    rows = []
    for label, trials in drifts:
        delays = [t.detection_delay_s for t in trials if t.detection_delay_s is not None]
        within = sum(d <= 1800.0 for d in delays)
        med = f"{float(np.median(delays)):.0f}" if delays else "-"
        worst_delay = f"{max(delays):.0f}" if delays else "-"
        fa = sum(t.false_alarm for t in trials)
        rows.append(f"| {label} | {len(trials)} | {within} | {med} | {worst_delay} | {fa} |")
    return rows


def format_health_report(bench: HealthBenchmark, *, ts_s: float) -> str:
    """The numbers as Markdown (stdout and BENCHMARKS.md share it)."""
    st = bench.settings
    bound = st.false_alarm_bound(86_400.0, ts_s)
    profile = OperatingProfile()
    lines = [
        f"Command: `{bench.command}`",
        "",
        f"Machine: {bench.machine}; wall time {bench.wall_time_s:.0f} s.",
        "",
        "Rule (`czmpc.health`): every "
        f"{st.test_every_samples} samples, the regression F test of the model's one-step "
        f"residuals on past data over the last {st.window_samples} samples; alarm when its "
        f"p-value < {st.false_alarm_per_test:g} (latched). False-alarm bound (union bound): "
        f"{bound:.2g} per 24 h at Ts = {ts_s:g} s (one false alarm in about "
        f"{1.0 / bound:.0f} days at most).",
        "",
        "Unchanged plant (the model's own equation, noise on), 24 h of plant time each: "
        "open loop through an input staircase (2..4 % steps every 5 min inside the model's "
        "input range), closed loop through the setpoint staircase below.",
        "",
        "| trials | samples each | false alarms | largest health figure (alarm at 1) |",
        "|---|---:|---:|---:|",
    ]
    for label, trials in (("open loop", bench.open_loop_days),
                          ("closed loop (MPC)", bench.closed_loop_days)):
        if trials:
            n = int(round(trials[0].duration_s / ts_s))
            fa = sum(t.false_alarm for t in trials)
            worst = max(t.max_health_before_drift for t in trials)
            lines.append(f"| {len(trials)} x 24 h {label} | {n} | {fa} | {worst:.2f} |")
    lines += [
        "",
        "Drifts, test against the model (closed loop, MPC on the model plant; setpoint "
        "staircase: "
        f"{profile.step_kw[0]:g}..{profile.step_kw[1]:g} kW steps every "
        f"{profile.step_every_s:g} s inside {profile.band_kw[0]:g}..{profile.band_kw[1]:g} kW; "
        "drift at 1800 s, run 2400 s past it; seeds 1..N):",
        "",
        "| drift | trials | alarmed within 30 min | delay median [s] | delay max [s] | "
        "false alarms before the drift |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    lines += _drift_rows(bench.drifts)
    lines += [
        "",
        "Which reference? On a plant the model describes only approximately (the virtual "
        "heater the shipped model was identified from; closed loop, same staircase), the "
        "test against the model flags that structural mismatch, the test against a "
        f"baseline (the first {RUNTIME_HEALTH.baseline_samples} samples of the run, what "
        "`czmpc run` uses) only a change since:",
        "",
        "| reference | runs | alarms | first alarm [s] | largest health figure |",
        "|---|---:|---:|---:|---:|",
        *[f"| {label} | {len(trials)} x {trials[0].duration_s / 3600:g} h | "
          f"{sum(t.alarm_at_s is not None for t in trials)} | "
          f"{min((t.alarm_at_s for t in trials if t.alarm_at_s is not None), default=None) or '-'} | "
          f"{max(t.max_health_before_drift for t in trials):.2f} |"
          for label, trials in bench.heater_days if trials],
        "",
        "Drifts with the baseline test (model plant; baseline = the first "
        f"{RUNTIME_HEALTH.baseline_samples * 2:g} s at Ts = 2 s, drift 600 s after it):",
        "",
        "| drift | trials | alarmed within 30 min | delay median [s] | delay max [s] | "
        "false alarms before the drift |",
        "|---|---:|---:|---:|---:|---:|",
        *_drift_rows(bench.baseline_drifts),
        "",
        "The delay depends on the excitation: the test sees a model error only through "
        "input moves (a time-constant change shows only in the sag after a step, about 12 % "
        "of it on this heater). With a constant input a stale model cannot be seen, and does "
        "no harm to offset-free tracking of a constant setpoint.",
    ]
    return "\n".join(lines) + "\n"


def build_parser() -> argparse.ArgumentParser:
    """The options of ``python -m benchmarks.health``."""
    parser = benchmark_parser("health", __doc__)
    parser.add_argument("--model", metavar="MODEL.json", type=Path, default=None,
                        help="model of the controller, the monitor and the plant (default: the "
                             "shipped data/cz_heater_model.json)")
    parser.add_argument("--days-open", metavar="N", type=_argtypes.integer(0), default=3,
                        help="24 h open-loop trials of the unchanged plant (default: 3)")
    parser.add_argument("--days-closed", metavar="N", type=_argtypes.integer(0), default=1,
                        help="24 h closed-loop trials of the unchanged plant (about 1 min "
                             "each) (default: 1)")
    parser.add_argument("--seeds", metavar="N", type=_argtypes.positive_int, default=10,
                        help="closed-loop trials per drift (default: 10)")
    parser.add_argument("--benchmarks-md", metavar="FILE", type=Path, default=BENCHMARKS_MD,
                        help="Markdown file to put the section in (default: BENCHMARKS.md of "
                             "this repository)")
    parser.add_argument("--no-record", action="store_true",
                        help="only print the numbers; do not write them into BENCHMARKS.md")
    return parser


def _run(args: argparse.Namespace) -> int:
    model = load_model(args.model or shipped_path(HAMMERSTEIN_MODEL_JSON))
    progress = Progress()
    bench = run_health_benchmark(model, command=args.command_line,
                                 machine=machine_info().describe(), n_days_open=args.days_open,
                                 n_days_closed=args.days_closed, n_drift_seeds=args.seeds,
                                 progress=progress)
    text = format_health_report(bench, ts_s=model.ts_s)
    print(text, end="")
    if not args.no_record:
        write_benchmarks_section(args.benchmarks_md, text, heading=BENCHMARK_HEADING)
        progress(f"wrote the numbers to {args.benchmarks_md}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run the trials, print the table, record it in BENCHMARKS.md; return the exit code."""
    return run_main(build_parser(), _run, argv)


__all__ = ["BENCHMARK_HEADING", "HealthBenchmark", "HealthTrial", "OperatingProfile",
           "build_parser", "closed_loop_trial", "false_alarm_trial", "format_health_report",
           "heater_trials", "main", "monitor_record", "run_health_benchmark",
           "slow_time_constant_s"]


if __name__ == "__main__":
    sys.exit(main())
