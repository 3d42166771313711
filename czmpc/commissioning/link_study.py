"""The commissioning journey through the plant link, measured against a paper-length model.

`czmpc.commissioning.length_study` trades test length against tracking with the plant
simulated in process. This module runs the same comparison the way a user meets it:
the issue's heater (`length_study.ISSUE_VARIATION`: gain x0.8, time constant 600 s,
two samples more delay) is served over OPC UA by ``czmpc plant serve`` in a process of
its own (`czmpc.runtime.serve_process`), and `czmpc.commissioning.journey.commission`
designs the test, runs it through the link, identifies, checks and, on a ``ready``
verdict, switches the MPC on for the staircase of `length_study.commissioning_staircase`
(a recipe file). The reference is the same MPC on a model identified from the paper's
24,000 s experiment on the same plant and seed (identified in process: 6.7 h of plant
time through the link adds nothing but wall time), run through the link on a freshly
served plant that starts at the input the commissioned run started from.

Both runs are scored on the plant's *true* power from the served plant's log
(`czmpc.runtime.served.PLANT_LOG_COLUMNS`), lined up with the run log by wall time:
the IAE from the first setpoint change on (the first segment only settles the start,
which differs between the two runs) and the mean error over the last
`length_study.SEGMENT_TAIL_SAMPLES` samples of every segment.
"""

from __future__ import annotations

import asyncio
import csv
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from czmpc.commissioning.journey import JourneyPlan, commission, identify_test
from czmpc.commissioning.length_study import (
    ISSUE_VARIATION,
    MAX_IAE_RATIO,
    OFFSET_FREE_ATOL_KW,
    TEST_BAND_PCT,
    apply_open_loop,
    commissioning_staircase,
    offset_free,
    paper_schedule_pct,
    segment_tail_errors_kw,
)
from czmpc.controller import OffsetFreeMPC
from czmpc.errors import CzmpcError
from czmpc.runtime.config import load_run_config
from czmpc.runtime.loop import ControlLoop
from czmpc.runtime.serve_process import serving
from czmpc.runtime.served import SERVED_NODE_IDS
from czmpc.settings import MPCSettings
from sim.drift import PlantVariation
from sysid.errors import SysidError
from sysid.modelfile import load_model, save_model

#: Sampling time of the served heater [s] (the paper's).
TS_S = 2.0
#: Input the served plant's watchdog applies while no heartbeat comes (the
#: identification and check between test and switch-on) [%].
SAFE_TRIAC_PCT = 45.0
#: Heartbeat silence that trips the served plant's watchdog [plant s].
WATCHDOG_S = 600.0
#: The test's safety band on the measured power [kW] (the varied heater gives about
#: 25..60 kW over the test band 35..65 %).
POWER_BAND_KW = (15.0, 80.0)
#: Columns of the run log and plant log this module reads.
_RUN_COLUMNS = ("wall_time_s", "time_s", "setpoint_kw")


class LinkStudyError(CzmpcError, RuntimeError):
    """A log of the study lacks what the scoring needs."""


@dataclass(frozen=True, kw_only=True)
class Tracking:
    """A closed-loop run scored on the true power.

    Attributes
    ----------
    iae_kw_s :
        IAE of setpoint minus true power from the first setpoint change to the end [kW s].
    segment_errors_kw :
        Mean error over the last samples of each setpoint segment [kW].
    """

    iae_kw_s: float
    segment_errors_kw: tuple[float, ...]

    @property
    def offset_free(self) -> bool:
        """Every segment's tail mean error within `length_study.OFFSET_FREE_ATOL_KW`."""
        return offset_free(self.segment_errors_kw)


@dataclass(frozen=True, kw_only=True)
class LinkRun:
    """One seed of the study.

    Attributes
    ----------
    seed :
        Seed of the served plant's noise and of the test design.
    test_s :
        Plant time of the designed test [s].
    stage :
        Where the journey ended (`czmpc.commissioning.journey.JourneyResult.stage`).
    verdict :
        check-model's verdict on the commissioned model.
    reasons :
        Its reasons (empty for ``ready``).
    orders :
        ``(degree, nb, nf, nk)`` of the commissioned model.
    fit_pct :
        Its fit on the test's held-out end [%].
    commissioned, reference :
        The two runs' tracking (None where a run did not happen).
    n_overruns :
        Loop periods that ended past their deadline, test and run together.
    wall_s :
        Wall time of the whole seed [s].
    failure :
        Why a stage did not happen (None when all did).
    """

    seed: int
    test_s: float
    stage: str
    verdict: str | None = None
    reasons: tuple[str, ...] = ()
    orders: tuple[int, ...] = ()
    fit_pct: float = math.nan
    commissioned: Tracking | None = None
    reference: Tracking | None = None
    n_overruns: int = 0
    wall_s: float = math.nan
    failure: str | None = None

    @property
    def iae_ratio(self) -> float:
        """Commissioned over reference IAE [-] (NaN without both)."""
        if self.commissioned is None or self.reference is None:
            return math.nan
        return self.commissioned.iae_kw_s / self.reference.iae_kw_s


def write_staircase_recipe(path: Path) -> Path:
    """The commissioning staircase as a recipe file (``time_s,setpoint_kw``)."""
    scenario = commissioning_staircase()
    setpoints = scenario.setpoint_profile_kw()
    change = np.flatnonzero(np.diff(setpoints) != 0.0) + 1
    rows = [(0.0, float(setpoints[0]))] + [(float(k) * scenario.ts_s, float(setpoints[k]))
                                           for k in change]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("time_s,setpoint_kw\n" + "".join(f"{t:g},{p:g}\n" for t, p in rows),
                    encoding="utf-8")
    return path


def _columns(path: Path, names: Sequence[str]) -> dict[str, np.ndarray]:
    with open(path, newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.DictReader(fh) if r.get(names[0])]
    if not rows or any(n not in rows[0] for n in names):
        raise LinkStudyError(f"{path}: expected columns {list(names)} with rows")
    return {n: np.array([float(r[n]) for r in rows]) for n in names}


def tracking_from_logs(plant_log: Path, run_log: Path, *, ts_s: float = TS_S) -> Tracking:
    """Score a run on the true power of the served plant's log.

    Each plant sample taken while the run ran gets the setpoint of the run's last row
    written before it (by wall time); the IAE counts the samples from the first
    setpoint change on, the segment errors the last samples of every segment.
    """
    plant = _columns(plant_log, ("wall_time_s", "power_true_kw"))
    run = _columns(run_log, _RUN_COLUMNS)
    inside = (plant["wall_time_s"] >= run["wall_time_s"][0]) & \
             (plant["wall_time_s"] <= run["wall_time_s"][-1])
    wall, true_kw = plant["wall_time_s"][inside], plant["power_true_kw"][inside]
    if wall.size < 2:
        raise LinkStudyError(f"{plant_log} has no samples inside the run of {run_log}")
    row = np.searchsorted(run["wall_time_s"], wall, side="right") - 1
    setpoint = run["setpoint_kw"][row]
    changed = np.flatnonzero(np.diff(setpoint) != 0.0)
    first = int(changed[0]) + 1 if changed.size else 0
    iae = float(np.sum(np.abs(setpoint[first:] - true_kw[first:])) * ts_s)
    return Tracking(iae_kw_s=iae, segment_errors_kw=segment_tail_errors_kw(setpoint, true_kw))


def _serve_args(variation: PlantVariation, seed: int, log: Path,
                initial_triac_pct: float | None = None) -> list[str]:
    args = ["--plant", "heater", "--seed", str(seed), "--log", str(log),
            "--watchdog-s", f"{WATCHDOG_S:g}", "--safe-triac-pct", f"{SAFE_TRIAC_PCT:g}",
            "--gain-factor", f"{variation.gain_factor:g}",
            "--extra-delay-samples", str(variation.extra_delay_samples)]
    if variation.tau_s is not None:
        args += ["--tau-s", f"{variation.tau_s:g}"]
    if initial_triac_pct is not None:
        args += ["--initial-triac-pct", f"{initial_triac_pct:g}"]
    return args


def write_link_config(path: Path, endpoint: str, *, time_scale: float,
                      recipe: Path | None = None, model: Path | None = None,
                      log: str = "run.csv") -> Path:
    """A run config for the served heater: its nodes, the recipe, a test safety band."""
    nodes = "\n".join(f'{k} = "{SERVED_NODE_IDS[k]}"' for k in
                      ("power_kw", "triac_pct", "applied_triac_pct", "heartbeat"))
    text = (f'[plant]\nendpoint = "{endpoint}"\nts_s = {TS_S:g}\ntime_scale = {time_scale:g}\n'
            f"max_sample_age_s = {2 * TS_S:g}\n[nodes]\n{nodes}\n"
            + (f'[controller]\nmodel = "{model.resolve()}"\n' if model is not None else "")
            + f'[run]\nlog = "{log}"\n'
            + (f'schedule = "{recipe.resolve()}"\n' if recipe is not None else "")
            + f"[safety]\nsafe_triac_pct = {SAFE_TRIAC_PCT:g}\n"
            f"[test]\npower_band_kw = [{POWER_BAND_KW[0]:g}, {POWER_BAND_KW[1]:g}]\n"
            "max_bad_quality_s = 60.0\n")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def reference_model_path(out: Path, variation: PlantVariation, seed: int) -> Path:
    """Identify the paper-length reference on the same plant and seed; write it."""
    data = apply_open_loop(paper_schedule_pct(TS_S), variation, ts_s=TS_S, seed=seed)
    path = out / "reference_model.json"
    save_model(identify_test(data).model, path)
    return path


def run_seed(seed: int, *, out_dir: Path, time_scale: float, test_s: float = 7200.0,
             kind: str = "multilevel", variation: PlantVariation = ISSUE_VARIATION,
             progress: Callable[[str], None] | None = None) -> LinkRun:
    """Commission the served heater, then run the reference; score both (module docstring)."""
    say = progress or (lambda _m: None)
    started = time.perf_counter()
    out = out_dir / f"seed{seed}"
    recipe = write_staircase_recipe(out / "recipe.csv")
    run_s = commissioning_staircase().duration_s
    plan = JourneyPlan(range_pct=TEST_BAND_PCT, tau_s=600.0, out_dir=out / "commission",
                       duration_s=test_s, kind=kind, max_step_pct=5.0, seed=seed,
                       switch_on=True, run_duration_s=run_s)
    say(f"seed {seed}: commissioning the served heater ({kind} test of {test_s:g} s at time "
        f"scale {time_scale:g})")
    with serving(*_serve_args(variation, seed, out / "plant_commission.csv"),
                 output=out / "serve_commission.log", time_scale=time_scale) as endpoint:
        config = load_run_config(write_link_config(out / "commission.toml", endpoint,
                                                   time_scale=time_scale, recipe=recipe))
        result = commission(config, plan, progress=say)
    check = result.check
    model_orders: tuple[int, ...] = ()
    if result.model_path is not None and result.model_path.is_file():
        m = load_model(result.model_path)
        model_orders = (m.input_degree, m.b.size - m.delay_steps, m.a.size - 1, m.delay_steps)
    base = LinkRun(seed=seed, test_s=test_s, stage=result.stage,
                   verdict=None if check is None else check.verdict,
                   reasons=() if check is None else check.reasons, orders=model_orders,
                   fit_pct=math.nan if result.fit_pct is None else result.fit_pct,
                   n_overruns=result.test_summary.n_overruns)
    if result.stage != "switched on" or result.run_summary is None:
        return _done(base, started, failure="; ".join(result.messages) or result.stage)
    commissioned = tracking_from_logs(out / "plant_commission.csv", out / "commission" / "run.csv")
    overruns = base.n_overruns + result.run_summary.n_overruns
    start_pct = _first_applied_pct(out / "commission" / "run.csv")
    say(f"seed {seed}: commissioned IAE {commissioned.iae_kw_s:.1f} kW s; identifying the "
        "paper-length reference")
    try:
        ref_model = reference_model_path(out, variation, seed)
    except (SysidError, CzmpcError) as exc:
        return _done(base, started, commissioned=commissioned, n_overruns=overruns,
                     failure=f"reference identification: {exc}")
    say(f"seed {seed}: the reference through the link")
    try:
        with serving(*_serve_args(variation, seed, out / "plant_reference.csv", start_pct),
                     output=out / "serve_reference.log", time_scale=time_scale) as endpoint:
            config = load_run_config(write_link_config(
                out / "reference.toml", endpoint, time_scale=time_scale, recipe=recipe,
                model=ref_model, log=str((out / "reference_run.csv").resolve())))
            model = load_model(ref_model)
            mpc = OffsetFreeMPC(model, MPCSettings.default_for(model))
            summary = asyncio.run(ControlLoop(replace(config, duration_s=run_s), mpc).run())
    except CzmpcError as exc:
        return _done(base, started, commissioned=commissioned, n_overruns=overruns,
                     failure=f"reference run: {exc}")
    reference = tracking_from_logs(out / "plant_reference.csv", out / "reference_run.csv")
    return _done(base, started, commissioned=commissioned, reference=reference,
                 n_overruns=overruns + summary.n_overruns)


def _first_applied_pct(run_log: Path) -> float:
    applied = _columns(run_log, ("applied_triac_pct",))["applied_triac_pct"]
    finite = applied[np.isfinite(applied)]
    if finite.size == 0:
        raise LinkStudyError(f"{run_log} has no applied input")
    return float(finite[0])


def _done(base: LinkRun, started: float, **changes: object) -> LinkRun:
    return replace(base, wall_s=time.perf_counter() - started, **changes)  # type: ignore[arg-type]


def format_link_study(runs: Sequence[LinkRun], *, command: str, machine: str,
                      time_scale: float) -> str:
    """The study as a Markdown section body: command, machine, what was run, every seed."""
    lines = [f"Command: `{command}`", "", f"Machine: {machine}", "",
             "Through the plant link: the issue's heater (virtual heater, gain x0.8, slow time "
             "constant 600 s, 2 samples more delay, noise on) served by `czmpc plant serve` in "
             f"its own process on 127.0.0.1 at a time scale of {time_scale:g}; `czmpc commission "
             "--switch-on` as a user runs it (test, identification, check-model, MPC on a "
             "recipe 36 -> 40 -> 45 -> 50 kW, 6,000 s). Reference: the same MPC on a model "
             "identified from the paper's 24,000 s experiment on the same plant and seed, "
             "through the link on a fresh served plant started at the commissioned run's first "
             "input. Scored on the served plant's true power (its --log), IAE from the first "
             "setpoint change; offset-free: |mean error| < "
             f"{OFFSET_FREE_ATOL_KW:g} kW over the last 20 samples of every segment.", "",
             "| seed | test [s] | verdict | orders (deg, nb, nf, nk) | held-out fit [%] | "
             "IAE [kW s] | reference IAE [kW s] | IAE ratio [-] | offset-free | "
             "reference offset-free | overruns | wall [s] |",
             "| ---: | ---: | --- | --- | ---: | ---: | ---: | ---: | --- | --- | ---: | ---: |"]
    for r in runs:
        c, ref = r.commissioned, r.reference
        verdict = r.verdict or "-"
        if r.reasons and r.verdict != "ready":
            verdict += " (" + "; ".join(r.reasons) + ")"
        lines.append(
            f"| {r.seed} | {r.test_s:g} | {verdict} | {r.orders or '-'} | {r.fit_pct:.1f} | "
            + (f"{c.iae_kw_s:.1f}" if c else "-") + " | "
            + (f"{ref.iae_kw_s:.1f}" if ref else "-") + f" | {r.iae_ratio:.3f} | "
            + ("yes" if c and c.offset_free else "no") + " | "
            + ("yes" if ref and ref.offset_free else "no" if ref else "-")
            + f" | {r.n_overruns} | {r.wall_s:.0f} |")
    failures = [f"seed {r.seed}: {r.failure}" for r in runs if r.failure]
    ratios = [r.iae_ratio for r in runs if math.isfinite(r.iae_ratio)]
    met = (bool(runs) and all(r.stage == "switched on" and r.commissioned is not None
                              and r.commissioned.offset_free for r in runs)
           and bool(ratios) and all(v <= MAX_IAE_RATIO for v in ratios))
    lines += [""] + [f"- {f}" for f in failures] + ([""] if failures else [])
    lines.append(("Goal met" if met else "Goal not met")
                 + f" (switched on and offset-free on every seed, IAE within "
                   f"{MAX_IAE_RATIO:.2f} of the reference on every seed with a reference).")
    return "\n".join(lines) + "\n"


#: Heading of the study's section in BENCHMARKS.md.
BENCHMARK_HEADING = "## Commissioning through the plant link"

__all__ = [
    "BENCHMARK_HEADING", "LinkRun", "LinkStudyError", "Tracking", "format_link_study",
    "reference_model_path", "run_seed", "tracking_from_logs", "write_link_config",
    "write_staircase_recipe",
]
