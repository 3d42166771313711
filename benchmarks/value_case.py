"""Value-case benchmark (issue 40, item 3): MPC with recipe preview and measured voltage vs PI.

On both plants (``model``: the model's own equation; ``heater``: the virtual heater's
grey-box physics), with plant noise on and off, every shipped scenario and the recipe
scenarios of ``benchmarks/scenarios/`` run four controllers, one seed for every run:

* ``mpc_today``: the offset-free MPC as shipped (no preview, no voltage);
* ``mpc_preview``: the same MPC told the recipe `PREVIEW_S` ahead and given the measured
  grid voltage (the scenario with ``setpoint_preview_s`` and ``measured_voltage``);
* ``pi_scheduled``: the gain-scheduled PI ``czmpc tune-pid --rule ms --ms 1.4`` writes for
  the shipped model, run as ``czmpc simulate --controller`` runs it
  (`czmpc.campaigns.pid_comparison.compare_pid_table`: the MPC's limits, rate limit, start
  input, and the same voltage compensation; a PI has no use for the preview);
* ``pi_fixed``: that table's row at the operating point, everywhere.

Metrics (`sim.metrics`, of the true power): IAE [kW s], the worst overshoot of a setpoint
change [% of the change], input travel ``sum |ds|`` [%], each also as a ratio to
``mpc_preview``'s. On the model plant without noise, `benchmarks.iae_bound` gives a lower
bound on any controller's IAE (an LP over the model knowing the whole recipe and every
disturbance), and the MPC with preview is compared with it.

Writes ``runs.csv``, ``bounds.csv``, ``pid/`` (tune-pid's output) and ``figure.png``
(staircase and ramp recipe on the heater with noise: power [kW] and TRIAC [%] against
time [s], the four controllers) into ``--out``, prints the section and records it in
BENCHMARKS.md under `SECTION_HEADING`.

    python -m benchmarks.value_case --out out/bench/value [--scenarios A,B] [--plants model,heater]
                                    [--short X] [--seed N] [--benchmarks-md FILE] [--no-record]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import math
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

from benchmarks._md import (
    BENCHMARKS_MD,
    benchmark_parser,
    machine_info,
    run_main,
    write_benchmarks_section,
)
from benchmarks.iae_bound import scenario_iae_bound
from czmpc.campaigns.pid_comparison import compare_pid_table
from czmpc.campaigns.simulation import PlantKind, SimulationOutcome, run_simulation
from czmpc.pid.controller import TableSchedule
from czmpc.pid.table import read_pid_table
from czmpc.settings import MPCSettings
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sim.loop import ClosedLoopResult
from sim.metrics import ClosedLoopMetrics
from sim.scenario import Scenario, list_scenarios, load_scenario
from sysid.model import HammersteinModel
from sysid.modelfile import load_model

#: Heading of this benchmark's section in BENCHMARKS.md.
SECTION_HEADING = "## Value case: MPC with recipe preview and measured voltage against the PI"
#: How far ahead the MPC with preview is told the recipe [s].
PREVIEW_S = 60.0
#: The PI's tuning: ``czmpc tune-pid --rule ms --ms <PID_MS>`` on the shipped model.
PID_MS = 1.4
#: The controllers, in report order; ratios are to `REFERENCE`.
CONTROLLERS = ("mpc_today", "mpc_preview", "pi_scheduled", "pi_fixed")
REFERENCE = "mpc_preview"
#: What each controller is, for the section.
CONTROLLER_NOTES = {
    "mpc_today": "offset-free MPC as shipped: no preview, no voltage",
    "mpc_preview": f"the same MPC, recipe known {PREVIEW_S:g} s ahead, grid voltage measured",
    "pi_scheduled": f"gain-scheduled PI of `czmpc tune-pid --rule ms --ms {PID_MS:g}`, "
                    "voltage compensated as the MPC",
    "pi_fixed": "that table's row at the operating point everywhere, voltage compensated",
}
PLANTS: tuple[PlantKind, ...] = ("model", "heater")
#: The recipe scenarios of this benchmark (beside the shipped ones).
RECIPE_DIR = Path(__file__).resolve().parent / "scenarios"
#: Seed of every run (as the tracking benchmark's).
DEFAULT_SEED = 7
#: Weights of the "sharp" MPC beside the bound: moves and input-target nearly free (the
#: defaults are 0.1 and 0.01), so its IAE shows what the bound asks of this controller.
SHARP_WEIGHTS = {"move_weight": 1e-3, "input_target_weight": 1e-6}
#: Goals of issue 40 (the controller's to meet; measured here).
STAIRCASE_RATIO_GOAL = 0.6
RAMP_RATIO_GOAL = 0.35
SAG_RATIO_GOAL = 0.6
#: The shipped MPC's IAE on the noise-free voltage_sag before issue 40 [kW s], per plant:
#: the "today's MPC" of the issue's goal. Measured with the code of 317d35c's behaviour on
#: this scenario (heater: `czmpc simulate --plant heater --no-noise`; model plant: this
#: benchmark's first run, at 24bd167). The MPC without a voltage reading has since become
#: faster on the sag (it takes the level change at once), so both references are checked.
MPC_BEFORE_ISSUE_40_SAG_KW_S = {"heater": 23.78, "model": 26.56}
BOUND_RATIO_GOAL = 1.15
#: How to read the section (facts of the method, true whatever the numbers).
READING_NOTES = (
    "IAE, overshoot and input travel are of the plant's true power (`sim.metrics`); a "
    "ratio is the controller's value over the MPC-with-preview's ('-': the MPC's is 0 or "
    "the scenario has no setpoint change). Overshoot is the worst of the run's setpoint "
    "changes, in % of that change: a controller told the recipe ahead starts the next step "
    "early, so its power passes the old setpoint before the next change, which counts as "
    "overshoot of the previous one (the MPC with preview's 30 % on the staircases is that, "
    "not a swing past the new setpoint). The LP bound (`benchmarks/iae_bound.py`) is the least "
    "IAE any controller can reach on the noise-free model plant: it knows the whole recipe "
    "(so it also bounds every finite preview) and every disturbance in advance, and relaxes "
    "the TRIAC rate limit by tangents of f (`rate_limit_cuts`); its goal is checked on "
    "scenarios with setpoint changes and no process disturbance. A ramp slower than the "
    "rate limit can be tracked exactly, so its bound is near 0 and its ratio measures "
    "residues of a few W. The 'sharp MPC' is the MPC with preview with move and "
    "input-target weights near 0 (`SHARP_WEIGHTS`): it shows that the bound is reachable "
    "by this controller's structure, and what the default weights cost. A setpoint above "
    "what the allowed input range holds (large_step's 80 kW) or a start below it (meltdown_ramp) "
    "costs every controller and the bound alike."
)


@dataclass(frozen=True, kw_only=True)
class RunRow:
    """One controller's run on one scenario, plant and noise setting.

    Parameters
    ----------
    scenario, plant, noise, controller :
        What ran.
    iae_kw_s :
        IAE of the true power [kW s].
    overshoot_pct :
        Worst overshoot of a setpoint change [% of the change] (NaN: no change).
    input_travel_pct :
        ``sum |s_k - s_{k-1}|`` [%].
    wall_s :
        Wall time of the run [s].
    result :
        The recorded run (for the figure).
    """

    scenario: str
    plant: str
    noise: bool
    controller: str
    iae_kw_s: float
    overshoot_pct: float
    input_travel_pct: float
    wall_s: float
    result: ClosedLoopResult


@dataclass(frozen=True, kw_only=True)
class BoundRow:
    """The LP bound of one scenario against the MPC with preview (model plant, no noise).

    Parameters
    ----------
    scenario :
        Its name.
    bound_iae_kw_s :
        The bound, rate limit relaxed by tangents [kW s].
    bound_max_slope_iae_kw_s :
        The looser bound, rate limit relaxed by ``max|f'| delta`` [kW s].
    solve_time_s :
        Wall time of the tangent LP [s].
    mpc_iae_kw_s :
        The MPC with preview's IAE on the model plant without noise [kW s] (NaN: not run).
    has_disturbance :
        The scenario has process disturbances (the goal is not checked on it).
    sharp_mpc_iae_kw_s :
        IAE of the same MPC and preview with `SHARP_WEIGHTS` (model plant, no noise) [kW s]:
        how close a controller of this structure can come to the bound (NaN: not run).
    """

    scenario: str
    bound_iae_kw_s: float
    bound_max_slope_iae_kw_s: float
    solve_time_s: float
    mpc_iae_kw_s: float
    has_disturbance: bool
    sharp_mpc_iae_kw_s: float = math.nan

    @property
    def ratio(self) -> float:
        """MPC's IAE over the bound [-]."""
        return _ratio(self.mpc_iae_kw_s, self.bound_iae_kw_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class GoalCheck:
    """One goal of issue 40: what, where, the measured ratio, met or not."""

    goal: str
    where: str
    value: float
    limit: float
    met: bool
    detail: str


def _ratio(value: float, reference: float) -> float:
    return value / reference if math.isfinite(reference) and reference > 0 else math.nan


def worst_overshoot_pct(metrics: ClosedLoopMetrics) -> float:
    """Largest overshoot of the run's setpoint changes [% of the change]; NaN without one."""
    values = [c.overshoot_pct for c in metrics.changes if math.isfinite(c.overshoot_pct)]
    return max(values, default=math.nan)


def recipe_scenarios() -> tuple[Scenario, ...]:
    """The recipe scenarios of ``benchmarks/scenarios/``, by file name."""
    return tuple(load_scenario(p) for p in sorted(RECIPE_DIR.glob("*.toml")))


def all_scenarios(names: Sequence[str] | None = None, short: float | None = None
                  ) -> tuple[Scenario, ...]:
    """Shipped then recipe scenarios (only ``names`` if given), shortened by ``short``.

    Raises
    ------
    ValueError
        A name that is neither shipped nor a recipe.
    """
    found = {s: load_scenario(s) for s in list_scenarios()}
    found.update({s.name: s for s in recipe_scenarios()})
    if names is not None:
        unknown = [n for n in names if n not in found]
        if unknown:
            raise ValueError(f"value_case: unknown scenario(s) {', '.join(unknown)}; expected "
                             f"among {', '.join(found)}")
        found = {n: found[n] for n in names}
    out = tuple(found.values())
    return out if short is None or short >= 1.0 else tuple(s.shortened(short) for s in out)


def with_preview(scenario: Scenario) -> Scenario:
    """``scenario`` with the recipe known `PREVIEW_S` ahead and the voltage measured."""
    return replace(scenario, setpoint_preview_s=PREVIEW_S, measured_voltage=True)


def tune_pid_table(model_path: Path, out_dir: Path) -> TableSchedule:
    """Run ``czmpc tune-pid MODEL --rule ms --ms PID_MS --out out_dir``; read its table.

    Raises
    ------
    RuntimeError
        tune-pid exits non-zero (its output is in the message).
    """
    from czmpc.cli import main as czmpc_main

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
        code = czmpc_main(["tune-pid", str(model_path), "--rule", "ms", "--ms", f"{PID_MS:g}",
                           "--out", str(out_dir)])
    if code != 0:
        raise RuntimeError(f"value_case: czmpc tune-pid exited {code}:\n{buffer.getvalue()}")
    return read_pid_table(out_dir / "pid_table.csv").schedule


def _row(outcome: SimulationOutcome, controller: str, wall_s: float) -> RunRow:
    m = outcome.metrics
    return RunRow(scenario=outcome.scenario.name, plant=outcome.plant, noise=outcome.noise,
                  controller=controller, iae_kw_s=m.iae_kw_s, overshoot_pct=worst_overshoot_pct(m),
                  input_travel_pct=m.input_total_variation_pct, wall_s=wall_s,
                  result=outcome.result)


def run_case(model: HammersteinModel, schedule: TableSchedule, scenario: Scenario, *,
             plant: PlantKind, noise: bool, seed: int) -> tuple[RunRow, ...]:
    """The four controllers (`CONTROLLERS`) on one scenario, plant and noise setting."""
    t0 = time.perf_counter()
    today = run_simulation(model, scenario, plant=plant, seed=seed, noise=noise)
    t1 = time.perf_counter()
    compared = compare_pid_table(model, schedule, with_preview(scenario), plant=plant, seed=seed,
                                 noise=noise)
    share = (time.perf_counter() - t1) / len(compared)
    names = {"mpc": "mpc_preview", "pi_table": "pi_scheduled", "pi_fixed": "pi_fixed"}
    rows = [_row(today, "mpc_today", t1 - t0)]
    rows += [_row(s.outcome, names[s.name], share) for s in compared]
    return tuple(sorted(rows, key=lambda r: CONTROLLERS.index(r.controller)))


def _find(rows: Iterable[RunRow], scenario: str, plant: str, noise: bool, controller: str
          ) -> RunRow | None:
    return next((r for r in rows if (r.scenario, r.plant, r.noise, r.controller)
                 == (scenario, plant, noise, controller)), None)


def _ratio_goal(goal: str, where: str, value: float, reference: float, limit: float,
                unit: str = "kW s") -> GoalCheck:
    ratio = _ratio(value, reference)
    return GoalCheck(goal=goal, where=where, value=ratio, limit=limit,
                     met=math.isfinite(ratio) and ratio <= limit,
                     detail=f"{value:.4g} vs {reference:.4g} {unit} ({ratio:.3f}x)")


def check_goals(rows: Sequence[RunRow], bounds: Sequence[BoundRow],
                shipped: Sequence[str]) -> tuple[GoalCheck, ...]:
    """The Done-when items of issue 40 this benchmark measures, where their runs exist."""
    out: list[GoalCheck] = []
    for sc, limit in (("staircase", STAIRCASE_RATIO_GOAL), ("ramp_recipe", RAMP_RATIO_GOAL)):
        mpc, pi = (_find(rows, sc, "heater", True, c) for c in ("mpc_preview", "pi_scheduled"))
        if mpc and pi:
            out.append(_ratio_goal(f"MPC IAE <= {limit:g} x scheduled PI's", f"{sc}, heater, noise on",
                                   mpc.iae_kw_s, pi.iae_kw_s, limit))
    for sc in shipped:
        mpc, pi = (_find(rows, sc, "heater", True, c) for c in ("mpc_preview", "pi_scheduled"))
        if mpc and pi:
            out.append(_ratio_goal("MPC IAE <= scheduled PI's (same voltage compensation)",
                                   f"{sc}, heater, noise on", mpc.iae_kw_s, pi.iae_kw_s, 1.0))
    for plant in PLANTS:
        new, old = (_find(rows, "voltage_sag", plant, False, c) for c in ("mpc_preview", "mpc_today"))
        if new:
            out.append(_ratio_goal(
                f"MPC with measured voltage <= {SAG_RATIO_GOAL:g} x the MPC before issue 40",
                f"voltage_sag, {plant}, noise off", new.iae_kw_s,
                MPC_BEFORE_ISSUE_40_SAG_KW_S[plant], SAG_RATIO_GOAL))
        if new and old:
            out.append(_ratio_goal(f"MPC with measured voltage <= {SAG_RATIO_GOAL:g} x today's MPC",
                                   f"voltage_sag, {plant}, noise off", new.iae_kw_s, old.iae_kw_s,
                                   SAG_RATIO_GOAL))
    for b in bounds:
        if not b.has_disturbance and math.isfinite(b.mpc_iae_kw_s):
            out.append(_ratio_goal(f"MPC with preview <= {BOUND_RATIO_GOAL:g} x LP bound",
                                   f"{b.scenario}, model, noise off", b.mpc_iae_kw_s,
                                   b.bound_iae_kw_s, BOUND_RATIO_GOAL))
    return tuple(out)


def compute_bounds(model: HammersteinModel, scenarios: Sequence[Scenario],
                   rows: Sequence[RunRow], *, seed: int | None = None) -> tuple[BoundRow, ...]:
    """The LP bound of every scenario, beside the MPC with preview (model, noise off).

    With a ``seed``, the MPC with preview and `SHARP_WEIGHTS` also runs on each scenario
    (model plant, no noise): the bound's distance from what this controller can reach.
    """
    out = []
    sharp = MPCSettings.default_for(model).with_updates(**SHARP_WEIGHTS)
    for sc in scenarios:
        tight = scenario_iae_bound(model, sc, relaxation="tangents")
        loose = scenario_iae_bound(model, sc, relaxation="max_slope")
        mpc = _find(rows, sc.name, "model", False, REFERENCE)
        sharp_iae = math.nan if seed is None else run_simulation(
            model, with_preview(sc), plant="model", seed=seed, noise=False,
            settings=sharp).metrics.iae_kw_s
        out.append(BoundRow(scenario=sc.name, bound_iae_kw_s=tight.iae_kw_s,
                            bound_max_slope_iae_kw_s=loose.iae_kw_s, solve_time_s=tight.solve_time_s,
                            mpc_iae_kw_s=math.nan if mpc is None else mpc.iae_kw_s,
                            has_disturbance=bool(sc.disturbances), sharp_mpc_iae_kw_s=sharp_iae))
    return tuple(out)


# --- outputs --------------------------------------------------------------------------------
RUN_COLUMNS = ("scenario", "plant", "noise", "controller", "iae_kw_s", "iae_ratio",
               "overshoot_pct", "overshoot_ratio", "input_travel_pct", "input_travel_ratio",
               "wall_s")
BOUND_COLUMNS = ("scenario", "bound_iae_kw_s", "bound_max_slope_iae_kw_s", "solve_time_s",
                 "mpc_preview_iae_kw_s", "mpc_to_bound_ratio", "has_disturbance",
                 "sharp_mpc_preview_iae_kw_s")


def _ratios(row: RunRow, rows: Sequence[RunRow]) -> tuple[float, float, float]:
    ref = _find(rows, row.scenario, row.plant, row.noise, REFERENCE)
    if ref is None:
        return math.nan, math.nan, math.nan
    return (_ratio(row.iae_kw_s, ref.iae_kw_s), _ratio(row.overshoot_pct, ref.overshoot_pct),
            _ratio(row.input_travel_pct, ref.input_travel_pct))


def write_csvs(rows: Sequence[RunRow], bounds: Sequence[BoundRow], out_dir: Path) -> tuple[Path, Path]:
    """``runs.csv`` (`RUN_COLUMNS`) and ``bounds.csv`` (`BOUND_COLUMNS`) into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    runs, bnds = out_dir / "runs.csv", out_dir / "bounds.csv"
    with runs.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(RUN_COLUMNS)
        for r in rows:
            iae_r, over_r, travel_r = _ratios(r, rows)
            writer.writerow([r.scenario, r.plant, int(r.noise), r.controller, repr(r.iae_kw_s),
                             repr(iae_r), repr(r.overshoot_pct), repr(over_r),
                             repr(r.input_travel_pct), repr(travel_r), f"{r.wall_s:.3f}"])
    with bnds.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(BOUND_COLUMNS)
        for b in bounds:
            writer.writerow([b.scenario, repr(b.bound_iae_kw_s), repr(b.bound_max_slope_iae_kw_s),
                             f"{b.solve_time_s:.3f}", repr(b.mpc_iae_kw_s), repr(b.ratio),
                             int(b.has_disturbance), repr(b.sharp_mpc_iae_kw_s)])
    return runs, bnds


def plot_recipes(rows: Sequence[RunRow], path: Path, *, scenarios: Sequence[str] = (
        "staircase", "ramp_recipe"), plant: str = "heater", noise: bool = True) -> Path | None:
    """Power [kW], its error [kW] and TRIAC [%] against time [s] of the four controllers.

    Returns None (and writes nothing) when none of ``scenarios`` ran on ``plant``.
    """
    from czmpc.reports.figure_style import PALETTE, new_figure, save_figure

    ran = dict.fromkeys(r.scenario for r in rows)          # shortened runs end in "-short"
    present = [name for s in scenarios for name in ran if name == s or name.startswith(f"{s}-")]
    present = [s for s in present if _find(rows, s, plant, noise, REFERENCE) is not None]
    if not present:
        return None
    fig = new_figure((6.0 * len(present), 8.5))
    axes = fig.subplots(3, len(present), sharex="col", squeeze=False)
    for j, sc in enumerate(present):
        ax_p, ax_e, ax_s = axes[0, j], axes[1, j], axes[2, j]
        runs = [(c, r) for c, name in zip(PALETTE, CONTROLLERS, strict=False)
                if (r := _find(rows, sc, plant, noise, name)) is not None]
        ax_p.plot(runs[0][1].result.time_s, runs[0][1].result.setpoint_kw, color="black",
                  linestyle="--", linewidth=1.0, label="setpoint")
        for colour, r in runs:
            name = r.controller
            ax_p.plot(r.result.time_s, r.result.power_true_kw, color=colour, linewidth=0.9,
                      label=f"{name} (IAE {r.iae_kw_s:.0f} kW s)")
            ax_e.plot(r.result.time_s, r.result.power_true_kw - r.result.setpoint_kw,
                      color=colour, linewidth=0.8, label=name)
            ax_s.plot(r.result.time_s, r.result.triac_pct, color=colour, linewidth=0.9, label=name)
        ax_p.set_title(f"{sc}: {plant} plant, noise {'on' if noise else 'off'}", fontsize="medium")
        ax_p.set_ylabel("power [kW]")
        ax_e.set_ylabel("power - setpoint [kW]")
        ax_e.set_ylim(-2.0, 2.0)
        ax_s.set_ylabel("TRIAC input [%]")
        ax_s.set_xlabel("time [s]")
        for ax in (ax_p, ax_e, ax_s):
            ax.grid(True, linewidth=0.5, alpha=0.6)
        ax_p.legend(fontsize="small", loc="best")
    save_figure(fig, path)
    return path


def _fmt(value: float, spec: str) -> str:
    return "-" if not math.isfinite(value) else format(value, spec)


def _pivot(rows: Sequence[RunRow], plant: str, noise: bool, metric: str, spec: str) -> list[str]:
    index = {"iae": 0, "overshoot": 1, "travel": 2}[metric]
    lines = ["| scenario | " + " | ".join(CONTROLLERS) + " |", "|---|" + "---:|" * len(CONTROLLERS)]
    for sc in dict.fromkeys(r.scenario for r in rows if r.plant == plant and r.noise == noise):
        cells = []
        for c in CONTROLLERS:
            r = _find(rows, sc, plant, noise, c)
            if r is None:
                cells.append("-")
                continue
            value = (r.iae_kw_s, r.overshoot_pct, r.input_travel_pct)[index]
            ratio = _ratios(r, rows)[index]
            cells.append(f"{_fmt(value, spec)} ({_fmt(ratio, '.2f')})")
        lines.append(f"| {sc} | " + " | ".join(cells) + " |")
    return lines


def section_text(rows: Sequence[RunRow], bounds: Sequence[BoundRow], goals: Sequence[GoalCheck],
                 *, command: str, machine: str, date: str, wall_time_s: float, seed: int,
                 short: float | None) -> str:
    """The BENCHMARKS.md section: command, machine, date, goals, bound, metric tables."""
    lines = [f"Command: `{command}`", "", f"Machine: {machine}", "", f"Date: {date}", "",
             f"{len(rows)} runs ({sum(r.result.n_steps for r in rows)} controller steps) in "
             f"{wall_time_s:.0f} s wall time; seed {seed} for every run"
             + (f"; scenarios shortened x {short:g}" if short is not None and short < 1 else "")
             + ".", "", "Controllers: " + "; ".join(f"`{c}`: {CONTROLLER_NOTES[c]}"
                                                    for c in CONTROLLERS) + ".", "", READING_NOTES]
    if goals:
        lines += ["", f"Goals of issue 40: {sum(g.met for g in goals)} of {len(goals)} met.", "",
                  "| goal | where | measured | met |", "|---|---|---|---|"]
        lines += [f"| {g.goal} | {g.where} | {g.detail} | {'yes' if g.met else '**NO**'} |"
                  for g in goals]
    if bounds:
        lines += ["", "LP lower bound on IAE (model plant, no noise) and the MPC with preview:", "",
                  "| scenario | bound [kW s] | bound, max-slope relaxation [kW s] | LP solve [s] "
                  "| MPC with preview [kW s] | MPC - bound [kW s] | MPC / bound "
                  "| sharp MPC / bound |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
        lines += [f"| {b.scenario}{' (disturbances known to the bound)' if b.has_disturbance else ''}"
                  f" | {b.bound_iae_kw_s:.2f} | {b.bound_max_slope_iae_kw_s:.2f} | "
                  f"{b.solve_time_s:.2f} | {_fmt(b.mpc_iae_kw_s, '.2f')} | "
                  f"{_fmt(b.mpc_iae_kw_s - b.bound_iae_kw_s, '.2f')} | {_fmt(b.ratio, '.3f')} | "
                  f"{_fmt(_ratio(b.sharp_mpc_iae_kw_s, b.bound_iae_kw_s), '.3f')} |"
                  for b in bounds]
    for plant in dict.fromkeys(r.plant for r in rows):
        for noise in (True, False):
            if not any(r.plant == plant and r.noise == noise for r in rows):
                continue
            where = f"{plant} plant, noise {'on' if noise else 'off'}"
            for metric, title, spec in (("iae", "IAE [kW s]", ".1f"),
                                        ("overshoot", "worst overshoot [% of change]", ".1f"),
                                        ("travel", "input travel [%]", ".1f")):
                lines += ["", f"{title}, {where} (ratio to {REFERENCE}):", ""]
                lines += _pivot(rows, plant, noise, metric, spec)
    return "\n".join(lines) + "\n"


# --- the command ---------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.value_case``."""
    parser = benchmark_parser("value_case", __doc__)
    parser.add_argument("--out", metavar="DIR", type=Path, default=None,
                        help="output directory (default: a temporary one)")
    parser.add_argument("--scenarios", metavar="A,B", type=_scenario_names, default=None,
                        help="only these scenarios (default: every shipped one and the recipes)")
    parser.add_argument("--plants", metavar="A,B", type=_plants, default=PLANTS,
                        help="plants to run on (default: model,heater)")
    parser.add_argument("--short", metavar="X", type=_fraction, default=None,
                        help="shorten every scenario: times x X, 0 < X <= 1")
    parser.add_argument("--seed", metavar="N", type=int, default=DEFAULT_SEED,
                        help=f"seed of every run (default: {DEFAULT_SEED})")
    parser.add_argument("--model", metavar="MODEL.json", type=Path, default=None,
                        help="model file (default: the shipped data/cz_heater_model.json)")
    parser.add_argument("--benchmarks-md", metavar="FILE", type=Path, default=BENCHMARKS_MD,
                        help="Markdown file of the section (default: BENCHMARKS.md)")
    parser.add_argument("--no-record", action="store_true", help="only print the section")
    return parser


def _plants(text: str) -> tuple[PlantKind, ...]:
    names = [p.strip() for p in text.split(",") if p.strip()]
    if not names or any(p not in PLANTS for p in names):
        raise argparse.ArgumentTypeError(f"expected names among {', '.join(PLANTS)}; got {text!r}")
    return tuple(p for p in PLANTS if p in names)


def _scenario_names(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    known = [*list_scenarios(), *(s.name for s in recipe_scenarios())]
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"expected names among {', '.join(known)}; got {text!r}")
    return names


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"expected a number X with 0 < X <= 1; got {text!r}")
    return value


def run_benchmark(args: argparse.Namespace, out_dir: Path,
                  progress: Callable[[str], None] = print) -> tuple[
                      tuple[RunRow, ...], tuple[BoundRow, ...], tuple[GoalCheck, ...]]:
    """Tune the PI, run every case, compute the bounds; the rows, bounds and goals."""
    model_path = args.model or shipped_path(HAMMERSTEIN_MODEL_JSON)
    model = load_model(model_path)
    plants: tuple[PlantKind, ...] = args.plants
    scenarios = all_scenarios(args.scenarios, args.short)
    schedule = tune_pid_table(model_path, out_dir / "pid")
    progress(f"tuned {len(schedule.breakpoints_pct)} PI rows (tune-pid --rule ms --ms {PID_MS:g}) "
             f"into {out_dir / 'pid'}")
    cases = [(sc, p, n) for p in plants for n in (True, False) for sc in scenarios]
    rows: list[RunRow] = []
    for i, (sc, plant, noise) in enumerate(cases, start=1):
        t0 = time.perf_counter()
        case = run_case(model, schedule, sc, plant=plant, noise=noise, seed=args.seed)
        rows += case
        iae = "  ".join(f"{r.controller} {r.iae_kw_s:.1f}" for r in case)
        progress(f"[{i}/{len(cases)}] {sc.name}, {plant}, noise {'on' if noise else 'off'}: "
                 f"IAE [kW s] {iae} ({time.perf_counter() - t0:.1f} s)")
    bounds: tuple[BoundRow, ...] = ()
    if "model" in plants:
        bounds = compute_bounds(model, scenarios, rows, seed=args.seed)
        for b in bounds:
            progress(f"LP bound {b.scenario}: {b.bound_iae_kw_s:.2f} kW s (max-slope "
                     f"{b.bound_max_slope_iae_kw_s:.2f}; {b.solve_time_s:.1f} s), MPC with "
                     f"preview {b.mpc_iae_kw_s:.2f} kW s ({b.ratio:.3f}x), sharp MPC "
                     f"{b.sharp_mpc_iae_kw_s:.2f} kW s")
    shipped = [s.name for s in scenarios if s.name in list_scenarios()]
    return tuple(rows), bounds, check_goals(rows, bounds, shipped)


def code_version() -> str:
    """The commit the benchmark ran on, and whether tracked files differed from it."""
    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, check=True,
                              capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               check=True, capture_output=True, text=True).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return f"commit {head}" + (f" with uncommitted changes in {len(dirty)} files" if dirty else "")


def _run(args: argparse.Namespace) -> int:
    machine = machine_info().describe() + f"; code: {code_version()}"
    date = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = args.out or Path(tmp) / "value"
        rows, bounds, goals = run_benchmark(args, out_dir)
        files = [*write_csvs(rows, bounds, out_dir)]
        figure = plot_recipes(rows, out_dir / "figure.png")
        if figure is not None:
            files.append(figure)
    body = section_text(rows, bounds, goals, command=args.command_line, machine=machine, date=date,
                        wall_time_s=time.perf_counter() - t0, seed=args.seed, short=args.short)
    print(body, end="")
    if args.out is not None:
        print("wrote " + ", ".join(str(f) for f in files))
    if not args.no_record:
        write_benchmarks_section(args.benchmarks_md, body, heading=SECTION_HEADING)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark, print its section, record it in BENCHMARKS.md; return the exit code."""
    return run_main(build_parser(), _run, argv)


__all__ = ["BOUND_RATIO_GOAL", "CONTROLLERS", "PREVIEW_S", "PID_MS", "RAMP_RATIO_GOAL",
           "MPC_BEFORE_ISSUE_40_SAG_KW_S", "SAG_RATIO_GOAL", "SHARP_WEIGHTS", "SECTION_HEADING",
           "STAIRCASE_RATIO_GOAL",
           "BoundRow", "GoalCheck",
           "RunRow", "all_scenarios", "check_goals", "compute_bounds", "main", "plot_recipes",
           "recipe_scenarios", "run_case", "section_text", "tune_pid_table", "with_preview",
           "worst_overshoot_pct", "write_csvs"]


if __name__ == "__main__":
    sys.exit(main())

