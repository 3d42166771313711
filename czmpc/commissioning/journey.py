"""The commissioning journey (`czmpc commission`): test design to a running MPC.

Stages, each reported and each leaving its files in the output directory:

1. design the open-loop test (`sysid.design`, the staircase plus GBN of
   `czmpc design-test`) over the band the heater may visit -> ``test.csv``;
2. run it through the plant link (`czmpc.commissioning.test_run`, the same loop as
   the MPC, with the config's ``[test]`` safety band) -> ``test_run.csv`` and
   ``test_run.meta.json``; an aborted test ends the journey (exit 1);
3. identify from the first `ESTIMATION_FRACTION` of the log (`identify_test`)
   -> ``model.json`` and ``identification/report.md``;
4. check the model (`czmpc.commissioning.check.check_model`) on the held-out rest, with
   the settings the MPC will run with -> the verdict beside the model;
5. write ``commissioning.md`` with its figures: the test, the held-out fit, the verdict
   with every reason and the Monte Carlo distribution, the chosen settings;
6. only with ``switch_on`` and the verdict ``ready``: run the MPC with the new model,
   starting bumplessly from the input the plant applies then (`czmpc run`).
"""

from __future__ import annotations

import asyncio
import dataclasses
import datetime as dt
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from czmpc.commissioning.check import ModelCheck, check_model, write_check
from czmpc.commissioning.test_run import (
    InputSchedule,
    ScheduleDriver,
    ScheduleError,
    make_test_loop,
)
from czmpc.errors import CzmpcError, DesignError
from czmpc.reports import commissioning as figures
from czmpc.reports.identification import model_equation
from czmpc.runtime.config import RunConfig
from czmpc.runtime.loop import RunSummary
from czmpc.runtime.runlog import read_run_log
from czmpc.runtime.session import open_run
from czmpc.settings import MPCSettings
from czmpc.settings_file import load_settings
from sysid.atomic import atomic_write_text, file_sha256
from sysid.criteria import errors_with_fitted_state, fit_percent
from sysid.data import Dataset
from sysid.design import (
    ExcitationSignal,
    ExcitationSpec,
    design_test_signal,
    shortest_duration_s,
)
from sysid.model import HammersteinModel, Units
from sysid.modelfile import save_model

#: Share of the test's samples the model is identified from; the rest (the end of
#: the test, inside the GBN part of a mixed design) is held out for the check's fit.
ESTIMATION_FRACTION = 0.75
#: Degree of the input nonlinearity the test is designed for (the paper's f is
#: quadratic; the staircase then has degree + 2 = 4 levels).
DESIGN_DEGREE = 2


class JourneyError(CzmpcError, ValueError):
    """The journey cannot start (options or config that do not fit together)."""


@dataclass(frozen=True, kw_only=True)
class JourneyPlan:
    """What `commission` is asked to do.

    Parameters
    ----------
    range_pct :
        ``(lo, hi)``: the band of TRIAC inputs the test may visit [%].
    tau_s :
        Guess of the dominant time constant [s] (hold times and GBN switching).
    out_dir :
        Output directory.
    duration_s :
        Test length [plant s]; None: the shortest the design of ``kind`` accepts.
    kind :
        ``"mixed"`` (staircase + GBN), ``"steps"``, ``"gbn"`` or ``"multilevel"``
        (the short test for a slow plant, `sysid.design`).
    max_step_pct :
        Largest designed move per sample [%]; also the test's ramp rate.
    seed :
        Seed of the GBN part.
    switch_on :
        Continue with the MPC on the new model if the verdict is ``ready``.
    run_duration_s :
        Plant time the MPC runs after switch-on [s]; None: the config's
        ``[run] duration_s`` (None there too: until stopped).
    mc_runs :
        Plants of the check's closed-loop Monte Carlo.
    """

    range_pct: tuple[float, float]
    tau_s: float
    out_dir: Path
    duration_s: float | None = None
    kind: str = "mixed"
    max_step_pct: float = 100.0
    seed: int = 0
    switch_on: bool = False
    run_duration_s: float | None = None
    mc_runs: int = 20


@dataclass(frozen=True, kw_only=True, eq=False)
class JourneyResult:
    """What the journey did; ``stage`` says where it ended: ``"test aborted"``,
    ``"checked"`` (no switch-on asked or verdict not ready) or ``"switched on"``."""

    stage: str
    out_dir: Path
    report_path: Path
    test_summary: RunSummary
    model_path: Path | None = None
    check: ModelCheck | None = None
    fit_pct: float | None = None
    run_summary: RunSummary | None = None
    messages: tuple[str, ...] = field(default=())

    @property
    def ok(self) -> bool:
        """True when the journey reached a ``ready`` model (and ran it if asked)."""
        if self.stage == "test aborted" or self.check is None or self.check.verdict != "ready":
            return False
        return self.run_summary is None or not self.run_summary.failed


def design_spec(plan: JourneyPlan, ts_s: float) -> ExcitationSpec:
    """The test's design; the duration defaults to the shortest ``plan.kind`` accepts."""
    lo, hi = plan.range_pct
    common: dict[str, Any] = {"ts_s": ts_s, "lo_pct": lo, "hi_pct": hi, "tau_s": plan.tau_s,
                              "max_step_pct": plan.max_step_pct, "kind": plan.kind,
                              "degree": DESIGN_DEGREE}
    duration = plan.duration_s
    if duration is None:
        probe = ExcitationSpec(duration_s=2 * ts_s, **common)
        duration = ts_s * math.ceil(shortest_duration_s(probe) / ts_s)
    return ExcitationSpec(duration_s=duration, **common)


def split_estimation_validation(data: Dataset) -> tuple[Dataset, Dataset]:
    """First `ESTIMATION_FRACTION` of the samples and the rest (each at least 10 samples)."""
    n_est = int(round(ESTIMATION_FRACTION * data.n_samples))
    if n_est < 10 or data.n_samples - n_est < 10:
        raise JourneyError(f"the test log has {data.n_samples} usable samples; too few to "
                           "identify and hold out data (run a longer test)")
    return data.segment(0, n_est), data.segment(n_est, data.n_samples)


@dataclass(frozen=True, kw_only=True, eq=False)
class IdentifiedTest:
    """The model identified from a test log, and its fit on the held-out end.

    Attributes
    ----------
    model :
        The final model, in the log's units.
    pipeline :
        The whole pipeline result (`sysid.pipeline.PipelineResult`: every model,
        the findings, for the identification report).
    validation :
        The held-out samples (the last ``1 - ESTIMATION_FRACTION``).
    simulated_kw :
        The model's ballistic simulation over ``validation`` [output unit], its initial
        state fitted by least squares (`sysid.criteria.errors_with_fitted_state`: the
        held-out end of a test can start mid-ramp).
    fit_pct :
        MATLAB ``compare``'s fit on ``validation`` [%] (`sysid.criteria.fit_percent`);
        NaN for a constant held-out power.
    messages :
        The warnings of the identification, one line each.
    """

    model: HammersteinModel
    pipeline: Any
    validation: Dataset
    simulated_kw: np.ndarray
    fit_pct: float
    messages: tuple[str, ...]


def identify_test(data: Dataset, *,
                  progress: Callable[[str], None] | None = None) -> IdentifiedTest:
    """Identify a model from an open-loop test's log as the journey does (stage 3).

    The paper's pipeline on the first `ESTIMATION_FRACTION` of the samples (the rest is
    held out for the fit), with orders chosen on validation data (``orders="auto"``,
    degree `DESIGN_DEGREE`), at least one sample of delay (the loop reads the power
    before it writes the input), no level-shift repair (the designed steps are not
    sensor faults) and, without a steady window, the sample-mean operating point moved
    onto the steady-state curve (`sysid.offset`; unmoved, the order search chose
    pole-zero pairs near z = 1 with a static gain +-80 %).

    Raises
    ------
    JourneyError
        Too few samples to identify and hold out data.
    IdentificationError
        Data that support no model.
    """
    from sysid.pipeline import run_paper_pipeline

    est, val = split_estimation_validation(data)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = run_paper_pipeline(est, level_shift="none", orders="auto", degree=DESIGN_DEGREE,
                                    min_nk=1, means_on_steady_curve=True, progress=progress)
    if result.final is None:  # pragma: no cover - the pipeline raises instead
        raise JourneyError("identification produced no model")
    model = result.final.model.with_updates(units=Units(input=data.input_unit,
                                                        output=data.output_unit))
    simulated = val.power_kw - errors_with_fitted_state(model, val)
    constant = bool(np.all(val.power_kw == val.power_kw[0]))
    return IdentifiedTest(
        model=model, pipeline=result, validation=val, simulated_kw=simulated,
        fit_pct=math.nan if constant else fit_percent(val.power_kw, simulated),
        messages=tuple(f"identification: {w.category.__name__}: {w.message}" for w in caught))


def commission(config: RunConfig, plan: JourneyPlan, *,
               progress: Callable[[str], None] | None = None,
               command: str | None = None,
               run_status: Callable[[str], None] | None = None) -> JourneyResult:
    """Run the whole journey (module docstring); return what it did.

    Parameters
    ----------
    config :
        The run configuration (``[test]`` and ``[safety] safe_triac_pct`` required; a
        setpoint source required with ``switch_on``).
    plan :
        The options.
    progress :
        Called with a line per stage.
    command :
        The command line, recorded in the report.
    run_status :
        Live status of the loops (as `czmpc.runtime.loop.tty_status`).

    Raises
    ------
    JourneyError, ScheduleError, RunConfigError
        Options or config that do not fit (before anything is applied to the plant).
    """
    say = progress or (lambda _m: None)
    out = plan.out_dir
    out.mkdir(parents=True, exist_ok=True)
    for earlier in (out / "test_run.csv", out / "run.csv"):
        if earlier.exists():   # a run's log is its evidence: never written over
            raise JourneyError(f"{earlier} holds an earlier commissioning's log; give another "
                               "--out (or move that directory away)")
    if config.test_limits is None:
        raise ScheduleError("commission needs a [test] section in the run config: "
                            "power_band_kw = [LO, HI] (kW), max_bad_quality_s (s)")
    if plan.switch_on and config.setpoint_kw is None and config.schedule is None \
            and config.nodes.setpoint_kw is None:
        raise JourneyError("--switch-on needs a setpoint for the MPC: [run] setpoint_kw, "
                           "[run] schedule or [nodes] setpoint_kw")
    started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    # 1. design
    spec = design_spec(plan, config.ts_s)
    signal = design_test_signal(spec, np.random.default_rng(plan.seed))
    test_csv = out / "test.csv"
    rows = "".join(f"{t:.6g},{u:.6g}\n" for t, u in zip(signal.time_s, signal.triac_pct,
                                                       strict=True))
    atomic_write_text(test_csv, "time_s,triac_pct\n" + rows)
    schedule = InputSchedule(time_s=signal.time_s, triac_pct=signal.triac_pct,
                             source=str(test_csv), sha256=file_sha256(test_csv))
    say(f"1/5 designed the test: {spec.kind}, {schedule.duration_s:g} s of plant time, "
        f"{spec.lo_pct:g}..{spec.hi_pct:g} % -> {test_csv}")
    # 2. run the test
    test_cfg = dataclasses.replace(config, log_path=out / "test_run.csv")
    say(f"2/5 running the test through {config.endpoint} (time scale {config.time_scale:g}: "
        f"about {schedule.duration_s / config.time_scale:.0f} s of wall time)")
    loop = make_test_loop(test_cfg, schedule, status=run_status)
    test_summary = asyncio.run(loop.run())
    lead_in_s = (loop.ctrl.lead_in_samples - 1) * config.ts_s \
        if isinstance(loop.ctrl, ScheduleDriver) else 0.0
    messages: list[str] = []
    if test_summary.failed:
        messages.append(f"test aborted: {test_summary.abort_reason}")
        report = _write_report(out, config=config, plan=plan, signal=signal, schedule=schedule,
                               test_summary=test_summary, started=started, command=command)
        return JourneyResult(stage="test aborted", out_dir=out, report_path=report,
                             test_summary=test_summary, messages=tuple(messages))
    # 3. identify
    data = read_run_log(test_cfg.log_path)
    est, val = split_estimation_validation(data)
    say(f"3/5 identifying (orders auto) from {est.n_samples} samples; {val.n_samples} held out")
    identified = identify_test(data, progress=lambda m: say(f"    {m}"))
    messages += list(identified.messages)
    model, fit = identified.model, identified.fit_pct
    model_path = out / "model.json"
    save_model(model, model_path)
    from czmpc.reports.identification import write_report

    write_report(identified.pipeline, out / "identification", model_file="../model.json",
                 command=command)
    # 4. check
    settings = (MPCSettings.default_for(model) if config.settings_path is None
                else load_settings(config.settings_path, model))
    say(f"4/5 checking the model (held-out fit {fit:.1f} %, closed-loop Monte Carlo)")
    check = check_model(model, val, settings, mc_runs=plan.mc_runs,
                        model_sha256=file_sha256(model_path))
    write_check(check, model_path)   # the verdict beside the model: the switch-on rule reads it
    say(f"    verdict: {check.verdict}")
    # 5. report, 6. switch on
    run_summary: RunSummary | None = None
    stage = "checked"
    if plan.switch_on:
        run_cfg = dataclasses.replace(config, model_path=model_path, log_path=out / "run.csv",
                                      test_limits=None,
                                      duration_s=plan.run_duration_s or config.duration_s)
        try:
            opened = open_run(run_cfg, unattended=True)
        except DesignError as exc:   # a verdict that missed what the controller refuses
            messages.append(f"not switched on: the controller refuses the model: {exc}")
        else:
            if opened.switch_on.allowed:
                say(f"5/5 switching the MPC on with {model_path} (bumpless from the applied "
                    f"input); log {run_cfg.log_path}")
                run_loop = opened.loop(status=run_status, provenance={
                    "kind": "MPC run after commissioning", "closed_loop": True,
                    "commissioning": str(out)})
                run_summary = asyncio.run(run_loop.run())
                stage = "switched on"
            else:
                messages.append(f"not switched on: the verdict is {check.verdict!r}, not 'ready'")
    report = _write_report(out, config=config, plan=plan, signal=signal, schedule=schedule,
                           test_summary=test_summary, started=started, command=command,
                           lead_in_s=lead_in_s, data=data, identified=identified, check=check,
                           settings=settings, n_est=est.n_samples,
                           stage=stage, messages=messages)
    return JourneyResult(stage=stage, out_dir=out, report_path=report, test_summary=test_summary,
                         model_path=model_path, check=check, fit_pct=fit,
                         run_summary=run_summary, messages=tuple(messages))


def _equation(model: HammersteinModel) -> list[str]:
    op = model.operating_point
    return ["```", model_equation(model), f"ds = s - {op.triac_pct:g} %, dP = P - "
            f"{op.power_kw:g} kW; noise std(e) = {model.noise_std_kw:.4g} kW, Ts = {model.ts_s:g} s",
            "```"]


def _write_report(out: Path, *, config: RunConfig, plan: JourneyPlan, signal: ExcitationSignal,
                  schedule: InputSchedule, test_summary: RunSummary, started: str,
                  command: str | None, lead_in_s: float = 0.0, data: Dataset | None = None,
                  identified: IdentifiedTest | None = None, check: ModelCheck | None = None,
                  settings: MPCSettings | None = None, n_est: int = 0,
                  stage: str = "test aborted", messages: Sequence[str] = ()) -> Path:
    fig_dir = out / "figures"
    fig_dir.mkdir(exist_ok=True)
    limits = config.test_limits
    band = limits.power_band_kw if limits is not None else (math.nan, math.nan)
    lines = ["# Commissioning report", "",
             f"- started {started} UTC; plant {config.endpoint} (Ts {config.ts_s:g} s, time scale "
             f"{config.time_scale:g})", f"- config: `{config.source_path}`",
             f"- command: `{command}`" if command else "- called from Python", "",
             "## 1. Test design", "", f"Test file `test.csv` (SHA-256 `{schedule.sha256}`).", "",
             "```", signal.summary(), "```", "",
             "## 2. The test through the plant link", "",
             f"- {test_summary.n_steps} sample periods, {test_summary.n_writes} writes, "
             f"{test_summary.n_missing} missing samples ({test_summary.n_repeated} read twice: "
             "the plant's step came after the read), "
             f"{test_summary.n_overruns} overruns "
             f"({test_summary.n_skipped} periods skipped), {test_summary.n_reconnects} reconnects",
             f"- safety band {band[0]:g}..{band[1]:g} kW; stopped by: {test_summary.stopped_by}",
             "- log `test_run.csv` (provenance in `test_run.meta.json`)"]
    if test_summary.abort_reason is not None:
        lines += ["", f"**The test was aborted: {test_summary.abort_reason}.** The TRIAC was moved "
                  f"to {config.safe_triac_pct:g} % at the schedule's largest step per sample. "
                  "Nothing was identified; widen the band or narrow --range-pct and run again."]
    if data is not None:
        fig = figures.experiment_figure(
            fig_dir / "test.png", data.time_s, data.triac_pct, data.power_kw, band_kw=band,
            schedule_time_s=signal.time_s + lead_in_s,
            schedule_triac_pct=signal.triac_pct)
        lines += ["", f"![the test: input and measured power](figures/{fig.name})"]
    if identified is not None:
        val, fit = identified.validation, identified.fit_pct
        lines += ["", "## 3. Identification", "",
                  f"From the first {n_est} of {data.n_samples if data else 0} usable samples "
                  f"({data.n_segments if data else 0} segment(s)); orders chosen automatically "
                  "on validation data; no level-shift repair (the designed steps are not "
                  "sensor faults). Full report: [identification/report.md]"
                  "(identification/report.md). Model `model.json`:", "", *_equation(identified.model), "",
                  *[f"- {m}" for m in messages if m.startswith("identification:")], "",
                  "## 4. Fit on held-out data", "",
                  f"The last {val.n_samples} samples, simulated with their initial state "
                  f"fitted by least squares (ballistic, as MATLAB `compare`): fit "
                  f"**{fit:.1f} %**."]
        fig = figures.fit_figure(fig_dir / "fit.png", val.time_s, val.power_kw,
                                 identified.simulated_kw, fit_pct=fit)
        lines += ["", f"![held-out fit](figures/{fig.name})"]
    if check is not None:
        lines += ["", "## 5. Check-model verdict", "", f"**{check.verdict}**", ""]
        lines += [f"- {r}" for r in check.reasons] or ["- (no reasons given)"]
        lines += ["", "| check | status | detail |", "| --- | --- | --- |"]
        lines += [f"| {i.name} | {i.status} | {i.detail} |" for i in check.items]
        if check.monte_carlo is not None and check.monte_carlo.iae_ratios:
            fig = figures.monte_carlo_figure(fig_dir / "monte_carlo.png",
                                             check.monte_carlo.iae_ratios)
            lines += ["", f"![closed-loop Monte Carlo](figures/{fig.name})"]
    if settings is not None:
        lines += ["", "## 6. Controller settings chosen", "",
                  "The config's [controller] settings file if it names one, else "
                  "`MPCSettings.default_for(model)` (with its rate limit).", "",
                  "| setting | value |", "| --- | --- |"]
        for f in dataclasses.fields(settings):
            value = getattr(settings, f.name)
            if not dataclasses.is_dataclass(value):
                lines.append(f"| {f.name} | {value} |")
    lines += ["", "## 7. Switch-on", ""]
    if stage == "switched on":
        lines.append("The MPC was switched on with `model.json` (log `run.csv`).")
    elif plan.switch_on:
        lines += [f"- {m}" for m in messages if not m.startswith("identification:")] \
            or ["- not switched on"]
    else:
        lines.append("Not asked (--switch-on not given). To run the MPC: put `model.json` in "
                     "[controller] model and run `czmpc run CONFIG.toml`.")
    path = out / "commissioning.md"
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


__all__ = ["DESIGN_DEGREE", "ESTIMATION_FRACTION", "JourneyError", "JourneyPlan", "JourneyResult",
           "commission", "design_spec", "fit_percent", "split_estimation_validation"]
