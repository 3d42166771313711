"""Setpoint-tracking benchmark: every controller on every scenario and plant, measured.

Controllers (all behind the `sim.protocols.Controller` protocol, see `CONTROLLERS`):

* ``mpc`` — `OffsetFreeMPC` (OSQP, inversion of ``f``) on the noise-model Hammerstein;
* ``nmpc`` — `czmpc.peers.nmpc.NonlinearMPC` (CasADi + IPOPT, ``f`` inside the dynamics),
  same model, settings, estimator, target, cost and constraints;
* ``linear_mpc`` — `OffsetFreeMPC` on the linear ARMAX(1,2,1) model (no ``f``);
* ``pi_gs`` / ``pi`` — `czmpc.peers.pi.PIController` tuned by its lambda rule on the
  Hammerstein, with and without gain scheduling on ``f'``;
* ``open_loop`` — `czmpc.peers.pi.OpenLoopInversion`, the feed-forward floor.

`build_controller` also builds ``pi_table`` (`OPTIONAL_CONTROLLERS`), the PI schedule
that `czmpc.pid` tunes on the Hammerstein (as ``czmpc tune-pid MODEL --ms 1.4``) over
the same allowed range; campaigns and regression suites run it, ``czmpc bench`` and the
project's golden set keep the six above.

Plants: ``model`` (`sim.model_plant.ModelPlant` of the Hammerstein: no mismatch for the
Hammerstein controllers) and ``heater`` (`sim.heater.VirtualHeater`: grey-box physics),
built and started as `czmpc.campaigns.simulation` does. Fairness: every controller gets the same
input range, the Hammerstein MPC's allowed range (the model's identified range widened
by the validity margin, inside the scenario's TRIAC limits; the linear model has the same
identified range), the scenario's rate limit and the same start input; every run of a
(scenario, plant) pair uses the same seed `BENCH_SEED`, so the noise and faults are
identical across controllers. Errors are of the true (noise-free) power.
"""

from __future__ import annotations

import csv
import io
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks._md import write_benchmarks_section as _write_section
from czmpc.campaigns.simulation import controller_settings, heater_steady_state_triac_pct
from czmpc.controller import OffsetFreeMPC
from czmpc.errors import CzmpcError
from czmpc.peers.nmpc import NonlinearMPC
from czmpc.peers.open_loop import OpenLoopInversion
from czmpc.peers.pi import PIController
from czmpc.pid.controller import ScheduledPID
from czmpc.pid.design import DesignSpec
from czmpc.pid.schedule import tune_schedule
from czmpc.settings import MPCSettings
from czmpc.settings_file import settings_from_dict
from czmpc.shipped import ARMAX_MODEL_JSON, HAMMERSTEIN_MODEL_JSON, shipped_path
from sim.heater import HeaterParams, VirtualHeater
from sim.loop import ClosedLoopResult, run_closed_loop
from sim.metrics import ClosedLoopMetrics, compute_metrics
from sim.model_plant import ModelPlant
from sim.protocols import Controller, Plant
from sim.scenario import Scenario
from sysid.atomic import atomic_path, atomic_write_text
from sysid.model import HammersteinModel
from sysid.modelfile import load_model

#: Shipped models the benchmark uses by default.
DEFAULT_MODEL_PATH = shipped_path(HAMMERSTEIN_MODEL_JSON)
DEFAULT_LINEAR_MODEL_PATH = shipped_path(ARMAX_MODEL_JSON)

#: Seed of every run (plant noise and sensor faults); the same for every controller.
BENCH_SEED = 7

#: Controller names and what they are.
CONTROLLERS: dict[str, str] = {
    "mpc": "offset-free MPC, OSQP, inverted f (Hammerstein)",
    "nmpc": "nonlinear MPC, CasADi + IPOPT, f inside the dynamics (Hammerstein)",
    "linear_mpc": "offset-free MPC on the linear ARMAX(1,2,1)",
    "pi_gs": "PI, anti-windup, gain scheduled on f'(ds)",
    "pi": "PI, anti-windup, fixed gain",
    "open_loop": "open-loop inversion of the steady state (no feedback)",
}
#: Controllers `build_controller` builds beside `CONTROLLERS` (not in the default bench).
OPTIONAL_CONTROLLERS: dict[str, str] = {
    "pi_table": "PI scheduled by a czmpc.pid table (SIMC, Ms <= 1.4 per row), velocity form",
}
#: Ms bound of the ``pi_table`` controller's rows [-].
PI_TABLE_MS = 1.4
#: Plant names and what they are.
PLANTS: dict[str, str] = {
    "model": "ModelPlant of the Hammerstein (no mismatch for the Hammerstein controllers)",
    "heater": "VirtualHeater (grey-box physics, model mismatch)",
}
#: Scenarios on which the MPC must beat the linear MPC (large steps and the ramp).
NONLINEAR_SCENARIOS = ("large_step", "meltdown_ramp")
#: Goal: the MPC's IAE within this fraction of the NMPC's.
IAE_MATCH_FRACTION = 0.02
#: Goal: the NMPC's median step time over the MPC's at least this.
STEP_TIME_RATIO_GOAL = 100.0

#: Columns of bench.csv (units in the names).
CSV_COLUMNS = (
    "scenario", "plant", "controller", "n_steps", "seed", "iae_kw_s", "ise_kw2_s",
    "max_overshoot_kw", "max_overshoot_pct", "max_settling_time_s", "n_not_settled",
    "max_abs_steady_state_error_kw", "input_total_variation_pct", "n_limit_violations",
    "n_rate_violations", "n_solver_failures", "step_time_median_ms", "step_time_p95_ms",
    "step_time_max_ms", "run_wall_time_s",
)

BenchProgress = Callable[[str], None]


class BenchError(CzmpcError, ValueError):
    """An unknown controller, plant or scenario name, or an unusable bench option."""


@dataclass(frozen=True, eq=False, kw_only=True)
class BenchModels:
    """The models the benchmark builds its controllers and model plant from.

    Parameters
    ----------
    hammerstein :
        The noise-model Hammerstein (MPC, NMPC, PI tuning, open loop, model plant).
    linear :
        The linear ARMAX model (``kind = "linear"``) of the linear MPC.
    """

    hammerstein: HammersteinModel
    linear: HammersteinModel

    @classmethod
    def shipped(cls) -> BenchModels:
        """The shipped models `DEFAULT_MODEL_PATH` and `DEFAULT_LINEAR_MODEL_PATH`."""
        return cls(hammerstein=load_model(DEFAULT_MODEL_PATH),
                   linear=load_model(DEFAULT_LINEAR_MODEL_PATH))


@dataclass(frozen=True, eq=False, kw_only=True)
class BenchRun:
    """One (scenario, plant, controller) run.

    Parameters
    ----------
    scenario, plant, controller :
        Names.
    metrics :
        `sim.metrics.compute_metrics` of the run (true power).
    result :
        The recorded run.
    wall_time_s :
        Wall-clock time of the whole run (construction and loop) [s].
    """

    scenario: str
    plant: str
    controller: str
    metrics: ClosedLoopMetrics
    result: ClosedLoopResult = field(repr=False)
    wall_time_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class GoalCheck:
    """One goal of the benchmark on one (scenario, plant).

    Parameters
    ----------
    goal :
        What is checked.
    scenario, plant :
        Where.
    value :
        The measured ratio or difference.
    met :
        Whether the goal holds.
    detail :
        The numbers behind ``value``.
    """

    goal: str
    scenario: str
    plant: str
    value: float
    met: bool
    detail: str


def _check_names(kind: str, names: Sequence[str], allowed: Sequence[str]) -> tuple[str, ...]:
    out = tuple(names)
    unknown = [n for n in out if n not in allowed]
    if unknown or not out:
        raise BenchError(
            f"bench: expected {kind} among {', '.join(allowed)}; got {', '.join(out) or 'none'}"
        )
    return out


def build_plant(kind: str, model: HammersteinModel, scenario: Scenario) -> tuple[Plant, float]:
    """The plant of ``kind`` for ``scenario`` and the TRIAC input it starts at [%].

    ``"model"``: `ModelPlant.for_scenario`; ``"heater"``: `VirtualHeater` started in
    steady state at the input whose heater power is the initial setpoint (as
    `czmpc.campaigns.simulation`). The plant noise follows ``scenario.plant_noise``.

    Raises
    ------
    BenchError
        An unknown kind.
    """
    if kind == "model":
        plant = ModelPlant.for_scenario(model, scenario)
        return plant, plant.initial_triac_pct
    if kind == "heater":
        params = HeaterParams(ts_s=scenario.ts_s)
        if not scenario.plant_noise:
            params = replace(params, sensor_noise_std_kw=0.0, grid_wander_std=0.0)
        s0 = heater_steady_state_triac_pct(scenario.initial_setpoint_kw, params)
        return VirtualHeater(replace(params, initial_triac_pct=s0)), s0
    raise BenchError(f"bench: expected a plant among {', '.join(PLANTS)}; got {kind!r}")


def build_controller(
    name: str, models: BenchModels, scenario: Scenario, *, initial_triac_pct: float,
    settings_updates: Mapping[str, Any] | None = None, ipopt_tol: float | None = None,
    settings_doc: Mapping[str, object] | None = None,
) -> Controller:
    """Controller ``name`` (see `CONTROLLERS` and `OPTIONAL_CONTROLLERS`) set up for ``scenario``.

    Parameters
    ----------
    name :
        A key of `CONTROLLERS` or `OPTIONAL_CONTROLLERS`.
    models :
        The models.
    scenario :
        Supplies the TRIAC and rate limits.
    initial_triac_pct :
        The plant's start input [%] (clipped to the allowed range).
    settings_updates :
        Changes to the MPC settings (``mpc``, ``nmpc`` and ``linear_mpc``), e.g. a
        deliberately worse ``move_weight`` in a regression test.
    ipopt_tol :
        IPOPT tolerance of ``nmpc``; None: `czmpc.peers.nmpc.IPOPT_TOL`.
    settings_doc :
        A parsed settings file (`czmpc.settings_file`) applied to each model's own
        defaults before ``settings_updates``; None: `MPCSettings.default_for`.

    Raises
    ------
    BenchError
        An unknown name.
    """
    ham = models.hammerstein
    updates = dict(settings_updates or {})
    def base(model: HammersteinModel) -> MPCSettings:
        if settings_doc is None:
            return MPCSettings.default_for(model).with_updates(**updates)
        return settings_from_dict(settings_doc, model).with_updates(**updates)

    ham_settings = controller_settings(ham, scenario, initial_triac_pct=initial_triac_pct,
                                       settings=base(ham))
    if name == "mpc":
        return OffsetFreeMPC(ham, ham_settings)
    if name == "nmpc":
        if ipopt_tol is None:
            return NonlinearMPC(ham, ham_settings)
        return NonlinearMPC(ham, ham_settings, ipopt_tol=ipopt_tol)
    if name == "linear_mpc":
        lin = models.linear
        return OffsetFreeMPC(lin, controller_settings(lin, scenario,
                                                      initial_triac_pct=initial_triac_pct,
                                                      settings=base(lin)))
    lo, hi = OffsetFreeMPC(ham, ham_settings).allowed_triac_range_pct
    s0 = ham_settings.initial_triac_pct
    if name in ("pi", "pi_gs"):
        return PIController.tuned_for(
            ham, gain_scheduled=name == "pi_gs", initial_triac_pct=s0, triac_limits_pct=(lo, hi),
            max_move_pct_per_step=ham_settings.max_move_pct_per_step,
            validity_margin_pct=ham_settings.validity_margin_pct,
        )
    if name == "pi_table":
        schedule = tune_schedule(ham, DesignSpec(ms=PI_TABLE_MS), triac_range_pct=(lo, hi))
        return ScheduledPID(schedule=schedule.table_schedule(), ts_s=ham.ts_s,
                            initial_triac_pct=min(hi, max(lo, initial_triac_pct)),
                            triac_limits_pct=(lo, hi),
                            max_move_pct_per_step=ham_settings.max_move_pct_per_step)
    if name == "open_loop":
        return OpenLoopInversion(ham, initial_triac_pct=s0, triac_limits_pct=(lo, hi),
                                 validity_margin_pct=ham_settings.validity_margin_pct,
                                 max_move_pct_per_step=ham_settings.max_move_pct_per_step)
    raise BenchError(f"bench: expected a controller among "
                     f"{', '.join([*CONTROLLERS, *OPTIONAL_CONTROLLERS])}; got {name!r}")


def run_case(
    scenario: Scenario, plant: str, controller: str, models: BenchModels, *,
    seed: int = BENCH_SEED, settings_updates: Mapping[str, Any] | None = None,
    ipopt_tol: float | None = None, settings_doc: Mapping[str, object] | None = None,
) -> BenchRun:
    """Run one (scenario, plant, controller) case and compute its metrics.

    Parameters
    ----------
    scenario :
        The scenario (already shortened if wanted).
    plant, controller :
        Keys of `PLANTS` and `CONTROLLERS`.
    models :
        The models.
    seed :
        Seed of the run.
    settings_updates, ipopt_tol, settings_doc :
        See `build_controller`.
    """
    t0 = time.perf_counter()
    the_plant, s0 = build_plant(plant, models.hammerstein, scenario)
    ctrl = build_controller(controller, models, scenario, initial_triac_pct=s0,
                            settings_updates=settings_updates, ipopt_tol=ipopt_tol,
                            settings_doc=settings_doc)
    result = run_closed_loop(the_plant, ctrl, scenario, rng=seed)
    metrics = compute_metrics(result)
    return BenchRun(scenario=scenario.name, plant=plant, controller=controller,
                    metrics=metrics, result=result, wall_time_s=time.perf_counter() - t0)


#: Rough cost of one sample per controller relative to the MPC, for the first ETA only
#: (measured times replace it as soon as a controller has run).
_COST_GUESS = {"nmpc": 20.0}


def run_bench(
    scenarios: Sequence[Scenario], *, controllers: Sequence[str] = tuple(CONTROLLERS),
    plants: Sequence[str] = tuple(PLANTS), models: BenchModels | None = None,
    seed: int = BENCH_SEED, progress: BenchProgress | None = None,
    settings_doc: Mapping[str, object] | None = None,
) -> tuple[BenchRun, ...]:
    """Run every controller on every scenario and plant.

    Parameters
    ----------
    scenarios :
        The scenarios (shortened or not).
    controllers, plants :
        Names (keys of `CONTROLLERS`, `PLANTS`).
    models :
        None: `BenchModels.shipped`.
    seed :
        Seed of every run.
    progress :
        Called with one line per run (which run, elapsed, ETA).
    settings_doc :
        A parsed settings file for the MPC controllers (see `build_controller`).

    Raises
    ------
    BenchError
        Unknown names or no scenario.
    """
    controllers = _check_names("controllers", controllers, tuple(CONTROLLERS))
    plants = _check_names("plants", plants, tuple(PLANTS))
    if not scenarios:
        raise BenchError("bench: expected at least one scenario; got none")
    models = BenchModels.shipped() if models is None else models
    cases = [(sc, p, c) for sc in scenarios for p in plants for c in controllers]
    per_sample: dict[str, list[float]] = {}
    runs: list[BenchRun] = []
    start = time.perf_counter()
    for i, (sc, p, c) in enumerate(cases, start=1):
        elapsed = time.perf_counter() - start
        if progress is not None:
            eta = _eta(cases[i - 1:], per_sample)
            eta_text = "unknown" if math.isnan(eta) else f"{eta:.0f} s"
            progress(f"[{i}/{len(cases)}] {sc.name} / {p} / {c} ({sc.n_steps} samples); "
                     f"elapsed {elapsed:.1f} s, ETA {eta_text}")
        run = run_case(sc, p, c, models, seed=seed, settings_doc=settings_doc)
        per_sample.setdefault(c, []).append(run.wall_time_s / sc.n_steps)
        runs.append(run)
    if progress is not None:
        progress(f"done: {len(cases)} runs in {time.perf_counter() - start:.1f} s")
    return tuple(runs)


def _eta(remaining: Sequence[tuple[Scenario, str, str]],
         per_sample: Mapping[str, list[float]]) -> float:
    """Seconds left: measured time per sample of each controller, else a scaled guess."""
    if not per_sample:
        return math.nan
    base = float(np.median([np.mean(v) / _COST_GUESS.get(c, 1.0)
                            for c, v in per_sample.items()]))
    total = 0.0
    for sc, _, c in remaining:
        rate = float(np.mean(per_sample[c])) if c in per_sample else base * _COST_GUESS.get(c, 1.0)
        total += rate * sc.n_steps
    return total


# --- summaries ------------------------------------------------------------------------
def _max_or_nan(values: Sequence[float | None]) -> float:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return max(finite) if finite else math.nan


def run_row(run: BenchRun, *, seed: int = BENCH_SEED) -> dict[str, Any]:
    """One bench.csv row (`CSV_COLUMNS`) of ``run``."""
    m = run.metrics
    settling = [c.settling_time_s for c in m.changes]
    return {
        "scenario": run.scenario, "plant": run.plant, "controller": run.controller,
        "n_steps": run.result.n_steps, "seed": seed, "iae_kw_s": m.iae_kw_s,
        "ise_kw2_s": m.ise_kw2_s,
        "max_overshoot_kw": _max_or_nan([c.overshoot_kw for c in m.changes]),
        "max_overshoot_pct": _max_or_nan([c.overshoot_pct for c in m.changes]),
        "max_settling_time_s": _max_or_nan(settling),
        "n_not_settled": sum(1 for s in settling if s is None),
        "max_abs_steady_state_error_kw": m.max_abs_steady_state_error_kw,
        "input_total_variation_pct": m.input_total_variation_pct,
        "n_limit_violations": m.n_limit_violations, "n_rate_violations": m.n_rate_violations,
        "n_solver_failures": m.n_solver_failures if m.n_solver_failures is not None else 0,
        "step_time_median_ms": m.step_time_median_ms, "step_time_p95_ms": m.step_time_p95_ms,
        "step_time_max_ms": m.step_time_max_ms, "run_wall_time_s": run.wall_time_s,
    }


def write_csv(runs: Sequence[BenchRun], path: str | Path, *, seed: int = BENCH_SEED) -> None:
    """Write bench.csv: one row per run, `CSV_COLUMNS` (NaN written as ``nan``)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for run in runs:
        writer.writerow({k: (repr(v) if isinstance(v, float) else v)
                         for k, v in run_row(run, seed=seed).items()})
    atomic_write_text(path, buf.getvalue())


def _find(runs: Sequence[BenchRun], scenario: str, plant: str, controller: str) -> BenchRun | None:
    for r in runs:
        if (r.scenario, r.plant, r.controller) == (scenario, plant, controller):
            return r
    return None


def _base_name(scenario: str) -> str:
    return scenario.removesuffix("-short")


def check_goals(runs: Sequence[BenchRun]) -> tuple[GoalCheck, ...]:
    """The issue's goals on every (scenario, plant) whose controllers were run.

    * MPC IAE within `IAE_MATCH_FRACTION` of the NMPC's;
    * NMPC median step time at least `STEP_TIME_RATIO_GOAL` times the MPC's;
    * MPC IAE below the linear MPC's on `NONLINEAR_SCENARIOS`;
    * MPC IAE below the gain-scheduled PI's everywhere.
    """
    out: list[GoalCheck] = []
    pairs = list(dict.fromkeys((r.scenario, r.plant) for r in runs))
    for sc, p in pairs:
        mpc = _find(runs, sc, p, "mpc")
        if mpc is None:
            continue
        iae = mpc.metrics.iae_kw_s
        nmpc = _find(runs, sc, p, "nmpc")
        if nmpc is not None:
            ref = nmpc.metrics.iae_kw_s
            rel = (iae - ref) / ref
            out.append(GoalCheck(
                goal=f"MPC IAE within {100 * IAE_MATCH_FRACTION:g} % of NMPC", scenario=sc,
                plant=p, value=rel, met=abs(rel) <= IAE_MATCH_FRACTION,
                detail=f"{iae:.4g} vs {ref:.4g} kW s ({100 * rel:+.3f} %)"))
            ratio = nmpc.metrics.step_time_median_ms / mpc.metrics.step_time_median_ms
            out.append(GoalCheck(
                goal=f"MPC median step time >= {STEP_TIME_RATIO_GOAL:g}x lower than NMPC",
                scenario=sc, plant=p, value=ratio, met=ratio >= STEP_TIME_RATIO_GOAL,
                detail=(f"{mpc.metrics.step_time_median_ms:.3f} vs "
                        f"{nmpc.metrics.step_time_median_ms:.3f} ms ({ratio:.0f}x)")))
        lin = _find(runs, sc, p, "linear_mpc")
        if lin is not None and _base_name(sc) in NONLINEAR_SCENARIOS:
            other = lin.metrics.iae_kw_s
            out.append(GoalCheck(
                goal="MPC IAE below linear MPC", scenario=sc, plant=p, value=iae / other,
                met=iae < other, detail=f"{iae:.4g} vs {other:.4g} kW s ({iae / other:.3f}x)"))
        pi = _find(runs, sc, p, "pi_gs")
        if pi is not None:
            other = pi.metrics.iae_kw_s
            out.append(GoalCheck(
                goal="MPC IAE below gain-scheduled PI", scenario=sc, plant=p,
                value=iae / other, met=iae < other,
                detail=f"{iae:.4g} vs {other:.4g} kW s ({iae / other:.3f}x)"))
    return tuple(out)


def _fmt(value: float, spec: str) -> str:
    return "n/a" if not math.isfinite(value) else format(value, spec)


def format_markdown(runs: Sequence[BenchRun], goals: Sequence[GoalCheck], *,
                    header: str = "") -> str:
    """bench.md: the metrics table (one row per run) and the goals table."""
    lines = [header.rstrip(), ""] if header else []
    lines += [
        "| scenario | plant | controller | IAE [kW s] | ISE [kW² s] | overshoot [kW] | "
        "settling [s] | ss error [kW] | input TV [%] | violations | failures | "
        "step median / p95 / max [ms] |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for run in runs:
        row = run_row(run)
        settle = _fmt(row["max_settling_time_s"], ".0f")
        if row["n_not_settled"]:
            settle += f" ({row['n_not_settled']} not settled)"
        lines.append(
            f"| {run.scenario} | {run.plant} | {run.controller} | {_fmt(row['iae_kw_s'], '.1f')} | "
            f"{_fmt(row['ise_kw2_s'], '.1f')} | {_fmt(row['max_overshoot_kw'], '.3f')} | "
            f"{settle} | {_fmt(row['max_abs_steady_state_error_kw'], '.4f')} | "
            f"{_fmt(row['input_total_variation_pct'], '.1f')} | "
            f"{row['n_limit_violations'] + row['n_rate_violations']} | "
            f"{row['n_solver_failures']} | {row['step_time_median_ms']:.3f} / "
            f"{row['step_time_p95_ms']:.3f} / {row['step_time_max_ms']:.2f} |")
    if goals:
        lines += ["", "| goal | scenario | plant | measured | met |", "|---|---|---|---|---|"]
        for g in goals:
            lines.append(f"| {g.goal} | {g.scenario} | {g.plant} | {g.detail} | "
                         f"{'yes' if g.met else '**NO**'} |")
    return "\n".join(lines) + "\n"


#: Heading of this benchmark's section in BENCHMARKS.md.
SECTION_HEADING = "## Setpoint-tracking benchmark"

#: How to read the goals (facts of the design, true whatever the numbers).
READING_NOTES = (
    "IAE is of the true (noise-free) power against the setpoint over the whole run, so a "
    "setpoint no allowed input can hold (large_step's 80 kW lies above the steady power "
    "of the allowed range's top, 70 %) counts against every controller; the MPCs then "
    "aim at the reachable steady state (DESIGN.md item 4: the target is clipped, not "
    "chased), while the PIs and the open loop sit at the input limit, which passes "
    "through more power while the element heats. Step times are wall-clock times of "
    "one controller call on a shared 2-core machine."
)


def _pivot(runs: Sequence[BenchRun], plant: str, key: str, spec: str) -> list[str]:
    scenarios = list(dict.fromkeys(r.scenario for r in runs if r.plant == plant))
    controllers = list(dict.fromkeys(r.controller for r in runs if r.plant == plant))
    lines = ["| scenario | " + " | ".join(controllers) + " |",
             "|---|" + "---:|" * len(controllers)]
    for sc in scenarios:
        cells = []
        for c in controllers:
            run = _find(runs, sc, plant, c)
            cells.append("-" if run is None else _fmt(float(run_row(run)[key]), spec))
        lines.append(f"| {sc} | " + " | ".join(cells) + " |")
    return lines


def section_text(runs: Sequence[BenchRun], goals: Sequence[GoalCheck], *, command: str,
                 machine: str, wall_time_s: float, short_factor: float | None = None) -> str:
    """The BENCHMARKS.md section body: command, machine, IAE and step-time tables, goals."""
    n_samples = sum(r.result.n_steps for r in runs)
    lines = [
        f"Command: `{command}`",
        "",
        f"Machine: {machine}",
        "",
        f"{len(runs)} runs ({n_samples} controller steps) in {wall_time_s:.1f} s wall time"
        + (f"; scenarios shortened x {short_factor:g}" if short_factor is not None else "")
        + f"; seed {BENCH_SEED} for every run.",
        "",
        READING_NOTES,
    ]
    for plant in dict.fromkeys(r.plant for r in runs):
        lines += ["", f"IAE [kW s] on the {plant} plant ({PLANTS[plant]}):", ""]
        lines += _pivot(runs, plant, "iae_kw_s", ".1f")
        lines += ["", f"Median step time [ms] on the {plant} plant:", ""]
        lines += _pivot(runs, plant, "step_time_median_ms", ".3f")
    if goals:
        n_met = sum(g.met for g in goals)
        lines += ["", f"Goals: {n_met} of {len(goals)} met.", "",
                  "| goal | scenario | plant | measured | met |", "|---|---|---|---|---|"]
        lines += [f"| {g.goal} | {g.scenario} | {g.plant} | {g.detail} | "
                  f"{'yes' if g.met else '**NO**'} |" for g in goals]
    return "\n".join(lines) + "\n"


def write_benchmarks_section(path: str | Path, body: str, *,
                             heading: str = SECTION_HEADING) -> None:
    """Put ``body`` under ``heading`` (default: this benchmark's) in a BENCHMARKS.md."""
    _write_section(path, body, heading=heading)


def plot_scenario(runs: Sequence[BenchRun], path: str | Path) -> None:
    """One figure per scenario: power (with setpoint) and TRIAC input of every controller,
    one column per plant, shared axes, units on the axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    plants = list(dict.fromkeys(r.plant for r in runs))
    controllers = list(dict.fromkeys(r.controller for r in runs))
    palette = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")
    fig = Figure(figsize=(6.0 * len(plants), 6.5), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, len(plants), sharex=True, sharey="row", squeeze=False)
    for col, plant in enumerate(plants):
        ax_p, ax_s = axes[0, col], axes[1, col]
        first = True
        for i, ctrl in enumerate(controllers):
            run = _find(runs, runs[0].scenario, plant, ctrl)
            if run is None:
                continue
            res = run.result
            t_min = res.time_s / 60.0
            if first:
                ax_p.plot(t_min, res.setpoint_kw, color="black", linestyle="--", linewidth=1.0,
                          label="setpoint")
                first = False
            ax_p.plot(t_min, res.power_true_kw, color=palette[i % len(palette)], linewidth=1.0,
                      label=ctrl)
            ax_s.step(t_min, res.triac_pct, where="post", color=palette[i % len(palette)],
                      linewidth=1.0, label=ctrl)
        ax_p.set_title(f"{runs[0].scenario} on {plant}", fontsize="medium")
        ax_s.set_xlabel("time [min]")
        for ax in (ax_p, ax_s):
            ax.grid(True, linewidth=0.5, alpha=0.6)
    axes[0, 0].set_ylabel("true power P [kW]")
    axes[1, 0].set_ylabel("TRIAC input s [%]")
    axes[0, 0].legend(loc="best", fontsize="small", ncols=2)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")


def write_outputs(runs: Sequence[BenchRun], goals: Sequence[GoalCheck], out_dir: str | Path,
                  *, header: str = "", seed: int = BENCH_SEED) -> tuple[Path, ...]:
    """Write DIR/bench.md, DIR/bench.csv and DIR/figures/<scenario>.png; return the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    md = out / "bench.md"
    atomic_write_text(md, format_markdown(runs, goals, header=header + "\nAll runs:\n"))
    csv_path = out / "bench.csv"
    write_csv(runs, csv_path, seed=seed)
    paths = [md, csv_path]
    for sc in dict.fromkeys(r.scenario for r in runs):
        fig_path = out / "figures" / f"{sc}.png"
        plot_scenario([r for r in runs if r.scenario == sc], fig_path)
        paths.append(fig_path)
    return tuple(paths)


__all__ = [
    "BENCH_SEED",
    "CONTROLLERS",
    "CSV_COLUMNS",
    "DEFAULT_LINEAR_MODEL_PATH",
    "DEFAULT_MODEL_PATH",
    "IAE_MATCH_FRACTION",
    "NONLINEAR_SCENARIOS",
    "PLANTS",
    "READING_NOTES",
    "SECTION_HEADING",
    "STEP_TIME_RATIO_GOAL",
    "BenchError",
    "BenchModels",
    "BenchRun",
    "GoalCheck",
    "build_controller",
    "build_plant",
    "check_goals",
    "format_markdown",
    "plot_scenario",
    "run_bench",
    "run_case",
    "run_row",
    "section_text",
    "write_benchmarks_section",
    "write_csv",
    "write_outputs",
]
