"""Benchmark of the MPC in closed loop: controller step time (N = 50) and a 24 h simulation.

``python -m benchmarks.mpc_step [--model MODEL.json] [--repeats N]`` (``--help``).

Two measurements, each run through `czmpc.campaigns.simulation.run_simulation` (so the loop,
plants and controller are exactly those of ``czmpc simulate``):

* **step time**: the wall time of `OffsetFreeMPC.step` alone (`time.perf_counter`
  around each call, recorded by `sim.loop.run_closed_loop`) on the shipped staircase
  scenario (3,900 samples) against the plant built from the model (noisy), with the
  default tuning at horizon ``N = 50``; median, p95, p99 and maximum over each run,
  repeated. Goal (issue 4): median <= 0.3 ms and p99 <= 2 ms on this machine, judged
  on the median over the repeats.
* **step against a bare OSQP solve** (issue 30): the same closed loop, stepped here
  with each step timed and the QP data it sent to OSQP (``q``, ``l``, ``u``) kept;
  then, in the same process, the same QP set up afresh and the kept data replayed
  through OSQP's own interface, ``update(q=..., l=..., u=...)`` then ``solve()``, each
  call timed. The ratio of the medians is what the controller costs around its QP.
  Goal: at most 1.25. Measured twice: as above, and (issue 40) with the recipe known
  60 s ahead (``setpoint_preview_kw``) and the grid voltage measured
  (``grid_voltage_factor``: 1 +- 1e-4, then a 3 % sag for the second half, which the
  plant applies too), so that both the preview's cost and the voltage's scaled map run.
* **the same with DAQP** (issue 42, ``MPCSettings.solver = "daqp"``, when ``daqp`` is
  installed): each repeat also steps a DAQP controller through the same closed loop
  (same seed), timing each step and keeping its QP data; replays that data on a DAQP
  QP set up afresh through ``daqp.Model`` (``update(f=..., bupper=..., blower=...)`` +
  ``solve()``, what `czmpc.qp_daqp.DAQPMPCQP` calls), each call timed; and replays the
  OSQP run's QP data on DAQP too, so that the plans of the two solvers on the very same
  QPs give ``max |w_daqp - w_osqp|``. Both solvers' own (C) solve times are reported
  beside the Python calls.
* **24 h simulation**: `day_scenario` (43,200 samples of 2 s: a staircase up and down
  with a grid level shift and a voltage sag) with the MPC in the loop at its default
  tuning, on both plants; wall time of the whole `run_simulation` call (plant and
  controller set-up, the loop, metrics). Goal: under 30 s.

The numbers go to stdout and, with the machine they ran on, under
`SECTION_HEADING` in BENCHMARKS.md (`write_benchmarks_section`; other sections are kept).

Exit codes: 0 done (goals met or not, unless --strict); 1 a goal missed with
--strict; 2 bad input (model file).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.metadata
import importlib.util
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks._md import BENCHMARKS_MD, MachineInfo, benchmark_parser, machine_info, run_main
from benchmarks._md import write_benchmarks_section as _write_section
from czmpc.campaigns.simulation import PLANT_DESCRIPTIONS, PlantKind, run_simulation
from czmpc.cli import _argtypes, _progress
from czmpc.controller import OffsetFreeMPC
from czmpc.qp import MPCQP
from czmpc.qp_daqp import DAQP_ITER_LIMIT, DAQP_PRIMAL_TOL_KW, DAQPMPCQP
from czmpc.settings import MPCSettings
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sim.disturbances import PowerShift, VoltageStep
from sim.model_plant import ModelPlant
from sim.protocols import NOMINAL, Exogenous
from sim.scenario import Scenario, SetpointStep, load_scenario
from sysid.model import HammersteinModel
from sysid.modelfile import load_model

#: Heading of this benchmark's section in BENCHMARKS.md.
SECTION_HEADING = "## Controller step time and 24 h simulation"
#: Horizon of the step-time benchmark [samples] (issue 4).
BENCH_HORIZON_STEPS = 50
#: Step-time goals of issue 4 [ms].
STEP_MEDIAN_GOAL_MS = 0.3
STEP_P99_GOAL_MS = 2.0
#: Wall-time goal of the 24 h closed-loop simulation [s].
DAY_SIMULATION_GOAL_S = 30.0
#: Plant time of the long simulation [s]: 24 h = 43,200 samples of 2 s.
DAY_DURATION_S = 86_400.0
#: Seed of every benchmark run (the numbers do not depend on it beyond noise).
BENCH_SEED = 0
#: Setpoints the step is told ahead in the second overhead measurement (60 s at 2 s).
PREVIEW_STEPS = 30
#: Grid voltage factor of the sag over its second half [-].
SAG_FACTOR = 0.97
#: Goal of issue 30: the step's median at most this times a bare OSQP update-and-solve's.
STEP_OVER_QP_GOAL = 1.25

Progress = Callable[[str], None]


@dataclass(frozen=True, slots=True, kw_only=True)
class StepTimeRun:
    """Step-time statistics of one closed-loop run [ms].

    Parameters
    ----------
    n_steps :
        Controller steps timed.
    median_ms, p95_ms, p99_ms, max_ms :
        Median, 95th and 99th percentile and maximum of the step time [ms].
    mean_iterations :
        Mean OSQP iterations per step.
    n_fallbacks :
        Steps whose QP result was not used.
    """

    n_steps: int
    median_ms: float
    p95_ms: float
    p99_ms: float
    max_ms: float
    mean_iterations: float
    n_fallbacks: int


@dataclass(frozen=True, slots=True, kw_only=True)
class DAQPRun:
    """The closed loop of an `OverheadRun` with ``solver = "daqp"``, and its QPs on DAQP.

    Parameters
    ----------
    step_median_ms :
        Median of `OffsetFreeMPC.step` with ``solver = "daqp"`` (its own closed loop, the
        same plant seed) [ms].
    bare_median_ms :
        Median of ``daqp.Model.update(f=..., bupper=..., blower=...)`` + ``solve()``
        replaying that loop's QP data on the same QP set up afresh [ms].
    internal_median_ms :
        Median of DAQP's own solve time in that replay (C, from its ``info``) [ms].
    osqp_internal_median_ms :
        Median of OSQP's own solve time in its solver-object replay (C,
        ``info.solve_time``) [ms].
    mean_iterations, max_iterations :
        DAQP iterations (active-set changes) per step in the controller's loop.
    same_iterations :
        Fraction of replayed steps that took as many iterations as in the loop.
    max_plan_diff_kw :
        ``max |w_daqp - w_osqp|`` over the OSQP run's QPs replayed on DAQP, every plan
        entry of every step whose OSQP plan was usable [kW-equivalent].
    n_fallbacks :
        Steps of the DAQP loop whose QP result was not used.
    """

    step_median_ms: float
    bare_median_ms: float
    internal_median_ms: float
    osqp_internal_median_ms: float
    mean_iterations: float
    max_iterations: int
    same_iterations: float
    max_plan_diff_kw: float
    n_fallbacks: int


@dataclass(frozen=True, slots=True, kw_only=True)
class OverheadRun:
    """One closed loop timed step by step, then its QPs replayed on a bare OSQP [ms].

    Parameters
    ----------
    n_steps :
        Steps timed (and QPs replayed).
    step_median_ms :
        Median of `OffsetFreeMPC.step` [ms].
    bare_median_ms :
        Median of ``update(q=..., l=..., u=...)`` + ``solve()`` of ``osqp.OSQP`` on the
        same QP data, in the same order [ms].
    solver_median_ms :
        The same through OSQP's solver object (``update_data_vec`` + ``solve``, what
        `czmpc.qp.MPCQP` calls), without the interface's own work [ms].
    same_iterations :
        Fraction of steps whose replay took as many ADMM iterations as the
        controller's solve (1.0: the replay solved the same problems from the same
        warm starts).
    daqp :
        The same with DAQP, or None (not measured: ``daqp`` not installed).
    """

    n_steps: int
    step_median_ms: float
    bare_median_ms: float
    solver_median_ms: float
    same_iterations: float
    daqp: DAQPRun | None = None

    @property
    def ratio(self) -> float:
        """Step median over the bare update-and-solve median."""
        return self.step_median_ms / self.bare_median_ms


@dataclass(frozen=True, slots=True, kw_only=True)
class DayRun:
    """Wall time of one 24 h closed-loop simulation.

    Parameters
    ----------
    plant :
        ``"model"`` or ``"heater"``.
    n_steps :
        Samples simulated.
    wall_s :
        Wall time of the whole `run_simulation` call [s].
    controller_s :
        Sum of the controller's step times within it [s].
    horizon_steps :
        ``N`` of the controller.
    max_abs_steady_state_error_kw :
        Largest steady-state error of the measured power over the setpoint segments
        [kW] (a sanity check that the run did control; see
        `SimulationOutcome.metrics_measured` for why the measured power).
    """

    plant: PlantKind
    n_steps: int
    wall_s: float
    controller_s: float
    horizon_steps: int
    max_abs_steady_state_error_kw: float


@dataclass(frozen=True, kw_only=True)
class MPCBenchmark:
    """Everything `run_benchmark` measured.

    Parameters
    ----------
    machine :
        The machine (cores, CPU, Python, numpy/scipy/osqp versions, load average).
    model_label :
        Which model the controller (and the model plant) used.
    step_runs :
        One `StepTimeRun` per repeat.
    day_runs :
        One `DayRun` per plant.
    command :
        The command line that produced the numbers.
    overhead_runs :
        One `OverheadRun` per repeat (empty: not measured).
    context_runs :
        The same with a setpoint preview and a measured voltage (issue 40).
    """

    machine: MachineInfo
    model_label: str
    step_runs: tuple[StepTimeRun, ...]
    day_runs: tuple[DayRun, ...]
    command: str
    overhead_runs: tuple[OverheadRun, ...] = ()
    context_runs: tuple[OverheadRun, ...] = ()

    @property
    def step_over_qp(self) -> float:
        """Median over the repeats of each run's step-to-bare-QP ratio."""
        return float(np.median([r.ratio for r in self.overhead_runs]))

    @property
    def step_median_ms(self) -> float:
        """Median over the repeats of each run's median step time [ms]."""
        return float(np.median([r.median_ms for r in self.step_runs]))

    @property
    def step_p99_ms(self) -> float:
        """Median over the repeats of each run's p99 step time [ms]."""
        return float(np.median([r.p99_ms for r in self.step_runs]))

    @property
    def step_goal_met(self) -> bool:
        """Median <= 0.3 ms and p99 <= 2 ms (medians over the repeats)."""
        return self.step_median_ms <= STEP_MEDIAN_GOAL_MS and self.step_p99_ms <= STEP_P99_GOAL_MS

    @property
    def day_goal_met(self) -> bool:
        """Every 24 h simulation under 30 s."""
        return all(r.wall_s < DAY_SIMULATION_GOAL_S for r in self.day_runs)


def day_scenario(ts_s: float = 2.0) -> Scenario:
    """24 h of plant time: the staircase up and down twice, a grid level shift, a sag.

    Setpoint 45 kW, then 50, 55, 60, 65, 60, 55, 50, 45 kW every 80 min (two cycles
    in 24 h); the paper's +0.15 kW level shift (sec. 5.2) at 6 h for good; a 3 % grid
    voltage sag of 10 min at 15 h; plant noise on.

    Parameters
    ----------
    ts_s :
        Sampling time [s] (the model's).
    """
    levels_kw = (50.0, 55.0, 60.0, 65.0, 60.0, 55.0, 50.0, 45.0)
    period_s = 4800.0
    steps = tuple(
        SetpointStep(at_s=period_s * (1 + i), power_kw=levels_kw[i % len(levels_kw)])
        for i in range(int(DAY_DURATION_S // period_s) - 1)
    )
    return Scenario(
        name="day-24h",
        description="24 h: staircase 45..65 kW up and down (80 min per level), +0.15 kW "
                    "level shift at 6 h, 3 % voltage sag for 10 min at 15 h",
        duration_s=DAY_DURATION_S, ts_s=ts_s, initial_setpoint_kw=45.0, initial_triac_pct=45.0,
        setpoints=steps,
        disturbances=(PowerShift(at_s=6 * 3600.0, offset_kw=0.15),
                      VoltageStep(at_s=15 * 3600.0, factor=0.97, duration_s=600.0)),
    )


def measure_step_times(
    model: HammersteinModel, *, repeats: int, progress: Progress | None = None,
) -> tuple[StepTimeRun, ...]:
    """Time `OffsetFreeMPC.step` at ``N = 50`` on the staircase, model plant, ``repeats`` times.

    Parameters
    ----------
    model :
        Controller model and plant.
    repeats :
        Closed-loop runs (>= 1); each gives its own statistics.
    progress :
        Called with a short message after each run.
    """
    scenario = load_scenario("staircase")
    settings = MPCSettings.default_for(model).with_updates(horizon_steps=BENCH_HORIZON_STEPS)
    runs = []
    for i in range(repeats):
        outcome = run_simulation(model, scenario, plant="model", seed=BENCH_SEED + i,
                                 settings=settings)
        ms = outcome.result.step_time_s * 1e3
        diags = outcome.result.diagnostics or ()
        iterations = [float(getattr(d, "n_iterations", 0)) for d in diags]
        runs.append(StepTimeRun(
            n_steps=int(ms.size), median_ms=float(np.median(ms)),
            p95_ms=float(np.percentile(ms, 95)), p99_ms=float(np.percentile(ms, 99)),
            max_ms=float(ms.max()), mean_iterations=float(np.mean(iterations)) if iterations else 0.0,
            n_fallbacks=int(outcome.metrics.n_solver_failures or 0),
        ))
        if progress is not None:
            progress(f"step time, run {i + 1}/{repeats}: median {runs[-1].median_ms:.3f} ms")
    return tuple(runs)


def measure_qp_overhead(
    model: HammersteinModel, *, repeats: int, progress: Progress | None = None,
    context: bool = False,
) -> tuple[OverheadRun, ...]:
    """Time the step and a bare OSQP update-and-solve of the same QPs, ``repeats`` times.

    Each repeat steps the controller (``N = 50``, default tuning) through the shipped
    staircase's setpoints against the noisy model plant (no disturbance events),
    timing each `OffsetFreeMPC.step` and keeping the ``q``, ``l``, ``u`` it sent to
    OSQP; then sets the same QP up afresh twice and replays the kept data through
    ``osqp.OSQP.update`` + ``solve`` and through its solver object. With ``daqp``
    installed, the same with ``solver = "daqp"`` (`DAQPRun`, module notes).

    Parameters
    ----------
    model :
        Controller model and plant.
    repeats :
        Closed loops (>= 1); each gives its own medians.
    progress :
        Called with a short message after each repeat.
    context :
        Give each step the next `PREVIEW_STEPS` setpoints and a measured grid voltage
        (module notes), the plant the same voltage.
    """
    scenario = load_scenario("staircase")
    settings = MPCSettings.default_for(model).with_updates(
        horizon_steps=BENCH_HORIZON_STEPS, initial_triac_pct=scenario.initial_triac_pct)
    n = len(scenario.setpoint_profile_kw())
    with_daqp = importlib.util.find_spec("daqp") is not None
    runs = []
    for i in range(repeats):
        loop = _timed_loop(model, settings, scenario, seed=BENCH_SEED + i, context=context)
        step_s, iterations, problems = loop.step_s, loop.iterations, loop.problems
        bare = OffsetFreeMPC(model, settings).qp._solver  # osqp.OSQP, the same QP afresh
        bare_s = np.empty(n)
        same = 0
        for k, (q, lo, up) in enumerate(problems):
            t0 = time.perf_counter()
            bare.update(q=q, l=lo, u=up)
            result = bare.solve(raise_error=False)
            bare_s[k] = time.perf_counter() - t0
            same += int(int(result.info.iter) == int(iterations[k]))
        solver = OffsetFreeMPC(model, settings).qp._ext  # the solver object behind osqp.OSQP
        solver_s = np.empty(n)
        internal_s = np.empty(n)
        for k, (q, lo, up) in enumerate(problems):
            t0 = time.perf_counter()
            solver.update_data_vec(q=q, l=lo, u=up)
            solver.solve()
            solver_s[k] = time.perf_counter() - t0
            internal_s[k] = solver.info.solve_time
        daqp = (_measure_daqp(model, settings, scenario, loop, seed=BENCH_SEED + i, context=context,
                              osqp_internal_median_ms=float(np.median(internal_s)) * 1e3)
                if with_daqp else None)
        runs.append(OverheadRun(
            n_steps=n, step_median_ms=float(np.median(step_s)) * 1e3,
            bare_median_ms=float(np.median(bare_s)) * 1e3,
            solver_median_ms=float(np.median(solver_s)) * 1e3, same_iterations=same / n,
            daqp=daqp,
        ))
        if progress is not None:
            progress(f"step against a bare OSQP solve{' (preview, voltage)' if context else ''}, "
                     f"run {i + 1}/{repeats}: {runs[-1].ratio:.2f}x"
                     + (f"; DAQP step {daqp.step_median_ms:.4f} ms" if daqp is not None else ""))
    return tuple(runs)


@dataclass(frozen=True, slots=True, kw_only=True)
class _Loop:
    """One timed closed loop of `measure_qp_overhead`: per step, in order."""

    step_s: np.ndarray                 # step wall times [s]
    iterations: np.ndarray             # solver iterations
    plans: np.ndarray                  # (n, N) the QP's plan, NaN where not usable
    problems: list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # (q, l, u) as sent
    n_fallbacks: int


def _timed_loop(model: HammersteinModel, settings: MPCSettings, scenario: Scenario, *,
                seed: int, context: bool) -> _Loop:
    """Step a controller through the staircase against the model plant (seed ``seed``).

    Each `OffsetFreeMPC.step` is timed and the ``q``, ``l``, ``u`` it sent kept (one
    array in `czmpc.qp.MPCQP`, whichever solver). ``context``: `measure_qp_overhead`.
    """
    setpoints = [float(v) for v in scenario.setpoint_profile_kw()]
    n = len(setpoints)
    mpc = OffsetFreeMPC(model, settings)
    qp = mpc.qp
    n_var, m = qp.n_variables, qp.n_constraints
    sent = np.empty((n, n_var + 2 * m))
    iterations = np.empty(n, dtype=int)
    plans = np.empty((n, settings.horizon_steps))
    step_s = np.empty(n)
    plant = ModelPlant.for_scenario(model, scenario)
    power = plant.reset(np.random.default_rng(seed))
    ahead = np.array(setpoints)
    volts = (np.where(np.arange(n) < n // 2, 1.0, SAG_FACTOR)
             + 1e-4 * np.random.default_rng(seed + 1000).standard_normal(n))
    for k, setpoint in enumerate(setpoints):
        if context:
            preview = ahead[k + 1 : k + 1 + PREVIEW_STEPS]
            volt = float(volts[k])
            t0 = time.perf_counter()
            triac = mpc.step(power, setpoint, setpoint_preview_kw=preview,
                             grid_voltage_factor=volt)
            step_s[k] = time.perf_counter() - t0
        else:
            t0 = time.perf_counter()
            triac = mpc.step(power, setpoint)
            step_s[k] = time.perf_counter() - t0
        sent[k] = qp._data  # q, l, u as this step sent them (one array in MPCQP)
        last = mpc.last_step
        iterations[k] = last.n_iterations  # type: ignore[union-attr]
        plans[k] = last.planned_w  # type: ignore[union-attr]
        power = plant.step(triac, Exogenous(grid_voltage_factor=float(volts[k])) if context
                           else NOMINAL)
    problems = [(row[:n_var], row[n_var:n_var + m], row[n_var + m:]) for row in sent]
    return _Loop(step_s=step_s, iterations=iterations, plans=plans, problems=problems,
                 n_fallbacks=mpc.n_fallbacks)


def _daqp_qp(model: HammersteinModel, settings: MPCSettings) -> DAQPMPCQP:
    qp: MPCQP = OffsetFreeMPC(model, settings.with_updates(solver="daqp")).qp
    if not isinstance(qp, DAQPMPCQP):  # pragma: no cover - the setting chooses the class
        raise TypeError(f"expected a DAQPMPCQP; got {type(qp).__name__}")
    return qp


def _measure_daqp(model: HammersteinModel, settings: MPCSettings, scenario: Scenario,
                  osqp_loop: _Loop, *, seed: int, context: bool,
                  osqp_internal_median_ms: float) -> DAQPRun:
    """`DAQPRun` of one repeat: the DAQP loop, its bare replay, the OSQP run's QPs on DAQP."""
    loop = _timed_loop(model, settings.with_updates(solver="daqp"), scenario, seed=seed,
                       context=context)
    n = len(loop.problems)
    bare = _daqp_qp(model, settings).daqp_model  # the same QP afresh: daqp.Model
    bare_s = np.empty(n)
    internal_s = np.empty(n)
    same = 0
    for k, (q, lo, up) in enumerate(loop.problems):
        t0 = time.perf_counter()
        bare.update(f=q, bupper=up, blower=lo)
        _, _, _, info = bare.solve()
        bare_s[k] = time.perf_counter() - t0
        internal_s[k] = info["solve_time"]
        same += int(info["iterations"] == loop.iterations[k])
    replay = _daqp_qp(model, settings).daqp_model
    worst = 0.0
    N = settings.horizon_steps
    for (q, lo, up), w_osqp in zip(osqp_loop.problems, osqp_loop.plans, strict=True):
        replay.update(f=q, bupper=up, blower=lo)
        x, _, exitflag, _ = replay.solve()
        if exitflag == 1 and np.isfinite(w_osqp).all():
            worst = max(worst, float(np.max(np.abs(x[:N] - w_osqp))))
    return DAQPRun(
        step_median_ms=float(np.median(loop.step_s)) * 1e3,
        bare_median_ms=float(np.median(bare_s)) * 1e3,
        internal_median_ms=float(np.median(internal_s)) * 1e3,
        osqp_internal_median_ms=osqp_internal_median_ms,
        mean_iterations=float(np.mean(loop.iterations)),
        max_iterations=int(np.max(loop.iterations)), same_iterations=same / n,
        max_plan_diff_kw=worst, n_fallbacks=loop.n_fallbacks,
    )


def measure_day_simulation(
    model: HammersteinModel, plant: PlantKind, *, progress: Progress | None = None,
) -> DayRun:
    """Wall time of `run_simulation` over `day_scenario` with the default tuning.

    Parameters
    ----------
    model :
        Controller model (and plant for ``plant="model"``).
    plant :
        ``"model"`` or ``"heater"``.
    progress :
        Called with a short message when done.
    """
    scenario = day_scenario(model.ts_s)
    t0 = time.perf_counter()
    outcome = run_simulation(model, scenario, plant=plant, seed=BENCH_SEED)
    wall_s = time.perf_counter() - t0
    run = DayRun(
        plant=plant, n_steps=outcome.result.n_steps, wall_s=wall_s,
        controller_s=float(np.sum(outcome.result.step_time_s)),
        horizon_steps=outcome.settings.horizon_steps,
        max_abs_steady_state_error_kw=outcome.metrics_measured.max_abs_steady_state_error_kw,
    )
    if progress is not None:
        progress(f"24 h simulation on the {plant} plant: {wall_s:.2f} s")
    return run


def run_benchmark(
    model: HammersteinModel, *, model_label: str, repeats: int = 5, command: str,
    progress: Progress | None = None,
) -> MPCBenchmark:
    """Run both measurements (the machine is described before they start).

    Parameters
    ----------
    model :
        The controller's model.
    model_label :
        How to name the model in the report (e.g. its file).
    repeats :
        Step-time runs.
    command :
        The command line, recorded with the numbers.
    progress :
        Called with a short message after each run.
    """
    machine = machine_info()
    step_runs = measure_step_times(model, repeats=repeats, progress=progress)
    overhead_runs = measure_qp_overhead(model, repeats=repeats, progress=progress)
    context_runs = measure_qp_overhead(model, repeats=repeats, progress=progress, context=True)
    day_runs = tuple(measure_day_simulation(model, plant, progress=progress)
                     for plant in ("model", "heater"))
    return MPCBenchmark(machine=machine, model_label=model_label, step_runs=step_runs,
                        day_runs=day_runs, command=command, overhead_runs=overhead_runs,
                        context_runs=context_runs)


def _met(ok: bool) -> str:
    return "**met**" if ok else "**missed**"


def _load_note(machine: MachineInfo) -> list[str]:
    """A note when other work shared the machine (it shows in p99 and max, not the median)."""
    load = machine.load_average
    if load is None or load < 0.5 * machine.n_cpus:
        return []
    return [
        "",
        f"Note: other jobs shared the machine (load average {load:.2f} on {machine.n_cpus} "
        "cores). A step that loses its core to another process for one time slice takes "
        "milliseconds: that shows in p99 and max, which vary from run to run, not in the "
        "median.",
    ]


def format_report(bench: MPCBenchmark) -> str:
    """The numbers as Markdown (stdout and BENCHMARKS.md share it)."""
    lines = [
        f"Command: `{bench.command}`",
        "",
        f"Machine: {bench.machine.describe()}",
        "",
        f"Model: {bench.model_label}. Controller: `OffsetFreeMPC`, default tuning; OSQP "
        "warm-started, eps 1e-5.",
        "",
        f"### Step time, N = {BENCH_HORIZON_STEPS}",
        "",
        f"Wall time of `OffsetFreeMPC.step` alone (perf_counter around each call) on the "
        f"shipped staircase (45 -> 65 kW, {bench.step_runs[0].n_steps} samples) against the "
        "plant built from the model (noise on), one row per run (seeds "
        f"{BENCH_SEED}..{BENCH_SEED + len(bench.step_runs) - 1}).",
        "",
        "| run | median [ms] | p95 [ms] | p99 [ms] | max [ms] | OSQP iterations (mean) | fallbacks |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i, r in enumerate(bench.step_runs, start=1):
        lines.append(f"| {i} | {r.median_ms:.3f} | {r.p95_ms:.3f} | {r.p99_ms:.3f} | "
                     f"{r.max_ms:.3f} | {r.mean_iterations:.1f} | {r.n_fallbacks} |")
    lines += [
        "",
        f"Goal: median <= {STEP_MEDIAN_GOAL_MS:g} ms and p99 <= {STEP_P99_GOAL_MS:g} ms "
        f"(medians over the runs: {bench.step_median_ms:.3f} ms, {bench.step_p99_ms:.3f} ms): "
        f"{_met(bench.step_goal_met)}.",
        *_load_note(bench.machine),
        *_overhead_lines(bench),
        "",
        "### 24 h closed-loop simulation",
        "",
        f"{int(DAY_DURATION_S / 3600)} h of plant time ({bench.day_runs[0].n_steps} samples "
        "of 2 s): staircase 45..65 kW up and down, +0.15 kW level shift, 3 % voltage sag, "
        "noise on; wall time of the whole `czmpc.campaigns.simulation.run_simulation` call (set-up, "
        "loop, metrics).",
        "",
        "| plant | N | wall time [s] | of which controller [s] | largest steady error, measured [kW] |",
        "|---|---:|---:|---:|---:|",
    ]
    for d in bench.day_runs:
        lines.append(f"| {PLANT_DESCRIPTIONS[d.plant]} | {d.horizon_steps} | {d.wall_s:.2f} | "
                     f"{d.controller_s:.2f} | {d.max_abs_steady_state_error_kw:.4f} |")
    slowest = max(d.wall_s for d in bench.day_runs)
    lines += [
        "",
        f"Goal: under {DAY_SIMULATION_GOAL_S:g} s (slowest plant: {slowest:.2f} s): "
        f"{_met(bench.day_goal_met)}.",
    ]
    return "\n".join(lines) + "\n"


def _overhead_lines(bench: MPCBenchmark) -> list[str]:
    """The step-against-bare-OSQP tables (none if not measured)."""
    if not bench.overhead_runs:
        return []
    lines = _overhead_table(bench.overhead_runs, "")
    if bench.context_runs:
        lines += _overhead_table(bench.context_runs, (
            f" with a {PREVIEW_STEPS * 2} s setpoint preview and a measured voltage"))
    return lines


def _overhead_table(runs: tuple[OverheadRun, ...], what: str) -> list[str]:
    """One step-against-bare-OSQP table and its goal line."""
    lines = [
        "",
        f"### Step against a bare OSQP solve{what}, N = {BENCH_HORIZON_STEPS}",
        "",
        "The staircase's setpoints against the model plant (noise on, no disturbance "
        "events" + ("; each step told the next setpoints and a voltage reading of 1 +- "
                    "1e-4, then of the 3 % sag the plant gets too, for the second half"
                    if what else "") + "); each `OffsetFreeMPC.step` timed and the `q`, `l`, "
        "`u` it sent to OSQP "
        "kept, then replayed in the same process on the same QP set up afresh: through "
        "`osqp.OSQP` (`update(q=..., l=..., u=...)` + `solve()`, the bare solve) and "
        "through its solver object (`update_data_vec` + `solve`, what `czmpc.qp.MPCQP` "
        "calls). Medians over the steps, one row per run.",
        "",
        "| run | step [ms] | bare update + solve [ms] | solver object [ms] | step / bare | "
        "step / solver object | same iterations |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i, r in enumerate(runs, start=1):
        lines.append(f"| {i} | {r.step_median_ms:.4f} | {r.bare_median_ms:.4f} | "
                     f"{r.solver_median_ms:.4f} | {r.ratio:.2f} | "
                     f"{r.step_median_ms / r.solver_median_ms:.2f} | {r.same_iterations:.1%} |")
    ratio = float(np.median([r.ratio for r in runs]))
    lines += [
        "",
        f"Goal: step at most {STEP_OVER_QP_GOAL:g} x the bare update-and-solve (median over "
        f"the runs: {ratio:.2f} x): {_met(ratio <= STEP_OVER_QP_GOAL)}.",
    ]
    return lines + _daqp_table(runs, what)


def _daqp_version() -> str:
    try:
        return f"daqp {importlib.metadata.version('daqp')}"
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover - measured only if present
        return "daqp"


def _daqp_table(runs: tuple[OverheadRun, ...], what: str) -> list[str]:
    """The DAQP table of one overhead measurement and its summary (none if not measured)."""
    pairs = [(r, r.daqp) for r in runs if r.daqp is not None]
    if not pairs:
        return []
    lines = [
        "",
        f"### The same with DAQP (`solver = \"daqp\"`){what}, N = {BENCH_HORIZON_STEPS}",
        "",
        "Each run also stepped a controller with `solver = \"daqp\"` through the same closed "
        "loop (same seed, each step timed, the QP data kept), then replayed that data on the "
        "same QP set up afresh through `daqp.Model` (`update(f=..., bupper=..., blower=...)` "
        "+ `solve()`, what `czmpc.qp_daqp.DAQPMPCQP` calls), and the OSQP run's QP data too, "
        "for the plans of both solvers on the very same QPs. Own solve: the solver's time "
        f"inside its C code, from its info. Medians over the steps, one row per run; "
        f"{_daqp_version()}.",
        "",
        "| run | OSQP step [ms] | DAQP step [ms] | OSQP solver object [ms] | DAQP update + solve "
        "[ms] | OSQP own solve [ms] | DAQP own solve [ms] | DAQP iterations (mean / max) | "
        "same iterations | max abs(w_daqp - w_osqp) [kW] | DAQP fallbacks |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i, (r, d) in enumerate(pairs, start=1):
        lines.append(
            f"| {i} | {r.step_median_ms:.4f} | {d.step_median_ms:.4f} | {r.solver_median_ms:.4f} "
            f"| {d.bare_median_ms:.4f} | {d.osqp_internal_median_ms:.4f} | "
            f"{d.internal_median_ms:.4f} | {d.mean_iterations:.2f} / {d.max_iterations} | "
            f"{d.same_iterations:.1%} | {d.max_plan_diff_kw:.2e} | {d.n_fallbacks} |")

    def median(values: list[float]) -> float:
        return float(np.median(values))

    osqp_step = median([r.step_median_ms for r, _ in pairs])
    daqp_step = median([d.step_median_ms for _, d in pairs])
    osqp_solve = median([r.solver_median_ms for r, _ in pairs])
    daqp_solve = median([d.bare_median_ms for _, d in pairs])
    osqp_own = median([d.osqp_internal_median_ms for _, d in pairs])
    daqp_own = median([d.internal_median_ms for _, d in pairs])
    lines += [
        "",
        f"Medians over the runs: the step with DAQP {daqp_step:.4f} ms against {osqp_step:.4f} "
        f"ms with OSQP ({daqp_step / osqp_step:.2f} x); DAQP's update and solve "
        f"{daqp_solve * 1e3:.1f} us against {osqp_solve * 1e3:.1f} us for OSQP's solver object "
        f"({daqp_solve / osqp_solve:.2f} x), their own solve times {daqp_own * 1e3:.2f} us "
        f"against {osqp_own * 1e3:.2f} us. DAQP's worst iteration count: "
        f"{max(d.max_iterations for _, d in pairs)} (cap {DAQP_ITER_LIMIT}).",
        "",
        "How the plans differ: on the same QPs, DAQP's and OSQP's plans are at most "
        f"{max(d.max_plan_diff_kw for _, d in pairs):.2e} kW apart (every entry of every "
        "plan, all runs). DAQP solves each QP exactly (its optimal active set, every row held "
        f"to {DAQP_PRIMAL_TOL_KW:g} kW); OSQP stops at its tolerance, eps 1e-5. The difference "
        "is OSQP's.",
    ]
    return lines


def write_benchmarks_section(path: str | os.PathLike[str], body: str,
                             heading: str = SECTION_HEADING) -> None:
    """Put ``body`` under ``heading`` (default: this benchmark's) in a BENCHMARKS.md."""
    _write_section(path, body, heading=heading)


__all__ = [
    "BENCH_HORIZON_STEPS",
    "DAY_DURATION_S",
    "DAY_SIMULATION_GOAL_S",
    "SECTION_HEADING",
    "STEP_MEDIAN_GOAL_MS",
    "STEP_OVER_QP_GOAL",
    "STEP_P99_GOAL_MS",
    "DAQPRun",
    "DayRun",
    "MPCBenchmark",
    "OverheadRun",
    "StepTimeRun",
    "build_parser",
    "day_scenario",
    "format_report",
    "main",
    "measure_day_simulation",
    "measure_qp_overhead",
    "measure_step_times",
    "run_benchmark",
    "write_benchmarks_section",
]


def build_parser() -> argparse.ArgumentParser:
    """The options of ``python -m benchmarks.mpc_step``."""
    parser = benchmark_parser("mpc_step", __doc__)
    parser.add_argument(
        "--model", metavar="MODEL.json", type=Path, default=None,
        help="identified model file for the controller and the model plant (default: the "
             "shipped data/cz_heater_model.json)")
    parser.add_argument(
        "--repeats", metavar="N", type=_argtypes.positive_int, default=5,
        help="step-time runs of the staircase (3,900 steps each) (default: 5)")
    parser.add_argument(
        "--benchmarks-md", metavar="FILE", type=Path, default=BENCHMARKS_MD,
        help="Markdown file to put the section in (default: BENCHMARKS.md of this repository)")
    parser.add_argument(
        "--no-record", action="store_true",
        help="only print the numbers; do not write them into BENCHMARKS.md")
    parser.add_argument(
        "--strict", action="store_true",
        help="exit 1 if a goal (step median <= 0.3 ms and p99 <= 2 ms; 24 h under 30 s) "
             "is missed")
    return parser


def _run(args: argparse.Namespace) -> int:
    path = args.model if args.model is not None else shipped_path(HAMMERSTEIN_MODEL_JSON)
    model = load_model(path)
    label = str(path)
    if args.model is None:
        with contextlib.suppress(ValueError):  # show the shipped file relative to here if below
            label = str(path.relative_to(Path.cwd()))
    progress = _progress.Progress()
    bench = run_benchmark(model, model_label=f"`{label}`", repeats=args.repeats,
                          command=args.command_line, progress=progress)
    text = format_report(bench)
    print(text, end="")
    if not args.no_record:
        write_benchmarks_section(args.benchmarks_md, text)
        progress(f"wrote the numbers to {args.benchmarks_md}")
    if args.strict and not (bench.step_goal_met and bench.day_goal_met):
        print("error: a benchmark goal was missed (see above)", file=sys.stderr)
        return 1
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print it, record it in BENCHMARKS.md; return the exit code."""
    return run_main(build_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())
