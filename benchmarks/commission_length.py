"""How long must a commissioning test be? Test length against closed-loop tracking.

The journey of `czmpc commission` without the plant link: a test signal designed as
the journey designs it (`czmpc.commissioning.journey.design_spec`) is applied open
loop to a simulated plant that differs from the shipped model, the model is
identified from the log as the journey identifies it
(`czmpc.commissioning.journey.identify_test`), and the offset-free MPC on that model
tracks a setpoint staircase on the same plant (`czmpc.campaigns.simulation
.run_simulation`). The reference is the same MPC on a model identified the same way
from the paper's 24,000 s experiment (its input schedule, `sim.experiment
.ExperimentSpec`) on the same plant.

The plant is the virtual heater (`sim.drift.vary_heater`) with the issue's variation
(gain x0.8, time constant 600 s, two samples more delay); each test and each run draws
its own noise from its own seed.

With ``--plant-link`` the same comparison runs the way a user meets it: the issue's
heater is served over OPC UA by ``czmpc plant serve`` in a process of its own
(`benchmarks._serving`), and `czmpc.commissioning.journey.commission` designs
the test, runs it through the link, identifies, checks and, on a ``ready`` verdict,
switches the MPC on for the staircase of `commissioning_staircase` (a recipe file).
The reference is the same MPC on a model identified from the paper's 24,000 s
experiment on the same plant and seed (identified in process: 6.7 h of plant time
through the link adds nothing but wall time), run through the link on a freshly served
plant that starts at the input the commissioned run started from. Both runs are scored
on the plant's *true* power from the served plant's log
(`czmpc.runtime.served.PLANT_LOG_COLUMNS`), lined up with the run log by wall time: the
IAE from the first setpoint change on (the first segment only settles the start, which
differs between the two runs) and the mean error over the last `SEGMENT_TAIL_SAMPLES`
samples of every segment. One seed takes (test + 2 runs) / time scale of wall time:
7,200 s + 2 x 6,000 s at --time-scale 20 is 16 min.

``python -m benchmarks.commission_length [--case KIND[:S]|paper ...] [--plant-link]``
(``--help``) prints the table, draws the IAE ratio against the test length and, with
``--record-benchmarks``, writes the table into BENCHMARKS.md. A run takes a few minutes
(each identification takes 10 s to 1 min).

Exit codes: 0 done (whatever the numbers); 2 bad options.
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from benchmarks._md import BENCHMARKS_MD, benchmark_parser, machine_info, run_main, write_benchmarks_section
from benchmarks._serving import serving
from czmpc.campaigns.simulation import run_simulation
from czmpc.cli import _argtypes
from czmpc.cli._progress import Progress
from czmpc.commissioning.journey import JourneyPlan, commission, design_spec, identify_test
from czmpc.controller import OffsetFreeMPC
from czmpc.errors import CzmpcError, DesignError
from czmpc.runtime.config import load_run_config
from czmpc.runtime.loop import ControlLoop
from czmpc.runtime.served import SERVED_NODE_IDS
from czmpc.settings import MPCSettings
from sim.drift import PlantVariation, vary_heater
from sim.experiment import ExperimentSpec
from sim.heater import HeaterParams
from sim.protocols import NOMINAL
from sim.scenario import Scenario, load_scenario, scenario_from_dict
from sysid.data import Dataset
from sysid.design import SignalDesignError, design_test_signal
from sysid.errors import SysidError
from sysid.modelfile import load_model, save_model
from sysid.uncertainty import static_gain_kw_per_pct

#: The issue's plant: gain x0.8, slow time constant 600 s, two samples more delay.
ISSUE_VARIATION = PlantVariation(gain_factor=0.8, tau_s=600.0, extra_delay_samples=2)
#: The issue's bound on a test [s of plant time] (2 h).
MAX_TEST_S = 7200.0
#: Samples at the end of each setpoint segment whose mean error must be below
#: `OFFSET_FREE_ATOL_KW` (the issue's offset-free criterion).
SEGMENT_TAIL_SAMPLES = 20
#: |mean error| bound over the tail of each segment [kW].
OFFSET_FREE_ATOL_KW = 0.1
#: The issue's bound on the IAE against the paper-length reference [-].
MAX_IAE_RATIO = 1.10
#: The band every designed test visits [%]: the paper's experiment's (33..65 %), so that
#: the short tests and the reference see the same inputs.
TEST_BAND_PCT = (35.0, 65.0)


def commissioning_staircase() -> Scenario:
    """Setpoints 36 -> 40 -> 45 -> 50 kW: 10 min at 36 kW, then 30 min each (6,000 s).

    The shipped staircase climbs to 65 kW; at gain x0.8 that needs about 80 % input,
    beyond every test's band and the paper's experiment (65 %), where no model was
    identified and the controller (held to its model's input range) cannot go. These
    setpoints need 42..62 % on the varied heater, inside every band.
    """
    return scenario_from_dict({
        "name": "commissioning staircase", "duration_s": 6000.0, "ts_s": 2.0,
        "plant_noise": True, "initial_setpoint_kw": 36.0,
        "description": "setpoints 36 -> 40 -> 45 -> 50 kW inside the commissioned band",
        "setpoint": [{"kind": "step", "at_s": 600.0, "power_kw": 40.0},
                     {"kind": "step", "at_s": 2400.0, "power_kw": 45.0},
                     {"kind": "step", "at_s": 4200.0, "power_kw": 50.0}]})


class LengthStudyError(CzmpcError, ValueError):
    """Options of the test-length study that cannot work together."""


@dataclass(frozen=True, kw_only=True)
class LengthCase:
    """One test of the study.

    Parameters
    ----------
    kind :
        A `sysid.design` kind, or ``"paper"``: the paper's experiment schedule.
    duration_s :
        Test length [s of plant time]; None: the shortest the design of ``kind``
        accepts (`sysid.design.shortest_duration_s`). Ignored for ``"paper"`` (23,998 s).
    """

    kind: str
    duration_s: float | None = None

    @property
    def label(self) -> str:
        """``"multilevel 7200 s"``, ``"mixed, shortest"`` or ``"paper experiment"``."""
        if self.kind == "paper":
            return "paper experiment"
        return f"{self.kind}, shortest" if self.duration_s is None \
            else f"{self.kind} {self.duration_s:g} s"


@dataclass(frozen=True, kw_only=True)
class LengthRow:
    """What one test gave: its model, the model's fit, and the MPC's tracking.

    Attributes
    ----------
    case :
        The test.
    seed :
        Seed of the design, the test's noise and the closed loop's noise
        (`numpy.random.SeedSequence` streams).
    test_s :
        Plant time of the test as applied [s].
    orders :
        ``(degree, nb, nf, nk)`` chosen by the automatic order search.
    static_gain_kw_per_pct :
        The model's static gain at its operating point [kW/%] (the plant's is about
        0.8 of the nominal heater's).
    fit_pct :
        MATLAB ``compare`` fit on the test's held-out end [%].
    iae_kw_s :
        IAE of the true power over the staircase [kW s].
    segment_errors_kw :
        Mean error (setpoint minus true power) over the last `SEGMENT_TAIL_SAMPLES` of
        each setpoint segment [kW].
    identify_wall_s :
        Wall time of the identification [s].
    failure :
        Why no model or no run came out (None when both did).
    """

    case: LengthCase
    test_s: float
    seed: int = 0
    orders: tuple[int, ...] = ()
    static_gain_kw_per_pct: float = math.nan
    fit_pct: float = math.nan
    iae_kw_s: float = math.nan
    segment_errors_kw: tuple[float, ...] = ()
    identify_wall_s: float = math.nan
    failure: str | None = None

    @property
    def offset_free(self) -> bool:
        """Every segment's tail mean error within `OFFSET_FREE_ATOL_KW`."""
        return offset_free(self.segment_errors_kw)


def offset_free(segment_errors_kw: Sequence[float]) -> bool:
    """Offset-free as the issue defines it: at least one segment, and every segment's tail
    mean error [kW] within `OFFSET_FREE_ATOL_KW`."""
    return bool(segment_errors_kw) and all(abs(e) < OFFSET_FREE_ATOL_KW for e in segment_errors_kw)


def paper_schedule_pct(ts_s: float) -> np.ndarray:
    """The input of the paper's identification experiment at every sample [%]."""
    if ts_s != ExperimentSpec.ts_s:
        raise LengthStudyError(f"the paper's experiment is on a {ExperimentSpec.ts_s:g} s grid; "
                              f"got a scenario with ts_s = {ts_s!r}")
    return ExperimentSpec().triac_schedule_pct()


def apply_open_loop(triac_pct: np.ndarray, variation: PlantVariation, *, ts_s: float,
                    seed: int) -> Dataset:
    """Apply an input schedule to the varied virtual heater; return the log.

    The heater starts in steady state at the schedule's first input; the power logged at
    sample ``k`` responds to the inputs up to sample ``k - 1`` (read, then write, as the
    runtime's loop does).
    """
    u = np.asarray(triac_pct, dtype=float)
    params = HeaterParams(ts_s=ts_s, initial_triac_pct=float(u[0]))
    plant = vary_heater(variation, params)
    power = np.empty(u.size)
    power[0] = plant.reset(np.random.default_rng(seed))
    for k in range(1, u.size):
        power[k] = plant.step(float(u[k - 1]), NOMINAL)
    return Dataset(time_s=np.arange(u.size, dtype=np.float64) * ts_s, triac_pct=u, power_kw=power,
                   ts_s=ts_s)


def segment_tail_errors_kw(setpoint_kw: np.ndarray, power_kw: np.ndarray,
                           tail: int = SEGMENT_TAIL_SAMPLES) -> tuple[float, ...]:
    """Mean of ``setpoint - power`` over the last ``tail`` samples of each constant-setpoint
    segment [kW] (over the whole segment when it is shorter)."""
    r = np.asarray(setpoint_kw, dtype=float)
    y = np.asarray(power_kw, dtype=float)
    ends = np.concatenate((np.flatnonzero(np.diff(r) != 0.0) + 1, [r.size]))
    starts = np.concatenate(([0], ends[:-1]))
    return tuple(float(np.mean(r[max(s, e - tail):e] - y[max(s, e - tail):e]))
                 for s, e in zip(starts, ends, strict=True))


def run_case(case: LengthCase, *, variation: PlantVariation = ISSUE_VARIATION,
             range_pct: tuple[float, float], tau_s: float, max_step_pct: float,
             scenario: Scenario, seed: int = 0,
             progress: Callable[[str], None] | None = None) -> LengthRow:
    """Design (or take the paper's) test, apply it, identify, and track ``scenario``."""
    say = progress or (lambda _m: None)
    design_seed, test_seed, run_seed = (int(v) for v in np.random.SeedSequence(seed)
                                        .generate_state(3))
    ts_s = scenario.ts_s
    if case.kind == "paper":
        u = paper_schedule_pct(ts_s)
    else:
        plan = JourneyPlan(range_pct=range_pct, tau_s=tau_s, out_dir=Path("."), kind=case.kind,
                           duration_s=case.duration_s, max_step_pct=max_step_pct)
        try:
            u = design_test_signal(design_spec(plan, ts_s),
                                   np.random.default_rng(design_seed)).triac_pct
        except SignalDesignError as exc:
            return LengthRow(case=case, seed=seed, test_s=math.nan, failure=f"design: {exc}")
    data = apply_open_loop(u, variation, ts_s=ts_s, seed=test_seed)
    test_s = float(data.time_s[-1])
    say(f"{case.label}, seed {seed}: identifying from {data.n_samples} samples")
    start = time.perf_counter()
    try:
        identified = identify_test(data)
    except (SysidError, CzmpcError) as exc:
        return LengthRow(case=case, seed=seed, test_s=test_s,
                         failure=f"identification: {exc}")
    wall = time.perf_counter() - start
    model = identified.model
    orders = (model.input_degree, model.b.size - model.delay_steps, model.a.size - 1,
              model.delay_steps)
    gain = float(static_gain_kw_per_pct(model, np.array(model.operating_point.triac_pct)))
    row = LengthRow(case=case, seed=seed, test_s=test_s, orders=orders,
                    static_gain_kw_per_pct=gain, fit_pct=identified.fit_pct, identify_wall_s=wall)
    say(f"{case.label}, seed {seed}: fit {identified.fit_pct:.1f} %, orders {orders}; "
        f"tracking {scenario.name}")
    try:
        outcome = run_simulation(model, scenario, plant="heater", seed=run_seed,
                                 variation=variation)
    except (DesignError, CzmpcError) as exc:
        return replace(row, failure=f"MPC: {exc}")
    result = outcome.result
    return replace(row, iae_kw_s=outcome.metrics.iae_kw_s,
                   segment_errors_kw=segment_tail_errors_kw(result.setpoint_kw,
                                                            result.power_true_kw))


def run_length_study(cases: Sequence[LengthCase], *, variation: PlantVariation = ISSUE_VARIATION,
                      range_pct: tuple[float, float] = TEST_BAND_PCT, tau_s: float = 600.0,
                     max_step_pct: float = 5.0, scenario: str | Scenario | None = None,
                     seeds: Sequence[int] = (0,),
                     progress: Callable[[str], None] | None = None) -> list[LengthRow]:
    """`run_case` for every case and seed (module docstring).

    Parameters
    ----------
    cases :
        The tests; include ``LengthCase(kind="paper", ...)`` for the reference.
    variation :
        How the plant differs from the nominal heater.
    range_pct :
        Band of the designed tests [%] (the scenario's inputs on the varied plant
        must lie inside it).
    tau_s :
        The engineer's guess of the time constant [s] for the design.
    max_step_pct :
        Largest designed move per sample [%].
    scenario :
        The tracking scenario (a shipped name or a `Scenario`); None:
        `commissioning_staircase`.
    seeds :
        The seeds: each case runs once per seed (design, test noise, closed-loop
        noise); the IAE ratio compares rows of the same seed.
    """
    scen = (commissioning_staircase() if scenario is None
            else load_scenario(scenario) if isinstance(scenario, str) else scenario)
    return [run_case(c, variation=variation, range_pct=range_pct, tau_s=tau_s,
                     max_step_pct=max_step_pct, scenario=scen, seed=seed, progress=progress)
            for seed in seeds for c in cases]


#: Heading of the study's section in BENCHMARKS.md.
BENCHMARK_HEADING = "## Commissioning: test length against tracking"

#: The default study: short multilevel tests up to the issue's 2 h, the shortest GBN
#: and mixed designs for tau = 600 s, and the paper's experiment as the reference.
DEFAULT_CASES = (LengthCase(kind="multilevel", duration_s=4800.0),
                 LengthCase(kind="multilevel", duration_s=6000.0),
                 LengthCase(kind="multilevel", duration_s=7200.0),
                 LengthCase(kind="gbn", duration_s=12000.0),
                 LengthCase(kind="mixed"),
                 LengthCase(kind="paper"))


def reference_iae_kw_s(rows: Sequence[LengthRow], seed: int) -> float:
    """IAE of the paper-experiment row of ``seed`` [kW s] (NaN if absent or failed)."""
    return next((r.iae_kw_s for r in rows if r.case.kind == "paper" and r.seed == seed),
                math.nan)


def iae_ratio(row: LengthRow, rows: Sequence[LengthRow]) -> float:
    """``row``'s IAE over the paper-experiment IAE of the same seed [-] (NaN if none)."""
    return row.iae_kw_s / reference_iae_kw_s(rows, row.seed)


def goal_met(case: LengthCase, rows: Sequence[LengthRow]) -> bool:
    """A test of at most `MAX_TEST_S` whose every seed ran offset-free, within
    `MAX_IAE_RATIO` of its reference on every seed whose reference ran (a seed whose
    reference model the MPC refused has no ratio; at least one ratio is needed)."""
    mine = [r for r in rows if r.case == case]
    ratios = [iae_ratio(r, rows) for r in mine]
    finite = [v for v in ratios if math.isfinite(v)]
    return (case.kind != "paper" and bool(mine) and bool(finite)
            and all(r.test_s <= MAX_TEST_S and r.failure is None and r.offset_free
                    for r in mine)
            and all(v <= MAX_IAE_RATIO for v in finite))


def format_study(rows: Sequence[LengthRow], *, command: str, machine: str,
                 variation: PlantVariation = ISSUE_VARIATION) -> str:
    """The study as a Markdown section body: command, machine, summary, every run."""
    seeds = sorted({r.seed for r in rows})
    cases = list(dict.fromkeys(r.case for r in rows))
    lines = [f"Command: `{command}`", "", f"Machine: {machine}", "",
             f"Plant: the virtual heater with gain x{variation.gain_factor:g}, slow time constant "
             f"{variation.tau_s:g} s and {variation.extra_delay_samples} samples more delay "
             "(`sim.drift`), noise on. Each test is designed as `czmpc commission` designs it "
             f"(band {TEST_BAND_PCT[0]:g}..{TEST_BAND_PCT[1]:g} %, tau guess 600 s, at most 5 % "
             "per sample), applied open loop, and identified as the journey identifies "
             "(orders auto, at least one sample of delay, the last quarter held out for the "
             "fit). The MPC with default settings on that model then tracks setpoints "
             "36 -> 40 -> 45 -> 50 kW (6,000 s) on the same plant. Offset-free: |mean error| "
             f"< {OFFSET_FREE_ATOL_KW:g} kW over the last {SEGMENT_TAIL_SAMPLES} samples of "
             "every segment (true power). IAE ratio: against the paper's 24,000 s experiment "
             "identified the same way, same seed (goal: a test of at most "
             f"{MAX_TEST_S:g} s, offset-free on every seed and at most {MAX_IAE_RATIO:.2f} "
             "on every seed whose reference ran: where the MPC refused the reference "
             "model there is no ratio). "
             f"Seeds {', '.join(str(s) for s in seeds)}.", "",
             "| test | plant time [s] | runs | offset-free | no model or no MPC | "
             "IAE ratio, median [-] | IAE ratio, worst [-] |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for case in cases:
        mine = [r for r in rows if r.case == case]
        ratios = [iae_ratio(r, rows) for r in mine if r.failure is None]
        finite = [v for v in ratios if math.isfinite(v)]
        lines.append(
            f"| {case.label} | {mine[0].test_s:g} | {len(mine)} | "
            f"{sum(r.offset_free for r in mine)} | {sum(r.failure is not None for r in mine)} | "
            + (f"{float(np.median(finite)):.3f} | {max(finite):.3f} |" if finite else "- | - |"))
    lines += ["", "Every run:", "",
              "| test | seed | orders (deg, nb, nf, nk) | static gain [kW/%] | "
              "held-out fit [%] | IAE [kW s] | IAE ratio [-] | worst segment error [kW] | "
              "offset-free | identification [s wall] |",
              "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | --- | ---: |"]
    for r in rows:
        if not r.orders:
            lines.append(f"| {r.case.label} | {r.seed} | - | - | - | - | - | - | "
                         f"no model: {r.failure} | - |")
            continue
        worst = max(r.segment_errors_kw, key=abs) if r.segment_errors_kw else math.nan
        status = (("yes" if r.offset_free else "no") if r.failure is None
                  else f"no MPC: {r.failure}")
        lines.append(f"| {r.case.label} | {r.seed} | {r.orders} | "
                     f"{r.static_gain_kw_per_pct:.4g} | {r.fit_pct:.1f} | {r.iae_kw_s:.1f} | "
                     f"{iae_ratio(r, rows):.3f} | {worst:+.4f} | {status} | "
                     f"{r.identify_wall_s:.1f} |")
    met = [c.label for c in cases if goal_met(c, rows)]
    lines += ["", ("Goal met by: " + ", ".join(met) + ".") if met
              else "Goal not met: no test of at most 2 h gave an offset-free MPC on every "
                   f"seed within {MAX_IAE_RATIO:.2f} of the reference's IAE."]
    return "\n".join(lines) + "\n"


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
        """Every segment's tail mean error within `OFFSET_FREE_ATOL_KW`."""
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


#: Heading of the plant-link study's section in BENCHMARKS.md.
LINK_BENCHMARK_HEADING = "## Commissioning through the plant link"


def length_study_figure(path: Path, points: Sequence[tuple[str, float, float]], *,
                        goal_ratio: float = MAX_IAE_RATIO, max_test_s: float = MAX_TEST_S) -> Path:
    """IAE ratio against test length, one marker per test kind; write it as a PNG.

    Parameters
    ----------
    path :
        The PNG to write.
    points :
        ``(kind, test length [s], IAE / reference IAE [-])`` per run.
    goal_ratio :
        The goal, drawn as a horizontal line [-].
    max_test_s :
        The longest test allowed, drawn as a vertical line [s].

    Returns
    -------
    Path
        ``path``.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.0, 2.6), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    markers = {"multilevel": "o", "gbn": "s", "mixed": "D", "steps": "^", "paper": "*"}
    for kind in dict.fromkeys(k for k, _, _ in points):
        x = [t / 3600.0 for k, t, _ in points if k == kind]
        y = [r for k, _, r in points if k == kind]
        ax.plot(x, y, marker=markers.get(kind, "x"), ls="none", ms=8, label=kind)
    ax.axhline(goal_ratio, color="tab:red", ls="--", lw=0.8, label=f"goal: IAE ratio {goal_ratio:.2f}")
    ax.axvline(max_test_s / 3600.0, color="0.4", ls=":", lw=0.8,
               label=f"longest test allowed ({max_test_s / 3600.0:g} h)")
    ax.set_xlabel("test length [h of plant time]")
    ax.set_ylabel("IAE / IAE with the paper's experiment [-]")
    ax.legend(loc="best")
    fig.savefig(path, dpi=110)
    return path


def _case(text: str) -> tuple[str, float | None]:
    """``KIND:SECONDS``, ``KIND`` (its shortest design) or ``paper`` (argparse type)."""
    kind, colon, seconds = text.partition(":")
    if kind not in (*_argtypes.TEST_SIGNAL_KINDS, "paper") or (kind == "paper" and colon):
        raise argparse.ArgumentTypeError(
            f"expected KIND:SECONDS or KIND with KIND one of "
            f"{', '.join(_argtypes.TEST_SIGNAL_KINDS)}, or 'paper'; got {text!r}")
    return kind, _argtypes.number(above=0.0, unit="s")(seconds) if colon else None


def build_parser() -> argparse.ArgumentParser:
    """The options of ``python -m benchmarks.commission_length``."""
    parser = benchmark_parser("commission_length", __doc__)
    parser.add_argument("--case", metavar="KIND[:S]|paper", type=_case, action="append",
                        default=None,
                        help="a test: a design kind and its length in plant seconds "
                             "(multilevel:7200), a kind alone for its shortest design "
                             "(mixed), or 'paper' for the paper's experiment; repeatable "
                             "(default: multilevel:4800, multilevel:6000, multilevel:7200, "
                             "gbn:12000, mixed, paper)")
    parser.add_argument("--seeds", metavar="N", type=_argtypes.positive_int, default=3,
                        help="runs of every test, seeds 0..N-1 (design, test noise, "
                             "closed-loop noise) (default: 3)")
    parser.add_argument("--plant-link", action="store_true",
                        help="run `czmpc commission --switch-on` against the heater served over "
                             "OPC UA on loopback, with the reference through the link too (the "
                             "--case options do not apply; the test is --test-s of multilevel)")
    parser.add_argument("--time-scale", metavar="X", type=_argtypes.number(at_least=1.0),
                        default=20.0, help="with --plant-link: plant samples per Ts of wall "
                                           "time (default: 20, 100 ms periods)")
    parser.add_argument("--test-s", metavar="S", type=_argtypes.number(above=0.0, unit="s"),
                        default=7200.0, help="with --plant-link: length of the multilevel test "
                                             "[plant s] (default: 7200, the issue's 2 h)")
    parser.add_argument("--out", metavar="DIR", type=Path, default=Path("out/bench/commission"),
                        help="where the figure goes (default: out/bench/commission)")
    parser.add_argument("--record-benchmarks", action="store_true",
                        help="also put the table into BENCHMARKS.md")
    parser.add_argument("--benchmarks-md", metavar="FILE", type=Path, default=BENCHMARKS_MD,
                        help="the Markdown file for --record-benchmarks (default: "
                             "BENCHMARKS.md of this repository)")
    return parser


def _run(args: argparse.Namespace) -> int:
    if args.plant_link:
        return _run_plant_link(args)
    cases = DEFAULT_CASES if args.case is None else tuple(
        LengthCase(kind=k, duration_s=s) for k, s in args.case)
    progress = Progress()
    rows = run_length_study(cases, seeds=range(args.seeds), progress=progress)
    text = format_study(rows, command=args.command_line, machine=machine_info().describe())
    print(text, end="")
    args.out.mkdir(parents=True, exist_ok=True)
    fig = length_study_figure(
        args.out / "test_length.png",
        [(r.case.kind, r.test_s, iae_ratio(r, rows)) for r in rows if r.failure is None])
    progress(f"wrote {fig}")
    if args.record_benchmarks:
        write_benchmarks_section(args.benchmarks_md, text, heading=BENCHMARK_HEADING)
        progress(f"wrote the table to {args.benchmarks_md}")
    return 0


def _run_plant_link(args: argparse.Namespace) -> int:
    if args.case:
        print("error: --case does not apply with --plant-link (its test is --test-s of "
              "the multilevel design)", file=sys.stderr)
        return 2
    progress = Progress()
    runs = [run_seed(seed, out_dir=args.out / "plant_link", time_scale=args.time_scale,
                     test_s=args.test_s, progress=progress) for seed in range(args.seeds)]
    text = format_link_study(runs, command=args.command_line,
                             machine=machine_info().describe(), time_scale=args.time_scale)
    print(text, end="")
    if args.record_benchmarks:
        write_benchmarks_section(args.benchmarks_md, text, heading=LINK_BENCHMARK_HEADING)
        progress(f"wrote the table to {args.benchmarks_md}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run the study, print the table, draw the figure, record when asked; return the exit code."""
    return run_main(build_parser(), _run, argv)


__all__ = [
    "BENCHMARK_HEADING", "DEFAULT_CASES", "ISSUE_VARIATION", "LINK_BENCHMARK_HEADING",
    "MAX_IAE_RATIO", "MAX_TEST_S", "OFFSET_FREE_ATOL_KW", "SEGMENT_TAIL_SAMPLES",
    "TEST_BAND_PCT", "LengthCase", "LengthRow", "LengthStudyError", "LinkRun", "LinkStudyError",
    "Tracking", "apply_open_loop", "build_parser", "commissioning_staircase",
    "format_link_study", "format_study", "goal_met", "iae_ratio", "length_study_figure", "main",
    "offset_free", "paper_schedule_pct", "reference_iae_kw_s", "reference_model_path",
    "run_case", "run_length_study", "run_seed", "segment_tail_errors_kw",
    "tracking_from_logs", "write_link_config", "write_staircase_recipe",
]


if __name__ == "__main__":
    sys.exit(main())
